"""lcmesh bench api (the UI agent issue)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from lcmesh.cli.common import JsonOpt, bench_app, console, write_json


@bench_app.command("api")
def bench_api(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    quick: Annotated[bool, typer.Option(help="fewer requests and questions (smoke run)")] = False,
    llm: Annotated[bool, typer.Option(help="also measure chat phrased by the local LLM (loads the model)")] = True,
) -> None:
    """State endpoint p99 under 50 concurrent clients and chat latency (template and LLM), on a real mesh."""
    from lcmesh.bench.api import render_api, run_bench_api

    result = run_bench_api(quick=quick, llm=llm, say=console.print)
    write_json(json_out, result)
    if markdown is not None:
        from lcmesh.bench.report import update_benchmarks_md

        update_benchmarks_md(markdown, "api", result, render=render_api)
        console.print(f"updated {markdown}")
