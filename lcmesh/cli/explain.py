"""``lcmesh explain-eval`` (explanation scoring), ``lcmesh explain-twin`` (our pipeline's explanations of a
twin run, as explain-eval input) and ``lcmesh bench explain``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from lcmesh.cli.common import (
    JsonOpt, ScenarioOpt, SystemOpt, app, bench_app, console, fail, load_system_or_fail, progress_bar,
    write_bench, write_json,
)  # fmt: skip


@app.command("explain-eval")
def explain_eval(
    input_path: Annotated[
        Path, typer.Option("--input", "-i", help="JSON lines: {id, observation, action, explanation, facts?}")
    ],
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option("--markdown", help="also write a markdown report here")] = None,
    tolerance: Annotated[
        Optional[float], typer.Option(help="relative tolerance for powers, flows, pressures (default 0.01)")
    ] = None,
    temp_tolerance: Annotated[
        Optional[float], typer.Option(help="absolute tolerance on temperatures in K (default 0.1)")
    ] = None,
    config: Annotated[
        Optional[Path], typer.Option(help="JSON file with EvalConfig fields (tolerances, bounds)")
    ] = None,
    per_text: Annotated[
        bool, typer.Option("--per-text/--summary-only", help="print each text's claims, verdicts and flags")
    ] = True,
) -> None:
    """Score explanations from any system: each text's claims (numbers, directions, rankings, causes, bounds, the
    action's dimensions) checked against its decision's facts, its flags, and a summary."""
    from pydantic import ValidationError

    from lcmesh.mesh.tools.explain_eval import EvalConfig, evaluate_file, render_markdown

    if not input_path.is_file():
        fail(f"`--input` file not found: {input_path}")
    try:
        raw = json.loads(config.read_text()) if config is not None else {}
        if tolerance is not None:
            raw["rel_tol"] = tolerance
        if temp_tolerance is not None:
            raw["temp_tol_k"] = temp_tolerance
        cfg = EvalConfig.model_validate(raw)
    except (OSError, json.JSONDecodeError) as exc:
        fail(f"`--config` could not be read: {exc}")
    except ValidationError as exc:
        fail("invalid evaluator settings: " + "; ".join(
            f"`{'.'.join(map(str, e['loc']))}`: {e['msg']}" for e in exc.errors()))  # fmt: skip
    result = evaluate_file(input_path, cfg)
    agg = result["aggregate"]
    if per_text:
        for item in result["items"]:
            _print_item(item)
    table = Table(title=f"explain-eval: {input_path.name} ({agg['n_items']} items, {agg['n_invalid']} invalid, "
                        f"{agg['n_not_read']} not read)")  # fmt: skip
    for column in ("score", "mean", "min"):
        table.add_column(column)
    for key in ("numeric_grounding", "coverage", "direction_consistency"):
        table.add_row(key, f"{agg[key]:.3f}", f"{agg[key + '_min']:.3f}")
    console.print(table)
    console.print(f"texts without flags: {agg['items_without_flags']} of {agg['n_valid']} read; claims checked "
                  f"{agg['claims_checked']}, failed {agg['claims_failed']}")
    if agg["flag_counts"]:
        console.print("flags: " + ", ".join(f"{k} {v}" for k, v in agg["flag_counts"].items()))
    if markdown is not None:
        markdown.parent.mkdir(parents=True, exist_ok=True)
        markdown.write_text(render_markdown(result, title=f"Explanation evaluation: {input_path.name}"))
        console.print(f"wrote {markdown}")
    write_json(json_out, result)


_MARK = {"holds": "[green]ok[/green]", "fails": "[red]FAIL[/red]", "unchecked": "[dim]?[/dim]"}


def _print_item(item: dict) -> None:
    """One text: its verdict, each claim it read with the fact it was checked against, then its flags."""
    kinds = sorted({f["kind"] for f in item["flags"]})
    if "not_read" in kinds or "invalid_record" in kinds:
        verdict = "[yellow]not read[/yellow]" if "not_read" in kinds else "[red]invalid record[/red]"
    else:
        verdict = f"[red]flagged: {', '.join(kinds)}[/red]" if kinds else "[green]no flags[/green]"
    lang = f" ({item['language']})" if item.get("language") else ""
    console.print(f"[bold]{escape(item['id'])}[/bold]{lang}: {verdict}")
    for c in item.get("claims", []):
        said = c["text"] if len(c["text"]) <= 90 else c["text"][:87] + "..."
        against = f" <- {c['fact']}" if c.get("fact") else ""
        console.print(f"  {_MARK[c['verdict']]} {c['relation']:7s} {escape(said)}{escape(against)}", soft_wrap=True)
    for f in item["flags"]:
        console.print(f"  [red]{f['kind']}[/red]: {escape(f['detail'])}", soft_wrap=True)


@app.command("explain-twin")
def explain_twin(
    out: Annotated[Path, typer.Option("--out", "-o", help="JSON lines to write (explain-eval input)")],
    system: SystemOpt = "lcopt-5",
    trace: Annotated[str, typer.Option(help="frontier-2024-04-07, synthetic:SEED or a CSV path")] = (
        "frontier-2024-04-07"
    ),
    hours: Annotated[float, typer.Option(help="simulated hours")] = 24.0,
    controller: Annotated[str, typer.Option(help="controller name (static, g36, ...)")] = "g36",
    every: Annotated[int, typer.Option(help="explain a decision every N steps (15 s each)")] = 40,
    level: Annotated[list[str], typer.Option(help="short, detailed, very_detailed; repeatable")] = [
        "short", "detailed", "very_detailed"
    ],  # fmt: skip
    scenario: ScenarioOpt = "frontier",
    wet_bulb_offset: Annotated[float, typer.Option(help="K added to the wet bulb, on top of the scenario's")] = 0.0,
) -> None:
    """Run a controller on the twin and write our deterministic explanations of its decisions as JSON lines."""
    from lcmesh.mesh.tools.explain import LEVELS
    from lcmesh.mesh.tools.explain_eval.pipeline import twin_explanation_records
    from lcmesh.twin.controllers import make_controller
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.traces import TraceError, load_trace

    if not hours > 0 or every < 1:
        fail(f"`--hours` must be > 0 and `--every` >= 1, got {hours} and {every}")
    bad = [lv for lv in level if lv not in LEVELS]
    if bad:
        fail(f"`--level` must be one of {', '.join(LEVELS)}, got {', '.join(bad)}")
    desc = load_system_or_fail(system)
    try:
        tr = load_trace(trace, desc, scenario=scenario, wet_bulb_offset_k=wet_bulb_offset)
        ctrl = make_controller(controller, desc)
    except (TraceError, ValueError) as exc:
        fail(str(exc))
    n_steps = min(tr.n_steps, int(round(hours * 3600 / tr.step_s)))
    out.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    with Plant(desc) as plant, progress_bar() as progress, out.open("w") as fh:
        task = progress.add_task(f"{desc.name} / {controller}", total=n_steps)
        for record in twin_explanation_records(plant, tr, ctrl, n_steps=n_steps, every_steps=every, levels=level,
                                               on_step=lambda k: progress.update(task, completed=k + 1)):  # fmt: skip
            fh.write(json.dumps(record) + "\n")
            count += 1
    console.print(f"wrote {count} records to {out}")


@bench_app.command("explain")
def bench_explain(
    json_out: JsonOpt = None,
    quick: Annotated[bool, typer.Option(help="2 h instead of 24 h, one repeat (smoke run)")] = False,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
) -> None:
    """Facts, renderer and evaluator speed; explanation scores over a G36 day; the judge's precision and recall on
    the outside corpus (test part; dev beside it); the 40-record regression set."""
    from lcmesh.mesh.tools.explain_eval.bench import render_markdown_section, run_bench_explain

    with console.status("benchmarking explanations"):
        result = run_bench_explain(quick=quick)
    day, ts = result["day"]["aggregate"], result["testset"]
    console.print(f"grounding {day['numeric_grounding']:.4f}  coverage {day['coverage']:.4f}  direction "
                  f"{day['direction_consistency']:.4f}  40-record set {ts['matching']}/{ts['records']}")  # fmt: skip
    for part in ("test", "dev"):
        c = result["corpus"][part]
        recalls = "  ".join(f"{k} {v['recall']:.3f}" for k, v in c["per_flag"].items() if v["recall"] is not None)
        console.print(f"corpus {part}{' (tuned on)' if part == 'dev' else ''}: {c['texts']} texts; correct texts "
                      f"flagged {c['correct_flagged_share']:.3f}; recall {recalls}")  # fmt: skip
    write_bench(json_out, markdown, "explain", result, render=render_markdown_section)
