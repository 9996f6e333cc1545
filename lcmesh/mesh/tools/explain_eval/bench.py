"""``lcmesh bench explain``: facts and renderer speed, evaluator speed, explanation quality over a twin day,
and the verdict on the hand-written test set (docs/examples/explain-eval)."""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

from lcmesh.mesh.tools.explain import LEVELS, render_explanation
from lcmesh.mesh.tools.explain_eval import evaluate_file, evaluate_lines, evaluate_record
from lcmesh.mesh.tools.explain_eval.pipeline import twin_explanation_records
from lcmesh.mesh.tools.facts import cabinet_decision_facts
from lcmesh.twin.controllers import Observation, make_controller
from lcmesh.twin.plant import Plant
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import FRONTIER_DAY, load_trace, scenario_named

TESTSET = Path(__file__).resolve().parents[4] / "docs" / "examples" / "explain-eval"
TARGETS = {"numeric_grounding": 0.98, "coverage": 1.0, "direction_consistency": 0.95}


def run_bench_explain(quick: bool = False, testset_dir: Path = TESTSET) -> dict:
    """All figures of the explain benchmark (lcopt-5, G36, the Frontier day in the default scenario: real loads and
    wet bulb)."""
    from lcmesh.bench.machine import machine_info

    system = load_system("lcopt-5")
    trace = load_trace(FRONTIER_DAY, system)
    hours = 2.0 if quick else 24.0
    n_steps = int(hours * 3600 / trace.step_s)
    result: dict = {"machine": machine_info(), "system": system.name, "trace": trace.name, "scenario": trace.scenario,
                    "controller": "g36",
                    "load_average_1min_start": os.getloadavg()[0]}  # timings inflate on a shared machine
    with Plant(system) as plant:
        result["speed"] = _speed(plant, trace, repeats=1 if quick else 3)
        t0 = time.perf_counter()
        lines = [json.dumps(r) for r in twin_explanation_records(
            plant, trace, make_controller("g36", system), n_steps=n_steps, every_steps=40)]  # fmt: skip
        t1 = time.perf_counter()
    scores = evaluate_lines(lines)
    t2 = time.perf_counter()
    per_level = {}
    for level in LEVELS:
        items = [it for it in scores["items"] if it["id"].endswith("-" + level)]
        per_level[level] = {k: float(np.mean([it[k] for it in items])) for k in TARGETS} | {"records": len(items)}
    agg = scores["aggregate"]
    result["day"] = {
        "hours": hours, "decisions_every_steps": 40, "records": len(lines), "generate_s": t1 - t0,
        "evaluate_s": t2 - t1, "aggregate": agg, "per_level": per_level,
        "targets_met": {k: agg[k] >= v for k, v in TARGETS.items()},
    }  # fmt: skip
    result["testset"] = testset_verdict(testset_dir)
    return result


def testset_verdict(folder: Path = TESTSET) -> dict:
    """Items whose flag kinds equal the expected ones (planted flaws found, good ones left alone)."""
    expected = json.loads((folder / "expected.json").read_text())
    items = evaluate_file(folder / "testset.jsonl")["items"]
    rows = []
    for it in items:
        got = sorted({f["kind"] for f in it["flags"]})
        want = expected.get(it["id"], {}).get("flags")
        rows.append({"id": it["id"], "expected": want, "flagged": got, "match": got == want})
    return {"records": len(rows), "matching": sum(r["match"] for r in rows), "rows": rows}


def _speed(plant: Plant, trace, repeats: int) -> dict:
    system = plant.system
    controller = make_controller("g36", system)
    power = np.zeros(system.n_blade_groups)
    out = plant.reset()
    previous = None
    for k in range(240):  # an hour in: setpoints have moved, the load has rotated
        wet_bulb = float(trace.wet_bulb_k[k])
        action = controller.act(Observation(out, wet_bulb, trace.blade_power_w(k, out=power), k * trace.step_s))
        previous = action.copy()
        out = plant.step(power, wet_bulb, action)
    cabinets = range(system.cabinets.count)

    def facts_once():
        return [cabinet_decision_facts(system, out, previous, previous, wet_bulb, c) for c in cabinets]

    facts_us = _median_us(facts_once, 200, repeats) / system.cabinets.count
    facts = facts_once()[0]
    render_us = {lv: _median_us(lambda lv=lv: render_explanation(facts, lv), 200, repeats) for lv in LEVELS}
    from lcmesh.mesh.tools.explain import explanation_record

    eval_ms = {}
    for lv in LEVELS:
        rec = explanation_record(out, previous, facts, render_explanation(facts, lv), cabinet=0, record_id="bench",
                                 previous_action=previous, wet_bulb_k=wet_bulb, level=lv)  # fmt: skip
        eval_ms[lv] = _median_us(lambda rec=rec: evaluate_record(rec), 20, repeats) / 1e3
    return {"facts_us_per_cabinet": facts_us, "render_us": render_us, "evaluate_ms_per_record": eval_ms,
            "facts_per_cabinet": len(facts)}  # fmt: skip


def _median_us(fn, n: int, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        times.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(times)


def render_markdown_section(r: dict) -> str:
    """The BENCHMARKS.md section."""
    m, sp, day, ts = r["machine"], r["speed"], r["day"], r["testset"]
    agg = day["aggregate"]
    lines = [
        "## Explanations (`lcmesh bench explain --json runs/bench/explain.json --markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m.get('cpu')}, {m.get('logical_cpus')} logical CPUs; Python {m.get('python')}; commit "
        f"{m.get('commit')}; {m.get('date')}; load average {r.get('load_average_1min_start', 0):.1f} at the start "
        f"(timings are medians of repeats, not pinned). {r['system']}, {r['controller']}, {r['trace']}"
        + (f" (scenario {r['scenario']}, {scenario_named(r['scenario']).description})." if r.get("scenario") else "."),
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| decision facts per cabinet ({sp['facts_per_cabinet']} facts), µs | {sp['facts_us_per_cabinet']:,.0f} "
        "| < 1,000 |",
    ]
    lines += [f"| render {lv}, µs | {sp['render_us'][lv]:,.0f} | |" for lv in LEVELS]
    lines += [f"| evaluate one {lv} explanation, ms | {sp['evaluate_ms_per_record'][lv]:.1f} | |" for lv in LEVELS]
    lines += [
        f"| {day['hours']:g} h day, a decision every {day['decisions_every_steps']} steps x 5 cabinets x 3 levels: "
        f"records | {day['records']:,} | |",
        f"| numeric grounding (mean; pooled {agg['numeric_grounding_pooled']:.4f}) | "
        f"{agg['numeric_grounding']:.4f} | >= 0.98 |",
        f"| coverage (mean) | {agg['coverage']:.4f} | 1.0 |",
        f"| direction consistency (mean; {agg['direction_claims_checked']:,} claims) | "
        f"{agg['direction_consistency']:.4f} | >= 0.95 |",
        f"| flags over the day | {sum(agg['flag_counts'].values())} | 0 |",
        f"| hand-written test set: records whose flags equal the expected ones | {ts['matching']} / "
        f"{ts['records']} | all |",
    ]  # fmt: skip
    return "\n".join(lines)
