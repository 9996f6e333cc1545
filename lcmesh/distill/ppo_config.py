"""The PPO ablation's cases and training config (no torch import, so the CLI stays fast)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Case:
    tower: str | None  # None (G36), "joint" (decentralized) or "ca" (centralized action)
    cabinet: str | None
    valves: bool = True
    multihead: bool = False
    title: str = ""


CASES: dict[int, Case] = {
    2: Case("joint", None, title="CT RL + BG baseline"),
    3: Case(None, "joint", valves=False, title="CT baseline + BG RL, no valve control"),
    4: Case(None, "joint", title="CT baseline + BG RL, with valve control"),
    5: Case("joint", "joint", title="Multi-agent RL, decentralized action"),
    6: Case("ca", "ca", title="Multi-agent RL, centralized action"),
    7: Case("ca", "ca", multihead=True, title="Multi-agent RL, centralized action + multi-head"),
}


@dataclass
class PpoConfig:
    """``lcmesh train ppo`` settings; defaults train case 7 on lcopt-5 within the 60-minute CPU budget."""

    case: int = 7
    """Ablation case 2..7 (Table 3); case 1 is G36 and needs no training."""
    system: str = "lcopt-5-paper"
    """System to train on (reference name or JSON path)."""
    total_env_steps: int = 320_000
    """Plant steps over all parallel envs (the paper: 2e6)."""
    n_envs: int = 8
    """Parallel training plants, each on its own synthetic trace."""
    episode_steps: int = 200
    """Steps per episode and per rollout (LC-Opt's max_ep_len); update interval = n_envs * episode_steps."""
    refresh_envs_per_update: int = 1
    """Envs given a fresh training trace (next seed) after every update."""
    seed: int = 0
    cabinet_lr_actor: float = 3e-4
    cabinet_lr_critic: float = 1e-3
    cabinet_gamma: float = 0.80
    tower_lr_actor: float = 6e-4
    tower_lr_critic: float = 1e-3
    tower_gamma: float = 0.95
    gae_lambda: float = 0.95
    clip: float = 0.2
    epochs: int = 10
    """PPO epochs per update (the paper: 50; see the module docstring)."""
    minibatch: int = 256
    """Samples per gradient step (the paper: 32)."""
    ent_coef: float = 0.01
    cabinet_vf_coef: float = 0.5
    tower_vf_coef: float = 0.6
    init_std: float = 0.6
    min_std: float = 0.1
    max_grad_norm: float = 0.5
    eval_every: int = 10
    """Updates between validation runs (checkpoint selection)."""
    scenarios: str = "lcopt"
    """Training scenarios (comma list; a training seed s runs under scenario s mod their count): ``lcopt`` is the
    shipped policies' setting; ``frontier,design-day`` trains on the real loads, mild and hot weather."""
    eval_trace: str = "synthetic:1002,synthetic:1003,synthetic:1004,synthetic:1006"
    """Validation traces (comma list; ``SPEC@SCENARIO`` picks a scenario, default the first training scenario) for
    checkpoint selection: never a training seed and never a test day (lcmesh/bench/suite.py)."""
    eval_hours: float = 24.0
    eval_ct_weight_per_kw: float = 0.02
    """Checkpoint score = d_blade_pct - this * ct_power_kw_avg (2 points per 100 kW of fans) - ..."""
    eval_pump_weight_per_kw: float = 0.0
    """... - this * pump_power_kw_avg (pumps: CDU, hot water, tower water) ..."""
    eval_travel_weight_per_k: float = 0.0
    """... - this * supply-setpoint travel (K per day, summed over the CDUs) ..."""
    eval_hot_weight_per_k: float = 0.0
    """... - this * the hottest blade group's excess over ``eval_hot_limit_c`` (K, the day's maximum)."""
    eval_hot_limit_c: float = 40.0
    deploy_travel_scale: float = 1.0
    """Reward ``deploy`` only: multiplies its travel weights (0.5/K supply, 0.05/psi dp, 0.1/K leaving water)."""
    guardrails: bool = True
    """Train and validate behind the mesh's guardrails (``GuardrailLimits`` defaults); False: bare (the paper)."""
    reward: str = "lcopt"
    """Training reward (lcmesh/distill/ppo_env.py): ``lcopt`` (the paper policies'), ``energy`` (the band, then
    the cooling energy: what the suite scores), ``energy_smooth`` or ``deploy`` (``energy`` plus actuator travel
    and the hottest blade: the shipped policy's)."""
    threads: int = 1
    """torch threads (the envs step on one core; more threads rarely help nets this small)."""
    out: str = "runs/ppo"
    """Run folder: config, CSV log, checkpoints, plots."""

    def scenario_list(self) -> tuple[str, ...]:
        return tuple(s.strip() for s in self.scenarios.split(",") if s.strip())

    def eval_days(self) -> list[tuple[str, str]]:
        """(trace spec, scenario) pairs of the validation traces."""
        default = self.scenario_list()[0]
        days = []
        for item in self.eval_trace.split(","):
            if item.strip():
                spec, _, scenario = item.strip().partition("@")
                days.append((spec, scenario or default))
        return days

    def __post_init__(self) -> None:
        if self.reward not in ("lcopt", "energy", "energy_smooth", "deploy"):
            raise ValueError(f"`reward` must be 'lcopt', 'energy', 'energy_smooth' or 'deploy', got {self.reward!r}")
        if not self.scenario_list():
            raise ValueError("`scenarios` must name at least one scenario (e.g. 'lcopt' or 'frontier,design-day')")
        from lcmesh.twin.traces import scenario_named  # numpy only: the CLI stays fast

        for name in (*self.scenario_list(), *(scenario for _, scenario in self.eval_days())):
            scenario_named(name)
        if self.case not in CASES:
            raise ValueError(f"`case` must be one of {sorted(CASES)} (case 1 is G36, no training), got {self.case}")
        for name in ("total_env_steps", "n_envs", "episode_steps", "epochs", "minibatch", "eval_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"`{name}` must be >= 1, got {getattr(self, name)}")
        if not 0 < self.min_std <= self.init_std:
            raise ValueError(f"need 0 < `min_std` <= `init_std`, got {self.min_std}, {self.init_std}")
