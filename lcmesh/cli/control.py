"""``lcmesh train ppo``, ``lcmesh distill tree``, ``lcmesh bench control`` and ``bench actions`` (the controllers issue)."""

from __future__ import annotations

import dataclasses
import inspect
import typing
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import typer

from lcmesh.cli.common import (
    JsonOpt, bench_app, console, distill_app, engine_options, fail, progress_bar, say_cache, stage_progress, train_app,
    write_bench, write_json,
)  # fmt: skip


def dataclass_options(cls: type, run: Callable[[Any], None]) -> Callable[..., None]:
    """A typer command whose options are the fields of config dataclass ``cls`` (docstrings as help)."""
    hints = typing.get_type_hints(cls)
    docs = _field_docs(cls)
    params = []
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        base = next((a for a in typing.get_args(kind) if a is not type(None)), kind)
        flag = f.name.replace("_", "-")
        names = f"--{flag}/--no-{flag}" if base is bool else f"--{flag}"  # a bool can be turned both ways
        option = typer.Option(names, help=docs.get(f.name, ""))
        params.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default,
                                        annotation=Annotated[base, option]))  # fmt: skip

    def command(**kwargs: Any) -> None:
        try:
            config = cls(**kwargs)
        except (TypeError, ValueError) as exc:
            fail(str(exc))
        run(config)

    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__doc__ = (cls.__doc__ or "").strip()
    return command


def _field_docs(cls: type) -> dict[str, str]:
    """Field docstrings (the string literal under a field), as the dataclass source writes them."""
    import ast

    try:
        tree = ast.parse(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    docs, body = {}, tree.body[0].body  # type: ignore[attr-defined]
    for prev, node in zip(body, body[1:]):
        if isinstance(prev, ast.AnnAssign) and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            docs[prev.target.id] = " ".join(str(node.value.value).split())  # type: ignore[union-attr]
    return docs


def _train_ppo(config) -> None:
    from lcmesh.distill.ppo import train_ppo

    with progress_bar() as progress:
        task = progress.add_task(f"PPO case {config.case} on {config.system}", total=None)

        def on_update(update: int, total: int, row: dict) -> None:
            val = f"  val d_blade {row['val_d_blade_pct']:.1f} % CT {row['val_ct_power_kw']:.0f} kW" if "val_score" in row else ""
            progress.update(task, completed=update, total=total,
                            description=f"PPO case {config.case}: in-band {100 * row['in_band']:.1f} %{val}")  # fmt: skip

        summary = train_ppo(config, on_update=on_update)
    best = summary["best"]
    if "kpi" in best:
        console.print(
            f"best at update {best['update']}: d_blade {best['kpi']['d_blade_pct']:.2f} %, "
            f"CT {best['kpi']['ct_power_kw_avg']:.1f} kW on {config.eval_trace}; policy {summary['policy']}.json"
        )
    write_json(Path(config.out) / "summary.json", summary)


def _distill_tree(config) -> None:
    from lcmesh.distill.tree_distill import distill_trees

    with console.status("distilling trees") as status:
        report = distill_trees(config, on_step=lambda msg: status.update(msg))
    for variant in ("viper", "naive"):
        r = report[variant]
        f = r["fidelity"]
        console.print(
            f"{variant}: reward gap {r['reward_gap_pct']:+.2f} % vs teacher, CDU R2 {f['cdu_r2']:.3f}, "
            f"valve R2 {f.get('valve_r2', float('nan')):.3f}, tower accuracy {f.get('tower_accuracy', float('nan')):.3f}  "
            f"-> {r['path']}"
        )


def _register() -> None:
    from lcmesh.distill.ppo_config import PpoConfig
    from lcmesh.distill.tree_config import TreeDistillConfig

    train_app.command("ppo", help="Train a PPO ablation case (Table 3); writes a run folder with log, plots, policy.")(
        dataclass_options(PpoConfig, _train_ppo)
    )
    distill_app.command("tree", help="VIPER-distill a PPO policy into decision/regression trees (Tables 12-15).")(
        dataclass_options(TreeDistillConfig, _distill_tree)
    )


_register()


@bench_app.command("control")
@engine_options
def bench_control(
    json_out: JsonOpt = None,
    quick: Annotated[bool, typer.Option(help="2 h of the day, no scaling study or rewards (smoke run)")] = False,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    plots: Annotated[Path, typer.Option(help="folder for the radar and time-series plots")] = Path("docs/img"),
    engine=None,
) -> None:
    """Ablation (Table 3), scaling (Table 4), power-valve correlation (Table 5), trees (Tables 12-15)."""
    from lcmesh.bench.control import render_control, run_bench_control

    with stage_progress("the paper's tables on the Frontier day") as on_progress:
        try:
            result = run_bench_control(quick=quick, plot_dir=plots, progress=on_progress, engine=engine)
        except RuntimeError as exc:
            fail(str(exc))
    say_cache(result)
    write_bench(json_out, markdown, "control", result, render=render_control)


@bench_app.command("actions")
def bench_actions(
    json_out: JsonOpt = None,
    hours: Annotated[float, typer.Option(help="hours of the Frontier day per run", min=0.25, max=24.0)] = 24.0,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    plots: Annotated[Path, typer.Option(help="folder for actions.png")] = Path("docs/img"),
) -> None:
    """Setpoint tracking under the static rule and G36, and each action's effect on the KPIs, per scenario (issue 12)."""
    from lcmesh.bench.actions import render_actions, run_bench_actions

    with stage_progress("setpoint tracking and action sweeps") as on_progress:
        result = run_bench_actions(hours=hours, progress=on_progress, plot_dir=plots)
    write_bench(json_out, markdown, "actions", result, render=render_actions)


@bench_app.command("suite")
@engine_options
def bench_suite(
    controllers: Annotated[str, typer.Option(help="comma-separated controller names (registry or 'package.module:Class')")] = (
        "static,g36,rule,lookahead,ppo,tree,readable"
    ),
    system: Annotated[str, typer.Option("--system", "-s", help="reference system name (lcopt-5 ...) or a .json path")] = (
        "lcopt-5"
    ),
    hours: Annotated[float, typer.Option(help="hours of each day", min=0.25, max=24.0)] = 24.0,
    days: Annotated[Optional[str], typer.Option(help="comma-separated day labels (default: every day of the split)")] = None,
    validation: Annotated[bool, typer.Option(help="run the validation days (checkpoint selection) instead of the test days")] = False,
    reference: Annotated[str, typer.Option(help="the controller regret is measured against")] = "lookahead",
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    plots: Annotated[Path, typer.Option(help="folder for suite_pareto.png")] = Path("docs/img"),
    guardrails: Annotated[bool, typer.Option("--guardrails/--no-guardrails", help="every action through the mesh's "
                                             "guardrails, as the mesh applies it (off: the paper's setting)")] = True,
    hru: Annotated[bool, typer.Option(help="each controller without and with the heat-recovery unit (lcopt-5 and "
                                      "lcopt-5-hru) instead of the regret table")] = False,
    engine=None,
) -> None:
    """Every controller on the held-out days (lcmesh/bench/suite.py): mean ± std, per-day figures, regret (issue 13)."""
    from lcmesh.bench.suite import (
        TEST_DAYS, VALIDATION_DAYS, days_named, deploy_checks, plot_days, plot_pareto, render_hru, render_suite,
        run_hru, run_suite,
    )  # fmt: skip
    from lcmesh.cli.common import load_system_or_fail

    names = [n.strip() for n in controllers.split(",") if n.strip()]
    if not names:
        fail(f"`--controllers` must name at least one controller, e.g. static,g36; got {controllers!r}")
    load_system_or_fail(system)
    pool = VALIDATION_DAYS if validation else TEST_DAYS
    try:
        chosen = pool if days is None else days_named([d.strip() for d in days.split(",") if d.strip()], pool)
    except ValueError as exc:
        fail(f"`--days`: {exc}")
    if not chosen:
        fail(f"`--days` must name at least one day, got {days!r}")
    if hru:
        with stage_progress("held-out days, without and with the HRU") as on_progress:
            result = run_hru(names, chosen, hours=hours, progress=on_progress, guardrails=guardrails, engine=engine)
        say_cache(result)
        for name, row in result["rows"].items():
            if row["error"] is not None:
                console.print(f"[yellow]{name}: not run[/yellow] ({row['error']})")
            else:
                console.print(f"{name}: tower fans -{row['fan_cut_pct']:.1f} %, cooling -{row['cooling_cut_pct']:.1f} % "
                              f"with the HRU; D_blade {row['d_blade_pct_off']:.2f} -> {row['d_blade_pct_on']:.2f} %")  # fmt: skip
        write_bench(json_out, markdown, "hru", result, render=render_hru)
        return
    with stage_progress("held-out days") as on_progress:
        result = run_suite(names, system, chosen, hours=hours, reference=reference, progress=on_progress,
                           guardrails=guardrails, engine=engine)  # fmt: skip
    say_cache(result)
    for check in deploy_checks(result):
        colour = "green" if check["met"] else "yellow"
        console.print(f"[{colour}]{check['controller']}: {check['target']}: {check['measured']}[/{colour}]")
    for name, entry in result["controllers"].items():
        if entry["error"] is not None:
            console.print(f"[yellow]{name}: not run[/yellow] ({entry['error']})")
    if result["regret_note"]:
        console.print(result["regret_note"])
    result["plot"] = str(plot_pareto(result, plots / "suite_pareto.png"))
    result["plot_days"] = str(plot_days(result, plots / "suite_days.png"))
    write_bench(json_out, markdown, "suite", result, render=render_suite)


@bench_app.command("ablation")
@engine_options
def bench_ablation(
    folder: Annotated[Path, typer.Option(help="folder of case{C}-seed{S}.json policies")] = Path(
        "lcmesh/artifacts/ppo/frontier"
    ),
    system: Annotated[str, typer.Option("--system", "-s", help="reference system name (lcopt-5 ...) or a .json path")] = (
        "lcopt-5"
    ),
    hours: Annotated[float, typer.Option(help="hours of each day", min=0.25, max=24.0)] = 24.0,
    days: Annotated[Optional[str], typer.Option(help="comma-separated test-day labels (default: all)")] = None,
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    engine=None,
) -> None:
    """Every seed of every PPO case on the held-out days, mean ± std over seeds (lcmesh/bench/ablation.py, issue 13)."""
    from lcmesh.bench.ablation import render_ablation, run_ablation
    from lcmesh.bench.suite import TEST_DAYS, days_named
    from lcmesh.cli.common import load_system_or_fail

    load_system_or_fail(system)
    if not folder.is_dir():
        fail(f"`--folder` must be a folder of case{{C}}-seed{{S}}.json policies, got {folder}")
    try:
        chosen = TEST_DAYS if days is None else days_named([d.strip() for d in days.split(",") if d.strip()])
        with stage_progress("ablation seeds on the held-out days") as on_progress:
            result = run_ablation(folder, system, chosen, hours=hours, progress=on_progress, engine=engine)
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        fail(str(exc))
    say_cache(result)
    write_bench(json_out, markdown, "ablation", result, render=render_ablation)


@train_app.command("sweep")
@engine_options
def train_sweep(
    case: Annotated[int, typer.Option(help="the PPO ablation case (2-7)")] = 7,
    seeds: Annotated[str, typer.Option(help="comma-separated training seeds")] = "0,1,2",
    grid: Annotated[Optional[list[str]], typer.Option(help="a PPO setting and its values, name=v1,v2 (repeatable; "
                                                      "one value sets it for every run), e.g. reward=lcopt,energy")] = None,
    out: Annotated[Path, typer.Option(help="the sweep's folder: one run folder per grid point and seed")] = Path(
        "runs/ppo/sweep"
    ),
    json_out: JsonOpt = None,
    engine=None,
) -> None:
    """PPO seeds and setting grids, each run a unit on the engine (docs/bench.md): in parallel, cached, resumable."""
    from lcmesh.distill.ppo_config import PpoConfig
    from lcmesh.distill.sweep import parse_grid, run_sweep, sweep_configs

    try:
        seed_list = [int(s) for s in seeds.split(",") if s.strip()]
        # every run's settings are checked (PpoConfig validates) before any starts
        configs = sweep_configs(PpoConfig(case=case, out=str(out)), seed_list, parse_grid(grid or []))
    except ValueError as exc:
        fail(f"{exc}")
    with stage_progress(f"{len(configs)} PPO runs") as on_progress:
        outcomes = run_sweep(configs, engine, on_progress)
    rows = []
    for o in outcomes:
        if o.error is not None:
            console.print(f"[yellow]{o.unit.label}: failed[/yellow] ({o.error})")
            rows.append({"run": o.unit.label, "error": o.error})
            continue
        best = o.result.get("best", {})
        kpi = best.get("kpi", {})
        console.print(f"{o.unit.label}: best at update {best.get('update')}, validation D_blade "
                      f"{kpi.get('d_blade_pct', float('nan')):.2f} %" + (" (cached)" if o.cached else ""))  # fmt: skip
        rows.append({"run": o.unit.label, "cached": o.cached, "commit": o.commit, "summary": o.result})
    write_json(json_out or out / "sweep.json", {"runs": rows})
