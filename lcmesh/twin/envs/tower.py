"""The cooling-tower MDP (LC-Opt Table 1) over all N towers, as one Gymnasium agent.

Observation ``Box((N*m + N + 1,))``, physical units: the fan power (W) of every cell (tower-major),
the leaving-water temperature (K) of every tower, and the wet bulb (K) of the coming step.

Action ``MultiDiscrete([9] * N)``: tower i's leaving-water setpoint is
``wet bulb + 10 degF + LW_SETPOINT_DELTAS_K[a_i]`` with deltas -0.20, -0.15, ..., +0.20 K (LC-Opt).
An index outside 0..8 is clamped and listed in ``info["clamped"]``.

Reward: ``-sum_ij P_ij / (N * m * fan_power_nominal_w)``, LC-Opt's ``-sum P`` (eq. 17) as a
fraction of the installed fan power: 0 with every fan off, -1 with every fan at full speed.

The cabinets follow the static rule (design setpoints, equal valve split).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from lcmesh.twin.controllers.static import APPROACH_10F_K
from lcmesh.twin.envs.cabinet import TEMP_SCALE_RANGE_K
from lcmesh.twin.envs.episode import PHYSICAL_TEMP_BOUNDS_K, Clamp, EpisodeConfig, TwinEnv, open_episode
from lcmesh.twin.plant import PlantAction

LW_SETPOINT_DELTAS_K = np.round(np.linspace(-0.20, 0.20, 9), 10)
N_LW_ACTIONS = len(LW_SETPOINT_DELTAS_K)


class TowerActuator:
    """Turns N discrete setpoint choices into leaving-water setpoints of a PlantAction."""

    def __init__(self, n_towers: int):
        self.n_towers = n_towers
        self.space = spaces.MultiDiscrete([N_LW_ACTIONS] * n_towers)
        self._index = np.empty(n_towers, dtype=np.int64)

    def apply(self, action: np.ndarray, wet_bulb_k: float, target: PlantAction) -> list[Clamp]:
        """Write the setpoints for ``action`` at ``wet_bulb_k`` into ``target``; return what was clamped."""
        if np.shape(action) != (self.n_towers,):
            raise ValueError(f"tower action must have shape ({self.n_towers},), got {np.shape(action)}")
        index = self._index
        index[:] = action
        clamped = [] if index.min() >= 0 and index.max() < N_LW_ACTIONS else self._clamp(index)
        np.add(LW_SETPOINT_DELTAS_K[index], wet_bulb_k + APPROACH_10F_K, out=target.lw_setpoint_k)
        return clamped

    def _clamp(self, index: np.ndarray) -> list[Clamp]:
        clamped = [
            Clamp(f"tower_{i}", "lw_setpoint_index", float(index[i]), float(min(max(index[i], 0), N_LW_ACTIONS - 1)))
            for i in np.flatnonzero((index < 0) | (index >= N_LW_ACTIONS))
        ]
        np.clip(index, 0, N_LW_ACTIONS - 1, out=index)
        return clamped


class TowerEnv(TwinEnv):
    """LC-Opt's cooling-tower MDP over all towers; cabinets follow the static rule.

    ``TowerEnv(config=None, **overrides)``: an :class:`EpisodeConfig`, and/or its fields as keywords.
    ``reset(options={"start_row": k})`` pins the start.
    """

    metadata = {"render_modes": []}

    def __init__(self, config: EpisodeConfig | None = None, *, render_mode: str | None = None, **overrides: Any):
        self.config, self.driver = open_episode("TowerEnv", config, render_mode, overrides)
        system = self.driver.system
        n_towers, n_cells = system.towers.count, system.towers.cells
        self.n_towers, self.n_cells_per_tower = n_towers, n_cells
        fan_nominal_w = system.towers.cell.fan_power_nominal_w
        n_power, n_temp = n_towers * n_cells, n_towers + 1
        t_low, t_high = PHYSICAL_TEMP_BOUNDS_K
        self.observation_space = spaces.Box(
            np.array([0.0] * n_power + [t_low] * n_temp, dtype=np.float32),
            np.array([2.0 * fan_nominal_w] * n_power + [t_high] * n_temp, dtype=np.float32),
            dtype=np.float32,
        )
        self.actuator = TowerActuator(n_towers)
        self.action_space = self.actuator.space
        self.obs_scale_range = (
            np.array([0.0] * n_power + [TEMP_SCALE_RANGE_K[0]] * n_temp),
            np.array([fan_nominal_w] * n_power + [TEMP_SCALE_RANGE_K[1]] * n_temp),
        )
        self.action_scale_range = None  # discrete: nothing to scale
        self._reward_scale = -1.0 / (n_power * fan_nominal_w)
        self._action = self.driver.plant.default_action()
        out = self.driver.plant.out
        self._cell_fan_power_w = out["cell_fan_power_w"].reshape(-1)
        self._leaving_temp_k = out["ct_leaving_temp_k"]
        self._ct_fan_power_w = out["ct_fan_power_w"]
        self._n_power = n_power

    def step(self, action: np.ndarray):
        clamped = self.actuator.apply(action, self.driver.wet_bulb_k, self._action)
        default = self.driver.default_action()
        self._action.supply_temp_setpoint_k[:] = default.supply_temp_setpoint_k
        self._action.dp_setpoint_pa[:] = default.dp_setpoint_pa
        self._action.valve_fractions[:] = default.valve_fractions
        _, terminated, truncated = self.driver.step(self._action)
        info = {
            "time_s": self.driver.time_s,
            "clamped": clamped,
            "ct_fan_power_w": float(self._ct_fan_power_w),
            "lw_setpoint_k": self._action.lw_setpoint_k.copy(),
            "kpi_in_band_fraction": self.driver.in_band_fraction(),
        }
        reward = float(self._cell_fan_power_w.sum()) * self._reward_scale
        return self._observe(), reward, terminated, truncated, info

    def _observe(self) -> np.ndarray:
        obs = np.empty(self.observation_space.shape, dtype=np.float32)
        n = self._n_power
        obs[:n] = self._cell_fan_power_w
        obs[n:-1] = self._leaving_temp_k
        obs[-1] = self.driver.wet_bulb_k
        return obs
