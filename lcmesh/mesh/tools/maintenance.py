"""Model-based fault detection for the Maintenance agent: residuals from the toolbox, CUSUM, persistence, trends.

Each check compares what the plant reports with what the twin's own equations expect (docs/maintenance.md):

- pump_degradation: head the CDU pump should give at its measured speed (fitted curve, affinity laws) vs
  the head its measured flow needs through the loop resistance; a CUSUM on the missing head fraction.
- sensor_bias: the supply temperature the CDU heat balance implies (return temperature, heat moved, flow
  and the supply volume's energy balance) vs the supply sensor; a two-sided CUSUM on the difference.
- valve_stuck: the primary valve's PI loop must move the valve while the measured supply is outside the
  deadband and the valve is not at a stop; a valve that stays put accumulates the travel it owed.
- cell_out: the tower stages its first `cells_active` cells; a staged cell that neither runs its fan nor
  rejects heat, a cell that stops without the stage-down condition, or a stage-up blocked past its delay.
- overtemperature and trend: the hottest branch above the limit, or a rising trend (slope CI above zero)
  that reaches it within the horizon, fitted only after a warm-up (a start-up transient is not a trend);
  pump head-loss trends predict when the dp setpoint is lost.

The model is not the plant (its parameters are the description's, not the plant's): the two model residuals
(pump, sensor bias) are checked against their healthy values learned over a commissioning window after a
start (`baseline_learn_s`), which then follow slow drift (fouling, sensor drift) while nothing shifts; the
model's own zero is checked only with an allowance for how far a plant may be off its description. The
detector never reads the plant's true parameters, only its outputs.

A finding is raised after `persistence_steps` consecutive steps of evidence and stays active until its
clear condition holds for `clear_steps` steps. Locations, texts and the `branch` evidence count from 1, as a
person reads them (``cabinet_3`` is the third cabinet, ``tower_1/cell_2`` the first tower's second cell);
the detector's arrays stay 0-based.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Literal, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lcmesh.mesh.tools import stats, thermo
from lcmesh.mesh.tools.maintenance_text import DESCRIBE
from lcmesh.twin.system import SystemDescription

if TYPE_CHECKING:
    from lcmesh.twin.plant import PlantAction

FAULT_KINDS = ("pump_degradation", "valve_stuck", "cell_out", "sensor_bias")
FINDING_KINDS = (*FAULT_KINDS, "overtemperature", "trend")
_TREND_EVERY = 4  # refit the temperature trends every 4 updates (1 min at 15 s)
_PUMP_TREND_EVERY = 40  # sample the head-loss history every 40 updates (10 min)
Kind = Literal["pump_degradation", "valve_stuck", "cell_out", "sensor_bias", "overtemperature", "trend"]


class Finding(BaseModel):
    """One health finding: what, where, how bad, the numbers behind it and what to do."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Kind
    severity: Literal["info", "warning", "critical"]
    location: str
    message: str
    evidence: dict[str, float]
    prescription: str
    predicted_failure_s: float | None = Field(default=None, description="seconds from now until the limit")
    first_seen_s: float
    time_s: float


class DetectorConfig(BaseModel):
    """Thresholds of the fault detector; the defaults hold the benchmark's false-alarm target."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    persistence_steps: int = Field(2, ge=1, le=100, description="steps of evidence before a finding is raised")
    clear_steps: int = Field(20, ge=1, le=10_000, description="steps without evidence before a fault clears")
    condition_clear_steps: int = Field(40, ge=1, le=10_000, description="the same for overtemperature and trend")
    max_gap_s: float = Field(120.0, gt=0, description="a longer gap between updates restarts the dynamic checks")
    noise_k_sigma: float = Field(1.0, ge=0, description="CUSUM allowances are at least this x the residual noise")
    noise_h_sigma: float = Field(8.0, ge=0, description="CUSUM thresholds are at least this x the residual noise")
    baseline_learn_s: float = Field(3600.0, ge=0, description="commissioning: learn each residual's healthy mean "
                                    "over this much operation after a start (0: the model's own zero)")
    baseline_tau_s: float = Field(3 * 3600.0, ge=0, description="then follow slow drift (fouling, sensor drift) with "
                                  "this time constant while no shift builds up (0: hold)")
    pump_model_tolerance: float = Field(0.25, ge=0, description="head-loss allowance vs the described curve itself "
                                        "(a pump curve 20 % off its description), checked from the first step")
    bias_model_tolerance_k: float = Field(1.2, ge=0, description="the same for the supply-sensor residual, K "
                                          "(sensor offsets and drift)")
    pump_cusum_k: float = Field(0.04, ge=0, description="allowance on the head-loss fraction")
    pump_cusum_h: float = Field(0.25, gt=0, description="CUSUM threshold (head-loss fraction x steps)")
    pump_clear_head_loss: float = Field(0.03, ge=0, description="smoothed head loss below which it clears")
    bias_cusum_k: float = Field(0.2, ge=0, description="allowance on the supply-sensor residual, K")
    bias_cusum_h: float = Field(1.5, gt=0, description="CUSUM threshold, K x steps")
    bias_clear_k: float = Field(0.15, ge=0, description="smoothed residual below which it clears, K")
    bias_max_return_rate_k_per_min: float = Field(4.0, gt=0, description="a faster-changing return temperature "
                                                  "skips the step (the balance assumes a steady change)")
    valve_error_margin_k: float = Field(0.15, ge=0, description="error beyond the PID deadband that must move it")
    valve_margin_sigma: float = Field(3.0, ge=0, description="that margin is at least this x the error's noise")
    valve_move_min: float = Field(0.015, gt=0, description="valve travel per step that counts as moving")
    valve_owed_travel: float = Field(0.25, gt=0, description="travel the PI owed while the valve stood still")
    valve_min_steps: int = Field(3, ge=1, description="steps standing still before it can be flagged")
    cell_running_fraction: float = Field(0.01, gt=0, lt=1, description="of nominal fan power or design heat")
    cell_stage_slack_s: float = Field(60.0, ge=0, description="slack on the tower staging delay")
    overtemp_warning_k: float = Field(313.15, description="hottest branch above this: warning (40 C)")
    overtemp_critical_k: float = Field(318.15, description="hottest branch above this: critical (45 C)")
    overtemp_hysteresis_k: float = Field(1.0, ge=0, description="clears this far below the warning limit")
    trend_window_s: float = Field(1800.0, gt=0, description="history the temperature trend is fitted on")
    trend_horizon_s: float = Field(1800.0, gt=0, description="warn when the limit is this close")
    trend_min_slope_k_per_s: float = Field(0.02 / 60, ge=0, description="slower rises are not reported")
    trend_min_r2: float = Field(0.8, ge=0, le=1, description="how steady the rise must be (R^2 of the fit)")
    trend_warmup_s: float = Field(1800.0, ge=0, description="no trend is fitted until this much plant time after "
                                  "the detector's first sample (a run's start, a restarted agent): a start-up "
                                  "transient is not a trend")
    pump_trend_window_s: float = Field(7200.0, gt=0, description="history the head-loss trend is fitted on")
    pump_trend_horizon_s: float = Field(7 * 86400.0, gt=0, description="predict pump failures this far ahead")


class _Latch:
    """Persistence / clear counters over every (kind, location) slot of the detector."""

    def __init__(self, n: int):
        self.evidence_run = np.zeros(n, dtype=int)
        self.clear_run = np.zeros(n, dtype=int)
        self.active = np.zeros(n, dtype=bool)
        self.first_seen_s = np.full(n, np.nan)

    def update(self, time_s: float, evidence: np.ndarray, clear: np.ndarray, persistence: int, clear_steps: np.ndarray):
        """Advance the counters; returns the mask of slots raised by this step."""
        self.evidence_run = np.where(evidence, self.evidence_run + 1, 0)
        self.clear_run = np.where(clear & ~evidence, self.clear_run + 1, 0)
        raised = ~self.active & (self.evidence_run >= persistence)
        self.first_seen_s = np.where(raised, time_s, self.first_seen_s)
        self.active = (self.active | raised) & (self.clear_run < clear_steps)
        return raised


class _Ring:
    """A fixed-size history of (time, channels) samples, oldest first on read."""

    def __init__(self, size: int, channels: int):
        self.t = np.full(size, np.nan)
        self.y = np.full((size, channels), np.nan)
        self.i = 0

    def add(self, time_s: float, y: np.ndarray) -> None:
        k = self.i % self.t.size
        self.t[k], self.y[k] = time_s, y
        self.i += 1

    def since(self, t_min: float) -> tuple[np.ndarray, np.ndarray]:
        keep = np.isfinite(self.t) & (self.t >= t_min)
        order = np.argsort(self.t[keep])
        return self.t[keep][order], self.y[keep][order]


class _Baseline:
    """A residual's healthy mean per location: learned during commissioning, then following slow drift.

    Commissioning: the plain mean of the samples fit to learn from, until ``learn_s`` of them have been
    seen (``ready``). After it, an EWMA with time constant ``tau_s`` while the caller calls the location
    quiet (its CUSUM in control, no active finding), so fouling and sensor drift are followed while a
    fault, which drives the CUSUM up within a few steps, freezes it. ``learn_s = 0``: ready at once, from
    0 (the model's own zero).
    """

    def __init__(self, n: int, learn_s: float, tau_s: float):
        self.learn_s, self.tau_s = learn_s, tau_s
        self.value = np.zeros(n)
        self.seen_s = np.zeros(n)
        self._sum = np.zeros(n)
        self._count = np.zeros(n)

    @property
    def ready(self) -> np.ndarray:
        return self.seen_s >= self.learn_s

    def update(self, residual: np.ndarray, dt_s: float, learn: np.ndarray, quiet: np.ndarray) -> None:
        commissioning = ~self.ready
        take = commissioning & learn
        self._sum += np.where(take, residual, 0.0)
        self._count += take
        self.seen_s += np.where(take, dt_s, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(self._count > 0, self._sum / np.maximum(self._count, 1), 0.0)
        follow = ~commissioning & quiet & (self.tau_s > 0)
        alpha = 1.0 - np.exp(-dt_s / self.tau_s) if self.tau_s > 0 else 0.0
        self.value = np.where(commissioning, mean, np.where(follow, self.value + alpha * (residual - self.value),
                                                             self.value))  # fmt: skip


class _Checked(NamedTuple):
    alarm: np.ndarray  # evidence this step
    size: np.ndarray  # the fault's size: since commissioning once learned, else against the model
    smooth: np.ndarray  # EWMA of the residual against the model
    baseline: np.ndarray  # the learned healthy residual (0 until learned)
    learned: np.ndarray  # commissioning is over


class _ResidualCheck:
    """One model residual per location, zero for a healthy plant that is its model, checked twice.

    Against the model's own zero with the allowance `model_tolerance` (how far a plant may be off its
    description), from the first step: gross faults, also during commissioning. Against the healthy
    baseline learned at commissioning (:class:`_Baseline`) with the tight allowance `k`, once learned.
    Both are CUSUMs with threshold `h`, allowances and threshold scaled up with the residual's noise.
    """

    def __init__(self, n: int, cfg: DetectorConfig, k: float, h: float, model_tolerance: float, smoothing: float,
                 upward_only: bool):  # fmt: skip
        self.cfg, self.k, self.h, self.model_tolerance, self.upward_only = cfg, k, h, model_tolerance, upward_only
        self.cusum = stats.Cusum(k, h, (n,))
        self.model_cusum = stats.Cusum(model_tolerance, h, (n,))
        self.baseline = _Baseline(n, cfg.baseline_learn_s, cfg.baseline_tau_s)
        self.noise = stats.MovingRangeSigma(0.02)  # so noisier sensors need larger faults, not raise alarms
        self.ewma = stats.Ewma(smoothing)

    def update(self, residual: np.ndarray, valid: np.ndarray, dt_s: float, active: np.ndarray) -> _Checked:
        """One step; `active`: the locations with an active finding (their baseline holds)."""
        noise = self.noise.update(np.where(valid, residual, np.nan))
        residual = np.where(valid, residual, 0.0)
        _scale(self.model_cusum, self.model_tolerance, self.h, noise, self.cfg)
        _scale(self.cusum, self.k, self.h, noise, self.cfg)
        ready = self.baseline.ready
        model_alarm = _masked_cusum(self.model_cusum, residual, valid)
        alarm = _masked_cusum(self.cusum, residual - self.baseline.value, valid & ready)
        if self.upward_only:
            model_alarm &= self.model_cusum.pos > self.model_cusum.neg
            alarm &= self.cusum.pos > self.cusum.neg
        model_quiet = (self.model_cusum.pos == 0) & (self.model_cusum.neg == 0)
        self.baseline.update(residual, dt_s, valid & model_quiet, valid & _in_control(self.cusum) & ~active)
        previous = self.ewma.value if self.ewma.value is not None else residual
        smooth = self.ewma.update(np.where(valid, residual, previous))
        baseline = np.where(ready, self.baseline.value, 0.0)
        size = np.where(ready, _estimate(self.cusum, smooth - baseline), _estimate(self.model_cusum, smooth))
        return _Checked(alarm | model_alarm, size, smooth, baseline, ready.astype(float))


class FaultDetector:
    """Watches plant outputs step by step and keeps the set of active findings (see the module docstring)."""

    def __init__(self, system: SystemDescription, config: DetectorConfig | None = None):
        self.system = system
        self.config = config or DetectorConfig()
        self.pump = thermo.CduPumpModel.from_system(system)
        self.C, self.B = system.cabinets.count, system.cabinets.branches
        self.N, self.m = system.towers.count, system.towers.cells
        self._shapes = {
            "pump_speed": (self.C,), "secondary_flow_kg_s": (self.C,), "supply_temp_measured_k": (self.C,),
            "return_temp_k": (self.C,), "cdu_heat_w": (self.C,), "primary_valve": (self.C,),
            "applied_supply_setpoint_k": (self.C,), "applied_dp_setpoint_pa": (self.C,),
            "branch_max_temp_k": (self.C, self.B), "fan_speed": (self.N,), "cells_active": (self.N,),
            "cell_fan_power_w": (self.N, self.m), "cell_heat_w": (self.N, self.m), "approach_k": (self.N,),
        }  # fmt: skip
        self.reset()

    def reset(self) -> None:
        """Forget all history and findings."""
        C, N, m, cfg = self.C, self.N, self.m, self.config
        sizes = {"pump_degradation": C, "sensor_bias": C, "valve_stuck": C, "cell_out": N * m,
                 "overtemperature": C, "trend": C}  # fmt: skip
        self._slot_kind = [kind for kind, n in sizes.items() for _ in range(n)]
        self._slot_index = [i for n in sizes.values() for i in range(n)]
        self._slot_start = dict(zip(sizes, np.cumsum([0, *sizes.values()])))
        clear = {"valve_stuck": 1, "cell_out": 4,  # a moving valve, a running cell: plain facts
                 "overtemperature": cfg.condition_clear_steps, "trend": cfg.condition_clear_steps}  # fmt: skip
        self._clear_steps = np.array([clear.get(k, cfg.clear_steps) for k in self._slot_kind])
        self._latch = _Latch(len(self._slot_kind))
        self._pump = _ResidualCheck(C, cfg, cfg.pump_cusum_k, cfg.pump_cusum_h, cfg.pump_model_tolerance,
                                    smoothing=0.2, upward_only=True)  # fmt: skip
        self._bias = _ResidualCheck(C, cfg, cfg.bias_cusum_k, cfg.bias_cusum_h, cfg.bias_model_tolerance_k,
                                    smoothing=0.1, upward_only=False)  # fmt: skip
        self._supply_noise = stats.MovingRangeSigma(0.02)  # of the measured supply: the stuck-valve margin
        self._valve_owed = np.zeros(C)
        self._valve_still = np.zeros(C, dtype=int)
        self._cell_suspect = np.zeros((N, m), dtype=bool)
        self._stage_up_s = np.zeros(N)
        self._stage_down_s = np.zeros(N)
        self._prev: dict[str, np.ndarray] | None = None
        self._first_time_s: float | None = None
        self._last_time_s: float | None = None
        step = self.system.step_s
        self._hot_history = _Ring(int(cfg.trend_window_s / step) + 2, C)
        self._loss_history = _Ring(int(cfg.pump_trend_window_s / step / _PUMP_TREND_EVERY) + 2, C)
        self._n_updates = 0
        self._trend_evidence = np.zeros(C, bool)
        self._trend_clear = np.ones(C, bool)
        zeros = np.zeros(C)
        self._valve_free = np.ones(C, dtype=bool)
        self._pump_smooth = np.zeros(C)
        self._ev: dict[str, dict[str, np.ndarray]] = {k: {} for k in sizes}
        self._ev["pump_degradation"].update(time_to_limit_s=np.full(C, np.inf), head_loss_slope_per_h=zeros)
        self.findings: list[Finding] = []
        self.last_raised: list[Finding] = []
        self.ignored_updates = 0
        self.restarts = 0

    # --- the step ----------------------------------------------------------------------------
    def update(
        self, time_s: float, out: Mapping[str, np.ndarray], wet_bulb_k: float, action: PlantAction | None = None
    ) -> list[Finding]:
        """Take one step's outputs (shaped like ``Plant.out``); returns the findings active after it.

        `action` is the action applied in the step (used only if `out` lacks the ``applied_*`` setpoints).
        A repeated or slightly older `time_s` (a late message) is ignored and counted in ``ignored_updates``;
        a jump back by more than ``max_gap_s`` is a restarted plant: the detector starts over (``restarts``).
        Non-finite readings leave that location's checks unchanged for the step.
        """
        if not np.isfinite(time_s):
            raise ValueError(f"`time_s` must be finite, got {time_s}")
        if self._last_time_s is not None and time_s <= self._last_time_s:
            if self._last_time_s - time_s <= self.config.max_gap_s:
                self.ignored_updates += 1
                self.last_raised = []
                return self.findings
            ignored, restarts = self.ignored_updates, self.restarts + 1
            self.reset()
            self.ignored_updates, self.restarts = ignored, restarts
        x = self._read(out, action)
        dt_s = None if self._last_time_s is None else time_s - self._last_time_s
        if dt_s is not None and dt_s > self.config.max_gap_s:
            self._prev, dt_s = None, None
        self._last_time_s = time_s
        if self._first_time_s is None:
            self._first_time_s = time_s
        cfg = self.config
        checks = {
            "pump_degradation": self._check_pump(x, dt_s),
            "sensor_bias": self._check_bias(x, dt_s),
            "valve_stuck": self._check_valve(x, dt_s),
            "cell_out": self._check_cells(x, dt_s, wet_bulb_k),
            "overtemperature": self._check_overtemperature(x),
            "trend": self._check_trends(time_s, x),
        }
        self._prev = x
        self._n_updates += 1
        evidence = np.concatenate([np.ravel(e) for e, _ in checks.values()])
        clear = np.concatenate([np.ravel(c) for _, c in checks.values()])
        raised = self._latch.update(time_s, evidence, clear, cfg.persistence_steps, self._clear_steps)
        self.findings = [self._finding(int(slot), time_s) for slot in np.flatnonzero(self._latch.active)]
        self.last_raised = [f for f, slot in zip(self.findings, np.flatnonzero(self._latch.active)) if raised[slot]]
        return self.findings

    def _active(self, kind: str) -> np.ndarray:
        """Which locations of `kind` have an active finding (as of the previous step)."""
        start = self._slot_start[kind]
        return self._latch.active[start : start + (self.N * self.m if kind == "cell_out" else self.C)]

    def _read(self, out: Mapping[str, np.ndarray], action: PlantAction | None) -> dict[str, np.ndarray]:
        x = {}
        fallbacks = {"applied_supply_setpoint_k": "supply_temp_setpoint_k", "applied_dp_setpoint_pa": "dp_setpoint_pa"}
        for name, shape in self._shapes.items():
            if name in out:
                value = np.asarray(out[name], dtype=float)
            elif name in fallbacks and action is not None:
                value = np.asarray(getattr(action, fallbacks[name]), dtype=float)
            else:
                raise ValueError(f"`out` lacks {name!r}; pass the plant outputs (lcmesh.twin.plant.OUTPUT_BLOCKS)")
            if value.shape != shape:
                raise ValueError(f"`out[{name!r}]` must have shape {shape}, got {value.shape}")
            x[name] = value.copy()
        return x

    # --- checks: each returns (evidence, clear) masks over its locations ----------------------
    def _check_pump(self, x, dt_s):
        cfg, ev = self.config, self._ev["pump_degradation"]
        speed, flow = x["pump_speed"], x["secondary_flow_kg_s"]
        loss = self.pump.head_loss(speed, flow)  # of the described curve's head
        valid = np.isfinite(loss) & (speed > 0.05)
        r = self._pump.update(loss, valid, dt_s or self.system.step_s, self._active("pump_degradation"))
        self._pump_smooth = r.smooth
        # the curve as commissioned: head x (1 - baseline), as the speed x sqrt(1 - baseline) gives
        commissioned_speed = speed * np.sqrt(np.maximum(1.0 - r.baseline, 0.0))
        ev.update(
            head_loss=r.size, head_loss_vs_curve=r.baseline + r.size, head_loss_baseline=r.baseline,
            baseline_learned=r.learned, head_loss_limit=self.pump.head_loss_limit(x["applied_dp_setpoint_pa"]),
            pump_speed=speed, flow_kg_s=flow, expected_flow_kg_s=self.pump.flow_kg_s(commissioned_speed),
        )  # fmt: skip
        return r.alarm, r.smooth - r.baseline < cfg.pump_clear_head_loss

    def _check_bias(self, x, dt_s):
        cfg, prev = self.config, self._prev
        if prev is None or dt_s is None:
            return np.zeros(self.C, bool), np.zeros(self.C, bool)
        flow = 0.5 * (x["secondary_flow_kg_s"] + prev["secondary_flow_kg_s"])
        mass_kg = self.system.cabinets.cdu.hx_secondary_volume_m3 * thermo.RHO_WATER_KG_M3
        t_meas, t_prev = x["supply_temp_measured_k"], prev["supply_temp_measured_k"]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_return = 0.5 * (x["return_temp_k"] + prev["return_temp_k"])
            hx_out = t_return - x["cdu_heat_w"] / (flow * thermo.CP_WATER_J_KG_K)
            # supply volume energy balance over the step: M dT/dt = m (T_hx_out - T_true), T_meas = T_true + bias
            residual = 0.5 * (t_meas + t_prev) - hx_out + mass_kg * (t_meas - t_prev) / (dt_s * flow)
        # the trapezoid over the step is exact for a steady change; a load burst heats the return faster than that
        steady = np.abs(x["return_temp_k"] - prev["return_temp_k"]) <= cfg.bias_max_return_rate_k_per_min * dt_s / 60
        valid = np.isfinite(residual) & (flow > 0.5) & steady
        residual = np.clip(np.where(valid, residual, 0.0), -10.0, 10.0)
        r = self._bias.update(residual, valid, dt_s, self._active("sensor_bias"))
        self._ev["sensor_bias"].update(
            bias_estimate_k=r.size, residual_baseline_k=r.baseline, baseline_learned=r.learned,
            measured_supply_k=t_meas, implied_supply_k=t_meas - r.size, setpoint_k=x["applied_supply_setpoint_k"],
        )  # fmt: skip
        return r.alarm, np.abs(r.smooth - r.baseline) < cfg.bias_clear_k

    def _check_valve(self, x, dt_s):
        cfg, cdu, prev = self.config, self.system.cabinets.cdu, self._prev
        if prev is None or dt_s is None:
            return np.zeros(self.C, bool), np.zeros(self.C, bool)
        error = x["supply_temp_measured_k"] - x["applied_supply_setpoint_k"]  # > 0: too warm, the PI opens
        # noise of the measured supply, not of the error: setpoint steps (G36, a valve stroke) are not noise
        margin = np.maximum(cfg.valve_error_margin_k,
                            cfg.valve_margin_sigma * self._supply_noise.update(x["supply_temp_measured_k"]))
        beyond = np.maximum(np.abs(error) - cdu.temp_deadband_k - margin, 0.0)
        valve = x["primary_valve"]
        at_stop = ((error > 0) & (valve >= 0.98)) | ((error < 0) & (valve <= cdu.valve_opening_min + 0.02))
        owed = cdu.temp_pid.k * beyond * dt_s / cdu.temp_pid.ti_s  # the PI's integral push over the step
        moved = np.abs(valve - prev["primary_valve"]) > cfg.valve_move_min
        still = ~moved & ~at_stop & (beyond > 0) & np.isfinite(valve) & np.isfinite(error)
        self._valve_still = np.where(still, self._valve_still + 1, np.where(moved, 0, self._valve_still))
        self._valve_owed = np.where(still, self._valve_owed + owed, np.where(moved | at_stop, 0.0, self._valve_owed))
        self._valve_free = moved | (self._valve_free & ~still)
        self._ev["valve_stuck"].update(valve_position=valve, supply_error_k=error, owed_travel=self._valve_owed,
                                       still_steps=self._valve_still)  # fmt: skip
        evidence = (self._valve_owed > cfg.valve_owed_travel) & (self._valve_still >= cfg.valve_min_steps)
        return evidence, self._valve_free

    def _running(self, x) -> np.ndarray:
        cfg, cell = self.config, self.system.towers.cell
        return (x["cell_fan_power_w"] > cfg.cell_running_fraction * cell.fan_power_nominal_w) | (
            x["cell_heat_w"] > cfg.cell_running_fraction * cell.design_heat_w
        )

    def _check_cells(self, x, dt_s, wet_bulb_k):
        cfg, tw = self.config, self.system.towers
        running = self._running(x)
        on = np.round(np.where(np.isfinite(x["cells_active"]), x["cells_active"], 0.0)).astype(int)
        staged = np.arange(self.m)[None, :] < on[:, None]
        # the twin runs the first `on` available cells: a staged cell standing while a later one runs is out
        later_runs = np.flip(np.cumsum(np.flip(running, 1), 1), 1) - running > 0
        self._cell_suspect |= staged & ~running & later_runs
        if self._prev is not None and dt_s is not None:
            prev_on = np.round(np.where(np.isfinite(self._prev["cells_active"]), self._prev["cells_active"], 0.0))
            # a healthy tower drops a cell only after its fans ran below the stage-down speed for the delay
            unexplained = (on < prev_on) & (self._stage_down_s < tw.stage_delay_s - cfg.cell_stage_slack_s)
            self._cell_suspect |= unexplained[:, None] & self._running(self._prev) & ~running
        speed, step_s = x["fan_speed"], dt_s or self.system.step_s
        # a stage-down speed of 0 is never undercut (cells once on stay on): then no drop is explained
        slow = (speed < tw.stage_down_speed + 0.02) if tw.stage_down_speed > 0 else np.zeros(self.N, bool)
        self._stage_down_s = np.where(slow & (on > 1), self._stage_down_s + step_s, 0.0)
        self._stage_up_s = np.where((speed > tw.stage_up_speed + 0.01) & (on < self.m), self._stage_up_s + step_s, 0.0)
        # a healthy tower stages another cell after the delay; if it cannot, every idle cell is unavailable
        blocked = self._stage_up_s >= tw.stage_delay_s + cfg.cell_stage_slack_s
        self._cell_suspect |= blocked[:, None] & ~running
        self._cell_suspect &= ~running
        rep = lambda a: np.repeat(a, self.m)  # noqa: E731  (per tower -> per cell)
        self._ev["cell_out"].update(
            fan_power_w=x["cell_fan_power_w"].ravel(), heat_w=x["cell_heat_w"].ravel(), cells_active=rep(on),
            fan_speed=rep(speed), stage_up_demand_s=rep(self._stage_up_s), tower_heat_w=rep(x["cell_heat_w"].sum(1)),
            approach_k=rep(x["approach_k"]), wet_bulb_k=np.full(self.N * self.m, float(wet_bulb_k)),
        )  # fmt: skip
        return self._cell_suspect.ravel(), running.ravel()

    def _check_overtemperature(self, x):
        cfg = self.config
        hot = np.where(np.isfinite(x["branch_max_temp_k"]), x["branch_max_temp_k"], -np.inf)
        hottest = hot.max(axis=1)  # the branch evidence is 1-based: alerts show it to people
        self._ev["overtemperature"].update(hottest_branch_temp_k=hottest, branch=hot.argmax(axis=1) + 1,
                                           limit_k=np.full(self.C, cfg.overtemp_warning_k))  # fmt: skip
        return hottest > cfg.overtemp_warning_k, hottest < cfg.overtemp_warning_k - cfg.overtemp_hysteresis_k

    def _check_trends(self, time_s, x):
        cfg = self.config
        hottest = x["branch_max_temp_k"].max(axis=1)
        self._hot_history.add(time_s, hottest)
        # Warm-up. The plant itself settles within minutes of a change (blades ~18 s = 1.5 MJ/K over 85 kW/K,
        # the HTW loop turns over in ~3 min, 45 m3 at 250 kg/s, cells stage after 5 min), but a run's start
        # also hands the spun-up plant (held at the trace's first row) to the controller and the trace: G36's
        # trim-and-respond walks its supply setpoint every 2 min (0.3 K a request) for 20-30 min, and the
        # hottest branches climb 1-5 K meanwhile. A 30 min trend fitted on the first 2 min of that predicted
        # 40 C on 4-5 of 5 cabinets at minute 2 (lcopt-5 after the mesh's 1 h spin-up, Frontier day and
        # synthetic:1000).
        # So the trend waits for a full window of its own history (default: trend_window_s) after the
        # detector's first sample; the overtemperature check is not delayed.
        warmed_up = time_s - self._first_time_s >= cfg.trend_warmup_s
        if warmed_up and self._n_updates % _TREND_EVERY == 0:
            t, y = self._hot_history.since(time_s - cfg.trend_window_s)
            ok = np.isfinite(y).all(axis=1)
            if ok.sum() >= 8:
                trend = stats.linear_trend(t[ok] - time_s, y[ok])
                eta = np.atleast_1d(stats.time_to_threshold(trend, cfg.overtemp_warning_k))
                now = np.atleast_1d(trend.predict(0.0))
                below = now < cfg.overtemp_warning_k
                rising = np.atleast_1d(trend.slope) > cfg.trend_min_slope_k_per_s
                straight = np.atleast_1d(trend.r2) >= cfg.trend_min_r2
                self._trend_evidence = below & rising & straight & (eta < cfg.trend_horizon_s)
                self._trend_clear = ~below | ~(eta < 2.0 * cfg.trend_horizon_s)
                self._ev["trend"].update(
                    slope_k_per_s=np.atleast_1d(trend.slope), slope_low_k_per_s=np.atleast_1d(trend.slope_low),
                    hottest_branch_temp_k=now, time_to_limit_s=eta, limit_k=np.full(self.C, cfg.overtemp_warning_k),
                )  # fmt: skip
        if self._n_updates % _PUMP_TREND_EVERY == 0:
            self._pump_trend(time_s)
        return self._trend_evidence, self._trend_clear

    def _pump_trend(self, time_s: float) -> None:
        """Head-loss trend per CDU pump: when does it reach the loss at which the dp setpoint is lost?"""
        ev = self._ev["pump_degradation"]
        self._loss_history.add(time_s, self._pump_smooth)
        t, y = self._loss_history.since(time_s - self.config.pump_trend_window_s)
        ok = np.isfinite(y).all(axis=1)
        if ok.sum() < 8 or t[ok][-1] - t[ok][0] < 0.25 * self.config.pump_trend_window_s:
            return
        trend = stats.linear_trend(t[ok] - time_s, y[ok])
        ev["time_to_limit_s"] = np.atleast_1d(stats.time_to_threshold(trend, ev["head_loss_limit"]))
        ev["head_loss_slope_per_h"] = np.atleast_1d(trend.slope) * 3600.0

    # --- findings ----------------------------------------------------------------------------
    def location(self, kind: str, i: int) -> str:
        """Where slot `i` of `kind` is, numbered from 1: ``cabinet_3``, ``tower_1/cell_2``."""
        if kind == "cell_out":
            tower, cell = divmod(i, self.m)
            return f"tower_{tower + 1}/cell_{cell + 1}"
        return f"cabinet_{i + 1}"

    def _finding(self, slot: int, time_s: float) -> Finding:
        kind, i = self._slot_kind[slot], self._slot_index[slot]
        d = {name: float(values[i]) for name, values in self._ev[kind].items()}
        severity, message, prescription, eta = DESCRIBE[kind](self, i, d)
        evidence = {name: value for name, value in d.items() if np.isfinite(value)}  # JSON has no inf
        # built from checked numbers only, so validation is skipped (this runs for every active finding, every step)
        return Finding.model_construct(
            kind=kind, severity=severity, location=self.location(kind, i), message=message, evidence=evidence,
            prescription=prescription, predicted_failure_s=eta, first_seen_s=float(self._latch.first_seen_s[slot]),
            time_s=float(time_s),
        )  # fmt: skip

    def active_out_cells(self, tower: int) -> int:
        """Cells of `tower` with an active cell_out finding."""
        start = self._slot_start["cell_out"] + tower * self.m
        return int(self._latch.active[start : start + self.m].sum())


def _masked_cusum(cusum: stats.Cusum, x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Update a CUSUM where `valid`; elsewhere keep its statistics as they were. Returns valid alarms."""
    names = ("pos", "neg", "n_pos", "n_neg")
    before = [getattr(cusum, n) for n in names]
    alarm = cusum.update(x)
    for name, old in zip(names, before):
        setattr(cusum, name, np.where(valid, getattr(cusum, name), old))
    return alarm & valid


def _in_control(cusum: stats.Cusum) -> np.ndarray:
    """No shift building up: both CUSUM statistics below half the threshold. A baseline follows every sample
    while this holds (not only the samples near it, which would bias it against a drift)."""
    return np.maximum(cusum.pos, cusum.neg) < 0.5 * cusum.h


def _scale(cusum: stats.Cusum, k: float, h: float, noise: np.ndarray, cfg: DetectorConfig) -> None:
    """Allowance and threshold of a CUSUM: the configured `k` and `h`, or more where the residual is noisier."""
    cusum.k = np.maximum(k, cfg.noise_k_sigma * noise)
    cusum.h = np.maximum(h, cfg.noise_h_sigma * noise)


def _estimate(cusum: stats.Cusum, smooth: np.ndarray, fresh_steps: int = 20) -> np.ndarray:
    """The size of a fault to report: right after a CUSUM alarm its shift estimate (the mean since the change,
    exact for a step), once the EWMA has caught up (or for a slow drift) the EWMA."""
    alarmed = np.maximum(cusum.pos, cusum.neg) > cusum.h
    fresh = np.where(cusum.pos >= cusum.neg, cusum.n_pos, cusum.n_neg) <= fresh_steps
    return np.where(alarmed & fresh, cusum.shift_estimate, smooth)


class ValveExercise:
    """A periodic stroke test of each CDU's primary valve (the maintenance practice of exercising valves).

    A valve stuck where its PI loop would hold it anyway changes nothing the detector can see. Every
    ``period_s`` each cabinet in turn (start times spread evenly over the period) gets its supply
    setpoint moved for ``steps`` plant steps: ``size_k`` below the measured supply (more cooling)
    unless the valve is nearly open or that would leave ``bounds_k``; then ``size_k`` above the
    measured supply (a valve pinned open by a supply that cannot reach its setpoint must close). A
    healthy valve follows within a step; a stuck one owes travel and the ``valve_stuck`` check flags
    it. ``period_s = 0`` turns it off.
    """

    def __init__(self, system: SystemDescription, period_s: float = 600.0, steps: int = 4, size_k: float = 1.5,
                 bounds_k: tuple[float, float] = (293.15, 313.15)):  # fmt: skip
        if period_s < 0 or steps < 1 or size_k <= 0:
            raise ValueError(f"valve exercise needs period_s >= 0, steps >= 1, size_k > 0; got {period_s}, {steps}, "
                             f"{size_k}")  # fmt: skip
        self.C, self.step_s = system.cabinets.count, system.step_s
        self.period_steps = int(round(period_s / self.step_s))
        if 0 < self.period_steps < steps:
            raise ValueError(f"valve exercise period {period_s} s is shorter than its {steps} steps")
        self.steps, self.size_k, self.bounds_k = steps, size_k, bounds_k
        self.offsets = (np.arange(self.C) * self.period_steps) // max(self.C, 1)
        self._target = np.full(self.C, np.nan)

    @property
    def enabled(self) -> bool:
        return self.period_steps > 0

    def under_test(self, step: int) -> np.ndarray:
        """(C,) bool: the cabinets whose valve is being exercised at plant step ``step``."""
        if not self.enabled:
            return np.zeros(self.C, dtype=bool)
        return (step - self.offsets) % self.period_steps < self.steps

    def stroked(
        self, step: int, action: "PlantAction", out: Mapping[str, np.ndarray]
    ) -> tuple["PlantAction", list[int]]:
        """A copy of ``action`` with this step's strokes, and the cabinets under test (``action`` itself when none is)."""
        if not self.under_test(step).any():
            return action, []
        copy = action.copy()
        return copy, self.apply(step, copy, out)

    def apply(self, step: int, action: "PlantAction", out: Mapping[str, np.ndarray]) -> list[int]:
        """Move the supply setpoints of the cabinets under test in ``action`` (in place); their indices.

        ``out``: the plant outputs (``primary_valve``, ``supply_temp_measured_k``). The target is set
        at a test's first step and held for its duration.
        """
        testing = self.under_test(step)
        if not testing.any():
            return []
        starting = testing & (((step - self.offsets) % self.period_steps == 0) | np.isnan(self._target))
        valve = np.nan_to_num(np.asarray(out["primary_valve"], dtype=float).reshape(self.C), nan=0.5)
        measured = np.asarray(out["supply_temp_measured_k"], dtype=float).reshape(self.C)
        measured = np.where(np.isfinite(measured), measured, action.supply_temp_setpoint_k)
        down = np.minimum(action.supply_temp_setpoint_k, measured) - self.size_k
        up = np.maximum(action.supply_temp_setpoint_k, measured) + self.size_k
        target = np.where((valve < 0.85) & (down >= self.bounds_k[0]), down, up)
        self._target = np.where(starting, np.clip(target, *self.bounds_k), self._target)
        action.supply_temp_setpoint_k[testing] = self._target[testing]
        self._target[~testing] = np.nan
        return np.flatnonzero(testing).tolist()
