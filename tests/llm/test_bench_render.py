"""The BENCHMARKS.md section renders every figure of a bench result (structure from run_bench_llm)."""

from __future__ import annotations

from lcmesh.bench.llm import render_llm
from lcmesh.bench.report import update_benchmarks_md


def _result() -> dict:
    scores = {"numeric_grounding": 1.0, "coverage": 1.0, "direction_consistency": 1.0}
    expl = {"n": 2, "seconds_median": 2.5, "seconds_max": 2.9, "llm_used": 1, "fallback_reasons": {"coverage": 1},
            "llm_scores": scores, "pipeline_scores": scores}  # fmt: skip
    expl = {**expl, "llm_with_whatif_claim": 1, "whatif_claims": {"hottest_branch_if_held": 1}}
    day = {"d_blade_pct": 90.0, "cooling_kwh": 120.0, "blade_max_c": 39.0}
    row = {"days": {"frontier": day, "hot-1033": {**day, "d_blade_pct": 80.0}},
           "mean": {"d_blade_pct": 85.0, "cooling_kwh": 120.0, "blade_max_c": 39.0,
                    "travel": {"supply_temp_setpoint_k": 42.0, "dp_setpoint_pa": 6894.757 * 3, "lw_setpoint_k": 7.0}},
           "std_d_blade": 7.07}
    return {
        "machine": {"cpu": "cpu", "logical_cpus": 2, "commit": "abc", "date": "today", "load_avg_1m_at_start": 1.0,
                    "load_avg_1m_at_end": 2.0},
        "config": {"hours": 24.0, "period_steps": 8, "system": "lcopt-5", "control_threads": 1},
        "load": {"gguf_s": 15.0, "safetensors_cache_s": 0.7, "speedup": 21.0, "model_id": "m+a",
                 "control_model_id": "q4+llm-control@llama.cpp", "control_load_s": 0.4},
        "fidelity": {"trace": "synthetic:1003@design-day", "teacher": "ppo:case7", "n": 10, "supply_mae_k": 0.61,
                     "dp_mae_psi": 0.9, "valve_weight_mae": 0.4, "approach_mae_k": 0.25, "exact_answer_rate": 0.3},
        "control_latency": {"cabinets": 5, "towers": 2, "decisions": 3, "seconds_median": 2.0, "seconds_max": 2.2,
                            "fallbacks": 0, "forward_passes_per_decision": 44},
        "explanations": {"short": expl, "detailed": expl},
        "closed_loop": {"days": {"frontier": {"start_h": 5.5, "hours": 1.0}, "hot-1033": {"start_h": 14.0, "hours": 1.0}},
                        "period_steps": 4,
                        "controllers": {"g36": row, "tree": {"error": "FileNotFoundError: no trees"},
                                        "rule": {**row, "mean": {**row["mean"], "d_blade_pct": 84.0}},
                                        "llm": {**row, "llm_stats": {"cabinet_decisions": 5, "tower_decisions": 2,
                                                "llm_cabinet_actions": 5, "llm_tower_actions": 1,
                                                "fallbacks": 1, "fallbacks_by_kind": {"tower": 1},
                                                "fallback_controller": "ppo", "fallback_reasons": {"not_json": 1},
                                                "latency_s_mean": 2.0}}}},
    }  # fmt: skip


def test_section_has_the_targets_and_the_figure_10_table(tmp_path):
    text = render_llm(_result())
    for piece in ("<= 3", "<= 10", "0.61, 0.90, 0.40, 0.25", "30 %", "44 forward passes",
                  "| g36 | 85.00 +- 7.07 | 120 | 39.0 | 42 | 3 | 7 | 90.00 | 80.00 |",
                  "| tree | not available", "it made 6 of 7 cabinet and tower decisions (85.7 %); 1 served by ppo",
                  "15.0 vs 0.70 vs 0.40", "--hours 24 --period 8", "5 cabinets, 2 towers",
                  "what-if claim the rendering lacks (of 2", "frontier 5.50, hot-1033 14.00",
                  "| mean D_blade >= the strong rule's and >= 97 % | 85.00 % (rule 84.00 %) | no |",
                  "| no day more than 5 points below G36 | worst frontier: +0.00 points below G36 | yes |",
                  "| <= 2 % of decisions served by the fallback (no deadline here) | 14.3 % of 7 | no |"):
        assert piece in text, piece
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\n<!-- bench:twin:start -->\nkeep\n<!-- bench:twin:end -->\n")
    update_benchmarks_md(md, "llm", _result(), render=render_llm)
    update_benchmarks_md(md, "llm", _result(), render=render_llm)  # replaced, not appended twice
    body = md.read_text()
    assert body.count("<!-- bench:llm:start -->") == 1 and "keep" in body
