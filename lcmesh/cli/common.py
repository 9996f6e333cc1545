"""Shared pieces of the ``lcmesh`` command line: the root app, sub-apps, console and helpers."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

app = typer.Typer(help="lc-mesh: liquid-cooling digital twin, controllers and agent mesh.", no_args_is_help=True)
twin_app = typer.Typer(help="Build, validate and run the digital twin.", no_args_is_help=True)
bench_app = typer.Typer(help="Benchmarks (results go to BENCHMARKS.md).", no_args_is_help=True)
app.add_typer(twin_app, name="twin")
train_app = typer.Typer(help="Train controllers (run folders under runs/).", no_args_is_help=True)
distill_app = typer.Typer(help="Distill a trained policy into trees or a small LLM.", no_args_is_help=True)
app.add_typer(bench_app, name="bench")
app.add_typer(train_app, name="train")
app.add_typer(distill_app, name="distill")

console = Console(stderr=True)

SystemOpt = Annotated[str, typer.Option("--system", "-s", help="reference system name (lcopt-5 ...) or a .json path")]
ScenarioOpt = Annotated[
    str, typer.Option(help="frontier (real loads and weather), design-day (Knoxville's 0.4 % design wet bulb) or "
                      "lcopt (LC-Opt's +15 K and 25:1 branch skew); docs/traces.md")
]
JsonOpt = Annotated[Optional[Path], typer.Option("--json", help="write the result as JSON here")]


def fail(message: str) -> None:
    console.print(f"[red]error:[/red] {message}")
    raise typer.Exit(2)


def load_system_or_fail(name: str):
    from lcmesh.twin.system import SystemDescriptionError, load_system

    try:
        return load_system(name)
    except SystemDescriptionError as exc:
        fail(str(exc))


def write_json(path: Path | None, data: dict) -> None:
    text = json.dumps(data, indent=2, default=json_default)
    if path is None:
        print(text)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")
    console.print(f"wrote {path}")


def json_default(value):
    import numpy as np

    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serializable: {type(value).__name__}")


def progress_bar() -> Progress:
    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
        console=console,
    )  # fmt: skip
