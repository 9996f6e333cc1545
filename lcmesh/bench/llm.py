"""``lcmesh bench llm``: the LLM backend, the distilled controller and its explanations, measured.

- load: the model straight from the GGUF vs from the unpacked safetensors cache (adapter merged);
- explanations: latency of short and detailed explanations of decisions spread over the Frontier
  day, and the pipeline's scores (LLM text, or the renderer where the LLM's text failed the checks);
  how many LLM texts are the rendering word for word (the template's), and how many carry a what-if
  claim the rendering lacks that the judge passed (``lcmesh.llm.explainer.whatif_claims``);
- control: latency of one batched lcopt-5 decision (5 cabinets and 2 towers, one generate call);
- fidelity: action R^2 / MAE per head against the teacher on held-out decisions, the towers' approach
  MAE, parse failures;
- closed loop on the held-out suite (``lcmesh.bench.suite.TEST_DAYS``): on each day the busiest
  ``hours`` (the window of highest mean load, picked from the trace alone) after a 30-minute warm-up
  run by the same controller, the LLM deciding every k steps beside G36, the strong rule, the PPO
  teacher, the trees and the readable tree (LC-Opt Figure 10).
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from lcmesh.bench.engine import cache_lines
from lcmesh.bench.machine import machine_info

EVAL_TRACE = "frontier-2024-04-07"
EVAL_SCENARIO = "frontier"
HELDOUT_TRACE = "synthetic:1003@design-day"  # the teacher's decisions on a day no model trained on
LOOP_CONTROLLERS = ("g36", "rule", "ppo", "tree", "readable", "llm")
WARMUP_STEPS = 120  # 30 min run by each controller itself before its scored window: stateful ones (G36) settle


@dataclass
class BenchLlmConfig:
    """Sample counts and the closed-loop window."""

    hours: float = 1.0
    period_steps: int = 8
    adapter: str = "default"
    heldout_samples: int = 100
    explain_per_level: int = 12
    control_repeats: int = 8
    teacher: str = "ppo"
    system: str = "lcopt-5"
    days: str = ""
    """Comma-separated suite test days for the closed loop (empty: all)."""
    control_adapter: str = "default"
    """The LLM controller's adapter (lcmesh/artifacts/llm-control by default)."""
    control_threads: int = 1
    """llama.cpp threads of the LLM controller (as the mesh runs it)."""
    sections: str = "fidelity,control,explain,loop"
    """What to run: fidelity, control, explain, loop (busiest hour per day), days (whole days: hours each)."""
    whole_day_period: int = 8
    """Whole days: the decision period, as the demo mesh runs the LLM at its default speed (see docs/llm.md)."""

    @classmethod
    def make(cls, *, quick: bool, **kw) -> "BenchLlmConfig":
        """The full benchmark, or with ``quick`` a smoke run (1 h loop, few samples)."""
        cfg = cls(**kw)
        if quick:
            cfg.hours, cfg.heldout_samples, cfg.explain_per_level, cfg.control_repeats = min(cfg.hours, 0.25), 15, 2, 2
            cfg.days = cfg.days or "frontier,hot-1033"
        return cfg


def run_bench_llm(cfg: BenchLlmConfig, on_stage: Callable[[str], None] | None = None, engine=None) -> dict:
    """All figures as one JSON-ready dict; the closed-loop and whole-day units run on ``engine`` (EngineSettings)."""
    from lcmesh.llm.base import LlmBackendSettings, make_backend
    from lcmesh.llm.controller import make_control_backend
    from lcmesh.llm.explainer import short_backend_for
    from lcmesh.llm.hf.backend import HfBackend, resolve_adapter
    from lcmesh.llm.hf.unpack import gguf_load_seconds
    from lcmesh.llm.model_cache import resolve_model, shipped_gguf
    from lcmesh.twin.system import load_system

    say = on_stage or (lambda _m: None)
    system = load_system(cfg.system)
    result: dict = {"machine": {**machine_info(), "load_avg_1m_at_start": os.getloadavg()[0]}, "config": asdict(cfg)}
    say("loading the model (GGUF, then the safetensors cache)")
    model_dir = resolve_model("smollm2-135m-instruct")
    gguf_s = gguf_load_seconds(shipped_gguf())
    settings = LlmBackendSettings(adapter=cfg.adapter)
    hf = HfBackend(model_dir, adapter=resolve_adapter(settings.adapter), dtype=settings.dtype)
    cached_s = HfBackend(model_dir, adapter=resolve_adapter(settings.adapter), dtype=settings.dtype).load_seconds
    backend = make_backend(settings)  # the explainer as the mesh runs it (llama.cpp with the merged adapter)
    control = make_control_backend(cfg.control_adapter, threads=cfg.control_threads)
    result["load"] = {"gguf_s": gguf_s, "safetensors_cache_s": cached_s, "speedup": gguf_s / cached_s,
                      "model_id": backend.model_id, "hf_model_id": hf.model_id, "control_model_id": control.model_id,
                      "control_load_s": control.load_seconds}  # fmt: skip
    sections = {s.strip() for s in cfg.sections.split(",") if s.strip()}
    if "fidelity" in sections:
        say("held-out fidelity against the teacher")
        result["fidelity"] = _fidelity(cfg, system, control, say)
    if "control" in sections:
        say("control decisions")
        result["control_latency"] = _control_latency(cfg, system, control)
    if "explain" in sections:
        say("explanations over the evaluation day")
        result["explanations"] = _explanations(cfg, system, backend, say, short_backend_for(settings))
    if "loop" in sections:
        say("closed loop on the held-out days")
        result["closed_loop"] = _closed_loop(cfg, system, say, engine)
    if "days" in sections:
        say("whole held-out days")
        result["whole_days"] = _whole_days(cfg, system, say, engine)
    result["machine"]["load_avg_1m_at_end"] = os.getloadavg()[0]
    return result


def _fidelity(cfg: BenchLlmConfig, system, control, say) -> dict:
    """The controller's answers on decisions of a held-out day against its teacher's (the raw policy targets)."""
    from lcmesh.distill.experience import collect_experience
    from lcmesh.distill.llm_control import build_samples, raw_targets, score_dev
    from lcmesh.distill.policy import PpoController

    teacher = PpoController(system)
    held = collect_experience(teacher, system, [HELDOUT_TRACE], 960)
    cab, appr = raw_targets(teacher, held)
    rng = np.random.default_rng(1)
    T, C, N = held.cabinet_rows.shape[0], system.cabinets.count, system.towers.count
    n_t = max(cfg.heldout_samples // 4, 1)
    idx_c = np.column_stack([rng.integers(0, T, cfg.heldout_samples), rng.integers(0, C, cfg.heldout_samples)])
    idx_t = np.column_stack([rng.integers(0, T, n_t), rng.integers(0, N, n_t)])
    samples = build_samples(held, cab, appr, system, idx_c, idx_t)
    scores = score_dev(control.decoder, samples, lambda _s, i, n: say(f"held-out fidelity {i}/{n}"))
    return {"trace": HELDOUT_TRACE, "teacher": f"{teacher.name}:{teacher.version}", **scores}


def _eval_day_decisions(cfg: BenchLlmConfig, system, n: int):
    """(out, action, previous, wet bulb, cabinet) of the teacher at ``n`` steps spread over the evaluation day."""
    from lcmesh.distill.llm import make_teacher
    from lcmesh.twin.controllers import Observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import load_trace

    trace = load_trace(EVAL_TRACE, system, scenario=EVAL_SCENARIO)
    picks = set(np.linspace(60, trace.n_steps - 1, n).astype(int).tolist())
    teacher, found, previous = make_teacher(cfg.teacher, system), [], None
    with Plant(system) as plant:
        power = np.zeros(system.n_blade_groups)
        out = plant.out
        for k in range(max(picks) + 1):
            obs = Observation(out, float(trace.wet_bulb_k[k]), trace.blade_power_w(k, out=power), k * trace.step_s)
            action = teacher.act(obs).copy()
            if k in picks:
                cabinet = int(np.argmax(out["branch_temp_k"].max(axis=1)))  # the mesh explains the hottest cabinet
                found.append(({key: np.array(v) for key, v in out.items()}, action, previous, obs.wet_bulb_k, cabinet))
            previous = action
            out = plant.step(power, obs.wet_bulb_k, action)
    return found


def _explanations(cfg: BenchLlmConfig, system, backend, say, short_backend=None) -> dict:
    from lcmesh.llm.explainer import TARGET_S, LlmExplainer

    decisions = _eval_day_decisions(cfg, system, cfg.explain_per_level)
    explainer = LlmExplainer(system, backend, short_backend=short_backend)  # as make_explainer builds it for the mesh
    result = {}
    for level in ("short", "detailed"):
        rows = []
        for i, (out, action, previous, wb, cabinet) in enumerate(decisions):
            say(f"{level} explanation {i + 1}/{len(decisions)}")
            t0 = time.perf_counter()  # the whole pipeline: facts, LLM, checks, fallback
            r = explainer.explain(out, action, previous, wb, cabinet, level, record_id=f"{level}-{i}")
            seconds = time.perf_counter() - t0
            passes = getattr(backend, "last_forward_passes", None) if r.llm_part == "whole" else None
            rendered, rendered_scores = _rendering(system, out, action, previous, wb, cabinet, level)
            final = r.llm_scores if r.source == "llm" else rendered_scores
            rows.append({"seconds": seconds, "llm_seconds": r.seconds, "source": r.source, "reason": r.fallback_reason,
                         "new_tokens": r.new_tokens, "passes": passes, "llm": r.llm_scores, "final": final,
                         "as_rendered": r.source == "llm" and r.text.strip() == rendered.strip(),
                         "whatif_claims": r.whatif_claims, "llm_part": r.llm_part, "text": r.text})  # fmt: skip
        secs = [row["seconds"] for row in rows]
        reasons = [row["reason"] for row in rows if row["reason"]]
        result[level] = {
            "n": len(rows), "seconds_median": statistics.median(secs), "seconds_max": max(secs),
            "llm_seconds_median": statistics.median(row["llm_seconds"] for row in rows),
            "llm_used": sum(row["source"] == "llm" for row in rows),
            "llm_part": sorted({row["llm_part"] for row in rows}),
            "llm_with_whatif_claim_in_budget": sum(bool(row["whatif_claims"]) and row["seconds"] <= TARGET_S[level]
                                                   for row in rows),  # fmt: skip
            "llm_text_as_rendered": sum(row["as_rendered"] for row in rows),
            "llm_with_whatif_claim": sum(bool(row["whatif_claims"]) for row in rows),
            "whatif_claims": {k: sum(k in row["whatif_claims"] for row in rows)
                              for k in sorted({c for row in rows for c in row["whatif_claims"]})},
            "example": next((row["text"] for row in rows if row["whatif_claims"]), None),
            "forward_passes_median": (statistics.median(row["passes"] for row in rows)
                                      if all(row["passes"] is not None for row in rows) else None),
            "new_tokens_median": statistics.median(row["new_tokens"] for row in rows),
            "fallback_reasons": {k: reasons.count(k) for k in sorted(set(reasons))},
            "llm_scores": _mean_scores([row["llm"] for row in rows]),
            "pipeline_scores": _mean_scores([row["final"] for row in rows]),
        }  # fmt: skip
    return result


def _rendering(system, out, action, previous, wb, cabinet, level) -> tuple[str, dict]:
    """The toolbox rendering of the decision and its scores."""
    from lcmesh.mesh.tools.explain import explanation_record, render_explanation
    from lcmesh.mesh.tools.explain_eval import evaluate_record
    from lcmesh.mesh.tools.facts import cabinet_decision_facts

    facts = cabinet_decision_facts(system, out, action, previous, wb, cabinet)
    text = render_explanation(facts, level)
    record = explanation_record(out, action, facts, text, cabinet=cabinet, record_id="r", previous_action=previous,
                                wet_bulb_k=wb, level=level)  # fmt: skip
    item = evaluate_record(record)
    return text, {k: float(item[k]) for k in ("numeric_grounding", "coverage", "direction_consistency")}


def _mean_scores(rows: list[dict]) -> dict:
    return {k: float(np.mean([r[k] for r in rows])) for k in ("numeric_grounding", "coverage", "direction_consistency")}


def _control_latency(cfg: BenchLlmConfig, system, control) -> dict:
    from lcmesh.llm.controller import LlmController
    from lcmesh.twin.controllers import Observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import load_trace

    trace = load_trace(EVAL_TRACE, system, scenario=EVAL_SCENARIO, hours=1)
    # the plant's decisions batched (the default) and one prompt after another, side by side on the same observation
    # and the same runtime, alternating, so a busy moment hits both alike
    ways = {"batched": LlmController(system, backend=control, period_steps=1),
            "sequential": LlmController(system, backend=control, period_steps=1)}  # fmt: skip
    lat: dict[str, list[float]] = {w: [] for w in ways}
    passes: dict[str, list[int]] = {w: [] for w in ways}
    same = 0
    with Plant(system) as plant:
        power = np.zeros(system.n_blade_groups)
        out = plant.out
        for k in range(cfg.control_repeats):
            obs = Observation(out, float(trace.wet_bulb_k[k]), trace.blade_power_w(k, out=power), k * trace.step_s)
            actions = {}
            for way, controller in ways.items():
                control.batched = way == "batched"
                actions[way] = controller.act(obs)
                lat[way].append(controller.stats["latency_s_last"])
                passes[way].append(control.last_forward_passes)
            same += ways["batched"].last_answers == ways["sequential"].last_answers
            out = plant.step(power, obs.wet_bulb_k, actions["batched"])
    control.batched = True
    b, s = statistics.median(lat["batched"]), statistics.median(lat["sequential"])
    return {"cabinets": system.cabinets.count, "towers": system.towers.count, "decisions": len(lat["batched"]),
            "seconds_median": b, "seconds_max": max(lat["batched"]), "sequential_seconds_median": s,
            "speedup": s / b, "same_answers": same,
            "fallbacks": ways["batched"].stats_snapshot()["fallbacks"],
            "forward_passes_per_decision": statistics.mean(passes["batched"]),
            "sequential_forward_passes_per_decision": statistics.mean(passes["sequential"]),
            "threads": cfg.control_threads, "runtime": "llama.cpp"}  # fmt: skip


def busiest_window(trace, steps: int) -> int:
    """The first step of the ``steps``-long window with the highest mean plant load (from the trace alone)."""
    load = trace.cabinet_load_w.sum(axis=1)
    if steps >= load.size:
        return 0
    window = np.convolve(load, np.ones(steps), mode="valid")
    return int(np.argmax(window))


def _llm_options(cfg: BenchLlmConfig, period: int) -> dict:
    """The LLM controller as the bench runs it: its own runtime in the unit's process, the bench's adapter, threads."""
    return {"period_steps": period, "adapter": cfg.control_adapter, "threads": cfg.control_threads}


def _days(cfg: BenchLlmConfig):
    from lcmesh.bench.suite import TEST_DAYS, VALIDATION_DAYS, days_named

    return TEST_DAYS if not cfg.days else days_named([d.strip() for d in cfg.days.split(",") if d.strip()],
                                                     TEST_DAYS + VALIDATION_DAYS)  # fmt: skip


def _closed_loop(cfg: BenchLlmConfig, system, say, engine=None) -> dict:
    """The busiest ``hours`` of each day after a warm-up, every loop controller; the (controller, day) units on the
    engine (lcmesh/bench/engine.py), the LLM's with its threads as CPUs."""
    from lcmesh.bench.engine import cache_summary, run_units
    from lcmesh.bench.suite import day_units, load_day

    days = _days(cfg)
    steps = max(int(round(cfg.hours * 240)), 1)
    windows, spans = {}, {}
    for day in days:
        full = load_day(day, system)
        start = busiest_window(full, steps)
        warm = min(WARMUP_STEPS, start)
        spans[day.label] = (start, warm, min(steps, full.n_steps - start))
        windows[day.label] = {"start_h": start * full.step_s / 3600.0,
                              "hours": spans[day.label][2] * full.step_s / 3600.0,
                              "warmup_h": warm * full.step_s / 3600.0}  # fmt: skip
    rows: dict[str, dict] = {}
    units = []
    for name in LOOP_CONTROLLERS:
        options = _llm_options(cfg, cfg.period_steps) if name == "llm" else None
        try:
            units += day_units(name, cfg.system, days, None, options=options, windows=spans)
            rows[name] = {"days": {}}
        except Exception as exc:  # a controller not trained yet is reported, not fatal
            rows[name] = {"error": f"{type(exc).__name__}: {exc}"}
    outcomes = run_units(units, engine, lambda stage, done, total: say(f"closed loop: {stage} ({done}/{total})"))
    labels = {(d.trace, d.scenario): d.label for d in days}
    for o in outcomes:
        row = rows[o.unit.kwargs["controller"]]
        label = labels[(o.unit.kwargs["trace"], o.unit.kwargs["scenario"])]
        if "error" in row:
            continue
        if o.error is not None:
            rows[o.unit.kwargs["controller"]] = {"error": f"{label}: {o.error}"}
            continue
        row["days"][label] = o.result
    for name, row in rows.items():
        if "error" not in row and row["days"]:
            got = list(row["days"].values())
            row["mean"] = {k: float(np.mean([d[k] for d in got])) for k in ("d_blade_pct", "cooling_kwh", "blade_max_c")}
            row["mean"]["travel"] = {k: float(np.mean([d["travel"][k] for d in got]))
                                     for k in ("supply_temp_setpoint_k", "dp_setpoint_pa", "lw_setpoint_k")}  # fmt: skip
            row["std_d_blade"] = float(np.std([d["d_blade_pct"] for d in got], ddof=1)) if len(got) > 1 else 0.0
            if name == "llm":
                row["llm_stats"] = _sum_stats([d.pop("controller_stats") for d in got])
    return {"days": windows, "period_steps": cfg.period_steps, "controllers": rows, "cache": cache_summary(outcomes)}


def _whole_days(cfg: BenchLlmConfig, system, say, engine=None) -> dict:
    """Whole held-out days: the LLM (deciding every ``whole_day_period`` steps) beside its teacher, same guardrails;
    every (controller, day) a unit on the engine."""
    from lcmesh.bench.engine import cache_summary, run_units
    from lcmesh.bench.suite import day_units

    days = _days(cfg)
    units = day_units("ppo", cfg.system, days, None)
    units += day_units("llm", cfg.system, days, None, options=_llm_options(cfg, cfg.whole_day_period))
    outcomes = run_units(units, engine, lambda stage, done, total: say(f"whole days: {stage} ({done}/{total})"))
    failed = [f"{o.unit.label}: {o.error}" for o in outcomes if o.error is not None]
    if failed:
        raise RuntimeError("whole days failed: " + "; ".join(failed))
    rows = {"ppo": {d.label: o.result for d, o in zip(days, outcomes[:len(days)])},
            "llm": {d.label: o.result for d, o in zip(days, outcomes[len(days):])}}  # fmt: skip
    stats = [r.pop("controller_stats") for r in rows["llm"].values()]
    mean = {name: float(np.mean([d["d_blade_pct"] for d in r.values()])) for name, r in rows.items()}
    return {"period_steps": cfg.whole_day_period, "days": rows, "mean_d_blade": mean,
            "gap_points": mean["ppo"] - mean["llm"], "llm_stats": _sum_stats(stats),
            "cache": cache_summary(outcomes)}  # fmt: skip


def _sum_stats(stats: list[dict]) -> dict:
    """The LLM controller's counters over the days."""
    total: dict = {}
    for s in stats:
        for k in ("decisions", "cabinet_decisions", "llm_cabinet_actions", "tower_decisions", "llm_tower_actions",
                  "fallbacks", "latency_s_total"):
            total[k] = total.get(k, 0) + s.get(k, 0)
        for key in ("fallback_reasons", "fallbacks_by_kind"):
            for r, n in s.get(key, {}).items():
                total.setdefault(key, {})[r] = total.setdefault(key, {}).get(r, 0) + n
        total["fallback_controller"] = s.get("fallback_controller")
    total["latency_s_mean"] = total.get("latency_s_total", 0.0) / max(total.get("decisions", 0), 1)
    return total


def _draft_note(e: dict) -> str:
    """How the LLM's texts relate to the draft: word for word as rendered, forward passes per text."""
    if "llm_text_as_rendered" not in e:  # a report from before these were counted
        return ""
    passes = e.get("forward_passes_median")
    return (f", {e['llm_text_as_rendered']} of them word for word the rendering"
            + (f"; median {passes:g} forward pass{'' if passes == 1 else 'es'} for {e['new_tokens_median']:g} tokens"
               if passes else ""))


def render_llm(r: dict) -> str:
    """The BENCHMARKS.md section (the parts that were run)."""
    from lcmesh.llm.explainer import TARGET_S

    m, load, c = r["machine"], r["load"], r["config"]

    def f(x, spec=".2f"):
        return "n/a" if x is None else format(x, spec)

    lines = [
        f"## LLM controller (`lcmesh bench llm --hours {c['hours']:g} --period {c['period_steps']} "
        "--json runs/bench/llm.json --markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs (shared; 1-min load average "
        f"{m['load_avg_1m_at_start']:.1f} at start, {m['load_avg_1m_at_end']:.1f} at end); commit {m['commit']}; "
        f"{m['date']}. Controller: {load.get('control_model_id', '?')} (llama.cpp, {c.get('control_threads', 1)} "
        f"thread); explainer: {load['model_id']}.",
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| model load: GGUF into transformers vs unpacked safetensors cache vs llama.cpp with the control adapter, s | "
        f"{load['gguf_s']:.1f} vs {load['safetensors_cache_s']:.2f} vs {f(load.get('control_load_s'))} | |",
    ]
    ex = r.get("explanations")
    if r.get("explain_run"):  # the explanation rows were measured in a run of their own (`--sections explain`)
        run = r["explain_run"]
        lines[2] += (f" The explanation rows: `lcmesh bench llm --sections explain` at commit {run['commit']}, "
                     f"{run['date']} (load average {run['load_avg_1m_at_start']:.1f} at start).")
    if ex:
        lines += [f"| {lvl} explanation, whole pipeline, s (median / max of {ex[lvl]['n']}; LLM text used in "
                  f"{ex[lvl]['llm_used']}{_draft_note(ex[lvl])}) | {ex[lvl]['seconds_median']:.1f} / "
                  f"{ex[lvl]['seconds_max']:.1f} | <= {limit} |" for lvl, limit in (("short", 3), ("detailed", 10))]
    ctl = r.get("control_latency")
    if ctl:
        lines.append(f"| one control decision, {c['system']} ({ctl['cabinets']} cabinets, {ctl.get('towers', 0)} towers, "
                     f"{f(ctl.get('forward_passes_per_decision'), '.0f')} forward passes), s (median / max of "
                     f"{ctl['decisions']}) | {ctl['seconds_median']:.2f} / {ctl['seconds_max']:.2f} | |")
        if "sequential_seconds_median" in ctl:
            lines.append(f"| the same decisions one prompt after another ({f(ctl['sequential_forward_passes_per_decision'], '.0f')}"
                         f" passes), s (median); batched speed-up; answers the same | "
                         f"{ctl['sequential_seconds_median']:.2f}; {ctl['speedup']:.2f}x; {ctl['same_answers']} of "
                         f"{ctl['decisions']} | batched <= 1/3 of the sequential |")  # fmt: skip
    fid = r.get("fidelity")
    if fid:
        lines += [
            f"| held-out decisions ({fid['trace']}, {fid['n']} answers) vs teacher {fid['teacher']}: supply MAE K, "
            f"dp MAE psi, valve weight MAE (0-9), approach MAE K | {f(fid['supply_mae_k'])}, {f(fid['dp_mae_psi'])}, "
            f"{f(fid['valve_weight_mae'])}, {f(fid['approach_mae_k'])} | |",
            f"| answers exactly the teacher's (at the protocol's resolution) | {100 * fid['exact_answer_rate']:.0f} % | |",
        ]
    if ex:
        for level in ("short", "detailed"):
            e = ex[level]
            p, q = e["pipeline_scores"], e["llm_scores"]
            lines.append(
                f"| {level} explanations over the day: grounding / coverage / direction (pipeline; LLM text alone) | "
                f"{p['numeric_grounding']:.3f} / {p['coverage']:.3f} / {p['direction_consistency']:.3f} "
                f"({q['numeric_grounding']:.3f} / {q['coverage']:.3f} / {q['direction_consistency']:.3f}; LLM text "
                f"used {e['llm_used']} of {e['n']}) | >= 0.98 / 1.0 / >= 0.95 |"
            )
            if "llm_with_whatif_claim" in e:
                part = " (the rendering, then the LLM's WHAT IF)" if e.get("llm_part") == ["what-if"] else ""
                in_budget = e.get("llm_with_whatif_claim_in_budget")
                within = "" if in_budget is None else f", and within {TARGET_S[level]:g} s"
                counted = "" if in_budget is None else f", {in_budget} within it"
                lines.append(f"| {level}{part}: explanations with a verified what-if claim the rendering lacks (of "
                             f"{e['n']}; claims {e['whatif_claims'] or 'none'}){within} | {e['llm_with_whatif_claim']} "
                             f"({100 * e['llm_with_whatif_claim'] / max(e['n'], 1):.0f} %){counted} | >= 50 % |")
    cl = r.get("closed_loop")
    if cl:
        lines += _render_loop(cl)
    wd = r.get("whole_days")
    if wd:
        lines += _render_whole_days(wd)
    return "\n".join(lines)


def _llm_line(llm: dict) -> str:
    n = llm["cabinet_decisions"] + llm.get("tower_decisions", 0)
    made = llm["llm_cabinet_actions"] + llm.get("llm_tower_actions", 0)
    return (f"LLM controller: it made {made:,} of {n:,} cabinet and tower decisions ({100 * made / max(n, 1):.1f} %); "
            f"{llm['fallbacks']} served by {llm['fallback_controller']} ({llm.get('fallback_reasons') or 'none'}); mean "
            f"decision {llm['latency_s_mean']:.2f} s.")


def _render_loop(cl: dict) -> list[str]:
    labels = list(cl["days"])
    lines = ["", f"Closed loop on the held-out suite: each day's busiest {next(iter(cl['days'].values()))['hours']:g} h "
             "(highest mean load; start hour per day below) after a 30-min warm-up by the same controller, the LLM "
             f"deciding every {cl['period_steps']} steps with no deadline "
             "(Figure 10), every controller behind the mesh's guardrails. D_blade % per day; mean over the days, "
             "cooling kWh and supply / dp / tower leaving-water travel per window:", "",
             "| controller | mean D_blade % | mean cooling kWh | worst blade °C | supply travel K | dp travel psi | "
             "tower LW travel K | " + " | ".join(labels) + " |",
             "|---|---|---|---|---|---|---|" + "---|" * len(labels)]  # fmt: skip
    for name, row in cl["controllers"].items():
        if "error" in row:
            lines.append(f"| {name} | not available: {row['error'][:80]} |")
            continue
        if "mean" not in row:
            continue
        worst = max(d["blade_max_c"] for d in row["days"].values())
        cells = " | ".join(f"{row['days'][d]['d_blade_pct']:.2f}" if d in row["days"] else "-" for d in labels)
        tr = row["mean"].get("travel", {})
        nan = float("nan")
        lines.append(f"| {name} | {row['mean']['d_blade_pct']:.2f} +- {row['std_d_blade']:.2f} | "
                     f"{row['mean']['cooling_kwh']:.0f} | {worst:.1f} | {tr.get('supply_temp_setpoint_k', nan):,.0f} | "
                     f"{tr.get('dp_setpoint_pa', nan) / 6894.757:,.0f} | {tr.get('lw_setpoint_k', nan):,.0f} | "
                     f"{cells} |")  # fmt: skip
    lines += ["", "Window start hour per day: " + ", ".join(f"{d} {w['start_h']:.2f}" for d, w in cl["days"].items())]
    llm = cl["controllers"].get("llm", {}).get("llm_stats")
    if llm:
        lines += ["", _llm_line(llm)]
    checks = loop_checks(cl)
    if checks:
        lines += ["", "| issue 22 target (closed loop) | measured | met |", "|---|---|---|"]
        lines += [f"| {c['target']} | {c['measured']} | {'yes' if c['met'] else 'no'} |" for c in checks]
    lines += cache_lines(cl.get("cache", {}))
    return lines


def loop_checks(cl: dict) -> list[dict]:
    """The closed-loop targets checked on the result itself."""
    rows = cl["controllers"]
    llm, rule, g36 = rows.get("llm", {}), rows.get("rule", {}), rows.get("g36", {})
    if "mean" not in llm:
        return []
    out = []
    m = llm["mean"]["d_blade_pct"]
    if "mean" in rule:
        out.append({"target": "mean D_blade >= the strong rule's and >= 97 %", "met": m >= rule["mean"]["d_blade_pct"] and m >= 97.0,
                    "measured": f"{m:.2f} % (rule {rule['mean']['d_blade_pct']:.2f} %)"})  # fmt: skip
    if "days" in g36:
        gaps = {d: g36["days"][d]["d_blade_pct"] - v["d_blade_pct"] for d, v in llm["days"].items() if d in g36["days"]}
        worst = max(gaps, key=gaps.get)
        out.append({"target": "no day more than 5 points below G36", "met": gaps[worst] <= 5.0,
                    "measured": f"worst {worst}: {gaps[worst]:+.2f} points below G36"})  # fmt: skip
    s = llm.get("llm_stats")
    if s:
        n = s["cabinet_decisions"] + s.get("tower_decisions", 0)
        share = s["fallbacks"] / max(n, 1)
        out.append({"target": "<= 2 % of decisions served by the fallback (no deadline here)", "met": share <= 0.02,
                    "measured": f"{100 * share:.1f} % of {n:,}"})  # fmt: skip
    return out


def _render_whole_days(wd: dict) -> list[str]:
    labels = list(wd["days"]["llm"])
    lines = ["", f"Whole held-out days: the LLM deciding every {wd['period_steps']} steps (the demo mesh's period at "
             "its default speed), beside its teacher deciding every step; both behind the guardrails and the hold "
             "band. D_blade % per day:", "",
             "| controller | mean D_blade % | " + " | ".join(labels) + " |", "|---|---|" + "---|" * len(labels)]  # fmt: skip
    for name, days in wd["days"].items():
        lines.append(f"| {name} | {wd['mean_d_blade'][name]:.2f} | "
                     + " | ".join(f"{days[d]['d_blade_pct']:.2f}" for d in labels) + " |")  # fmt: skip
    short_by = {d: wd["days"]["ppo"][d]["d_blade_pct"] - wd["days"]["llm"][d]["d_blade_pct"] for d in labels}
    worst = max(short_by, key=short_by.get)
    lines += ["", f"Gap to the teacher: {wd['gap_points']:+.2f} points over the days (target: within 1; positive: the "
              f"LLM below); the day furthest below: {worst}, {short_by[worst]:+.2f}. " + _llm_line(wd["llm_stats"])]
    if wd.get("run"):  # measured in runs of their own (`--sections days`)
        run = wd["run"]
        lines.append(f"Measured by `lcmesh bench llm --sections days --days {','.join(labels)} --whole-day-period "
                     f"{wd['period_steps']}` at commit {run['commit']}, {run['date']}.")
    from lcmesh.bench.suite import TEST_DAYS

    missing = [d.label for d in TEST_DAYS if d.label not in labels]
    llm, ppo = wd["days"]["llm"], wd["days"]["ppo"]
    cooling = {name: sum(days[d]["cooling_kwh"] for d in labels) for name, days in (("llm", llm), ("ppo", ppo))}
    wall_h = np.mean([llm[d]["wall_s"] for d in labels]) / 3600
    lines.append(f"Cooling energy over the days: {cooling['llm']:,.0f} kWh for the LLM against {cooling['ppo']:,.0f} "
                 f"for the teacher ({100 * (cooling['llm'] / cooling['ppo'] - 1):+.1f} %). A day took {wall_h:.2f} h "
                 f"of wall time for the LLM (one thread; on shared cores, so the decision times above are an upper bound)." + (f" Not run: {', '.join(missing)} ({len(labels)} of {len(TEST_DAYS)} "
                                                 f"test days measured)." if missing else ""))  # fmt: skip
    lines += cache_lines(wd.get("cache", {}))
    return lines
