"""``lcmesh bench maintenance`` (the fault-detector benchmark) and ``lcmesh tools list|call`` (the math toolbox)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from lcmesh.cli.common import (
    JsonOpt, SystemOpt, app, bench_app, console, fail, load_system_or_fail, progress_bar, write_bench, write_json,
)  # fmt: skip

tools_app = typer.Typer(help="The math toolbox: the tools the agents host as lcmesh/{site}/tools/{name}.",
                        no_args_is_help=True)  # fmt: skip
app.add_typer(tools_app, name="tools")


@bench_app.command("maintenance")
def bench_maintenance(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    quick: Annotated[bool, typer.Option(help="two days, one injection per kind (smoke run)")] = False,
    seeds: Annotated[Optional[int], typer.Option(min=1, max=50, help="injections per day and fault kind")] = None,
    noise_scale: Annotated[float, typer.Option(min=0.0, max=10.0, help="x the default sensor noise (0: none)")] = 1.0,
    valve_exercise: Annotated[float, typer.Option(min=0.0, help="stroke each primary valve every N s (0: off)")] = 600.0,
    mismatch: Annotated[bool, typer.Option(help="also run plants that differ from the detector's model")] = True,
    nominal_detector: Annotated[bool, typer.Option(
        help="also run the detector without baseline learning on the mismatched plants")] = False,
    held_out: Annotated[bool, typer.Option(
        help="days, injections and plants not used while tuning the detector (synthetic:1004-1007)")] = False,
) -> None:
    """Detection rate, delay and false alarms of the fault detector on lcopt-5 under G36 (simulated days),
    on the detector's own model and on plants that differ from it."""
    from lcmesh.bench.maintenance import SCENARIOS, render_maintenance, run_bench_maintenance

    with progress_bar() as progress:
        task = progress.add_task("maintenance runs", total=None)
        result = run_bench_maintenance(
            quick=quick, seeds=seeds, noise_scale=noise_scale, valve_exercise_s=valve_exercise, mismatch=mismatch,
            nominal_detector=nominal_detector, held_out=held_out,
            on_run=lambda n, total: progress.update(task, completed=n, total=total),
        )  # fmt: skip
    table = Table(title="fault detection (lcopt-5, G36)")
    for column in ("fault", "plant", "detected", "median delay (min)", "rate once shown", "median once shown (min)"):
        table.add_column(column)
    scenarios = {"matched": result, **{name: result[name] for name in SCENARIOS if name in result}}
    for kind in result["per_kind"]:
        for name, scenario in scenarios.items():
            k = scenario["per_kind"][kind]
            med, shown = k["delay_from_injection"]["median_min"], k["detection_rate_manifested"]
            med_shown = k["delay_from_manifestation"]["median_min"]
            table.add_row(kind, name, f"{k['detected']}/{k['injected']}", _fmt(med, ".1f"), _fmt(shown, ".0%"),
                          _fmt(med_shown, ".1f"))  # fmt: skip
    console.print(table)
    for name, scenario in scenarios.items():
        fa = scenario["false_alarms"]
        console.print(f"false alarms ({name}): {fa['count']} in {fa['fault_free_days']:.1f} fault-free days = "
                      f"{fa['per_day']:.2f}/day")  # fmt: skip
    write_bench(json_out, markdown, "maintenance", result, render=render_maintenance)


@tools_app.command("list")
def tools_list(
    schemas: Annotated[bool, typer.Option(help="print every tool's request and response JSON schema")] = False,
) -> None:
    """The tools, what each computes and the fields its request takes."""
    from lcmesh.mesh.tools.registry import TOOLS, catalog

    if schemas:
        write_json(None, {"tools": catalog()})
        return
    table = Table(title="lcmesh tools")
    table.add_column("tool")
    table.add_column("description")
    table.add_column("request fields")
    for spec in TOOLS.values():
        table.add_row(spec.name, spec.description, ", ".join(spec.request_model.model_fields))
    console.print(table)


@tools_app.command("call")
def tools_call(
    name: Annotated[str, typer.Argument(help="tool name (lcmesh tools list)")],
    request: Annotated[str, typer.Argument(help='the request as JSON, e.g. \'{"mass_flow_kg_s": 10}\'')] = "{}",
    system: SystemOpt = "lcopt-5",
    with_twin: Annotated[bool, typer.Option("--twin", help="load the twin (whatif needs it), at design load")] = False,
    json_out: JsonOpt = None,
) -> None:
    """Call one tool as the bus would; prints {"ok", "tool", "result" | "error"}. Exit 1 on an error result."""
    from lcmesh.mesh.tools.registry import ToolContext, invoke

    desc = load_system_or_fail(system)
    try:
        payload = json.loads(request)
    except json.JSONDecodeError as exc:
        fail(f"the request is not valid JSON: {exc}")
    if with_twin:
        import numpy as np

        from lcmesh.twin.plant import Plant

        with Plant(desc) as plant:
            per_group_w = desc.cabinets.design_heat_w * desc.cabinets.count / desc.n_blade_groups
            plant.spin_up(np.full(desc.n_blade_groups, per_group_w), 293.15, plant.default_action(), hours=1.0)
            plant.reset()
            result = invoke(name, payload, ToolContext(desc, plant=plant, latest_out=plant.out))
    else:
        result = invoke(name, payload, ToolContext(desc))
    write_json(json_out, result.model_dump(mode="json"))
    if not result.ok:
        raise typer.Exit(1)


def _fmt(value: float | None, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)
