"""``lcmesh bench llm``: the LLM backend, the distilled controller and its explanations, measured.

- load: the model straight from the GGUF vs from the unpacked safetensors cache (adapter merged);
- explanations: latency of short and detailed explanations of decisions spread over the Frontier
  day, and the pipeline's scores (LLM text, or the renderer where the LLM's text failed the checks);
- control: latency of one batched lcopt-5 decision (5 cabinets, one generate call);
- fidelity: action R^2 / MAE per head against the teacher on held-out decisions, parse failures;
- closed loop: KPIs on the Frontier day (+15 K wet bulb) with the LLM deciding every k steps,
  beside G36, the PPO teacher and the VIPER trees (LC-Opt Figure 10).
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from lcmesh.bench.machine import machine_info

EVAL_TRACE = "frontier-2024-04-07"
WET_BULB_OFFSET_K = 15.0


@dataclass
class BenchLlmConfig:
    """Sample counts and the closed-loop window."""

    hours: float = 2.0
    period_steps: int = 4
    adapter: str = "default"
    heldout_samples: int = 100
    explain_per_level: int = 12
    control_repeats: int = 8
    teacher: str = "ppo"
    system: str = "lcopt-5-paper"

    @classmethod
    def make(cls, *, quick: bool, **kw) -> "BenchLlmConfig":
        """The full benchmark, or with ``quick`` a smoke run (1 h loop, few samples)."""
        cfg = cls(**kw)
        if quick:
            cfg.hours, cfg.heldout_samples, cfg.explain_per_level, cfg.control_repeats = min(cfg.hours, 1.0), 15, 2, 2
        return cfg


def run_bench_llm(cfg: BenchLlmConfig, on_stage: Callable[[str], None] | None = None) -> dict:
    """All figures as one JSON-ready dict."""
    from lcmesh.llm.base import LlmBackendSettings
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
    backend = HfBackend(model_dir, adapter=resolve_adapter(settings.adapter), dtype=settings.dtype)
    cached_s = HfBackend(model_dir, adapter=resolve_adapter(settings.adapter), dtype=settings.dtype).load_seconds
    result["load"] = {"gguf_s": gguf_s, "safetensors_cache_s": cached_s, "speedup": gguf_s / cached_s,
                      "model_id": backend.model_id}  # fmt: skip
    say("held-out fidelity against the teacher")
    result["fidelity"] = _fidelity(cfg, system, backend)
    say("batched control decisions")
    result["control_latency"] = _control_latency(cfg, system, backend)
    say("explanations over the evaluation day")
    result["explanations"] = _explanations(cfg, system, backend, say)
    say("closed loop on the Frontier day")
    result["closed_loop"] = _closed_loop(cfg, system, backend, say)
    result["machine"]["load_avg_1m_at_end"] = os.getloadavg()[0]
    return result


def _fidelity(cfg: BenchLlmConfig, system, backend) -> dict:
    from lcmesh.distill.experience import collect_experience, resample
    from lcmesh.distill.llm import make_teacher, score_actions, step_view, teacher_targets

    teacher = make_teacher(cfg.teacher, system)
    held = collect_experience(teacher, system, ["synthetic:1003"], 960, wet_bulb_offset_k=WET_BULB_OFFSET_K)
    idx = resample(held, cfg.heldout_samples, np.random.default_rng(1), "cabinet", uniform=True)
    views = [step_view(held, int(t), int(c)) for t, c in idx]
    return {"trace": "synthetic:1003", "teacher": f"{teacher.name}:{teacher.version}",
            **score_actions(backend, views, teacher_targets(held, idx))}  # fmt: skip


def _eval_day_decisions(cfg: BenchLlmConfig, system, n: int):
    """(out, action, previous, wet bulb, cabinet) of the teacher at ``n`` steps spread over the evaluation day."""
    from lcmesh.distill.llm import make_teacher
    from lcmesh.twin.controllers import Observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import load_trace, scenario_with_offset

    trace = load_trace(EVAL_TRACE, system, scenario=scenario_with_offset("lcopt", WET_BULB_OFFSET_K))
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


def _explanations(cfg: BenchLlmConfig, system, backend, say) -> dict:
    from lcmesh.llm.explainer import LlmExplainer

    decisions = _eval_day_decisions(cfg, system, cfg.explain_per_level)
    explainer = LlmExplainer(system, backend)
    result = {}
    for level in ("short", "detailed"):
        rows = []
        for i, (out, action, previous, wb, cabinet) in enumerate(decisions):
            say(f"{level} explanation {i + 1}/{len(decisions)}")
            t0 = time.perf_counter()  # the whole pipeline: facts, LLM, checks, fallback
            r = explainer.explain(out, action, previous, wb, cabinet, level, record_id=f"{level}-{i}")
            seconds = time.perf_counter() - t0
            passes = getattr(backend, "last_forward_passes", None)
            rendered, rendered_scores = _rendering(system, out, action, previous, wb, cabinet, level)
            final = r.llm_scores if r.source == "llm" else rendered_scores
            rows.append({"seconds": seconds, "llm_seconds": r.seconds, "source": r.source, "reason": r.fallback_reason,
                         "new_tokens": r.new_tokens, "passes": passes, "llm": r.llm_scores, "final": final,
                         "as_rendered": r.source == "llm" and r.text.strip() == rendered.strip()})  # fmt: skip
        secs = [row["seconds"] for row in rows]
        reasons = [row["reason"] for row in rows if row["reason"]]
        result[level] = {
            "n": len(rows), "seconds_median": statistics.median(secs), "seconds_max": max(secs),
            "llm_seconds_median": statistics.median(row["llm_seconds"] for row in rows),
            "llm_used": sum(row["source"] == "llm" for row in rows),
            "llm_text_as_rendered": sum(row["as_rendered"] for row in rows),
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


def _control_latency(cfg: BenchLlmConfig, system, backend) -> dict:
    from lcmesh.llm.controller import LlmController
    from lcmesh.twin.controllers import Observation
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import load_trace, scenario_with_offset

    trace = load_trace(EVAL_TRACE, system, scenario=scenario_with_offset("lcopt", WET_BULB_OFFSET_K), hours=1)
    controller = LlmController(system, backend=backend, period_steps=1)
    lat = []
    with Plant(system) as plant:
        power = np.zeros(system.n_blade_groups)
        out = plant.out
        for k in range(cfg.control_repeats):
            obs = Observation(out, float(trace.wet_bulb_k[k]), trace.blade_power_w(k, out=power), k * trace.step_s)
            out = plant.step(power, obs.wet_bulb_k, controller.act(obs))
            lat.append(controller.stats["latency_s_last"])
    return {"cabinets": system.cabinets.count, "decisions": len(lat), "seconds_median": statistics.median(lat),
            "seconds_max": max(lat), "fallbacks": controller.stats_snapshot()["fallbacks"]}  # fmt: skip


def _closed_loop(cfg: BenchLlmConfig, system, backend, say) -> dict:
    from lcmesh.distill.llm import make_teacher
    from lcmesh.llm.controller import LlmController
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.run import run_twin
    from lcmesh.twin.traces import load_trace, scenario_with_offset

    trace = load_trace(EVAL_TRACE, system, scenario=scenario_with_offset("lcopt", WET_BULB_OFFSET_K), hours=cfg.hours)
    rows = {}
    for name in ("g36", "ppo", "tree", "llm"):
        try:
            if name == "llm":
                controller = LlmController(system, backend=backend, period_steps=cfg.period_steps)
            else:
                controller = make_teacher(name, system)
        except Exception as exc:  # a controller not trained yet is reported, not fatal
            rows[name] = {"error": f"{type(exc).__name__}: {exc}"}
            continue
        with Plant(system) as plant:
            t0 = time.perf_counter()
            n = trace.n_steps

            def on_step(k: int, name: str = name) -> None:
                if k % 20 == 0:
                    say(f"closed loop {name}: step {k + 1}/{n}")

            run = run_twin(plant, trace, controller, on_step=on_step)
            wall = time.perf_counter() - t0
        k = run.kpi
        rows[name] = {"d_blade_pct": k["d_blade_pct"], "ct_power_kw_avg": k["ct_power_kw_avg"],
                      "it_cooling_kw_avg": k["it_cooling_kw_avg"], "blade_temp_mean_c": k["blade_temp_mean_c"],
                      "blade_temp_max_c": k["blade_temp_max_c"], "cooling_power_kw_avg": k["cooling_power_kw_avg"],
                      "wall_s": wall, "version": getattr(controller, "version", "?")}  # fmt: skip
        if name == "llm":
            rows[name]["llm_stats"] = controller.stats_snapshot()
    return {"trace": f"{EVAL_TRACE} +{WET_BULB_OFFSET_K:g} K wet bulb, first {cfg.hours:g} h",
            "period_steps": cfg.period_steps, "controllers": rows}  # fmt: skip


def _draft_note(e: dict) -> str:
    """How the LLM's texts relate to the draft: word for word as rendered, forward passes per text."""
    if "llm_text_as_rendered" not in e:  # a report from before these were counted
        return ""
    passes = e.get("forward_passes_median")
    return (f", {e['llm_text_as_rendered']} of them word for word the rendering"
            + (f"; median {passes:g} forward pass{'' if passes == 1 else 'es'} for {e['new_tokens_median']:g} tokens"
               if passes else ""))


def render_llm(r: dict) -> str:
    """The BENCHMARKS.md section."""
    m, load, fid, ctl, ex, cl = (r["machine"], r["load"], r["fidelity"], r["control_latency"], r["explanations"],
                                 r["closed_loop"])  # fmt: skip

    def f(x, spec=".3f"):
        return "n/a" if x is None else format(x, spec)

    lines = [
        f"## LLM controller (`lcmesh bench llm --hours {r['config']['hours']:g} --period {r['config']['period_steps']} "
        "--json runs/bench/llm.json --markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs (shared; 1-min load average "
        f"{m['load_avg_1m_at_start']:.1f} at start, {m['load_avg_1m_at_end']:.1f} at end); commit {m['commit']}; "
        f"{m['date']}. Model {load['model_id']}.",
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| model load: GGUF vs unpacked safetensors cache (adapter merged), s | {load['gguf_s']:.1f} vs "
        f"{load['safetensors_cache_s']:.2f} | |",
        *(f"| {lvl} explanation, whole pipeline, s (median / max of {ex[lvl]['n']}; LLM text used in "
          f"{ex[lvl]['llm_used']}{_draft_note(ex[lvl])}) | {ex[lvl]['seconds_median']:.1f} / "
          f"{ex[lvl]['seconds_max']:.1f} | <= {limit} |"
          for lvl, limit in (("short", 3), ("detailed", 10))),
        f"| batched control decision, lcopt-5 ({ctl['cabinets']} cabinets), s (median / max of {ctl['decisions']}) | "
        f"{ctl['seconds_median']:.2f} / {ctl['seconds_max']:.2f} | <= 5 |",
        f"| CDU head R^2 vs teacher ({fid['teacher']}, {fid['parsed']} of {fid['n']} held-out decisions parsed) | "
        f"{f(fid.get('cdu_r2'))} (supply {f(fid.get('cdu_r2_per_dim', {}).get('supply_setpoint'))}, "
        f"dp {f(fid.get('cdu_r2_per_dim', {}).get('dp_setpoint'))}) | >= 0.9 |",
        f"| CDU MAE (supply °C, dp psi) | {f(fid.get('cdu_mae', {}).get('supply_setpoint_c'), '.2f')}, "
        f"{f(fid.get('cdu_mae', {}).get('dp_psi'), '.2f')} | |",
        f"| valve head R^2 / MAE per branch | {f(fid.get('valve_r2'))} / "
        f"{', '.join(f'{v:.3f}' for v in fid.get('valve_mae', []))} | |",
        f"| parse-failure rate (held-out) | {100 * fid['parse_failure_rate']:.1f} % {fid['failure_reasons'] or ''} | |",
    ]
    for level in ("short", "detailed"):
        e = ex[level]
        p, q = e["pipeline_scores"], e["llm_scores"]
        lines.append(
            f"| {level} explanations over the day: grounding / coverage / direction (pipeline; LLM text alone) | "
            f"{p['numeric_grounding']:.3f} / {p['coverage']:.3f} / {p['direction_consistency']:.3f} "
            f"({q['numeric_grounding']:.3f} / {q['coverage']:.3f} / {q['direction_consistency']:.3f}; LLM text used "
            f"{e['llm_used']} of {e['n']}) | >= 0.98 / 1.0 / >= 0.95 |"
        )
    lines += ["", f"Closed loop, {cl['trace']}, LLM deciding every {cl['period_steps']} steps (Figure 10):", "",
              "| controller | d_blade % | CT fan kW | blade mean °C | blade max °C | cooling kW | wall s |",
              "|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, row in cl["controllers"].items():
        if "error" in row:
            lines.append(f"| {name} | not available: {row['error'][:80]} | | | | | |")
            continue
        lines.append(f"| {name} | {row['d_blade_pct']:.2f} | {row['ct_power_kw_avg']:.1f} | "
                     f"{row['blade_temp_mean_c']:.2f} | {row['blade_temp_max_c']:.2f} | "
                     f"{row['cooling_power_kw_avg']:.1f} | {row['wall_s']:.0f} |")  # fmt: skip
    llm = cl["controllers"].get("llm", {}).get("llm_stats")
    if llm:
        lines += ["", f"LLM controller: {llm['cabinet_decisions']} cabinet decisions, {llm['fallbacks']} fallbacks to "
                      f"{llm['fallback_controller']} ({llm['fallback_reasons'] or 'none'}), mean decision "
                      f"{llm['latency_s_mean']:.2f} s."]  # fmt: skip
    return "\n".join(lines)
