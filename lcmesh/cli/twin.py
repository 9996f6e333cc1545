"""``lcmesh twin build|validate|run`` and ``lcmesh bench twin``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from lcmesh.cli.common import (
    JsonOpt, ScenarioOpt, SystemOpt, bench_app, console, fail, load_system_or_fail, progress_bar, twin_app,
    write_bench, write_json,
)  # fmt: skip


@twin_app.command("build")
def twin_build(
    system: Annotated[list[str], typer.Option("--system", "-s", help="system(s) to build; repeatable")] = [
        "lcopt-5"
    ],
    all_systems: Annotated[bool, typer.Option("--all", help="build every reference system")] = False,
    out: Annotated[Optional[Path], typer.Option(help="copy the FMU(s) into this folder")] = None,
    force: Annotated[bool, typer.Option(help="rebuild even if cached")] = False,
) -> None:
    """Generate C + modelDescription.xml, compile, package and validate the FMU (cached by content hash)."""
    import shutil

    from lcmesh.twin.fmu_build import FmuBuildError, build_fmu
    from lcmesh.twin.fmu_runner import validate_fmu
    from lcmesh.twin.system import reference_systems

    names = reference_systems() if all_systems else system
    for name in names:
        desc = load_system_or_fail(name)
        try:
            built = build_fmu(desc, force=force)
        except FmuBuildError as exc:
            fail(str(exc))
        problems = validate_fmu(built.path)
        status = "cached" if built.cached else "built"
        console.print(f"{desc.name}: {status} {built.path} ({built.layout.n_reals} variables)")
        if problems:
            fail(f"fmpy validate found problems in {built.path}:\n" + "\n".join(problems))
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            shutil.copy2(built.path, out / f"{desc.name}.fmu")
            console.print(f"  copied to {out / (desc.name + '.fmu')}")


@twin_app.command("validate")
def twin_validate(
    system: SystemOpt = "lcopt-5",
    json_out: JsonOpt = None,
    plots: Annotated[Optional[Path], typer.Option(help="folder for validation plots")] = None,
) -> None:
    """Physics checks (energy balance, blade band, setpoint step, monotonicity, tower fans), published figures
    and the fan/pump split of the cooling power per scenario."""
    from lcmesh.twin.validate import validate_twin

    desc = load_system_or_fail(system)
    with console.status(f"validating {desc.name}"):
        report = validate_twin(desc, plot_dir=plots)
    table = Table(title=f"twin validate: {desc.name}")
    table.add_column("check")
    table.add_column("passed")
    table.add_column("criterion")
    for check in report["checks"]:
        table.add_row(check["name"], "[green]yes[/green]" if check["passed"] else "[red]NO[/red]", check["criterion"])
    console.print(table)
    split = next((c for c in report["checks"] if c["name"] == "fan_pump_split"), None)
    if split is not None:
        console.print(_split_table(desc.name, split))
    write_json(json_out, report)
    if not report["passed"]:
        raise typer.Exit(1)


def _split_table(system: str, split: dict) -> Table:
    """The cooling-power split per scenario (G36 day means, kW) beside the cited fan share."""
    from lcmesh.twin.validate import FAN_SPLIT_DOC

    cited = split["rows"][0]["cited_fan_share_pct"]
    table = Table(title=f"cooling power, G36 day means, kW: {system}",
                  caption=f"fans' share against the cited {cited:g} % (Jadhav and Liu); outside: the limit "
                          f"documented in {FAN_SPLIT_DOC}")  # fmt: skip
    table.add_column("scenario", no_wrap=True)
    for column in ("fans", "CDU pumps", "HTW pumps", "tower pumps", "fans %", "fans % w/o CDU"):
        table.add_column(column, justify="right")
    table.add_column("status", no_wrap=True)
    for r in split["rows"]:
        inside = r["status"].startswith("inside")
        table.add_row(
            r["scenario"], f"{r['fans_kw']:.1f}", f"{r['cdu_pumps_kw']:.1f}", f"{r['htw_pumps_kw']:.1f}",
            f"{r['tower_pumps_kw']:.1f}", f"{r['fan_share_pct']:.1f}", f"{r['fan_share_without_cdu_pumps_pct']:.1f}",
            "[green]inside[/green]" if inside else "[yellow]outside: limit[/yellow]",
        )  # fmt: skip
    return table


@twin_app.command("run")
def twin_run(
    system: SystemOpt = "lcopt-5",
    trace: Annotated[str, typer.Option(help="frontier-2024-04-07, synthetic:SEED or a CSV path")] = "frontier-2024-04-07",
    hours: Annotated[float, typer.Option(help="simulated hours (capped at the trace length)")] = 24.0,
    controller: Annotated[str, typer.Option(help="static, g36, rule, lookahead, ppo, tree, llm, or a third-party "
                                            "package.module:Class (docs/controllers.md)")] = "static",  # fmt: skip
    policy: Annotated[Optional[str], typer.Option(help="policy file for ppo/tree/llm (default: the shipped one)")] = None,
    scenario: ScenarioOpt = "frontier",
    wet_bulb_offset: Annotated[float, typer.Option(help="K added to the wet bulb, on top of the scenario's")] = 0.0,
    pool_cells: Annotated[bool, typer.Option(help="ppo/tree: pool this system's tower cells into the count the "
                                             "policy was trained for")] = False,  # fmt: skip
    json_out: JsonOpt = None,
    plot: Annotated[Optional[Path], typer.Option(help="PNG plot (default: beside --json)")] = None,
    guardrails: Annotated[bool, typer.Option("--guardrails/--no-guardrails", help="every action through the mesh's "
                                             "guardrails, as the mesh applies it (off: the paper's setting)")] = True,
) -> None:
    """Run a controller on the twin over a trace; KPIs as JSON, a progress bar, a PNG plot."""
    from lcmesh.twin.controllers.guarded import MESH_GUARDRAILS
    from lcmesh.twin.controllers import make_controller
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.run import plot_run, run_twin
    from lcmesh.twin.traces import TraceError, load_trace

    if not (hours > 0 and math.isfinite(hours)):
        fail(f"`--hours` must be > 0, got {hours}")
    desc = load_system_or_fail(system)
    try:
        tr = load_trace(trace, desc, scenario=scenario, wet_bulb_offset_k=wet_bulb_offset)
        kwargs = {"policy": policy} if policy else {}
        if pool_cells:
            if controller not in ("ppo", "tree"):
                fail(f"`--pool-cells` applies to ppo and tree, not {controller!r}")
            kwargs["pool_cells"] = True
        ctrl = make_controller(controller, desc, **kwargs)
    except (TraceError, ValueError, FileNotFoundError) as exc:
        fail(str(exc))
    n_steps = min(tr.n_steps, int(round(hours * 3600 / tr.step_s)))
    if n_steps < int(round(hours * 3600 / tr.step_s)):
        console.print(f"[yellow]note:[/yellow] the trace holds {tr.n_steps * tr.step_s / 3600:.2f} h; running that")
    with Plant(desc) as plant, progress_bar() as progress:
        task = progress.add_task(f"{desc.name} / {controller}", total=n_steps)
        every = max(1, n_steps // 200)
        result = run_twin(plant, tr, ctrl, n_steps=n_steps, record_every=max(1, n_steps // 2000),
                          on_step=lambda k: (k + 1) % every == 0 and progress.update(task, completed=k + 1),
                          guardrails=MESH_GUARDRAILS if guardrails else None)  # fmt: skip
        progress.update(task, completed=n_steps)
    data = result.to_json()
    plot_path = plot or (json_out.with_suffix(".png") if json_out else None)
    if plot_path is not None:
        data["plot"] = str(plot_run(result, plot_path))
    k = result.kpi
    console.print(
        f"d_blade {k['d_blade_pct']:.2f} %  CT {k['ct_power_kw_avg']:.1f} kW  IT cooling {k['it_cooling_kw_avg']:.0f} kW"
        f"  energy balance {k['energy_balance_error_pct']:.2e} %  {result.realtime_factor:,.0f}x real time"
    )
    g = result.guardrails
    if g["guardrails"] == "off":
        console.print("guardrails off: the controller's actions went to the plant as proposed (the mesh would clamp them)")
    else:
        console.print(f"guardrails (the mesh's): {g['clamped_steps']:,} of {g['steps']:,} decisions clamped "
                      f"({g['clamped_steps_pct']:.1f} %), {g['rejected']} rejected and held")  # fmt: skip
    if result.decided_by is not None:
        console.print(f"who decided: {result.decided_by['summary']}")
    if result.controller_cost is not None:
        cost = result.controller_cost
        console.print(f"{result.controller} simulated {cost['sim_steps']:,} plant steps in {cost['wall_s']:.1f} s")
    write_json(json_out, data)


@bench_app.command("twin")
def bench_twin(
    json_out: JsonOpt = None,
    quick: Annotated[bool, typer.Option(help="fewer steps and repeats (smoke run)")] = False,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
) -> None:
    """Env steps/s (lcopt-5), a 24 h frontier-full day, raw fmi2 vs fmpy list API."""
    from lcmesh.bench.twin import run_bench_twin

    with console.status("benchmarking the twin (one core)"):
        result = run_bench_twin(quick=quick)
    write_bench(json_out, markdown, "twin", result)
