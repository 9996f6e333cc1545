"""Write benchmark results into BENCHMARKS.md, one marked section per benchmark."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path


def update_benchmarks_md(path: Path, name: str, result: dict, render: Callable[[dict], str] | None = None) -> None:
    """Replace (or append) the section between ``<!-- bench:NAME -->`` markers (``render`` overrides the renderer)."""
    render = render or {"twin": render_twin}[name]
    start, end = f"<!-- bench:{name}:start -->", f"<!-- bench:{name}:end -->"
    block = f"{start}\n{render(result)}\n{end}"
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    if start in text and end in text:
        head, rest = text.split(start, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    path.write_text(text)


def render_twin(r: dict) -> str:
    m, env, loop, cmp_, day = r["machine"], r["env_lcopt5"], r["plant_loop_lcopt5"], r["fmi2_raw_vs_list"], r[
        "frontier_full_day"
    ]
    lines = [
        "## Twin (`lcmesh bench twin --json runs/bench/twin.json --markdown BENCHMARKS.md`)",
        "",
        f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs, pinned to CPU {m['pinned_cpu']}; "
        f"Python {m['python']}, numpy {m['numpy']}, fmpy {m['fmpy']}; commit {m['commit']}; {m['date']}.",
        "Medians of repeats in one run.",
        "",
        "| figure | measured | target |",
        "|---|---|---|",
        f"| lcopt-5 cabinet env (Gymnasium), steps/s | {env['cabinet']['steps_per_s']:,.0f} | >= 5,000 (LC-Opt: ~50) |",
        f"| lcopt-5 tower env, steps/s | {env['tower']['steps_per_s']:,.0f} | |",
        f"| lcopt-5 parallel env (PettingZoo, 7 agents), steps/s | {env['parallel']['steps_per_s']:,.0f} | |",
        f"| lcopt-5 closed-loop run (trace + static rule + guardrails + FMU + KPIs + recording), steps/s | "
        f"{loop['steps_per_s']:,.0f} | |",
    ]
    if "bare_steps_per_s" in loop:
        lines.append(f"| the same loop bare (no guardrails), steps/s; guarded slowdown | {loop['bare_steps_per_s']:,.0f}; "
                     f"{loop['guard_slowdown']:.2f}x | <= 2x |")  # fmt: skip
    lines += [
        f"| frontier-full ({day['blade_groups']:,} blade groups) 24 h day, wall s | {day['wall_s']:.2f} "
        f"({day['realtime_factor']:,.0f}x real time) | <= 20 s (>= 4,000x) |",
        f"| raw fmi2 + numpy buffers vs fmpy list API (lcopt-5 loop) | {cmp_['raw_fmi2_steps_per_s']:,.0f} vs "
        f"{cmp_['fmpy_list_steps_per_s']:,.0f} steps/s = {cmp_['speedup']:.1f}x | |",
    ]
    if "fmi2_raw_vs_list_frontier" in r:
        big = r["fmi2_raw_vs_list_frontier"]
        lines.append(
            f"| raw fmi2 vs fmpy list API (frontier-full, {big['reals_set_per_step']:,} reals in, "
            f"{big['reals_read_per_step']:,} out per step) | {big['raw_fmi2_steps_per_s']:,.0f} vs "
            f"{big['fmpy_list_steps_per_s']:,.0f} steps/s = {big['speedup']:.1f}x | |"
        )
    return "\n".join(lines)
