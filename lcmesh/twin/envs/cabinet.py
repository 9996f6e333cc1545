"""The blade-group MDP (LC-Opt Table 2) over all C cabinets, as one Gymnasium agent.

Observation ``Box((C, 2B))``, physical units: row i = [branch temperatures (K) of cabinet i,
branch heat inputs (W) of cabinet i], read after the step.

Action ``Box((C, 2 + B))``, physical units: row i = [supply temperature setpoint (K, 293.15..313.15),
secondary dp setpoint (Pa, 25..38 psi), B valve fractions (0..1)]. Entries outside their range are
clamped and listed in ``info["clamped"]``; the valve fractions are then divided by their sum so
they split the flow (all zero: equal split), as the FMU needs for conservation of mass.

Reward, summed over cabinets (``info["cabinet_rewards"]`` holds the per-cabinet terms):

- temperature: ``-(mean_j T_ij - 303.15 K) / 10 K`` (0 at a 30 degC mean branch temperature,
  -1 per 10 K hotter): LC-Opt's ``-sum T`` (eq. 16) centred and scaled;
- valve shaping: ``-0.5 * sum_j |v_ij - P_ij / sum_j P_ij|``, the L1 distance between the
  commanded split and the branch power shares of the step (0 for a split proportional to power,
  -1 for the worst split): LC-Opt's term rewarding valves in proportion to branch power.

The cooling towers follow the static rule (wet bulb + 10 degF).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from lcmesh.twin.envs.episode import PHYSICAL_TEMP_BOUNDS_K, Clamp, EpisodeConfig, TwinEnv, open_episode
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import PSI_TO_PA

SUPPLY_SETPOINT_RANGE_K = (293.15, 313.15)
DP_SETPOINT_RANGE_PA = (25.0 * PSI_TO_PA, 38.0 * PSI_TO_PA)
TEMP_SCALE_RANGE_K = (273.15, 373.15)  # LC-Opt's observation scaling
BRANCH_POWER_SCALE_RANGE_W = (0.0, 400e3)
REWARD_TEMP_REF_K = 303.15
REWARD_TEMP_SCALE_K = 10.0
VALVE_SHAPING_WEIGHT = 0.5


class CabinetActuator:
    """Turns (C, 2 + B) physical cabinet actions into the CDU part of a PlantAction."""

    def __init__(self, n_cabinets: int, n_branches: int):
        shape = (n_cabinets, 2 + n_branches)
        low = np.array([SUPPLY_SETPOINT_RANGE_K[0], DP_SETPOINT_RANGE_PA[0]] + [0.0] * n_branches)
        high = np.array([SUPPLY_SETPOINT_RANGE_K[1], DP_SETPOINT_RANGE_PA[1]] + [1.0] * n_branches)
        self.space = spaces.Box(_f32(low, shape), _f32(high, shape), dtype=np.float32)
        # the float32 bounds, so nothing the space contains is ever reported as clamped
        self.low = self.space.low.astype(np.float64)
        self.high = self.space.high.astype(np.float64)
        self.shape = shape
        self.fields = ("supply_temp_setpoint_k", "dp_setpoint_pa", *(f"valve_fraction[{j}]" for j in range(n_branches)))
        self._buf = np.empty(shape)
        self._equal_split = 1.0 / n_branches

    def apply(self, action: np.ndarray, target: PlantAction) -> list[Clamp]:
        """Clamp ``action`` into range, write it into ``target``; return what was clamped."""
        if np.shape(action) != self.shape:
            raise ValueError(f"cabinet action must have shape {self.shape}, got {np.shape(action)}")
        a = self._buf
        a[...] = action
        clamped = [] if (a >= self.low).all() and (a <= self.high).all() else self._clamp(a)
        target.supply_temp_setpoint_k[:] = a[:, 0]
        target.dp_setpoint_pa[:] = a[:, 1]
        valves = a[:, 2:]
        total = valves.sum(axis=1, keepdims=True)
        if (total > 0.0).all():
            np.divide(valves, total, out=target.valve_fractions)
        else:
            np.divide(valves, np.where(total > 0.0, total, 1.0), out=target.valve_fractions)
            target.valve_fractions[total[:, 0] <= 0.0] = self._equal_split
        return clamped

    def _clamp(self, a: np.ndarray) -> list[Clamp]:
        if np.isnan(a).any():
            i, j = np.argwhere(np.isnan(a))[0]
            raise ValueError(f"cabinet action must be finite; `{self.fields[j]}` of cabinet_{i} is NaN")
        clamped = []
        for i, j in np.argwhere((a < self.low) | (a > self.high)):
            applied = min(max(a[i, j], self.low[i, j]), self.high[i, j])
            clamped.append(Clamp(f"cabinet_{i}", self.fields[j], float(a[i, j]), float(applied)))
        np.clip(a, self.low, self.high, out=a)
        return clamped


def _f32(values, shape: tuple[int, ...]) -> np.ndarray:
    """Space bounds as float32 (Box warns when it has to lower the precision itself)."""
    return np.broadcast_to(np.asarray(values, dtype=np.float32), shape).copy()


def cabinet_reward_terms(
    branch_temp_k: np.ndarray, branch_power_w: np.ndarray, valve_fractions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-cabinet (temperature term, valve-shaping term), both (C,); see the module docstring."""
    n_branches = branch_temp_k.shape[1]
    temperature = (REWARD_TEMP_REF_K - branch_temp_k.sum(axis=1) * (1.0 / n_branches)) * (1.0 / REWARD_TEMP_SCALE_K)
    share = branch_power_w / np.maximum(branch_power_w.sum(axis=1, keepdims=True), 1e-9)
    shaping = np.abs(valve_fractions - share).sum(axis=1)
    shaping *= -VALVE_SHAPING_WEIGHT
    return temperature, shaping


class CabinetEnv(TwinEnv):
    """LC-Opt's blade-group MDP over all cabinets; towers follow the static rule.

    ``CabinetEnv(config=None, **overrides)``: an :class:`EpisodeConfig`, and/or its fields as
    keywords (``CabinetEnv(episode_steps=30)``). ``reset(options={"start_row": k})`` pins the start.
    """

    metadata = {"render_modes": []}

    def __init__(self, config: EpisodeConfig | None = None, *, render_mode: str | None = None, **overrides: Any):
        self.config, self.driver = open_episode("CabinetEnv", config, render_mode, overrides)
        system = self.driver.system
        n_cab, n_br = system.cabinets.count, system.cabinets.branches
        self.n_cabinets, self.n_branches = n_cab, n_br
        obs_shape = (n_cab, 2 * n_br)
        power_high = 10.0 * system.cabinets.design_heat_w  # bounds of the space, not of the scaling
        obs_low = np.concatenate([np.full(n_br, PHYSICAL_TEMP_BOUNDS_K[0]), np.zeros(n_br)])
        obs_high = np.concatenate([np.full(n_br, PHYSICAL_TEMP_BOUNDS_K[1]), np.full(n_br, power_high)])
        self.observation_space = spaces.Box(_f32(obs_low, obs_shape), _f32(obs_high, obs_shape), dtype=np.float32)
        self.actuator = CabinetActuator(n_cab, n_br)
        self.action_space = self.actuator.space
        scale_low = [TEMP_SCALE_RANGE_K[0]] * n_br + [BRANCH_POWER_SCALE_RANGE_W[0]] * n_br
        scale_high = [TEMP_SCALE_RANGE_K[1]] * n_br + [BRANCH_POWER_SCALE_RANGE_W[1]] * n_br
        self.obs_scale_range = (np.broadcast_to(scale_low, obs_shape), np.broadcast_to(scale_high, obs_shape))
        self.action_scale_range = (self.actuator.low, self.actuator.high)
        self._action = self.driver.plant.default_action()
        out = self.driver.plant.out
        self._branch_temp_k, self._branch_power_w = out["branch_temp_k"], out["branch_power_w"]
        self._ct_fan_power_w = out["ct_fan_power_w"]

    def step(self, action: np.ndarray):
        clamped = self.actuator.apply(action, self._action)
        self._action.lw_setpoint_k[:] = self.driver.default_action().lw_setpoint_k
        _, terminated, truncated = self.driver.step(self._action)
        valves = self._action.valve_fractions
        temperature, shaping = cabinet_reward_terms(self._branch_temp_k, self._branch_power_w, valves)
        rewards = temperature + shaping
        info = {
            "time_s": self.driver.time_s,
            "clamped": clamped,
            "cabinet_rewards": rewards,
            "valve_shaping": shaping,
            "ct_fan_power_w": float(self._ct_fan_power_w),
            "kpi_in_band_fraction": self.driver.in_band_fraction(),
        }
        return self._observe(), float(rewards.sum()), terminated, truncated, info

    def _observe(self) -> np.ndarray:
        obs = np.empty(self.observation_space.shape, dtype=np.float32)
        obs[:, : self.n_branches] = self._branch_temp_k
        obs[:, self.n_branches :] = self._branch_power_w
        return obs
