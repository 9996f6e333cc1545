"""All cabinets and towers as PettingZoo parallel agents, with LC-Opt's per-agent decomposition (sec. 4.1).

Agents ``cabinet_0``..``cabinet_{C-1}`` and ``tower_0``..``tower_{N-1}``; every space is in the
normalized [-1, 1] form of :mod:`lcmesh.twin.envs.wrappers`:

- cabinet i: observation ``Box((2B,))`` = its branch temperatures and branch powers; action
  ``Box((2 + B,))`` = supply setpoint, dp setpoint, B valves (as :class:`CabinetEnv`, scaled);
  reward = its temperature term + valve-shaping term (see :mod:`lcmesh.twin.envs.cabinet`).
- tower j: observation ``Box((m + N + 2,))`` = its m cell fan powers, its leaving-water
  temperature, all N towers' leaving-water temperatures (they stay coupled through the HTW loop),
  and the wet bulb; action ``Discrete(9)`` (as :class:`TowerEnv`); reward =
  ``-sum of its cells' fan power / (m * fan_power_nominal_w)``.

All agents terminate (thermal runaway) or truncate together. An agent left out of the actions
dict follows the static rule for that step (its info says ``"default_action": True``).
Out-of-range actions are clamped and reported in that agent's ``info["clamped"]``.
"""

from __future__ import annotations

import difflib
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from lcmesh.twin.envs.cabinet import (
    BRANCH_POWER_SCALE_RANGE_W,
    TEMP_SCALE_RANGE_K,
    CabinetActuator,
    cabinet_reward_terms,
)
from lcmesh.twin.envs.episode import Clamp, EpisodeConfig, open_episode
from lcmesh.twin.envs.tower import N_LW_ACTIONS, TowerActuator
from lcmesh.twin.envs.wrappers import UnitScale


class CoolingParallelEnv(ParallelEnv):
    """Every cabinet and tower of the plant as its own agent.

    ``CoolingParallelEnv(config=None, **overrides)``: an :class:`EpisodeConfig`, and/or its fields
    as keywords. ``reset(options={"start_row": k})`` pins the start; other option keys are ignored.
    """

    metadata = {"name": "lcmesh_cooling_v0", "render_modes": []}

    def __init__(self, config: EpisodeConfig | None = None, *, render_mode: str | None = None, **overrides: Any):
        self.render_mode = None
        self.config, self.driver = open_episode("CoolingParallelEnv", config, render_mode, overrides)
        system = self.driver.system
        C, B = system.cabinets.count, system.cabinets.branches
        N, m = system.towers.count, system.towers.cells
        self._shape = (C, B, N, m)
        self.cabinet_agents = [f"cabinet_{i}" for i in range(C)]
        self.tower_agents = [f"tower_{j}" for j in range(N)]
        self.possible_agents = self.cabinet_agents + self.tower_agents
        self.agents: list[str] = []

        self.cabinet_actuator = CabinetActuator(C, B)
        self.tower_actuator = TowerActuator(N)
        self._cabinet_action_scale = UnitScale(self.cabinet_actuator.low, self.cabinet_actuator.high)
        t_lo, t_hi = TEMP_SCALE_RANGE_K
        p_lo, p_hi = BRANCH_POWER_SCALE_RANGE_W
        self._cabinet_obs_scale = UnitScale(
            np.broadcast_to([t_lo] * B + [p_lo] * B, (C, 2 * B)), np.broadcast_to([t_hi] * B + [p_hi] * B, (C, 2 * B))
        )
        fan_nominal_w = system.towers.cell.fan_power_nominal_w
        tower_obs_len = m + N + 2
        self._tower_obs_scale = UnitScale(
            np.broadcast_to([0.0] * m + [t_lo] * (N + 2), (N, tower_obs_len)),
            np.broadcast_to([fan_nominal_w] * m + [t_hi] * (N + 2), (N, tower_obs_len)),
        )
        self.observation_spaces = {
            **{a: spaces.Box(-1.0, 1.0, shape=(2 * B,), dtype=np.float32) for a in self.cabinet_agents},
            **{a: spaces.Box(-1.0, 1.0, shape=(tower_obs_len,), dtype=np.float32) for a in self.tower_agents},
        }
        self.action_spaces = {
            **{a: spaces.Box(-1.0, 1.0, shape=(2 + B,), dtype=np.float32) for a in self.cabinet_agents},
            **{a: spaces.Discrete(N_LW_ACTIONS) for a in self.tower_agents},
        }
        self._tower_reward_scale = -1.0 / (m * fan_nominal_w)
        self._np_random: np.random.Generator | None = None
        self._action = self.driver.plant.default_action()
        self._cabinet_unit = np.zeros((C, 2 + B))
        self._tower_index = np.full(N, N_LW_ACTIONS // 2, dtype=np.int64)
        self._cabinet_obs_phys = np.empty((C, 2 * B))
        self._tower_obs_phys = np.empty((N, tower_obs_len))
        self._out = self.driver.plant.out

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[self._check_agent(agent)]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[self._check_agent(agent)]

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None or self._np_random is None:
            self._np_random, _ = seeding.np_random(seed)
        start_row = options.get("start_row") if options else None
        self.driver.reset(self._np_random, start_row)
        self.agents = list(self.possible_agents)
        info = {"time_s": self.driver.time_s, "start_row": self.driver.start_row}
        return self._observe(), {a: dict(info) for a in self.agents}

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("the episode has ended (every agent is done); call reset() first")
        for agent in actions:
            if agent not in self.action_spaces:
                self._check_agent(agent)
        clamped = self._apply(actions)
        out, terminated, truncated = self.driver.step(self._action)
        temperature, shaping = cabinet_reward_terms(
            out["branch_temp_k"], out["branch_power_w"], self._action.valve_fractions
        )
        tower_fan_w = out["cell_fan_power_w"].sum(axis=1)
        rewards = {a: float(r) for a, r in zip(self.cabinet_agents, temperature + shaping, strict=True)}
        for agent, fan_w in zip(self.tower_agents, tower_fan_w, strict=True):
            rewards[agent] = float(fan_w) * self._tower_reward_scale

        time_s, kpi = self.driver.time_s, self.driver.in_band_fraction()
        infos: dict[str, dict[str, Any]] = {}
        for i, agent in enumerate(self.cabinet_agents):
            infos[agent] = {"time_s": time_s, "clamped": [], "valve_shaping": float(shaping[i])}
        for j, agent in enumerate(self.tower_agents):
            infos[agent] = {
                "time_s": time_s,
                "clamped": [],
                "fan_power_w": float(tower_fan_w[j]),
                "lw_setpoint_k": float(self._action.lw_setpoint_k[j]),
            }
        for agent, info in infos.items():
            info["kpi_in_band_fraction"] = kpi
            if agent not in actions:
                info["default_action"] = True
        for clamp in clamped:
            infos[clamp.agent]["clamped"].append(clamp)

        terminations = dict.fromkeys(self.agents, terminated)
        truncations = dict.fromkeys(self.agents, truncated)
        if terminated or truncated:
            self.agents = []
        return self._observe(), rewards, terminations, truncations, infos

    def _apply(self, actions: dict[str, Any]) -> list[Clamp]:
        """Write the agents' actions (the default policy's for absent agents) into the plant action."""
        default = self.driver.default_action()
        unit = self._cabinet_unit
        for i, agent in enumerate(self.cabinet_agents):
            if agent in actions:
                unit[i] = actions[agent]
        physical = self._cabinet_action_scale.from_unit(unit)
        for i, agent in enumerate(self.cabinet_agents):
            if agent not in actions:
                physical[i, 0] = default.supply_temp_setpoint_k[i]
                physical[i, 1] = default.dp_setpoint_pa[i]
                physical[i, 2:] = default.valve_fractions[i]
        clamped = self.cabinet_actuator.apply(physical, self._action)
        index = self._tower_index
        for j, agent in enumerate(self.tower_agents):
            index[j] = actions.get(agent, N_LW_ACTIONS // 2)
        clamped += self.tower_actuator.apply(index, self.driver.wet_bulb_k, self._action)
        for j, agent in enumerate(self.tower_agents):
            if agent not in actions:
                self._action.lw_setpoint_k[j] = default.lw_setpoint_k[j]
        return clamped

    def _observe(self) -> dict[str, np.ndarray]:
        _, B, N, m = self._shape
        out = self._out
        cab = self._cabinet_obs_phys
        cab[:, :B] = out["branch_temp_k"]
        cab[:, B:] = out["branch_power_w"]
        cab_unit = self._cabinet_obs_scale.to_unit(cab)
        tow = self._tower_obs_phys
        tow[:, :m] = out["cell_fan_power_w"]
        leaving_k = out["ct_leaving_temp_k"]
        tow[:, m] = leaving_k
        tow[:, m + 1 : m + 1 + N] = leaving_k
        tow[:, -1] = self.driver.wet_bulb_k
        tow_unit = self._tower_obs_scale.to_unit(tow)
        obs = dict(zip(self.cabinet_agents, cab_unit, strict=True))
        obs.update(zip(self.tower_agents, tow_unit, strict=True))
        return obs

    def _check_agent(self, agent: str) -> str:
        if agent not in self.observation_spaces:
            close = difflib.get_close_matches(str(agent), self.possible_agents, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise KeyError(f"unknown agent {agent!r}{hint} (agents: {', '.join(self.possible_agents)})")
        return agent

    def render(self) -> None:
        return None

    def close(self) -> None:
        self.driver.close()
