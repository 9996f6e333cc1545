"""LC-Opt's static rule: tower leaving water = wet bulb + 10 degF, fixed CDU setpoints, equal valve split."""

from __future__ import annotations

import numpy as np

from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import SystemDescription

APPROACH_10F_K = 10.0 / 1.8


class StaticController:
    name = "static"
    version = "1"

    def __init__(self, system: SystemDescription, approach_k: float = APPROACH_10F_K):
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self.approach_k = approach_k
        self._action = PlantAction(
            np.full(C, system.cabinets.cdu.supply_temp_setpoint_k),
            np.full(C, system.cabinets.cdu.dp_setpoint_pa),
            np.full((C, B), 1.0 / B),
            np.zeros(N),
        )

    def reset(self) -> None:
        pass

    def act(self, obs: Observation) -> PlantAction:
        self._action.lw_setpoint_k[:] = obs.wet_bulb_k + self.approach_k
        return self._action
