"""lcmesh router, lcmesh agent ROLE, lcmesh demo, lcmesh status, lcmesh stop, lcmesh bench mesh.

Every command reads the ``LCMESH_*`` settings (lcmesh.mesh.settings); options given here win.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from lcmesh.cli.common import JsonOpt, app, bench_app, console, fail, write_json

ROLE_HELP = "sensor, control, maintenance, monitor, configuration, orchestration, ui"
CONTROLLER_HELP = "tree (default; G36 until a tree is trained), g36, ppo, static, llm"


def _settings(**overrides):
    """MeshSettings from the environment with the non-None `overrides`; a clear error if invalid."""
    from pydantic import ValidationError

    from lcmesh.mesh.settings import MeshSettings

    try:
        return MeshSettings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        problems = [f"`{'.'.join(map(str, e['loc']))}` {e['msg']}" for e in exc.errors()]
        fail("invalid mesh settings: " + "; ".join(problems))


@app.command("router")
def router(
    listen: Annotated[Optional[list[str]], typer.Option(help="endpoint to listen on, e.g. tcp/127.0.0.1:7447")] = None,
    peer: Annotated[Optional[list[str]], typer.Option(help="another router to link to (scale-out); repeatable")] = None,
) -> None:
    """Run a zenoh router (the mesh hub); agents connect to it as clients."""
    from lcmesh.mesh.router import run_router

    raise typer.Exit(run_router(_settings(listen_endpoints=listen or None, router_peers=peer or None)))


@app.command("agent")
def agent(
    role: Annotated[str, typer.Argument(help=ROLE_HELP)],
    agent_id: Annotated[Optional[str], typer.Option("--id", help="agent id (default: the role)")] = None,
    check: Annotated[bool, typer.Option(help="healthcheck: exit 0 if this agent is alive on the mesh")] = False,
) -> None:
    """Run one agent until SIGTERM/Ctrl-C (connects to LCMESH_ROUTER_ENDPOINTS, retrying)."""
    from lcmesh.mesh.agents.registry import AgentUnavailable, check_role
    from lcmesh.mesh.agents.runner import check_agent, run_agent
    from lcmesh.mesh.bus import BusError

    try:
        check_role(role)
    except ValueError as exc:
        fail(str(exc))
    settings = _settings()
    if check:
        try:
            tokens = check_agent(role, settings, agent_id)
        except BusError as exc:
            fail(str(exc))
        console.print("alive: " + (", ".join(tokens) if tokens else "none"))
        raise typer.Exit(0 if tokens else 1)
    try:
        raise typer.Exit(run_agent(role, settings, agent_id))
    except AgentUnavailable as exc:
        fail(str(exc))


@app.command("demo")
def demo(
    system: Annotated[Optional[str], typer.Option(help="reference system or .json (default lcopt-5)")] = None,
    trace: Annotated[Optional[str], typer.Option(help="default frontier-2024-04-07")] = None,
    speed_factor: Annotated[Optional[float], typer.Option(help="simulated s per wall s (default 60)")] = None,
    controller: Annotated[Optional[str], typer.Option(help=CONTROLLER_HELP)] = None,
    port: Annotated[Optional[int], typer.Option(help="router port on 127.0.0.1 (default 7447)")] = None,
    ui_port: Annotated[Optional[int], typer.Option(help="UI port (default 8000)")] = None,
    data_dir: Annotated[Optional[Path], typer.Option(help="history, config, logs (default runs/mesh)")] = None,
    duration: Annotated[float, typer.Option(help="stop after this many seconds (0: run until Ctrl-C)")] = 0.0,
    resume: Annotated[bool, typer.Option(help="continue the last run of the plant instead of a new one")] = False,
) -> None:
    """Router + every agent as processes on the Frontier day; UI on http://127.0.0.1:8000; Ctrl-C stops all."""
    from lcmesh.mesh.demo import run_demo

    endpoints = [f"tcp/127.0.0.1:{port}"] if port else None
    settings = _settings(system=system, trace=trace, speed_factor=speed_factor, controller=controller,
                         router_endpoints=endpoints, listen_endpoints=endpoints, ui_port=ui_port,
                         data_dir=data_dir)  # fmt: skip
    changes = {k: v for k, v in {"speed_factor": speed_factor, "controller": controller}.items() if v is not None}
    raise typer.Exit(run_demo(settings, duration_s=duration, config_changes=changes, resume=resume,
                              say=lambda text: console.print(text, markup=False, highlight=False)))  # fmt: skip


DataDirOpt = Annotated[Optional[Path], typer.Option(help="the mesh's data dir (default LCMESH_DATA_DIR or runs/mesh)")]


@app.command("status")
def status(
    data_dir: DataDirOpt = None,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="also write the status as JSON here")] = None,
) -> None:
    """What runs for a data dir: the demo, every process with its uptime, the ports, the plant's last step.

    Exit 0 while something runs, 3 when nothing does (as `systemctl status`)."""
    from lcmesh.mesh.service import mesh_status

    settings = _settings(data_dir=data_dir)
    result = mesh_status(settings.data_dir, settings.history_file)
    for line in _status_lines(result):
        print(line)
    if json_out is not None:
        write_json(json_out, result)
    raise typer.Exit(0 if result["running"] else 3)


def _status_lines(result: dict) -> list[str]:
    lines = [f"mesh in {result['data_dir']}: {'running' if result['running'] else 'not running'}"]
    demo = result["demo"]
    if demo is not None:
        state = "running" if demo["running"] else "gone"
        lines.append(f"  demo pid {demo['pid']} ({state}), started {demo['started_at'][:19]} UTC: {demo['system']} on "
                     f"{demo['trace']}, controller {demo['controller']}")  # fmt: skip
    for name, port in result["ports"].items():
        holder = f"listening, pid {port['pid']}" if port["listening"] else "free"
        lines.append(f"  {name} port {port['port']}: {holder}")
    plant = result["plant"]
    if plant and "error" in plant:
        lines.append(f"  plant: {plant['error']}")
    elif plant and plant["step"] is not None:
        ended = ", ended" if plant["ended"] else ""
        lines.append(f"  plant: run {plant['run_id']}, step {plant['step']} ({plant['time_s'] / 3600:.2f} h of plant "
                     f"time){ended}")  # fmt: skip
    for proc in result["processes"]:
        lines.append(f"  pid {proc['pid']:>7}  {proc['role']:<14} up {proc['uptime_s']:.0f} s")
    if "note" in result:
        lines.append(f"  note: {result['note']}")
    return lines


@app.command("stop")
def stop(
    data_dir: DataDirOpt = None,
    timeout: Annotated[float, typer.Option(help="seconds for a clean stop before what is left is killed")] = 60.0,
) -> None:
    """Stop the mesh of a data dir cleanly (the demo stops its agents, then its router); kill what is left."""
    from lcmesh.mesh.service import mesh_processes, read_run_file, stop_mesh

    settings = _settings(data_dir=data_dir)
    run = read_run_file(settings.data_dir)
    if (run is None or not run.demo_running()) and not mesh_processes(settings.data_dir):
        print(f"nothing runs for {settings.data_dir.resolve()}")
        raise typer.Exit(0)
    left = stop_mesh(settings.data_dir, timeout_s=timeout, say=print)
    if left:
        fail("still running: " + ", ".join(f"{p.role} pid {p.pid}" for p in left))
    print(f"stopped the mesh in {settings.data_dir.resolve()}")


@bench_app.command("mesh")
def bench_mesh(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    quick: Annotated[bool, typer.Option(help="fewer steps and levels (smoke run)")] = False,
    controller: Annotated[str, typer.Option(help="controller measured (G36 if it is not available)")] = "tree",
) -> None:
    """Plant-state publish to applied action latency (lcopt-5, frontier-full) and the highest sustained speed factor."""
    from lcmesh.bench.mesh import render_mesh, run_bench_mesh

    result = run_bench_mesh(controller=controller, quick=quick, say=console.print)
    write_json(json_out, result)
    if markdown is not None:
        from lcmesh.bench.report import update_benchmarks_md

        update_benchmarks_md(markdown, "mesh", result, render=render_mesh)
        console.print(f"updated {markdown}")


@bench_app.command("lifecycle")
def bench_lifecycle(
    json_out: JsonOpt = None,
    markdown: Annotated[Optional[Path], typer.Option(help="update this BENCHMARKS.md section")] = None,
    trials: Annotated[int, typer.Option(min=0, help="instead: this many SIGKILLs of the demo as soon as its UI "
                                        "answers, counting what is left 10 s later")] = 0,
    load: Annotated[int, typer.Option(min=0, help="busy-loop processes to run meanwhile (cores kept busy)")] = 0,
) -> None:
    """How the demo stops on SIGHUP/SIGINT/SIGTERM/SIGKILL, an orchestrator's death, and a second start refused."""
    from lcmesh.bench.lifecycle import render_kill_after_ui, render_lifecycle, run_bench_lifecycle, run_kill_after_ui
    from lcmesh.cli.common import write_bench

    if trials:
        result = run_kill_after_ui(trials, load, say=console.print)
        print(render_kill_after_ui(result))
        write_bench(json_out or Path("runs/bench/lifecycle_kill_after_ui.json"), markdown, "lifecycle_kill", result,
                    render=lambda r: "### SIGKILL as soon as the UI answers, cores busy (`lcmesh bench lifecycle "
                    "--trials 20 --load 2 --markdown BENCHMARKS.md`)\n\n" + render_kill_after_ui(r))  # fmt: skip
        return
    if load:
        fail("`--load` goes with `--trials` (the SIGKILL race); the full lifecycle bench runs on a quiet machine")
    write_bench(json_out, markdown, "lifecycle", run_bench_lifecycle(say=console.print), render=render_lifecycle)
