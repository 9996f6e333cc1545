"""Shared pieces of the ``lcmesh`` command line: the root app, sub-apps, console and helpers."""

from __future__ import annotations

import functools
import inspect
import json
import typing
from collections.abc import Callable, Iterator
from contextlib import contextmanager
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

# soft wrap: a line is never broken at the console's width; a terminal wraps it for the eye, and a log file or pipe (the
# demo's output under systemd, a bench's .out file) keeps one message a line, greppable ("pid 9142", not "pid\n9142")
console = Console(stderr=True, soft_wrap=True)

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


_ENGINE_OPTIONS = {
    "engine_kind": (str, "ray", typer.Option("--engine", help="ray (a local instance unless --address) or serial "
                                             "(one unit after another, here)")),
    "address": (Optional[str], None, typer.Option(help="a Ray cluster to run the units on (default: RAY_ADDRESS, "
                                                  "else a local instance sized to this machine)")),
    "fresh": (bool, False, typer.Option("--fresh", help="recompute every unit, ignoring (and then overwriting) the result cache")),
    "cache": (Optional[Path], None, typer.Option(help="the result cache, a SQLite file (default: $LCMESH_BENCH_CACHE "
                                                 "or runs/cache/units.sqlite)")),
    "no_cache": (bool, False, typer.Option("--no-cache", help="neither read nor write the result cache")),
}


def engine_options(command: Callable) -> Callable:
    """A bench command with the engine's options (docs/bench.md): --engine, --address, --fresh, --cache, --no-cache,
    given to it as ``engine`` (EngineSettings), one clear error for a bad one."""
    signature = inspect.signature(command)
    hints = typing.get_type_hints(command, include_extras=True)  # the command's own names, resolved in its module
    params = [p.replace(annotation=hints.get(p.name, p.annotation)) for p in signature.parameters.values()
              if p.name != "engine"]  # fmt: skip
    params += [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                                 annotation=Annotated[kind, option])
               for name, (kind, default, option) in _ENGINE_OPTIONS.items()]  # fmt: skip

    @functools.wraps(command)
    def run(*args, engine_kind: str, address: str | None, fresh: bool, cache: Path | None, no_cache: bool, **kwargs):
        return command(*args, engine=_engine_settings(engine_kind, address, fresh, cache, no_cache), **kwargs)

    run.__signature__ = signature.replace(parameters=params, return_annotation=None)  # type: ignore[attr-defined]
    run.__annotations__ = {p.name: p.annotation for p in params}
    return run


def _engine_settings(engine: str, address: str | None, fresh: bool, cache: Path | None, no_cache: bool):
    from lcmesh.bench.engine import EngineSettings

    try:
        settings = EngineSettings(engine=engine, address=address, fresh=fresh)
    except ValueError as exc:
        fail(f"`--engine`: {exc}")
    if address and engine == "serial":
        fail("`--address` runs the units on a Ray cluster; it cannot go with `--engine serial`")
    if no_cache:
        settings.cache = None
    elif cache is not None:
        if cache.is_dir():
            fail(f"`--cache` must be a SQLite file, got the folder {cache}")
        settings.cache = cache
    return settings


def say_cache(result: dict) -> None:
    """One line on the console: how many units the cache gave."""
    from lcmesh.bench.engine import cache_line

    if line := cache_line(result.get("cache", {})):
        console.print(line)


def write_bench(json_out: Path | None, markdown: Path | None, section: str, result: dict, render=None) -> None:
    """A benchmark's result: JSON to `json_out` (stdout when None), and its BENCHMARKS.md section when asked."""
    write_json(json_out, result)
    if markdown is not None:
        from lcmesh.bench.report import update_benchmarks_md

        kwargs = {} if render is None else {"render": render}
        update_benchmarks_md(markdown, section, result, **kwargs)
        console.print(f"updated {markdown}")


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


@contextmanager
def stage_progress(description: str) -> Iterator[Callable[[str, int, int], None]]:
    """A progress bar driven by the benches' ``progress(stage, done, total)`` callback."""
    with progress_bar() as progress:
        task = progress.add_task(description, total=None)

        def on_progress(stage: str, done: int, total: int) -> None:
            progress.update(task, completed=done, total=total, description=stage)

        yield on_progress


@contextmanager
def stage_bars() -> Iterator[Callable[[str, int, int], None]]:
    """One progress bar per stage of a ``progress(stage, done, total)`` callback (a training stage's text may carry
    `` loss ...`` after its name: the same bar)."""
    with progress_bar() as progress:
        tasks: dict[str, int] = {}

        def on_progress(stage: str, done: int, total: int) -> None:
            key = stage.split(" loss ")[0]
            if key not in tasks:
                tasks[key] = progress.add_task(stage, total=total)
            progress.update(tasks[key], completed=done, total=total, description=stage)

        yield on_progress


def progress_bar() -> Progress:
    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
        console=console,
    )  # fmt: skip
