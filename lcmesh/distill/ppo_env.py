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

Reward ``"deploy"`` (issue 23: a policy an operator would run) is ``"energy"`` plus actuator travel and the
hottest blade, declared before any test day was looked at:

- cabinet i: ``- 0.5 / K`` of its applied supply-setpoint change ``- 0.05 / psi`` of its dp-setpoint change
  ``- 2 / K`` of its hottest blade group above 39 degC;
- tower j: ``- 0.1 / K`` of its applied leaving-water-setpoint change ``- 2 / K`` of the plant's hottest blade
  group above 39 degC.

Travel is measured on what the plant applied, after the mesh's guardrails (on in training by default).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from lcmesh.distill.features import FeatureBuilder, TowerSetpoints, decode_cabinet
from lcmesh.mesh.tools.guardrails import apply_guardrails
from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS, applied_action, guard
from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.envs.episode import KPI_BAND_K, EpisodeConfig, EpisodeDriver
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import PSI_TO_PA, load_system

OVERHEAT_MARGIN_K = 273.15 + 38.5
TEMP_REF_K = 273.15 + 35.0
VALVE_TERM_WEIGHT = 0.5
TOWER_OVERHEAT_WEIGHT = 3.0
BAND_WEIGHT = 5.0
ENERGY_WEIGHT = 0.3
TRAVEL_WEIGHT_PER_K = 0.1
DEPLOY_SUPPLY_PER_K = 0.5
DEPLOY_DP_PER_PSI = 0.05
DEPLOY_LW_PER_K = 0.1
DEPLOY_HOT_PER_K = 2.0
DEPLOY_HOT_LIMIT_K = 273.15 + 39.0
REWARDS = ("lcopt", "energy", "energy_smooth", "deploy")


@dataclass(frozen=True)
class Travel:
    """How far the applied setpoints moved over one step: supply (C,) K, dp (C,) psi, leaving water (N,) K."""

    supply_k: np.ndarray
    dp_psi: np.ndarray
    lw_k: np.ndarray

    @classmethod
    def between(cls, before: PlantAction, after: PlantAction) -> "Travel":
        return cls(np.abs(after.supply_temp_setpoint_k - before.supply_temp_setpoint_k),
                   np.abs(after.dp_setpoint_pa - before.dp_setpoint_pa) / PSI_TO_PA,
                   np.abs(after.lw_setpoint_k - before.lw_setpoint_k))  # fmt: skip


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
        guardrails=MESH_GUARDRAILS,
        travel_scale: float = 1.0,
    ):
        if reward not in REWARDS:
            raise ValueError(f"`reward` must be one of {REWARDS}, got {reward!r}")
        self.reward = reward
        self.guardrails = guardrails  # the mesh's limits on every action (None: bare, the paper's setting)
        self.travel_scale = travel_scale
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
            before = applied_action(obs.out)
            if self.guardrails is not None:  # what the mesh's Sensor would apply
                guarded = apply_guardrails(action, before, obs.wet_bulb_k, self.guardrails, self.system)
                if guarded.action is not None:
                    for dst, src in zip(action.astuple(), guarded.action.astuple()):
                        dst[...] = src
            out, term, _ = driver.step(action)
            terminated[e] = term
            cab_r[e], tow_r[e] = self._rewards(out, action, Travel.between(before, action))
            in_band[e] = driver.in_band_fraction()
            fan_kw[e] = float(out["ct_fan_power_w"]) / 1e3
        return {"cabinet_reward": cab_r, "tower_reward": tow_r, "terminated": terminated,
                "in_band": in_band, "ct_fan_kw": fan_kw}  # fmt: skip

    def _rewards(self, out, action: PlantAction, travel: "Travel") -> tuple[np.ndarray, np.ndarray]:
        return step_rewards(self.system, out, action, self.reward, travel, self.travel_scale)

    def close(self) -> None:
        for d in self.drivers:
            d.close()


def step_rewards(
    system, out, action: PlantAction, reward: str = "lcopt", travel: Travel | None = None, travel_scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Per-cabinet (C,) and per-tower (N,) rewards of the step just taken (see the module docstring).

    ``travel``: how far the applied setpoints moved over the step (``energy_smooth`` and ``deploy``; None: 0).
    """
    cab, tw = system.cabinets, system.towers
    C, B, N, m = cab.count, cab.branches, tw.count, tw.cells
    blade = out["blade_temp_k"].reshape(C, -1)
    overheat = np.maximum(blade - OVERHEAT_MARGIN_K, 0.0).mean(axis=1)
    power = out["branch_power_w"].reshape(C, B)
    share = power / np.maximum(power.sum(axis=1, keepdims=True), 1.0)
    valve_term = np.abs(action.valve_fractions - share).sum(axis=1)
    fans = out["cell_fan_power_w"].reshape(N, m).sum(axis=1) / (m * tw.cell.fan_power_nominal_w)
    if reward in ("energy", "energy_smooth", "deploy"):
        lo, hi = KPI_BAND_K
        outside = ((blade < lo) | (blade > hi)).mean(axis=1)
        pump = out["cdu_pump_power_w"] / _design_pump_w(system)
        primary = out["primary_flow_kg_s"] / cab.cdu.primary_flow_max_kg_s
        cabinet = (-BAND_WEIGHT * outside - overheat - ENERGY_WEIGHT * pump - ENERGY_WEIGHT * primary
                   - VALVE_TERM_WEIGHT * valve_term)  # fmt: skip
        tower = -fans - TOWER_OVERHEAT_WEIGHT * overheat.mean() - BAND_WEIGHT * outside.mean()
        if travel is not None and reward == "energy_smooth":
            cabinet = cabinet - TRAVEL_WEIGHT_PER_K * travel.supply_k
        if reward == "deploy":
            hottest = blade.max(axis=1)
            cabinet = cabinet - DEPLOY_HOT_PER_K * np.maximum(hottest - DEPLOY_HOT_LIMIT_K, 0.0)
            tower = tower - DEPLOY_HOT_PER_K * max(float(hottest.max()) - DEPLOY_HOT_LIMIT_K, 0.0)
            if travel is not None:
                w = travel_scale
                cabinet = cabinet - w * (DEPLOY_SUPPLY_PER_K * travel.supply_k + DEPLOY_DP_PER_PSI * travel.dp_psi)
                tower = tower - w * DEPLOY_LW_PER_K * travel.lw_k
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
    guardrails=MESH_GUARDRAILS,
) -> dict:
    """Mean episode reward per cabinet and per tower of ``controller`` over evaluation episodes (Tables 12/14).

    ``controller`` runs behind ``guardrails`` (default the mesh's; None: bare), as everywhere else.

    One episode per seed: the trace ``synthetic:SEED`` from row 0 (after the warm-up), ``steps`` steps, under
    scenario ``scenarios[seed % len(scenarios)]`` (``lcopt`` with ``wet_bulb_offset_k``), scored with ``reward``.
    """
    controller = guard(controller, load_system(system_name), guardrails)
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
                before = applied_action(obs.out)
                action = controller.act(obs)
                out, terminated, truncated = driver.step(action)
                c, t = step_rewards(driver.system, out, action, reward, Travel.between(before, action))
                cab += float(c.mean())
                tow += float(t.mean())
                if terminated or truncated:
                    break
            cab_total.append(cab)
            tow_total.append(tow)
        finally:
            driver.close()
    return {"cabinet_reward": float(np.mean(cab_total)), "tower_reward": float(np.mean(tow_total)), "episodes": len(cab_total)}

