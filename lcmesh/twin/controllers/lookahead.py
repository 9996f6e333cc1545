"""A look-ahead controller: the near-optimal reference a benchmark measures the others against.

Every ``period_steps`` (4 = 1 min) it saves the FMU state, simulates candidate settings over the
next ``horizon_steps`` (120 = 30 min) with the trace's actual future loads and wet bulb, restores the
state after each, and applies the cheapest. 30 min, not 5: the tower and HTW loop take longer than
5 min to answer a leaving-water change, so a 5-min horizon sees only the fans' cost of a lower
approach, never its benefit, and buys cooling with pump power instead (design-day, 6 h: cost 862
against 764 at 30 min; docs/controllers.md). It knows the future exactly (a perfect forecast) and
runs the plant itself, so it is a ceiling for what a controller could reach with this model, not a
controller one could deploy; the mesh refuses it (it has no future to give it).

A setting is three numbers, held over the horizon and between decisions:

- CDU supply setpoint (all cabinets): the current one -2, 0, +2 K, kept inside 20..40 C;
- CDU dp setpoint (all cabinets): 27.5, 33 or 38 psi;
- tower leaving water: the step's wet bulb + 3, 5 or 8 K;

valves follow branch power every step (``rule.load_proportional_valves``, not searched). The search
is one pass of coordinate descent from the current setting (7 rollouts a decision; ``search="grid"``
tries all 27). Cost of a rollout: ``out_of_band_kwh`` x (blade-group-steps outside the 20-40 C band)
+ cooling energy (pumps + tower fans, kWh). With the default 1 kWh, one blade group out of band for
one step costs as much as a kWh of cooling.

Its cost is counted: ``sim_steps`` (plant steps simulated since ``reset``) and ``wall_s`` (seconds
spent deciding), so a benchmark can state what the ceiling took.
"""

from __future__ import annotations

import itertools
import time
from typing import Literal

import numpy as np

from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.controllers.rule import MIN_VALVE_FRACTION, load_proportional_valves
from lcmesh.twin.kpi import BLADE_LOWER_C, BLADE_UPPER_C
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.system import PSI_TO_PA, SystemDescription
from lcmesh.twin.traces import Trace

K = 273.15
SUPPLY_MIN_C, SUPPLY_MAX_C = 20.0, 40.0
NOT_ATTACHED = "lookahead needs the plant and the trace: run it with lcmesh twin run / bench, not in the mesh"


class LookaheadController:
    """Receding-horizon search on the twin itself, with a perfect forecast: a ceiling, not a deployable controller."""

    name = "lookahead"
    version = "1"

    def __init__(
        self,
        system: SystemDescription,
        period_steps: int = 4,
        horizon_steps: int = 120,
        supply_offsets_k: tuple[float, ...] = (-2.0, 0.0, 2.0),
        dp_psi: tuple[float, ...] = (27.5, 33.0, 38.0),
        approaches_k: tuple[float, ...] = (3.0, 5.0, 8.0),
        out_of_band_kwh: float = 1.0,
        search: Literal["coordinate", "grid"] = "coordinate",
    ):
        if period_steps < 1 or horizon_steps < 1:
            raise ValueError(f"`period_steps` and `horizon_steps` must be >= 1, got {period_steps}, {horizon_steps}")
        if search not in ("coordinate", "grid"):
            raise ValueError(f"`search` must be 'coordinate' or 'grid', got {search!r}")
        if 0.0 not in supply_offsets_k:
            raise ValueError(f"`supply_offsets_k` must hold 0 (keep the setpoint), got {supply_offsets_k}")
        self.system = system
        self.period_steps, self.horizon_steps = period_steps, horizon_steps
        self.supply_offsets_k = tuple(sorted(supply_offsets_k))
        self.dp_psi, self.approaches_k = tuple(dp_psi), tuple(approaches_k)
        self.out_of_band_kwh, self.search = out_of_band_kwh, search
        self.plant: Plant | None = None
        self.trace: Trace | None = None
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._action = PlantAction(np.zeros(C), np.zeros(C), np.full((C, B), 1.0 / B), np.zeros(N))
        self._power = np.zeros(system.n_blade_groups)
        self._lower_k, self._upper_k = BLADE_LOWER_C + K, BLADE_UPPER_C + K
        self.reset()

    def attach(self, plant: Plant, trace: Trace) -> None:
        """The plant to simulate on and the trace whose future it reads (``run_twin`` calls this)."""
        if plant.system.n_blade_groups != self.system.n_blade_groups:
            raise ValueError(f"lookahead was made for {self.system.name!r}, the plant runs {plant.system.name!r}")
        self.plant, self.trace = plant, trace

    def reset(self) -> None:
        # the setting (supply C, dp psi, approach K); the search starts from the one in force
        supply_c = float(self.system.cabinets.cdu.supply_temp_setpoint_k - K)
        self.setting = (supply_c, self.dp_psi[0], self.approaches_k[len(self.approaches_k) // 2])
        self._steps = 0
        self.sim_steps = 0
        self.decisions = 0
        self.wall_s = 0.0
        self.last_costs: dict[tuple[float, float, float], float] = {}

    def act(self, obs: Observation) -> PlantAction:
        if self.plant is None or self.trace is None:
            raise RuntimeError(NOT_ATTACHED)
        if self._steps % self.period_steps == 0:
            t0 = time.perf_counter()
            self.setting = self._decide(self._trace_step(obs))
            self.decisions += 1
            self.wall_s += time.perf_counter() - t0
        self._steps += 1
        return self._apply(self.setting, obs.blade_power_w, obs.wet_bulb_k)

    # --- search ------------------------------------------------------------------------------------------
    def candidates(self) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """The values each coordinate may take at this decision; the current setting's value is among them."""
        low, high = SUPPLY_MIN_C - self.supply_offsets_k[0], SUPPLY_MAX_C - self.supply_offsets_k[-1]
        supply = min(max(self.setting[0], low), high)
        supplies = tuple(supply + d for d in self.supply_offsets_k)  # shifted, not clipped: always distinct values
        return supplies, self.dp_psi, self.approaches_k

    def _decide(self, k: int) -> tuple[float, float, float]:
        plant = self.plant
        horizon = min(self.horizon_steps, self.trace.n_steps - k)
        n_done, start = plant.n_steps_done, plant.save_state()  # the state carries the inputs too
        costs: dict[tuple[float, float, float], float] = {}

        def cost(setting: tuple[float, float, float]) -> float:
            if setting not in costs:
                plant.restore_state(start)
                costs[setting] = self._rollout(setting, k, horizon)
            return costs[setting]

        supplies, dps, approaches = self.candidates()
        s0 = min(supplies, key=lambda s: abs(s - self.setting[0]))
        d0 = self.setting[1] if self.setting[1] in dps else dps[0]
        a0 = self.setting[2] if self.setting[2] in approaches else approaches[len(approaches) // 2]
        best = (s0, d0, a0)
        try:  # on a tie the setting in force wins (tried first): no actuator moves for nothing
            if self.search == "grid":
                best = min(sorted(itertools.product(supplies, dps, approaches), key=lambda c: c != best), key=cost)
            else:
                for axis, values in enumerate((supplies, dps, approaches)):
                    tries = sorted(values, key=lambda v, axis=axis: v != best[axis])
                    best = min((best[:axis] + (v,) + best[axis + 1 :] for v in tries), key=cost)
        finally:
            plant.restore_state(start)
            plant.free_state(start)
            plant.n_steps_done = n_done
        self.last_costs = costs
        return best

    def _rollout(self, setting: tuple[float, float, float], k: int, horizon: int) -> float:
        """Cost of holding `setting` for `horizon` steps from trace step `k` (the plant is at step k's start)."""
        trace, plant, power = self.trace, self.plant, self._power
        out_of_band, cooling_j = 0, 0.0
        for t in range(k, k + horizon):
            wet_bulb = float(trace.wet_bulb_k[t])
            trace.blade_power_w(t, out=power)
            out = plant.step(power, wet_bulb, self._apply(setting, power, wet_bulb))
            temps = out["blade_temp_k"]
            out_of_band += temps.size - int(np.count_nonzero((temps > self._lower_k) & (temps < self._upper_k)))
            cooling_j += (float(out["ct_fan_power_w"]) + float(out["pump_power_w"])) * plant.step_s
        self.sim_steps += horizon
        return self.out_of_band_kwh * out_of_band + cooling_j / 3.6e6

    def _apply(self, setting: tuple[float, float, float], blade_power_w: np.ndarray, wet_bulb_k: float) -> PlantAction:
        supply_c, dp_psi, approach_k = setting
        a = self._action
        a.supply_temp_setpoint_k[:] = supply_c + K
        a.dp_setpoint_pa[:] = dp_psi * PSI_TO_PA
        load_proportional_valves(self.system, blade_power_w, MIN_VALVE_FRACTION, out=a.valve_fractions)
        a.lw_setpoint_k[:] = wet_bulb_k + approach_k
        return a

    def _trace_step(self, obs: Observation) -> int:
        """The trace step `obs` is for; refuses an observation that does not match the attached trace."""
        trace = self.trace
        k = round(obs.time_s / trace.step_s)
        if not 0 <= k < trace.n_steps or abs(float(trace.wet_bulb_k[k]) - obs.wet_bulb_k) > 1e-9:
            raise RuntimeError(f"lookahead: the observation at {obs.time_s:g} s is not step {k} of the attached trace "
                               f"{trace.name!r}; attach the trace the run follows")  # fmt: skip
        return k
