"""PPO for the LC-Opt ablation (Table 3): tower and cabinet agents, decentralized or centralized, single or multi-head.

One file, config as a dataclass (``lcmesh train ppo --help`` lists every field). The cases:

====  ===========================  ==========================================================
case  towers                       cabinets (CDU setpoints + valves)
====  ===========================  ==========================================================
1     G36                          G36 (no training: the baseline)
2     RL, decentralized            G36
3     G36                          RL, decentralized, no valve control (equal split)
4     G36                          RL, decentralized, with valves (one Gaussian head)
5     RL, decentralized            RL, decentralized, with valves
6     RL, centralized action       RL, centralized action (one policy, batched over rows)
7     RL, centralized action       RL, centralized action, multi-head (tanh Gaussian + Dirichlet)
====  ===========================  ==========================================================

Decentralized: one network sees all C cabinet rows (or N tower rows) at once and emits all their
actions; it fits one system size. Centralized action (LC-Opt sec. 4.1): one network sees one row and
is applied to every row in a batch, with per-row rollout streams; it runs on any C and N.

Hyperparameters follow the paper's Tables 9 (cabinet) and 10 (tower) except where the 2-core CPU
budget says otherwise, as documented on the fields: 10 epochs of 256-sample minibatches instead of 50
of 32 (the same number of gradient steps on 8x less wall time per sample is not available here), the
action std decays linearly to its minimum at 80 % of training.
"""

from __future__ import annotations

import csv
import itertools
import json
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from lcmesh.distill.features import APPROACH_LEVELS_K, FeatureLayout
from lcmesh.distill.policy import AgentNet, AgentSpec, PolicyFile, PpoController, save_policy
from lcmesh.distill.ppo_config import CASES, Case, PpoConfig
from lcmesh.distill.ppo_env import TrainPlants
from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS
from lcmesh.twin.traces import TRAIN_SEEDS


class AgentTrainer:
    """One agent's network, optimizers, rollout buffer and PPO update."""

    def __init__(self, name: str, spec: AgentSpec, lr_actor: float, lr_critic: float, gamma: float, vf_coef: float, cfg: PpoConfig):
        self.name, self.spec, self.gamma, self.vf_coef, self.cfg = name, spec, gamma, vf_coef, cfg
        self.net = AgentNet(spec)
        self.opt_actor = torch.optim.Adam(self.net.actor.parameters(), lr=lr_actor)
        self.opt_critic = torch.optim.Adam(self.net.critic.parameters(), lr=lr_critic)
        self.buf: dict[str, list] = {}

    def start_rollout(self) -> None:
        self.buf = {k: [] for k in ("obs", "act", "logp", "val", "rew", "done")}

    @torch.no_grad()
    def act(self, rows: np.ndarray, std: float) -> np.ndarray:
        """Sample actions for rows (E, R_total, F); returns (E, R_total, A) or choices (E, R_total)."""
        E = rows.shape[0]
        x = torch.as_tensor(rows, dtype=torch.float32).reshape(-1, self.spec.obs_dim)
        d = self.net.dist(x, std)
        a = d.sample()
        self.buf["obs"].append(x)
        self.buf["act"].append(a)
        self.buf["logp"].append(d.log_prob(a))
        self.buf["val"].append(self.net.value(x))
        if self.spec.kind == "categorical":
            return a.reshape(E, -1).long().numpy()
        return a.reshape(E, -1, self.spec.row_actions).numpy()

    def record(self, rewards: np.ndarray, done: np.ndarray) -> None:
        """rewards (E, R_total), done (E,): one reward per sample (mean over the rows it holds)."""
        E = rewards.shape[0]
        r = torch.as_tensor(rewards, dtype=torch.float32).reshape(E, -1, self.spec.rows).mean(-1).reshape(-1)
        d = torch.as_tensor(np.repeat(done, r.numel() // E), dtype=torch.float32)
        self.buf["rew"].append(r)
        self.buf["done"].append(d)

    def update(self, last_rows: np.ndarray, std: float) -> dict[str, float]:
        obs, act, logp, val = (torch.stack(self.buf[k]) for k in ("obs", "act", "logp", "val"))
        rew, done = torch.stack(self.buf["rew"]), torch.stack(self.buf["done"])
        with torch.no_grad():
            last_val = self.net.value(torch.as_tensor(last_rows, dtype=torch.float32).reshape(-1, self.spec.obs_dim))
        adv = torch.zeros_like(rew)
        gae = torch.zeros_like(last_val)
        next_val = last_val  # the rollout ends by truncation: bootstrap from the last state
        for t in reversed(range(rew.shape[0])):
            nonterminal = 1.0 - done[t]
            delta = rew[t] + self.gamma * next_val * nonterminal - val[t]
            gae = delta + self.gamma * self.cfg.gae_lambda * nonterminal * gae
            adv[t] = gae
            next_val = val[t]
        ret = adv + val
        flat = lambda t: t.reshape(-1, *t.shape[2:])  # noqa: E731
        obs, act, logp, adv, ret = map(flat, (obs, act, logp, adv, ret))
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        n = obs.shape[0]
        stats = {"policy_loss": 0.0, "value_loss": 0.0, "entropy": 0.0, "approx_kl": 0.0}
        steps = 0
        for _ in range(self.cfg.epochs):
            perm = torch.randperm(n)
            for start in range(0, n, self.cfg.minibatch):
                idx = perm[start : start + self.cfg.minibatch]
                d = self.net.dist(obs[idx], std)
                new_logp = d.log_prob(act[idx])
                ratio = torch.exp(new_logp - logp[idx])
                surr = torch.min(ratio * adv[idx], ratio.clamp(1 - self.cfg.clip, 1 + self.cfg.clip) * adv[idx])
                entropy = d.entropy().mean()
                policy_loss = -surr.mean() - self.cfg.ent_coef * entropy
                value_loss = (self.net.value(obs[idx]) - ret[idx]).pow(2).mean()
                self.opt_actor.zero_grad()
                self.opt_critic.zero_grad()
                (policy_loss + self.vf_coef * value_loss).backward()
                torch.nn.utils.clip_grad_norm_(self.net.parameters(), self.cfg.max_grad_norm)
                self.opt_actor.step()
                self.opt_critic.step()
                steps += 1
                stats["policy_loss"] += policy_loss.item()
                stats["value_loss"] += value_loss.item()
                stats["entropy"] += entropy.item()
                stats["approx_kl"] += (logp[idx] - new_logp).mean().item()
        return {f"{self.name}_{k}": v / steps for k, v in stats.items()}


def build_trainers(cfg: PpoConfig, plants: TrainPlants) -> dict[str, AgentTrainer]:
    """The RL agents of ``cfg.case`` with their specs (rows: 1 for centralized action)."""
    case = CASES[cfg.case]
    layout = FeatureLayout(plants.B, plants.m)
    trainers = {}
    if case.cabinet is not None:
        kind = "multihead" if case.multihead else "gaussian"
        n_act = 2 + (plants.B if case.valves else 0)
        spec = AgentSpec(kind, len(layout.cabinet_columns), n_act, rows=1 if case.cabinet == "ca" else plants.C)
        trainers["cabinet"] = AgentTrainer(
            "cabinet", spec, cfg.cabinet_lr_actor, cfg.cabinet_lr_critic, cfg.cabinet_gamma, cfg.cabinet_vf_coef, cfg
        )
    if case.tower is not None:
        spec = AgentSpec(
            "categorical", len(layout.tower_columns), len(APPROACH_LEVELS_K), rows=1 if case.tower == "ca" else plants.N,
            hidden_actor=(32, 64), hidden_critic=(32, 32),
        )  # fmt: skip
        trainers["tower"] = AgentTrainer(
            "tower", spec, cfg.tower_lr_actor, cfg.tower_lr_critic, cfg.tower_gamma, cfg.tower_vf_coef, cfg
        )
    return trainers


def train_ppo(cfg: PpoConfig, on_update: Callable[[int, int, dict], None] | None = None) -> dict:
    """Train ``cfg.case``; write the run folder; return a summary (best validation KPIs, paths)."""
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.run import run_twin
    from lcmesh.twin.traces import load_trace

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(cfg), indent=2) + "\n")
    seed_order = np.random.default_rng(cfg.seed).permutation(np.asarray(TRAIN_SEEDS))
    guardrails = MESH_GUARDRAILS if cfg.guardrails else None
    plants = TrainPlants(cfg.system, itertools.cycle(int(s) for s in seed_order), cfg.n_envs, cfg.episode_steps,
                         scenarios=cfg.scenario_list(), reward=cfg.reward, guardrails=guardrails,
                         travel_scale=cfg.deploy_travel_scale)  # fmt: skip
    system = plants.system
    trainers = build_trainers(cfg, plants)
    case = CASES[cfg.case]
    layout = FeatureLayout(plants.B, plants.m)
    steps_per_update = cfg.n_envs * cfg.episode_steps
    n_updates = max(1, cfg.total_env_steps // steps_per_update)
    eval_traces = [load_trace(spec, system, scenario=scenario, hours=cfg.eval_hours)
                   for spec, scenario in cfg.eval_days()]  # fmt: skip
    eval_plant = Plant(system)
    log_path = out / "log.csv"
    log_file = log_path.open("w", newline="")
    writer: csv.DictWriter | None = None
    best = {"score": -np.inf}
    t0 = time.perf_counter()

    def meta(std: float, metrics: dict) -> PolicyFile:
        return PolicyFile(
            case=cfg.case, layout=layout.to_json(), agents={k: asdict(t.spec) for k, t in trainers.items()}, std=std,
            manifest={"version": f"case{cfg.case}-seed{cfg.seed}", "title": case.title, "system": system.name,
                      "command": " ".join(sys.argv), "commit": git_commit(), "seed": cfg.seed,
                      "config": asdict(cfg), "metrics": metrics},
        )  # fmt: skip

    try:
        for update in range(n_updates):
            progress = update / max(1, n_updates - 1)
            std = max(cfg.min_std, cfg.init_std - (cfg.init_std - cfg.min_std) * progress / 0.8)
            for tr in trainers.values():
                tr.start_rollout()
                tr.net.train()
            cab_rows, tow_rows = plants.reset(rng)
            ep = {"cabinet_reward": 0.0, "tower_reward": 0.0, "in_band": 0.0, "ct_fan_kw": 0.0}
            for _ in range(cfg.episode_steps):
                cab_u = trainers["cabinet"].act(cab_rows, std) if "cabinet" in trainers else None
                tow_c = trainers["tower"].act(tow_rows, std) if "tower" in trainers else None
                res = plants.step(cab_u, tow_c, valves=case.valves, valves_given=case.multihead)
                done = res["terminated"]
                if "cabinet" in trainers:
                    trainers["cabinet"].record(res["cabinet_reward"], done)
                if "tower" in trainers:
                    trainers["tower"].record(res["tower_reward"], done)
                for e in np.flatnonzero(done):
                    plants.reset_one(int(e), rng)
                cab_rows, tow_rows = plants.rows()
                for k in ep:
                    ep[k] += float(np.mean(res[k].sum(axis=-1) if res[k].ndim > 1 else res[k])) / cfg.episode_steps
            row = {"update": update + 1, "env_steps": (update + 1) * steps_per_update,
                   "wall_s": round(time.perf_counter() - t0, 1), "std": round(std, 4), **ep}  # fmt: skip
            for name, tr in trainers.items():
                row.update(tr.update(cab_rows if name == "cabinet" else tow_rows, std))
            for i in range(cfg.refresh_envs_per_update):
                plants.refresh((update * cfg.refresh_envs_per_update + i) % plants.n_envs)
            if (update + 1) % cfg.eval_every == 0 or update == n_updates - 1:
                nets = {k: t.net.eval() for k, t in trainers.items()}
                ctrl = PpoController(system, loaded=(nets, meta(std, {})))
                runs = [run_twin(eval_plant, tr, ctrl, guardrails=guardrails).kpi for tr in eval_traces]
                kpi = validation_kpis(runs, cfg.eval_hours)
                score = selection_score(kpi, cfg)
                row.update({"val_d_blade_pct": kpi["d_blade_pct"], "val_ct_power_kw": kpi["ct_power_kw_avg"], "val_score": score})
                metrics = {"validation": {"trace": cfg.eval_trace, "hours": cfg.eval_hours, **kpi}, "update": update + 1,
                           "env_steps": (update + 1) * steps_per_update, "wall_s": row["wall_s"]}  # fmt: skip
                save_policy(out / "last", nets, meta(std, metrics))
                if score > best["score"]:
                    best = {"score": score, "update": update + 1, "kpi": kpi, "wall_s": row["wall_s"]}
                    save_policy(out / "best", nets, meta(std, metrics))
            if writer is None:
                fields = list(row) + ["val_d_blade_pct", "val_ct_power_kw", "val_score"]
                writer = csv.DictWriter(log_file, fieldnames=list(dict.fromkeys(fields)))
                writer.writeheader()
            writer.writerow({k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()})
            log_file.flush()
            if on_update is not None:
                on_update(update + 1, n_updates, row)
    finally:
        log_file.close()
        plants.close()
        eval_plant.close()
    summary = {"case": cfg.case, "title": case.title, "updates": n_updates, "env_steps": n_updates * steps_per_update,
               "wall_s": round(time.perf_counter() - t0, 1), "best": best, "run_dir": str(out),
               "policy": str(out / "best")}  # fmt: skip
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    _plot_log(log_path, out / "training.png")
    return summary


def validation_kpis(runs: list[dict], hours: float) -> dict:
    """The validation figures the selection score reads, averaged over the validation days."""
    per_day = 24.0 / hours
    return {
        **{k: float(np.mean([r[k] for r in runs])) for k in ("d_blade_pct", "ct_power_kw_avg", "pump_power_kw_avg")},
        "supply_travel_k_day": float(np.mean([r["actuator_travel"]["supply_temp_setpoint_k"] for r in runs])) * per_day,
        "blade_max_c": float(np.max([r["blade_temp_max_c"] for r in runs])),
    }


def selection_score(kpi: dict, cfg: PpoConfig) -> float:
    """The checkpoint (and seed) selection score, declared in the config before any test day is run."""
    return (kpi["d_blade_pct"] - cfg.eval_ct_weight_per_kw * kpi["ct_power_kw_avg"]
            - cfg.eval_pump_weight_per_kw * kpi["pump_power_kw_avg"]
            - cfg.eval_travel_weight_per_k * kpi["supply_travel_k_day"]
            - cfg.eval_hot_weight_per_k * max(0.0, kpi["blade_max_c"] - cfg.eval_hot_limit_c))  # fmt: skip


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).parent).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _plot_log(log_path: Path, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with log_path.open() as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    steps = [int(r["env_steps"]) for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.5))
    for key in ("cabinet_reward", "tower_reward"):
        axes[0].plot(steps, [float(r[key]) for r in rows], label=key)
    axes[0].set_title("episode reward per step")
    axes[0].legend()
    axes[1].plot(steps, [100 * float(r["in_band"]) for r in rows])
    axes[1].set_title("training in-band blade groups (%)")
    val = [(s, float(r["val_d_blade_pct"]), float(r["val_ct_power_kw"])) for s, r in zip(steps, rows) if r.get("val_d_blade_pct")]
    if val:
        axes[2].plot([v[0] for v in val], [v[1] for v in val], "o-", label="d_blade %")
        ax2 = axes[2].twinx()
        ax2.plot([v[0] for v in val], [v[2] for v in val], "s--", color="tab:red", label="CT kW")
        axes[2].set_title("validation: d_blade (o) and CT kW (s)")
    for ax in axes:
        ax.set_xlabel("env steps")
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    plt.close(fig)


__all__ = ["CASES", "Case", "PpoConfig", "train_ppo"]
