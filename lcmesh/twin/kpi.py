"""KPIs of a run (LC-Opt Section 6, plus energy and actuator accounting), accumulated step by step."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

BLADE_LOWER_C, BLADE_UPPER_C = 20.0, 40.0
_K = 273.15


class KpiAccumulator:
    """Add one step at a time; `result()` gives the DESIGN.md KPI keys."""

    def __init__(self, lower_c: float = BLADE_LOWER_C, upper_c: float = BLADE_UPPER_C):
        self.lower_k, self.upper_k = lower_c + _K, upper_c + _K
        self.steps = 0
        self._in_band = 0
        self._samples = 0
        self._sums = dict.fromkeys(
            ("ct_fan", "it_cooling", "it_power", "pump", "heat_recovered", "blade_mean"), 0.0
        )
        self._blade_max = -np.inf
        self._energy0: tuple[float, float, float, float] | None = None
        self._energy1: tuple[float, float, float, float] | None = None
        self._travel = dict.fromkeys(("supply_temp_setpoint_k", "dp_setpoint_pa", "valve_fraction", "lw_setpoint_k"), 0.0)
        self._last_action: tuple[np.ndarray, ...] | None = None

    def start(self, out: Mapping[str, np.ndarray]) -> None:
        """Record the energy counters at the start of the run window."""
        self._energy0 = _energy(out)

    def add(self, out: Mapping[str, np.ndarray]) -> None:
        """One step's outputs; actuator travel is measured on the applied (post-clamp) setpoints."""
        temps = out["blade_temp_k"]
        self._in_band += int(np.count_nonzero((temps > self.lower_k) & (temps < self.upper_k)))
        self._samples += temps.size
        self._blade_max = max(self._blade_max, float(temps.max()))
        s = self._sums
        s["blade_mean"] += float(temps.mean())
        s["ct_fan"] += float(out["ct_fan_power_w"])
        s["it_cooling"] += float(out["it_cooling_w"])
        s["it_power"] += float(out["it_power_w"])
        s["pump"] += float(out["pump_power_w"])
        s["heat_recovered"] += float(out["heat_recovered_w"])
        applied = (
            out["applied_supply_setpoint_k"], out["applied_dp_setpoint_pa"],
            out["applied_valve_fraction"], out["applied_lw_setpoint_k"],
        )  # fmt: skip
        if self._last_action is not None:
            for key, now, before in zip(self._travel, applied, self._last_action):
                self._travel[key] += float(np.abs(now - before).sum())
        self._last_action = tuple(np.array(a) for a in applied)
        self._energy1 = _energy(out)
        self.steps += 1

    def result(self) -> dict:
        n = max(self.steps, 1)
        s = self._sums
        ct_kw, pump_kw = s["ct_fan"] / n / 1e3, s["pump"] / n / 1e3
        it_kw = s["it_power"] / n / 1e3
        cooling_kw = ct_kw + pump_kw
        return {
            "d_blade_pct": 100.0 * self._in_band / max(self._samples, 1),
            "ct_power_kw_avg": ct_kw,
            "it_cooling_kw_avg": s["it_cooling"] / n / 1e3,
            "it_power_kw_avg": it_kw,
            "pump_power_kw_avg": pump_kw,
            "cooling_power_kw_avg": cooling_kw,
            "pue_cooling": (it_kw + cooling_kw) / it_kw if it_kw > 0 else None,
            "heat_recovered_kw_avg": s["heat_recovered"] / n / 1e3,
            "blade_temp_mean_c": s["blade_mean"] / n - _K,
            "blade_temp_max_c": self._blade_max - _K,
            "energy_balance_error_pct": self.energy_balance_error_pct(),
            "actuator_travel": dict(self._travel),
            "steps": self.steps,
        }

    def energy_balance_error_pct(self) -> float | None:
        """(heat in - rejected - recovered - stored change) / heat in, over the run window, in %."""
        if self._energy0 is None or self._energy1 is None:
            return None
        e_in, e_rej, e_rec, e_store = (b - a for a, b in zip(self._energy0, self._energy1))
        return 100.0 * (e_in - e_rej - e_rec - e_store) / e_in if e_in > 0 else None


def _energy(out: Mapping[str, np.ndarray]) -> tuple[float, float, float, float]:
    return (
        float(out["energy_in_j"]), float(out["energy_rejected_j"]),
        float(out["energy_recovered_j"]), float(out["stored_energy_change_j"]),
    )  # fmt: skip


def cooling_energies_kwh(kpi: dict, hours: float) -> tuple[float, float]:
    """Tower-fan and pump energy (kWh) of a run of ``hours`` from its KPIs' mean powers."""
    return kpi["ct_power_kw_avg"] * hours, kpi["pump_power_kw_avg"] * hours
