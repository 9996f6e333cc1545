"""Vectorized training plants for the PPO ablation: E twins stepped together, rows and rewards out.

Each plant runs its own synthetic training trace (seeds from ``TRAIN_SEEDS`` only) with LC-Opt's
+15 K wet-bulb hardening and random 200-step windows. G36 drives whatever the case leaves to the
baseline. Rewards (per cabinet and per tower) are written for this problem's KPIs:

- cabinet i: ``-0.1 * (mean branch temperature - 35 degC) - mean_g max(0, T_g - 38.5 degC)
  - 0.5 * sum_j |v_ij - P_ij / sum_j P_ij|``: cool, keep every blade group below the band's top
  with a margin, and split the flow like the heat (LC-Opt's valve term);
- tower j: ``-sum of its cells' fan power / (m * nominal)`` (LC-Opt eq. 17, scaled)
  ``- 3 * mean over all blade groups of max(0, T_g - 38.5 degC)``: the towers share the blades'
  overheating, otherwise a fan-power-only tower agent starves the CDUs of cold water.

That is reward ``"lcopt"``, the shipped policies'. Reward ``"energy"`` asks for what the benchmark scores,
the look-ahead controller's cost in per-step form: the band, then the cooling energy.

- cabinet i: ``-5 * share of its blade groups outside 20-40 degC - mean_g max(0, T_g - 38.5 degC)
  - 0.3 * CDU pump power / its power at the design dp - 0.3 * primary flow / its maximum`` (the
  hot-water pumping a cabinet causes) ``- 0.5 * valve term``: no reward for running colder than needed;
- tower j: ``-fan power / (m * nominal) - 3 * mean overheat - 5 * share of all blade groups outside
  the band``.

Reward ``"energy_smooth"`` is ``"energy"`` with ``-0.1 / K`` of the cabinet's supply-setpoint change over the
step: a policy trained on ``"energy"`` alone flips its supply setpoint between extremes (tens of thousands of
kelvin of travel a day, against G36's hundreds).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from lcmesh.distill.features import FeatureBuilder, TowerSetpoints, decode_cabinet
from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.envs.episode import KPI_BAND_K, EpisodeConfig, EpisodeDriver
from lcmesh.twin.plant import PlantAction

OVERHEAT_MARGIN_K = 273.15 + 38.5
TEMP_REF_K = 273.15 + 35.0
VALVE_TERM_WEIGHT = 0.5
TOWER_OVERHEAT_WEIGHT = 3.0
BAND_WEIGHT = 5.0
ENERGY_WEIGHT = 0.3
TRAVEL_WEIGHT_PER_K = 0.1
REWARDS = ("lcopt", "energy", "energy_smooth")


class TrainPlants:
    """E plants with their baseline, tower setpoint holder and feature builder."""

    def __init__(
        self,
        system: str,
        seeds: Iterator[int],
        n_envs: int,
        episode_steps: int,
        scenarios: tuple[str, ...] = ("lcopt",),
        reward: str = "lcopt",
    ):
        if reward not in REWARDS:
            raise ValueError(f"`reward` must be one of {REWARDS}, got {reward!r}")
        self.reward = reward
        self.seeds = seeds
        self.episode_steps = episode_steps
        self.scenarios = scenarios
        self.system_name = system
        self.drivers = [self._driver() for _ in range(n_envs)]
        self.system = self.drivers[0].system
        s = self.system
        self.C, self.B, self.G = s.cabinets.count, s.cabinets.branches, s.cabinets.blade_groups_per_branch
        self.N, self.m = s.towers.count, s.towers.cells
        self.features = [FeatureBuilder(s) for _ in self.drivers]
        self.baselines = [G36Controller(s) for _ in self.drivers]
        self.towers = [TowerSetpoints(s) for _ in self.drivers]
        self.actions = [PlantAction(np.zeros(self.C), np.zeros(self.C), np.zeros((self.C, self.B)), np.zeros(self.N)) for _ in self.drivers]
        self.fan_norm = 1.0 / (self.m * s.towers.cell.fan_power_nominal_w)

    def _driver(self) -> EpisodeDriver:
        seed = next(self.seeds)
        scenario = self.scenarios[seed % len(self.scenarios)]  # a seed's scenario is fixed, whatever the order
        config = EpisodeConfig(
            system=self.system_name, trace=f"synthetic:{seed}", scenario=scenario,
            wet_bulb_offset_k=None, episode_steps=self.episode_steps,  # each scenario's own (lcopt: +15 K)
        )  # fmt: skip
        return EpisodeDriver(config)

    @property
    def n_envs(self) -> int:
        return len(self.drivers)

    def refresh(self, index: int) -> None:
        """Give env ``index`` a fresh training trace (the next seed)."""
        self.drivers[index].close()
        self.drivers[index] = self._driver()

    def reset(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        for e, driver in enumerate(self.drivers):
            driver.reset(rng)
            self.baselines[e].reset()
            self.towers[e].reset()
        return self.rows()

    def reset_one(self, e: int, rng: np.random.Generator) -> None:
        """Restart env ``e`` after a thermal runaway (the other envs go on)."""
        self.drivers[e].reset(rng)
        self.baselines[e].reset()
        self.towers[e].reset()

    def rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Cabinet rows (E, C, Fc) and tower rows (E, N, Ft) of the coming step."""
        obs = [d.observation() for d in self.drivers]
        cab = np.stack([f.cabinet_rows(o) for f, o in zip(self.features, obs)])
        tow = np.stack([f.tower_rows(o) for f, o in zip(self.features, obs)])
        return cab, tow

    def step(
        self, cabinet_u: np.ndarray | None, tower_choice: np.ndarray | None, *, valves: bool, valves_given: bool
    ) -> dict[str, np.ndarray]:
        """Apply the RL parts (None: G36), step every plant; rewards and KPI samples per env."""
        E, C, N = self.n_envs, self.C, self.N
        cab_r, tow_r = np.empty((E, C)), np.empty((E, N))
        in_band, fan_kw = np.empty(E), np.empty(E)
        terminated = np.zeros(E, dtype=bool)
        for e, driver in enumerate(self.drivers):
            obs = driver.observation()
            action = self.actions[e]
            base = self.baselines[e].act(obs)
            for dst, src in zip(action.astuple(), base.astuple()):
                dst[...] = src
            if cabinet_u is not None:
                decode_cabinet(cabinet_u[e], action, valves_given=valves_given)
                if not valves:
                    action.valve_fractions[:] = base.valve_fractions
            if tower_choice is not None:
                self.towers[e].apply(tower_choice[e], obs.wet_bulb_k, action)
            travel_k = np.abs(action.supply_temp_setpoint_k - obs.out["applied_supply_setpoint_k"])
            out, term, _ = driver.step(action)
            terminated[e] = term
            cab_r[e], tow_r[e] = self._rewards(out, action, travel_k)
            in_band[e] = driver.in_band_fraction()
            fan_kw[e] = float(out["ct_fan_power_w"]) / 1e3
        return {"cabinet_reward": cab_r, "tower_reward": tow_r, "terminated": terminated,
                "in_band": in_band, "ct_fan_kw": fan_kw}  # fmt: skip

    def _rewards(self, out, action: PlantAction, travel_k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return step_rewards(self.system, out, action, self.reward, travel_k)

    def close(self) -> None:
        for d in self.drivers:
            d.close()


def step_rewards(
    system, out, action: PlantAction, reward: str = "lcopt", supply_travel_k: np.ndarray | float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Per-cabinet (C,) and per-tower (N,) rewards of the step just taken (see the module docstring).

    ``supply_travel_k``: each cabinet's supply-setpoint change over the step (``energy_smooth`` only).
    """
    cab, tw = system.cabinets, system.towers
    C, B, N, m = cab.count, cab.branches, tw.count, tw.cells
    blade = out["blade_temp_k"].reshape(C, -1)
    overheat = np.maximum(blade - OVERHEAT_MARGIN_K, 0.0).mean(axis=1)
    power = out["branch_power_w"].reshape(C, B)
    share = power / np.maximum(power.sum(axis=1, keepdims=True), 1.0)
    valve_term = np.abs(action.valve_fractions - share).sum(axis=1)
    fans = out["cell_fan_power_w"].reshape(N, m).sum(axis=1) / (m * tw.cell.fan_power_nominal_w)
    if reward in ("energy", "energy_smooth"):
        lo, hi = KPI_BAND_K
        outside = ((blade < lo) | (blade > hi)).mean(axis=1)
        pump = out["cdu_pump_power_w"] / _design_pump_w(system)
        primary = out["primary_flow_kg_s"] / cab.cdu.primary_flow_max_kg_s
        cabinet = (-BAND_WEIGHT * outside - overheat - ENERGY_WEIGHT * pump - ENERGY_WEIGHT * primary
                   - VALVE_TERM_WEIGHT * valve_term)  # fmt: skip
        if reward == "energy_smooth":
            cabinet = cabinet - TRAVEL_WEIGHT_PER_K * np.asarray(supply_travel_k)
        tower = -fans - TOWER_OVERHEAT_WEIGHT * overheat.mean() - BAND_WEIGHT * outside.mean()
        return cabinet, tower
    mean_t = out["branch_temp_k"].reshape(C, B).mean(axis=1)
    cabinet = -0.1 * (mean_t - TEMP_REF_K) - overheat - VALVE_TERM_WEIGHT * valve_term
    tower = -fans - TOWER_OVERHEAT_WEIGHT * overheat.mean()
    return cabinet, tower


def _design_pump_w(system) -> float:
    """A CDU pump's power at the description's design dp (the unit of the energy reward's pump term)."""
    cdu = system.cabinets.cdu
    flow = cdu.dp_setpoint_pa / cdu.r_cabinet_pa_per_kg_s
    return (cdu.r_hx_secondary_pa_per_kg_s + cdu.r_cabinet_pa_per_kg_s) * flow**2 / (997.0 * cdu.pump.efficiency)


def episode_rewards(
    controller,
    system_name: str,
    seeds,
    steps: int = 200,
    wet_bulb_offset_k: float = 15.0,
    scenarios: tuple[str, ...] = ("lcopt",),
    reward: str = "lcopt",
) -> dict:
    """Mean episode reward per cabinet and per tower of ``controller`` over evaluation episodes (Tables 12/14).

    One episode per seed: the trace ``synthetic:SEED`` from row 0 (after the warm-up), ``steps`` steps, under
    scenario ``scenarios[seed % len(scenarios)]`` (``lcopt`` with ``wet_bulb_offset_k``), scored with ``reward``.
    """
    cab_total, tow_total = [], []
    for seed in seeds:
        scenario = scenarios[seed % len(scenarios)]
        offset = wet_bulb_offset_k if scenario == "lcopt" else None
        driver = EpisodeDriver(EpisodeConfig(system=system_name, trace=f"synthetic:{seed}", scenario=scenario,
                                             wet_bulb_offset_k=offset, episode_steps=steps, random_start=False))  # fmt: skip
        try:
            driver.reset(np.random.default_rng(0), start_row=0)
            controller.reset()
            cab, tow = 0.0, 0.0
            for _ in range(steps):
                obs = driver.observation()
                before = obs.out["applied_supply_setpoint_k"].copy()
                action = controller.act(obs)
                travel_k = np.abs(action.supply_temp_setpoint_k - before)
                out, terminated, truncated = driver.step(action)
                c, t = step_rewards(driver.system, out, action, reward, travel_k)
                cab += float(c.mean())
                tow += float(t.mean())
                if terminated or truncated:
                    break
            cab_total.append(cab)
            tow_total.append(tow)
        finally:
            driver.close()
    return {"cabinet_reward": float(np.mean(cab_total)), "tower_reward": float(np.mean(tow_total)), "episodes": len(cab_total)}

