"""Closed-loop runs of the twin: a controller on a trace, with KPIs, a time series and a plot."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lcmesh.twin.controllers import Controller, Observation
from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS, guard, guardrail_report, spinup_action
from lcmesh.twin.kpi import KpiAccumulator
from lcmesh.twin.plant import Plant
from lcmesh.twin.traces import Trace

_K = 273.15
SERIES_KEYS = (
    "time_h", "wet_bulb_c", "blade_min_c", "blade_mean_c", "blade_max_c", "supply_temp_c", "supply_setpoint_c",
    "lw_setpoint_c", "ct_leaving_c", "ct_fan_kw", "pump_kw", "it_power_kw", "heat_rejected_kw", "cdu_flow_kg_s",
)  # fmt: skip


@dataclass
class RunResult:
    kpi: dict
    sim_seconds: float
    wall_seconds: float
    system: str
    trace: str
    controller: str
    controller_cost: dict | None = None  # a controller that simulates ahead: plant steps and seconds it took
    guardrails: dict = field(default_factory=lambda: {"guardrails": "off"})  # what the mesh's guardrails did
    decided_by: dict | None = None  # a controller that can fall back (the LLM): who made its decisions, and why not
    series: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    cabinet0: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    @property
    def realtime_factor(self) -> float:
        return self.sim_seconds / self.wall_seconds if self.wall_seconds > 0 else float("inf")

    def to_json(self) -> dict:
        return {
            "kpi": self.kpi,
            "sim_seconds": self.sim_seconds,
            "wall_seconds": self.wall_seconds,
            "realtime_factor": self.realtime_factor,
            "system": self.system,
            "trace": self.trace,
            "controller": self.controller,
            "guardrails": self.guardrails,
            **({"controller_cost": self.controller_cost} if self.controller_cost is not None else {}),
            **({"decided_by": self.decided_by} if self.decided_by is not None else {}),
        }


def run_twin(
    plant: Plant,
    trace: Trace,
    controller: Controller,
    *,
    n_steps: int | None = None,
    spinup_hours: float = 1.0,
    record_every: int = 1,
    on_step: Callable[[int], None] | None = None,
    score_from: int = 0,
    guardrails=MESH_GUARDRAILS,
) -> RunResult:
    """Run `controller` on `plant` over `trace` (from its first step), after a spin-up at its first row.

    With a spin-up the plant first restarts from the FMU's initial state (faults and deviations kept), so the
    result does not depend on what the plant ran before. With ``score_from = k`` the first k steps are a warm-up
    run by the same controller (its state carries over) and the KPIs cover the steps from k on.

    A controller with an ``attach(plant, trace)`` method (the look-ahead) gets both before the spin-up.

    ``guardrails``: the limits every action passes, as in the mesh (default: the mesh's own ``GuardrailLimits``
    through ``apply_guardrails``; lcmesh/twin/controllers/guarded.py); None runs the controller bare (the paper's
    setting). The result says which, and how often the guardrails clamped or rejected.
    """
    controller = guard(controller, plant.system, guardrails)
    n_steps = trace.n_steps if n_steps is None else min(n_steps, trace.n_steps)
    if not 0 <= score_from < n_steps:
        raise ValueError(f"`score_from` must be in 0..{n_steps - 1}, got {score_from}")
    attach = getattr(controller, "attach", None)
    if callable(attach):
        attach(plant, trace)
    power = np.zeros(plant.system.n_blade_groups)
    controller.reset()
    first = Observation(plant.out, float(trace.wet_bulb_k[0]), trace.blade_power_w(0, out=power), 0.0)
    if spinup_hours > 0:
        plant.restart()
        plant.spin_up(power, first.wet_bulb_k, spinup_action(controller, first), hours=spinup_hours)
    out = plant.reset()
    controller.reset()
    kpi = KpiAccumulator()
    kpi.start(out)
    rec = _Recorder(plant, n_steps, record_every)
    t0 = time.perf_counter()
    for k in range(n_steps):
        wet_bulb = float(trace.wet_bulb_k[k])
        trace.blade_power_w(k, out=power)
        action = controller.act(Observation(out, wet_bulb, power, k * trace.step_s))
        out = plant.step(power, wet_bulb, action)
        if k + 1 == score_from:
            kpi.start(out)  # the warm-up ends: KPIs from here
        if k >= score_from:
            kpi.add(out)
        if k % record_every == 0:
            rec.add(k * trace.step_s + trace.step_s, wet_bulb, out)
        if on_step is not None:
            on_step(k)
    wall = time.perf_counter() - t0
    return RunResult(
        kpi=kpi.result(),
        sim_seconds=(n_steps - score_from) * trace.step_s,
        wall_seconds=wall,
        system=plant.system.name,
        trace=trace.name,
        controller=getattr(controller, "name", type(controller).__name__),
        controller_cost=_controller_cost(controller),
        guardrails=guardrail_report(controller),
        decided_by=_decided_by(controller),
        series=rec.series(),
        cabinet0=rec.cabinet0(),
    )


def _decided_by(controller: Controller) -> dict | None:
    """A controller that may hand decisions to a fallback reports who decided (``decided_by()``), else None."""
    report = getattr(controller, "decided_by", None)
    return report() if callable(report) else None


def _controller_cost(controller: Controller) -> dict | None:
    """What a simulating controller reports of its own cost (``sim_steps``, ``wall_s``), else None."""
    if not hasattr(controller, "sim_steps"):
        return None
    return {"sim_steps": int(controller.sim_steps), "wall_s": float(getattr(controller, "wall_s", 0.0))}


class _Recorder:
    """Down-sampled time series for plots (cheap per step: a handful of reductions)."""

    def __init__(self, plant: Plant, n_steps: int, every: int):
        rows = n_steps // every + 1
        self._n = 0
        self._data = {k: np.zeros(rows) for k in SERIES_KEYS}
        B = plant.system.cabinets.branches
        self._cab = {k: np.zeros((rows, B)) for k in ("branch_temp_c", "branch_power_kw", "valve_fraction")}

    def add(self, time_s: float, wet_bulb_k: float, out) -> None:
        i, d = self._n, self._data
        temps = out["blade_temp_k"]
        d["time_h"][i] = time_s / 3600.0
        d["wet_bulb_c"][i] = wet_bulb_k - _K
        d["blade_min_c"][i] = temps.min() - _K
        d["blade_mean_c"][i] = temps.mean() - _K
        d["blade_max_c"][i] = temps.max() - _K
        d["supply_temp_c"][i] = out["supply_temp_k"].mean() - _K
        d["supply_setpoint_c"][i] = out["applied_supply_setpoint_k"].mean() - _K
        d["lw_setpoint_c"][i] = out["applied_lw_setpoint_k"].mean() - _K
        d["ct_leaving_c"][i] = out["ct_leaving_temp_k"].mean() - _K
        d["ct_fan_kw"][i] = out["ct_fan_power_w"] / 1e3
        d["pump_kw"][i] = out["pump_power_w"] / 1e3
        d["it_power_kw"][i] = out["it_power_w"] / 1e3
        d["heat_rejected_kw"][i] = out["heat_rejected_w"] / 1e3
        d["cdu_flow_kg_s"][i] = out["secondary_flow_kg_s"].mean()
        self._cab["branch_temp_c"][i] = out["branch_temp_k"][0] - _K
        self._cab["branch_power_kw"][i] = out["branch_power_w"][0] / 1e3
        self._cab["valve_fraction"][i] = out["applied_valve_fraction"][0]
        self._n += 1

    def series(self) -> dict[str, np.ndarray]:
        return {k: v[: self._n] for k, v in self._data.items()}

    def cabinet0(self) -> dict[str, np.ndarray]:
        return {k: v[: self._n] for k, v in self._cab.items()}


def plot_run(result: RunResult, path: str | Path) -> Path:
    """A four-panel PNG: blade temperatures, power, setpoints, cabinet 1's branches and valves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s, c = result.series, result.cabinet0
    t = s["time_h"]
    fig, axes = plt.subplots(4, 1, figsize=(11, 12), sharex=True)
    ax = axes[0]
    ax.fill_between(t, s["blade_min_c"], s["blade_max_c"], alpha=0.3, label="blade groups min-max")
    ax.plot(t, s["blade_mean_c"], label="mean")
    ax.axhline(20, color="k", ls=":", lw=0.8)
    ax.axhline(40, color="r", ls=":", lw=0.8, label="20-40 C band")
    ax.set_ylabel("blade temp (C)")
    g = result.guardrails
    guard_note = "no guardrails" if g["guardrails"] == "off" else f"guardrails clamped {g['clamped_steps_pct']:.0f} %"
    ax.set_title(
        f"{result.system} | {result.trace} | {result.controller}: d_blade {result.kpi['d_blade_pct']:.1f} %, "
        f"CT {result.kpi['ct_power_kw_avg']:.1f} kW, hottest {result.kpi['blade_temp_max_c']:.1f} C, {guard_note}"
        + (f"\n{result.decided_by['summary']}" if result.decided_by else "")
    )
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[1]
    ax.plot(t, s["ct_fan_kw"], label="tower fans")
    ax.plot(t, s["pump_kw"], label="pumps")
    ax.set_ylabel("power (kW)")
    ax2 = ax.twinx()
    ax2.plot(t, s["it_power_kw"], color="gray", alpha=0.6, label="IT load")
    ax2.set_ylabel("IT load (kW)")
    ax.legend(loc="upper left", fontsize=8)
    ax2.legend(loc="upper right", fontsize=8)
    ax = axes[2]
    ax.plot(t, s["supply_setpoint_c"], label="CDU supply setpoint (mean)")
    ax.plot(t, s["supply_temp_c"], label="CDU supply (mean)")
    ax.plot(t, s["lw_setpoint_c"], label="tower leaving-water setpoint")
    ax.plot(t, s["ct_leaving_c"], label="tower leaving water")
    ax.plot(t, s["wet_bulb_c"], label="wet bulb", color="k", lw=0.8)
    ax.set_ylabel("temperature (C)")
    ax.legend(loc="upper right", fontsize=8, ncol=2)
    ax = axes[3]
    for j in range(c["valve_fraction"].shape[1]):
        (line,) = ax.plot(t, c["valve_fraction"][:, j], label=f"valve {j + 1}")
        total = c["branch_power_kw"].sum(axis=1)
        share = np.divide(c["branch_power_kw"][:, j], total, out=np.zeros_like(total), where=total > 0)
        ax.plot(t, share, ls="--", color=line.get_color(), alpha=0.6, label=f"power share {j + 1}")
    ax.set_ylabel("cabinet 1 fraction")
    ax.set_xlabel("time (h)")
    ax.legend(loc="upper right", fontsize=8, ncol=3)
    return save_figure(fig, path, dpi=90)


def save_figure(fig, path: Path | str, dpi: int) -> Path:
    """Lay out, write (making the folder) and close a matplotlib figure; returns the path written."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
