"""``lcmesh distill tree``: VIPER-weighted trees from a PPO teacher, with the paper's Tables 12-15 metrics."""

from __future__ import annotations

import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from lcmesh.distill.experience import Experience, collect_experience, resample
from lcmesh.distill.tree_config import TreeDistillConfig, parse_seeds
from lcmesh.distill.features import APPROACH_LEVELS_K, DP_RANGE_PA, SUPPLY_RANGE_K, FeatureLayout
from lcmesh.distill.trees import DEFAULT_TREES, Tree, TreeController, rules_text, save_trees
from lcmesh.twin.system import PSI_TO_PA


def teacher_labels(teacher, exp: Experience) -> tuple[np.ndarray, np.ndarray]:
    """The teacher's deterministic outputs on every recorded row: cabinet (T, C, 2+B) with the split, tower (T, N)."""
    import torch

    from lcmesh.distill.features import normalize_split
    from lcmesh.distill.policy import policy_mode

    T, C, _ = exp.cabinet_rows.shape
    cab = tow = None
    with torch.no_grad():
        if "cabinet" in teacher.nets:
            net = teacher.nets["cabinet"]
            u = policy_mode(net, exp.cabinet_rows.reshape(T * C, -1), teacher.meta.std)
            u = u.reshape(T, C, -1)
            if net.spec.kind == "gaussian" and u.shape[-1] > 2:
                u[..., 2:] = normalize_split(((np.clip(u[..., 2:], -1, 1) + 1) / 2).reshape(T * C, -1)).reshape(T, C, -1)
            cab = u
        if "tower" in teacher.nets:
            tow = policy_mode(teacher.nets["tower"], exp.tower_rows.reshape(-1, exp.tower_rows.shape[-1]), teacher.meta.std)
            tow = tow.reshape(T, -1)
    return cab, tow


def fit_trees(exp: Experience, cab: np.ndarray, tow: np.ndarray, cfg: TreeDistillConfig, layout: FeatureLayout, uniform: bool) -> dict[str, Tree]:
    from sklearn.tree import DecisionTreeClassifier, DecisionTreeRegressor

    rng = np.random.default_rng(cfg.seed)
    trees = {}
    cab_cols = list(layout.cabinet_columns)
    idx = resample(exp, cfg.samples, rng, "cabinet", uniform=uniform)
    x = exp.cabinet_rows[idx[:, 0], idx[:, 1]]
    y = cab[idx[:, 0], idx[:, 1]]
    leaves = {"max_leaf_nodes": cfg.max_leaves} if cfg.max_leaves else {}
    model = DecisionTreeRegressor(max_depth=cfg.max_depth_cdu, min_samples_leaf=cfg.min_samples_leaf, random_state=cfg.seed,
                                  **leaves)  # fmt: skip
    trees["cdu"] = Tree.from_sklearn(model.fit(x, y[:, :2]), cab_cols, ["supply_setpoint_u", "dp_setpoint_u"])
    if y.shape[1] > 2:
        model = DecisionTreeRegressor(max_depth=cfg.max_depth_valves, min_samples_leaf=cfg.min_samples_leaf,
                                      random_state=cfg.seed, **leaves)  # fmt: skip
        names = [f"valve_fraction[{j}]" for j in range(y.shape[1] - 2)]
        trees["valves"] = Tree.from_sklearn(model.fit(x, y[:, 2:]), cab_cols, names)
    if tow is not None:
        idx = resample(exp, cfg.samples, rng, "tower", uniform=uniform)
        x = exp.tower_rows[idx[:, 0], idx[:, 1]]
        y = tow[idx[:, 0], idx[:, 1]]
        model = DecisionTreeClassifier(max_depth=cfg.max_depth_tower, min_samples_leaf=cfg.min_samples_leaf,
                                       random_state=cfg.seed, **leaves)  # fmt: skip
        model.fit(x, y)
        trees["tower"] = Tree.from_sklearn(model, list(layout.tower_columns), ["approach_step_index"], classes=model.classes_)
    return trees


def fidelity(trees: dict[str, Tree], exp: Experience, cab: np.ndarray, tow: np.ndarray) -> dict:
    """R^2 and MAE against the teacher on held-out rows, in physical units (Tables 12 and 14)."""
    from sklearn.metrics import r2_score

    T, C, F = exp.cabinet_rows.shape
    x = exp.cabinet_rows.reshape(T * C, F)
    y = cab.reshape(T * C, -1)
    p = trees["cdu"].predict(x)
    scale = np.array([(SUPPLY_RANGE_K[1] - SUPPLY_RANGE_K[0]) / 2, (DP_RANGE_PA[1] - DP_RANGE_PA[0]) / 2 / PSI_TO_PA])
    result = {
        "cdu_r2": float(r2_score(y[:, :2], p)),
        "cdu_mae": {"supply_setpoint_c": float(np.abs(y[:, 0] - p[:, 0]).mean() * scale[0]),
                    "dp_psi": float(np.abs(y[:, 1] - p[:, 1]).mean() * scale[1])},
    }  # fmt: skip
    if "valves" in trees:
        pv = trees["valves"].predict(x)
        result["valve_r2"] = float(r2_score(y[:, 2:], pv))
        result["valve_mae"] = [float(v) for v in np.abs(y[:, 2:] - pv).mean(axis=0)]
    if "tower" in trees and tow is not None:
        xt = exp.tower_rows.reshape(-1, exp.tower_rows.shape[-1])
        pt = trees["tower"].predict(xt)[:, 0]
        yt = tow.reshape(-1)
        steps = np.asarray(APPROACH_LEVELS_K)
        result["tower_accuracy"] = float((np.rint(pt) == yt).mean())
        result["tower_r2"] = float(r2_score(steps[yt.astype(int)], steps[np.rint(pt).astype(int)]))
        result["tower_mae_k"] = float(np.abs(steps[yt.astype(int)] - steps[np.rint(pt).astype(int)]).mean())
    return result


def complexity(trees: dict[str, Tree], teacher) -> dict:
    params = sum(p.numel() for net in teacher.nets.values() for p in net.actor.parameters())
    return {"teacher_actor_parameters": int(params),
            **{name: {"nodes": t.n_nodes, "leaves": t.n_leaves, "max_depth": t.depth} for name, t in trees.items()}}  # fmt: skip


def distill_trees(cfg: TreeDistillConfig, on_step: Callable[[str], None] | None = None) -> dict:
    """The whole pipeline; writes the trees, their rules and a report; returns the report."""
    from lcmesh.distill.policy import DEFAULT_POLICY, PpoController
    from lcmesh.distill.ppo import git_commit
    from lcmesh.distill.ppo_env import episode_rewards
    from lcmesh.twin.system import load_system

    import torch

    torch.set_num_threads(1)  # tiny networks: one thread is fastest, and polite to the other cores
    say = on_step or (lambda _msg: None)
    system = load_system(cfg.system)
    layout = FeatureLayout.for_system(system)
    policy = cfg.policy or str(DEFAULT_POLICY)
    teacher = PpoController(system, policy)
    say("rolling the teacher over the training traces")
    scenarios = cfg.scenario_list()

    def spec(seed: int) -> str:
        return f"synthetic:{seed}" if scenarios == ("lcopt",) else f"synthetic:{seed}@{scenarios[seed % len(scenarios)]}"

    traces = [spec(s) for s in parse_seeds(cfg.train_seeds)]
    exp = collect_experience(teacher, system, traces)
    cab, tow = teacher_labels(teacher, exp)
    say("rolling the teacher over the held-out trace")
    held = collect_experience(teacher, system, [spec(cfg.heldout_seed)])
    held_cab, held_tow = teacher_labels(teacher, held)
    out = Path(cfg.out) if cfg.out else DEFAULT_TREES
    report: dict = {"config": asdict(cfg), "experience_steps": exp.n_steps, "teacher": teacher.version}
    reward_seeds = parse_seeds(cfg.reward_seeds)
    say("evaluating the teacher's episode reward")
    def rewards(controller) -> dict:
        return episode_rewards(controller, system.name, reward_seeds, scenarios=scenarios, reward=cfg.reward)

    report["teacher_reward"] = rewards(PpoController(system, policy))
    manifest = {"version": f"viper-{teacher.version}", "teacher": policy, "command": " ".join(sys.argv),
                "commit": git_commit(), "seed": cfg.seed, "system": system.name}  # fmt: skip
    for variant, uniform in (("viper", False), ("naive", True)):
        say(f"fitting the {variant} trees")
        trees = fit_trees(exp, cab, tow, cfg, layout, uniform)
        path = out if variant == "viper" else out.with_name(out.stem + "-naive.json")
        metrics = {"fidelity": fidelity(trees, held, held_cab, held_tow), "complexity": complexity(trees, teacher)}
        save_trees(path, trees, layout, {**manifest, "version": f"{variant}-{teacher.version}", "metrics": metrics})
        say(f"evaluating the {variant} trees' episode reward")
        metrics["reward"] = rewards(TreeController(system, path))
        save_trees(path, trees, layout, {**manifest, "version": f"{variant}-{teacher.version}", "metrics": metrics})
        report[variant] = {"path": str(path), **metrics}
        if variant == "viper":
            out.with_suffix(".rules.txt").write_text(rules_text(trees, cfg.rules_depth))
    t_total = report["teacher_reward"]["cabinet_reward"] + report["teacher_reward"]["tower_reward"]
    for variant in ("viper", "naive"):
        r = report[variant]["reward"]
        total = r["cabinet_reward"] + r["tower_reward"]
        report[variant]["reward_gap_pct"] = float(100 * (t_total - total) / abs(t_total)) if t_total else 0.0
    out.with_suffix(".report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


__all__ = ["DEFAULT_TREES", "TreeDistillConfig", "distill_trees", "parse_seeds"]
