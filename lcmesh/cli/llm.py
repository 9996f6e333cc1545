"""lcmesh distill llm, lcmesh bench llm (the LLM controller issue)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from lcmesh.cli.common import (
    JsonOpt, bench_app, console, distill_app, engine_options, fail, progress_bar, stage_bars, write_bench,
)  # fmt: skip
from lcmesh.cli.control import dataclass_options


def _distill_llm(config) -> None:
    from lcmesh.distill.llm import distill_llm

    with stage_bars() as on_progress:
        manifest = distill_llm(config, progress=on_progress)
    h, t = manifest["metrics"]["heldout"], manifest["metrics"]["train"]
    console.print(
        f"adapter {manifest['adapter_id']} ({manifest['adapter_bytes'] / 1e6:.1f} MB): loss {t['loss_first']:.3f} -> "
        f"{t['loss_last10_mean']:.3f}, {t['tokens_per_s']:.0f} tokens/s; "
        f"held-out CDU R2 {h.get('cdu_r2', float('nan')):.3f}, "
        f"valve R2 {h.get('valve_r2') or float('nan'):.3f}, parse failures {100 * h['parse_failure_rate']:.1f} %"
    )


def _distill_llm_control(config) -> None:
    from lcmesh.distill.llm_control import distill_llm_control

    with stage_bars() as on_progress:
        manifest = distill_llm_control(config, progress=on_progress)
    d = manifest["dev_scores"]
    console.print(
        f"adapter {manifest['adapter_id']}: final loss {manifest['final_loss']:.3f}; dev day {manifest['dev_day']}: "
        f"supply MAE {d['supply_mae_k']:.2f} K, dp MAE {d['dp_mae_psi']:.2f} psi, approach MAE "
        f"{d['approach_mae_k']:.2f} K, exact answers {100 * d['exact_answer_rate']:.0f} % "
        f"({manifest['train_seconds'] / 60:.0f} min)"
    )


def _register() -> None:
    from lcmesh.distill.llm_control import LlmControlDistillConfig
    from lcmesh.llm.distill_config import LlmDistillConfig

    distill_app.command(
        "llm", help="QLoRA-distill a teacher (ppo | g36 | tree) into SmolLM2-135M-Instruct; adapter + manifest."
    )(dataclass_options(LlmDistillConfig, _distill_llm))
    distill_app.command(
        "llm-control", help="Distill the deployed PPO policy into SmolLM2-135M as the LLM controller (compact "
        "grammar-decoded answers, top layers LoRA on cached activations); adapter + manifest + loss plot."
    )(dataclass_options(LlmControlDistillConfig, _distill_llm_control))


_register()


@bench_app.command("llm")
@engine_options
def bench_llm(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update the llm section of this BENCHMARKS.md")] = None,
    quick: Annotated[bool, typer.Option(help="small sample counts, 15 min on two days (smoke run)")] = False,
    hours: Annotated[float, typer.Option(help="closed loop: the busiest hours of each held-out day", min=0.05,
                                         max=24.0)] = 1.0,
    period: Annotated[int, typer.Option(help="closed loop: the LLM decides every N steps", min=1)] = 8,
    days: Annotated[str, typer.Option(help="closed loop: comma-separated suite test days (default: all), or validation "
                                        "days to choose settings on (then no --markdown)")] = "",
    adapter: Annotated[str, typer.Option(help="the explainer's LoRA adapter folder, 'default' (packaged) or "
                                         "'none'")] = "default",
    sections: Annotated[str, typer.Option(help="what to run: fidelity, control, explain, loop (busiest hour per "
                                          "day), days (whole days, hours each)")] = "fidelity,control,explain,loop",
    whole_day_period: Annotated[int, typer.Option(help="whole days: the LLM decides every N steps", min=1)] = 8,
    engine=None,
) -> None:
    """Load time, explanation and control latency, action R^2 vs the teacher, closed-loop KPIs beside G36/PPO/trees."""
    from lcmesh.bench.llm import BenchLlmConfig, render_llm, run_bench_llm

    if days:
        from lcmesh.bench.suite import TEST_DAYS, VALIDATION_DAYS, days_named

        try:
            picked = days_named([d.strip() for d in days.split(",") if d.strip()], TEST_DAYS + VALIDATION_DAYS)
        except ValueError as exc:
            fail(f"`--days`: {exc}")
        if markdown is not None and any(d in VALIDATION_DAYS for d in picked):
            fail("`--days`: validation days are for choosing settings; their figures do not go into BENCHMARKS.md "
                 "(leave out --markdown, keep --json)")
    known = {"fidelity", "control", "explain", "loop", "days"}
    unknown = sorted({x.strip() for x in sections.split(",") if x.strip()} - known)
    if unknown:
        fail(f"`--sections`: unknown {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    cfg = BenchLlmConfig.make(quick=quick, hours=hours, period_steps=period, adapter=adapter, days=days,
                              sections=sections, whole_day_period=whole_day_period)
    with progress_bar() as progress:
        task = progress.add_task("bench llm", total=None)
        result = run_bench_llm(cfg, on_stage=lambda msg: progress.update(task, description=msg), engine=engine)
    write_bench(json_out, markdown, "llm", result, render=render_llm)


@bench_app.command("runtime")
def bench_runtime(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update the runtime section of this BENCHMARKS.md")] = None,
    threads: Annotated[int, typer.Option(help="CPU threads every runtime gets", min=1)] = 2,
) -> None:
    """transformers fp32 / bf16, llama.cpp (shipped GGUF) and CTranslate2 int8 (if installed), side by side."""
    from lcmesh.bench.runtime import render_runtime, run_bench_runtime

    with progress_bar() as progress:
        task = progress.add_task("bench runtime", total=None)
        result = run_bench_runtime(threads, say=lambda msg: progress.update(task, description=msg))
    write_bench(json_out, markdown, "runtime", result, render=render_runtime)
