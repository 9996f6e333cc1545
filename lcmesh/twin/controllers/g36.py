"""ASHRAE Guideline 36 trim-and-respond baseline, as in LC-Opt Appendix K (Algorithms 1 and 2).

Algorithm 1 resets the CDU coolant supply setpoint from cabinet cooling requests; Algorithm 2
resets the tower leaving-water setpoint from the CDUs' demand, with hysteresis, a wet-bulb reset and
limits. Temperatures inside the algorithms are in deg C as the paper states them (its 1.05 x
COOLANT_min test is on deg C values); the controller converts at its edges.

Choices the paper leaves open, stated here: the supply setpoint is plant-wide (one COOLANT_setpoint,
requests summed over all cabinets, as Algorithm 1 is written); a cabinet's "server temperature" is its
hottest branch; warning/critical thresholds are 37 / 40 C (the compliance band's top is 40 C);
utilization is cabinet IT power over twice its mean design load; "rising" compares with the previous
control step; both algorithms run every `interval_s` (120 s; the paper says 2-5 min) while request
conditions are tracked every step ("held for 2 minutes"); dp setpoint fixed, valves split equally.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

K = 273.15


@dataclass(frozen=True)
class CoolantParams:
    """Algorithm 1 parameters (Appendix K.0.1)."""

    coolant_min_c: float = 18.0
    coolant_max_c: float = 30.0
    trim_c: float = 0.1
    respond_c: float = 0.3
    request_threshold: int = 2
    warning_c: float = 37.0
    critical_c: float = 40.0
    utilization_high: float = 0.85
    hold_s: float = 120.0


@dataclass(frozen=True)
class TowerParams:
    """Algorithm 2 parameters (Appendix K.0.2)."""

    min_approach_c: float = 2.8
    optimal_approach_c: float = 3.5
    lwt_max_c: float = 29.4
    trim_c: float = 0.1
    respond_c: float = 0.3
    request_on_ratio: float = 1.05
    request_off_ratio: float = 1.15


def cabinet_requests(critical_held: np.ndarray, warning_held: np.ndarray, busy_and_rising: np.ndarray) -> np.ndarray:
    """Algorithm 1, lines 4-13: 3 if critical for the hold time, else 2 if warning, else 1 if busy and rising."""
    return np.where(critical_held, 3, np.where(warning_held, 2, np.where(busy_and_rising, 1, 0)))


def coolant_trim_respond(setpoint_c: float, total_requests: int, p: CoolantParams) -> float:
    """Algorithm 1, lines 16-23."""
    if total_requests == 0:
        setpoint_c += p.trim_c
    elif total_requests >= p.request_threshold:
        setpoint_c -= p.respond_c * total_requests
    return max(p.coolant_min_c, min(p.coolant_max_c, setpoint_c))


def tower_request(coolant_setpoint_c: float, requesting: bool, coolant_min_c: float, p: TowerParams) -> bool:
    """Algorithm 2, lines 3-9: on below 1.05 x COOLANT_min, held until above 1.15 x COOLANT_min."""
    if coolant_setpoint_c < p.request_on_ratio * coolant_min_c:
        return True
    if coolant_setpoint_c > p.request_off_ratio * coolant_min_c:
        return False
    return requesting


def lwt_trim_respond(lwt_setpoint_c: float, requests: int, wet_bulb_c: float, p: TowerParams) -> float:
    """Algorithm 2, lines 10-23: trim/respond, wet-bulb reset, then the limits."""
    if requests == 0:
        lwt_setpoint_c += p.trim_c
    else:
        lwt_setpoint_c -= p.respond_c * requests
    optimal = wet_bulb_c + p.optimal_approach_c
    if lwt_setpoint_c < optimal - 0.5:
        lwt_setpoint_c = optimal
    lwt_min = wet_bulb_c + p.min_approach_c
    return max(lwt_min, min(p.lwt_max_c, lwt_setpoint_c))


class G36Controller:
    name = "g36"
    version = "1"

    def __init__(
        self,
        system: SystemDescription,
        coolant: CoolantParams = CoolantParams(),
        tower: TowerParams = TowerParams(),
        interval_s: float = 120.0,
    ):
        self.system, self.coolant, self.tower = system, coolant, tower
        self.interval_s = interval_s
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._peak_cabinet_w = 2.0 * system.cabinets.design_heat_w
        self._action = PlantAction(
            np.full(C, system.cabinets.cdu.supply_temp_setpoint_k),
            np.full(C, system.cabinets.cdu.dp_setpoint_pa),
            np.full((C, B), 1.0 / B),
            np.full(N, system.towers.lw_setpoint_k),
        )
        self.reset()

    def reset(self) -> None:
        C = self.system.cabinets.count
        self.coolant_setpoint_c: float | None = None
        self.lwt_setpoint_c: float | None = None
        self.tower_requesting = False
        self._critical_s = np.zeros(C)
        self._warning_s = np.zeros(C)
        self._last_temp_c: np.ndarray | None = None
        self._since_update_s = np.inf
        self.last_requests = np.zeros(C, dtype=int)

    def act(self, obs: Observation) -> PlantAction:
        out, step_s = obs.out, self.system.step_s
        server_c = out["branch_temp_k"].max(axis=1) - K
        if self.coolant_setpoint_c is None:  # initialized to the measured values (Appendix K)
            self.coolant_setpoint_c = float(out["supply_temp_k"].mean() - K)
            self.lwt_setpoint_c = float(out["ct_leaving_temp_k"].mean() - K)
        p = self.coolant
        self._critical_s = np.where(server_c > p.critical_c, self._critical_s + step_s, 0.0)
        self._warning_s = np.where(server_c > p.warning_c, self._warning_s + step_s, 0.0)
        rising = server_c > self._last_temp_c if self._last_temp_c is not None else np.zeros_like(server_c, bool)
        utilization = out["branch_power_w"].sum(axis=1) / self._peak_cabinet_w
        self._last_temp_c = server_c
        self._since_update_s += step_s
        if self._since_update_s >= self.interval_s:
            self._since_update_s = 0.0
            requests = cabinet_requests(
                self._critical_s >= p.hold_s, self._warning_s >= p.hold_s, (utilization > p.utilization_high) & rising
            )
            self.last_requests = requests
            self.coolant_setpoint_c = coolant_trim_respond(self.coolant_setpoint_c, int(requests.sum()), p)
            self.tower_requesting = tower_request(
                self.coolant_setpoint_c, self.tower_requesting, p.coolant_min_c, self.tower
            )
            self.lwt_setpoint_c = lwt_trim_respond(
                self.lwt_setpoint_c, int(self.tower_requesting), obs.wet_bulb_k - K, self.tower
            )
        self._action.supply_temp_setpoint_k[:] = self.coolant_setpoint_c + K
        self._action.lw_setpoint_k[:] = self.lwt_setpoint_c + K
        return self._action
