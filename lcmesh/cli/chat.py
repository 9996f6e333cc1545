"""``lcmesh bench chat``: the operator assistant on the held-out questions (lcmesh/bench/chat.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from lcmesh.cli.common import JsonOpt, bench_app, console, engine_options, fail, stage_progress, write_bench


@bench_app.command("chat")
@engine_options
def bench_chat(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    split: Annotated[str, typer.Option(help="test (the evidence), dev (for tuning) or all")] = "test",
    planners: Annotated[str, typer.Option(help="comma list of llm, rules, openai, oracle (the expected calls)")] = \
        "llm,rules,oracle",
    site_minutes: Annotated[float, typer.Option(help="plant minutes the recorded site covers")] = 120.0,
    questions: Annotated[str, typer.Option(help="question sets: a (the first, dev and test), b (an outside author's, "
                                           "test only), c (another outside author's, dev only), d (a third's, "
                                           "test only), e (a fifth's, test only, with follow-ups; issue 34); comma "
                                           "list")] = "a,b,c,d,e",
    live: Annotated[int, typer.Option(help="instead: start the demo mesh and ask this many test questions through "
                                      "its REST API; who planned each answer and its latency", min=0)] = 0,
    controller: Annotated[Optional[str], typer.Option(help="--live: the demo's controller (default: the demo's)")] = None,
    speed: Annotated[Optional[float], typer.Option(help="--live: the demo's speed factor (default: the demo's)",
                                                   min=0.1, max=1000)] = None,
    hold: Annotated[float, typer.Option(help="--live: minutes the mesh runs on after the questions, for the "
                                        "controller's count of who decided", min=0, max=600)] = 0.0,
    explainer: Annotated[Optional[str], typer.Option(help="--live: 'llm': the Control agent explains with the LLM "
                                                     "(its count of who wrote them is reported)")] = None,
    check: Annotated[str, typer.Option(help="words (the default, as the mesh runs): every plan is also checked "
                                       "against the question's words, replaced by the rules' where they cover "
                                       "more; query: the model's reading against its own fields only")] = "words",
    engine=None,
) -> None:
    """Tool-call accuracy, answers right against state, refusals, wrong-but-grounded and latency per planner."""
    if explainer not in (None, "renderer", "llm"):
        raise typer.BadParameter(f"must be 'renderer' or 'llm', got {explainer!r}", param_hint="--explainer")
    if live:
        from lcmesh.bench.api import render_live_planner, run_live_planner

        with console.status("live demo") as status:
            result = run_live_planner(live, controller=controller, speed_factor=speed, hold_minutes=hold,
                                      explainer=explainer, say=lambda m: status.update(m))  # fmt: skip
        write_bench(json_out, markdown, "chat-live", result, render=render_live_planner)
        return
    from lcmesh.bench import chat
    from lcmesh.bench.chat_site import ensure_site
    from lcmesh.bench.engine import cache_summary, run_units
    from lcmesh.bench.machine import machine_info
    from lcmesh.llm.model_cache import models_dir

    if split not in ("test", "dev", "all"):
        fail(f"--split must be test, dev or all, not {split!r}")
    splits = ["dev", "test"] if split == "all" else [split]
    sets = [q.strip() for q in questions.split(",") if q.strip()]
    if not sets or any(q not in chat.QUESTION_SETS for q in sets):
        fail(f"--questions must be a comma list of {', '.join(chat.QUESTION_SETS)}, not {questions!r}")
    parts = [(qs, sp) for qs in sets for sp in splits if sp in chat.SET_SPLITS[qs]]  # b is all test, c all dev
    names = [p.strip() for p in planners.split(",") if p.strip()]
    unknown = [n for n in names if n not in ("llm", "openai", "rules", "oracle")]
    if unknown:
        fail(f"--planners: unknown {', '.join(unknown)} (known: llm, openai, rules, oracle)")
    with console.status("recording (or reusing) the bench site"):
        site = ensure_site(models_dir().parent / "chat-sites", minutes=site_minutes)
    sources, _ = chat.site_runner(site)
    report = {"site": f"{sources.manifest.system}, {sources.manifest.controller}, {site_minutes:g} min, "
                      f"{sources.manifest.scenario}",
              "command": "lcmesh bench chat " + " ".join(sys.argv[3:]), "machine": machine_info(), "planners": {},
              "check": check}
    # every (planner, part) is a unit on the engine (lcmesh/bench/engine.py); latency is each unit's own, one CPU each
    if check not in ("query", "words"):
        fail(f"--check must be query or words, not {check!r}")
    units = chat.part_units(names, parts, site, check)
    with stage_progress("planners on the question parts") as on_progress:
        outcomes = run_units(units, engine, on_progress)
    for o in outcomes:
        name, part = o.unit.kwargs["planner"], chat.part_name(o.unit.kwargs["question_set"], o.unit.kwargs["split"])
        if o.error is not None:
            fail(f"{name} on {part} failed: {o.error}")
        summary = report["planners"].setdefault(name, {})[part] = o.result
        console.print(f"{name} {part}: plans {summary['plan_accuracy']:.1%}, answers {summary['correct']:.1%}, "
                      f"wrong-but-grounded {summary['wrong_but_grounded']}, declined holding the answer "
                      f"{summary['declined_holding_answer']}, p99 {summary['latency_p99_s']:.2f} s; by language "
                      + ", ".join(f"{k} {v:.0%}" for k, v in summary["by_lang"].items())
                      + (" (cached)" if o.cached else ""))  # fmt: skip
    report["cache"] = cache_summary(outcomes)
    write_bench(json_out, markdown, "chat", report, render=chat.markdown)
