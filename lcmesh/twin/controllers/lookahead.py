"""A look-ahead controller: the energy-optimal reference a benchmark measures the others against.

Every ``period_steps`` (8 = 2 min) it saves the FMU state, simulates candidate settings over the next
``horizon_steps`` (120 = 30 min) with the trace's actual future loads and wet bulb, restores the state
after each, and applies the best. 30 min: the tower, the HTW loop and the blades take that long to
answer, and with a 10-min band window the blades overshoot to 47 C on a load step. It knows the future
exactly (a perfect forecast) and runs the plant itself, so it is a ceiling for what a controller could
reach with this model, not a controller one could deploy; the mesh refuses it (no future to give it).

Objective, lexicographic: first the fewest blade-group-steps outside the 20-40 C band (counted as the
KPI counts them, no margin), then the least cooling energy (tower fans + all pumps, kWh): it minimises
cooling energy subject to the band, and rides the band's top.

A setting, held over the horizon and between decisions: a CDU supply setpoint and a dp setpoint per
cabinet, and one tower leaving water (the step's wet bulb + an approach). Valves follow branch power
every step (``rule.load_proportional_valves`` above the guardrails' floor, not searched). Every setpoint
moves toward its setting at most the guardrails' rate a step (``GuardrailLimits``: supply 2 K, dp 5 psi,
leaving water 2 K, leaving water >= wet bulb + 2.8 K and 10..45 C), in the rollouts as on the plant, so
the guardrails never clamp it.

The search, coordinate descent from the setting in force, ``passes`` times (a pass that moves nothing
ends it):

=============  ==========================================================  ================================
coordinate     probes (every cabinet alike)                                then
=============  ==========================================================  ================================
supply         in force + ``supply_moves_k`` (-4, -2, -1, +1, +2, +4 K),   each cabinet takes the highest
               inside 18..40 C                                             supply with its fewest out-of-band
dp             ``dp_psi`` (25, 27.5, 30, 33, 38 psi)                       each cabinet the lowest dp, ditto
approach       ``approaches_k`` (3, 5, 8, 10 K)                            the best of them
=============  ==========================================================  ================================

The cabinets couple only through the HTW loop, so one rollout per probe tells each cabinet's band; the
per-cabinet pick is then simulated and kept only if it is the best so far. A rollout stops as soon as it
can no longer beat the best (both terms only grow along it), except the probes, which need every cabinet's
count. ``search="grid"`` tries every probe combination (every cabinet alike) instead.

Its cost is counted: ``sim_steps`` (plant steps simulated since ``reset``) and ``wall_s`` (seconds
spent deciding), so a benchmark can state what the ceiling took (docs/controllers.md has the figures).
"""

from __future__ import annotations

import itertools
import math
import time
from typing import Literal

import numpy as np

from lcmesh.mesh.tools.guardrails import GuardrailLimits
from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.controllers.rule import load_proportional_valves
from lcmesh.twin.kpi import BLADE_LOWER_C, BLADE_UPPER_C
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.system import PSI_TO_PA, SystemDescription
from lcmesh.twin.traces import Trace

K = 273.15
RATE_MARGIN = 1.0 - 1e-6  # a ramp step a hair inside the rate limit: no clamp from rounding
NOT_ATTACHED = "lookahead needs the plant and the trace: run it with lcmesh twin run / bench, not in the mesh"
Setting = tuple[tuple[float, ...], tuple[float, ...], float]  # per-cabinet supply C, per-cabinet dp psi, approach K
Cost = tuple[int, float]  # blade-group-steps out of band, cooling kWh: compared in that order


class LookaheadController:
    """Receding-horizon search on the twin itself, with a perfect forecast: a ceiling, not a deployable controller."""

    name = "lookahead"
    version = "2"

    def __init__(
        self,
        system: SystemDescription,
        period_steps: int = 8,
        horizon_steps: int = 120,
        supply_moves_k: tuple[float, ...] = (-4.0, -2.0, -1.0, 0.0, 1.0, 2.0, 4.0),
        dp_psi: tuple[float, ...] = (25.0, 27.5, 30.0, 33.0, 38.0),
        approaches_k: tuple[float, ...] = (3.0, 5.0, 8.0, 10.0),
        passes: int = 2,
        search: Literal["coordinate", "grid"] = "coordinate",
        limits: GuardrailLimits | None = None,
    ):
        limits = GuardrailLimits() if limits is None else limits
        if period_steps < 1 or horizon_steps < 1 or passes < 1:
            raise ValueError(f"`period_steps`, `horizon_steps` and `passes` must be >= 1, "
                             f"got {period_steps}, {horizon_steps}, {passes}")  # fmt: skip
        if search not in ("coordinate", "grid"):
            raise ValueError(f"`search` must be 'coordinate' or 'grid', got {search!r}")
        if 0.0 not in supply_moves_k:
            raise ValueError(f"`supply_moves_k` must hold 0 (keep the setpoint), got {supply_moves_k}")
        dp_low, dp_high = limits.dp_min_pa / PSI_TO_PA, limits.dp_max_pa / PSI_TO_PA
        if not dp_psi or not all(dp_low - 1e-9 <= d <= dp_high + 1e-9 for d in dp_psi):
            raise ValueError(f"`dp_psi` must lie in the guardrails' {dp_low:g}..{dp_high:g} psi, got {dp_psi}")
        if not approaches_k or min(approaches_k) < limits.min_approach_k:
            raise ValueError(f"`approaches_k` must be >= the guardrails' minimum approach "
                             f"{limits.min_approach_k} K, got {approaches_k}")  # fmt: skip
        self.system, self.limits = system, limits
        self.period_steps, self.horizon_steps, self.passes = period_steps, horizon_steps, passes
        self.supply_moves_k = tuple(sorted(supply_moves_k))
        self.dp_psi, self.approaches_k = tuple(sorted(dp_psi)), tuple(sorted(approaches_k))
        self.search = search
        self.plant: Plant | None = None
        self.trace: Trace | None = None
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._action = PlantAction(np.zeros(C), np.zeros(C), np.full((C, B), 1.0 / B), np.zeros(N))
        self._power = np.zeros(system.n_blade_groups)
        self._lower_k, self._upper_k = BLADE_LOWER_C + K, BLADE_UPPER_C + K
        self._supply_range_c = (limits.supply_temp_min_k - K, limits.supply_temp_max_k - K)
        self._rates = [RATE_MARGIN * r for r in (limits.supply_temp_rate_k, limits.dp_rate_pa, limits.lw_rate_k)]
        self.reset()

    def attach(self, plant: Plant, trace: Trace) -> None:
        """The plant to simulate on and the trace whose future it reads (``run_twin`` calls this)."""
        if plant.system.n_blade_groups != self.system.n_blade_groups:
            raise ValueError(f"lookahead was made for {self.system.name!r}, the plant runs {plant.system.name!r}")
        self.plant, self.trace = plant, trace

    def reset(self) -> None:
        # the setting the search starts from: the description's supply setpoint, the lowest dp, a middle approach
        C = self.system.cabinets.count
        supply_c = float(self.system.cabinets.cdu.supply_temp_setpoint_k - K)
        self.setting: Setting = ((supply_c,) * C, (self.dp_psi[0],) * C, self.approaches_k[len(self.approaches_k) // 2])
        self._command: list | None = None  # setpoints last sent: supply K (C,), dp Pa (C,), leaving water K
        self._steps = 0
        self.sim_steps = 0
        self.decisions = 0
        self.wall_s = 0.0
        self.last_costs: dict[Setting, Cost] = {}

    def act(self, obs: Observation) -> PlantAction:
        if self.plant is None or self.trace is None:
            raise RuntimeError(NOT_ATTACHED)
        if self._command is None:  # ramp from what the plant applied; before its first step, from the setting
            self._command = _applied_setpoints(obs) or self._targets(self.setting, obs.wet_bulb_k)
        if self._steps % self.period_steps == 0:
            t0 = time.perf_counter()
            self.setting = self._decide(self._trace_step(obs))
            self.decisions += 1
            self.wall_s += time.perf_counter() - t0
        self._steps += 1
        return self._apply(self.setting, obs.blade_power_w, obs.wet_bulb_k, self._command)

    # --- search ------------------------------------------------------------------------------------------
    def _decide(self, k: int) -> Setting:
        plant = self.plant
        horizon = min(self.horizon_steps, self.trace.n_steps - k)
        n_done, start = plant.n_steps_done, plant.save_state()  # the state carries the inputs too
        search = _Search(self, start, k, horizon)
        try:
            best = search.run(self.setting)
        finally:
            plant.restore_state(start)
            plant.free_state(start)
            plant.n_steps_done = n_done
        self.last_costs = search.costs
        return best

    def _rollout(self, setting: Setting, k: int, horizon: int, bound: Cost) -> tuple[Cost, np.ndarray]:
        """Cost of holding `setting` for `horizon` steps from trace step `k` (the plant is at step k's start), and
        each cabinet's out-of-band count; stops early, with the cost so far, once that exceeds `bound`."""
        trace, plant, power = self.trace, self.plant, self._power
        command = [np.array(self._command[0]), np.array(self._command[1]), self._command[2]]
        by_cabinet = np.zeros(self.system.cabinets.count, dtype=int)
        out_of_band, cooling_j = 0, 0.0
        bound_oob, bound_j = bound[0], bound[1] * 3.6e6
        for t in range(k, k + horizon):
            wet_bulb = float(trace.wet_bulb_k[t])
            trace.blade_power_w(t, out=power)
            out = plant.step(power, wet_bulb, self._apply(setting, power, wet_bulb, command))
            self.sim_steps += 1
            temps = out["blade_temp_k"].reshape(by_cabinet.size, -1)
            outside = np.count_nonzero((temps <= self._lower_k) | (temps >= self._upper_k), axis=1)
            by_cabinet += outside
            out_of_band += int(outside.sum())
            cooling_j += (float(out["ct_fan_power_w"]) + float(out["pump_power_w"])) * plant.step_s
            if out_of_band > bound_oob or (out_of_band == bound_oob and cooling_j > bound_j):
                break
        return (out_of_band, cooling_j / 3.6e6), by_cabinet

    def _targets(self, setting: Setting, wet_bulb_k: float) -> list:
        """The setpoints `setting` asks for at this wet bulb, inside the guardrails' ranges."""
        supply_c, dp_psi, approach_k = setting
        lw_k = min(max(wet_bulb_k + approach_k, self.limits.lw_min_k), self.limits.lw_max_k)
        return [np.array(supply_c) + K, np.array(dp_psi) * PSI_TO_PA, lw_k]

    def _apply(self, setting: Setting, blade_power_w: np.ndarray, wet_bulb_k: float, command: list) -> PlantAction:
        """The action that moves `command` (updated in place) toward `setting` within the guardrails' limits."""
        supply_k, dp_pa, lw_k = self._targets(setting, wet_bulb_k)
        r_supply, r_dp, r_lw = self._rates
        command[0] += np.clip(supply_k - command[0], -r_supply, r_supply)
        command[1] += np.clip(dp_pa - command[1], -r_dp, r_dp)
        lw_k = command[2] + min(max(lw_k - command[2], -r_lw), r_lw)
        command[2] = max(lw_k, wet_bulb_k + self.limits.min_approach_k)  # the floor wins over the rate, as there
        a = self._action
        a.supply_temp_setpoint_k[:] = command[0]
        a.dp_setpoint_pa[:] = command[1]
        load_proportional_valves(self.system, blade_power_w, self.limits.valve_fraction_min, out=a.valve_fractions)
        a.lw_setpoint_k[:] = command[2]
        return a

    def _trace_step(self, obs: Observation) -> int:
        """The trace step `obs` is for; refuses an observation that does not match the attached trace."""
        trace = self.trace
        k = round(obs.time_s / trace.step_s)
        if not 0 <= k < trace.n_steps or abs(float(trace.wet_bulb_k[k]) - obs.wet_bulb_k) > 1e-9:
            raise RuntimeError(f"lookahead: the observation at {obs.time_s:g} s is not step {k} of the attached trace "
                               f"{trace.name!r}; attach the trace the run follows")  # fmt: skip
        return k


class _Search:
    """One decision's search: rollouts from the saved state, cached by setting, the best so far kept."""

    def __init__(self, ctl: LookaheadController, start, k: int, horizon: int):
        self.ctl, self.start, self.k, self.horizon = ctl, start, k, horizon
        self.costs: dict[Setting, Cost] = {}
        self.by_cabinet: dict[Setting, np.ndarray] = {}  # only for rollouts run to the end
        self.best: Setting | None = None
        self.best_cost: Cost = (math.inf, math.inf)

    def cost(self, setting: Setting, full: bool = False) -> Cost:
        """The setting's cost (`full`: run to the horizon's end, for every cabinet's count)."""
        if setting not in self.costs or (full and setting not in self.by_cabinet):
            self.ctl.plant.restore_state(self.start)
            bound = (math.inf, math.inf) if full else self.best_cost
            cost, by_cabinet = self.ctl._rollout(setting, self.k, self.horizon, bound)
            self.costs[setting] = cost
            if cost <= bound:  # not stopped early
                self.by_cabinet[setting] = by_cabinet
            if cost < self.best_cost:  # on a tie the one tried first (the setting in force) stays
                self.best, self.best_cost = setting, cost
        return self.costs[setting]

    def run(self, in_force: Setting) -> Setting:
        ctl = self.ctl
        low, high = ctl._supply_range_c
        current = (tuple(min(max(s, low), high) for s in in_force[0]), in_force[1], in_force[2])
        self.cost(current, full=True)
        if ctl.search == "grid":
            for move, dp, approach in itertools.product(ctl.supply_moves_k, ctl.dp_psi, ctl.approaches_k):
                self.cost((self._moved(current[0], move), (dp,) * len(current[1]), approach))
            return self.best
        for _ in range(ctl.passes):
            before = self.best
            self._supply_and_dp()
            centre = self.best
            for approach in ctl.approaches_k:
                self.cost((centre[0], centre[1], approach))
            if self.best == before:
                break
        return self.best

    def _supply_and_dp(self) -> None:
        """Probe supply moves x dp levels, every cabinet alike, dp rising; then each cabinet's pick, together.

        A cabinet picks the probe with its fewest out-of-band blade-steps and, among those, the least cooling
        energy (the plant's: energy is not counted per cabinet).
        """
        centre = self.best
        picks = [(math.inf, math.inf, 0.0, 0.0)] * len(centre[0])  # per cabinet: out-of-band, kWh, supply C, dp psi
        for dp in self.ctl.dp_psi:
            if not self._probe_level(centre, dp, picks):
                break
        self.cost((tuple(p[2] for p in picks), tuple(p[3] for p in picks), centre[2]))

    def _probe_level(self, centre: Setting, dp: float, picks: list) -> bool:
        """Probe the supply moves at this dp level, highest supply first, into `picks`. False, and no more probes,
        when every cabinet has an in-band pick that costs no more than this level's first probe: a higher dp
        costs more still."""
        n = len(centre[0])
        for j, move in enumerate(sorted(self.ctl.supply_moves_k, reverse=True)):
            setting = (self._moved(centre[0], move), (dp,) * n, centre[2])
            kwh = self.cost(setting, full=True)[1]
            if j == 0 and all(oob == 0 and kwh >= e for oob, e, _, _ in picks):
                return False
            for i, oob in enumerate(self.by_cabinet[setting]):
                picks[i] = min(picks[i], (int(oob), kwh, setting[0][i], dp))
        return True

    def _moved(self, supplies_c: tuple[float, ...], move_k: float) -> tuple[float, ...]:
        low, high = self.ctl._supply_range_c
        return tuple(min(max(s + move_k, low), high) for s in supplies_c)


def _applied_setpoints(obs: Observation) -> list | None:
    """The setpoints the plant applied last step (supply K, dp Pa, leaving water K); None before its first step."""
    out = obs.out
    supply_k, dp_pa = np.array(out["applied_supply_setpoint_k"]), np.array(out["applied_dp_setpoint_pa"])
    lw_k = float(np.mean(out["applied_lw_setpoint_k"]))
    return [supply_k, dp_pa, lw_k] if min(supply_k.min(), dp_pa.min(), lw_k) > 0 else None
