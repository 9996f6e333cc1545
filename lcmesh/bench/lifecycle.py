"""``lcmesh bench lifecycle``: how the mesh stops, however it is stopped, and how a second start is refused.

Each trial runs ``lcmesh demo`` as a real process tree (router, orchestrator and the demo's own
agents: configuration, sensor, control, maintenance, monitor, UI) in a fresh data dir on free
loopback ports, in its own session as a terminal would run it, and then:

| trial | what is done | what is measured |
|---|---|---|
| SIGHUP, SIGINT | to the demo's process group (closed terminal, Ctrl-C) | s until nothing is left, ports, exit code |
| SIGTERM | ``lcmesh stop --data-dir D`` (which sends it) | the same |
| SIGKILL | the demo alone is killed | the same (its children are tied to it) |
| SIGKILL during the stop | SIGTERM, then SIGKILL once the demo says it is stopping | the same |
| orchestrator SIGKILL | the orchestrator alone is killed | s until none of its agents is left |
| stale | a second demo on the same ports, another data dir | s until it exits, its code, whether it names the holder |

The tests (tests/mesh/test_lifecycle.py) run the same trials on lighter meshes (configuration and
monitor agents) and assert what is left; the seconds are reported here only (the targets: 10 s to
stop, 15 s to refuse).

``--trials N`` runs instead N times the race that once left a process behind (1 of 13 on busy cores):
the demo is SIGKILLed as soon as its UI first answers, while its agents are still starting (the
Sensor in its spin-up), and whatever of its data dir still runs 10 s later is counted (and then
killed). ``--load N`` keeps N busy-loop processes running meanwhile.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lcmesh.bench.machine import machine_info
from lcmesh.mesh.processes import free_port, log_tail, wait_for_port
from lcmesh.mesh.service import mesh_processes, port_listener

LCMESH = str(Path(sys.executable).parent / "lcmesh")
STOP_TARGET_S, STALE_TARGET_S = 10.0, 15.0
START_TIMEOUT_S = 120.0  # generous: a busy machine starts slowly; liveness, not speed
ROLES = ("configuration", "monitor")  # the tests' light agents: what they check is the process tree, not the plant
DEMO_ROLES = ("configuration", "sensor", "control", "maintenance", "monitor", "ui")  # MeshSettings' default


@dataclass
class DemoRun:
    """A started ``lcmesh demo`` process: its data dir, its ports, its output file."""

    popen: subprocess.Popen
    data_dir: Path
    port: int
    ui_port: int
    roles: tuple[str, ...]
    output: Path

    @property
    def expected(self) -> int:
        """Processes the running mesh has: demo, router, orchestrator and the roles."""
        return 3 + len(self.roles)

    def ports(self) -> list[int]:
        return [self.port, self.ui_port] if "ui" in self.roles else [self.port]

    def text(self) -> str:
        return self.output.read_text(errors="replace")


def demo_env(roles: tuple[str, ...]) -> dict[str, str]:
    """This environment without LCMESH_* settings (but the FMU cache), the roles, the rules' planner."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("LCMESH_") or k == "LCMESH_CACHE_DIR"}
    env.update(LCMESH_ORCHESTRATION__ROLES=json.dumps(list(roles)), LCMESH_UI_PLANNER="rules",
               LCMESH_CONTROLLER="g36")  # fmt: skip
    return env


def start_demo(data_dir: Path, roles: tuple[str, ...] = ROLES, port: int | None = None,
               ui_port: int | None = None, wait: bool = True) -> DemoRun:  # fmt: skip
    """Start ``lcmesh demo`` in its own session (as a terminal's foreground job) and wait until all of it runs
    (unless not `wait`)."""
    data_dir.mkdir(parents=True, exist_ok=True)
    port, ui_port = port or free_port(), ui_port or free_port()
    output = data_dir.parent / f"{data_dir.name}.out"
    with open(output, "wb") as out:
        popen = subprocess.Popen([LCMESH, "demo", "--port", str(port), "--ui-port", str(ui_port), "--data-dir",
                                  str(data_dir)], env=demo_env(roles), stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    run = DemoRun(popen, data_dir, port, ui_port, tuple(roles), output)
    if not wait:
        return run
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline and popen.poll() is None:
        if len(mesh_processes(data_dir)) >= run.expected and all(wait_for_port("127.0.0.1", p, 0.1)
                                                                 for p in run.ports()):  # fmt: skip
            return run
        time.sleep(0.2)
    stop_everything(run)
    raise RuntimeError(f"the demo did not come up within {START_TIMEOUT_S:g} s:\n{run.text()[-3000:]}")


def wait_none_left(data_dir: Path, pids: set[int] | None = None, timeout_s: float = 60.0) -> tuple[float, list]:
    """(seconds until no process of `data_dir` (or of `pids`) is left, what is left after `timeout_s`)."""
    t0 = time.monotonic()
    while True:
        left = [p for p in mesh_processes(data_dir) if pids is None or p.pid in pids]
        if not left or time.monotonic() - t0 > timeout_s:
            return time.monotonic() - t0, left
        time.sleep(0.05)


def stop_everything(run: DemoRun) -> None:
    """Clean up after a failed trial (never part of what is measured)."""
    try:
        os.killpg(run.popen.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    run.popen.wait(timeout=30)
    for proc in mesh_processes(run.data_dir):
        try:
            os.kill(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def signal_trial(run: DemoRun, sig: signal.Signals, kill_during_stop: bool = False) -> dict:
    """Stop `run` with `sig` as a user would send it (then SIGKILL as soon as the demo says it is stopping, with
    `kill_during_stop`); what is left, how fast, the ports, the exit code."""
    before = len(mesh_processes(run.data_dir))
    t0 = time.monotonic()
    if kill_during_stop:
        os.kill(run.popen.pid, sig)
        while "stopping the mesh" not in run.text() and time.monotonic() - t0 < 30:
            time.sleep(0.005)
        os.kill(run.popen.pid, signal.SIGKILL)
        how = f"kill -{sig.name[3:]}, then -KILL {time.monotonic() - t0:.2f} s later, during the stop"
    elif sig == signal.SIGTERM:  # `lcmesh stop` sends it to the demo
        stop = subprocess.run([LCMESH, "stop", "--data-dir", str(run.data_dir)], capture_output=True, text=True,
                              timeout=180)  # fmt: skip
        how = f"lcmesh stop (exit {stop.returncode})"
    elif sig == signal.SIGKILL:
        os.kill(run.popen.pid, sig)
        how = "kill -KILL the demo"
    else:
        os.killpg(run.popen.pid, sig)
        how = f"kill -{sig.name[3:]} the demo's process group"
    seconds, left = wait_none_left(run.data_dir)
    seconds = max(seconds, time.monotonic() - t0)
    code = run.popen.wait(timeout=60)
    busy = [p for p in run.ports() if port_listener(p)[0]]
    return {"signal": sig.name, "how": how, "processes_before": before, "seconds_to_none_left": round(seconds, 2),
            "left": [f"{p.role} pid {p.pid}" for p in left], "ports_still_listening": busy, "exit_code": code,
            "within_target": seconds <= STOP_TARGET_S and not left and not busy}  # fmt: skip


def orchestrator_kill_trial(run: DemoRun) -> dict:
    """SIGKILL the orchestrator alone: its agents must end with it (the demo then starts a new one)."""
    procs = mesh_processes(run.data_dir)
    orchestrator = next(p for p in procs if p.role == "orchestration")
    agents = {p.pid for p in procs if p.role in run.roles}
    t0 = time.monotonic()
    os.kill(orchestrator.pid, signal.SIGKILL)
    seconds, left = wait_none_left(run.data_dir, agents)
    return {"agents_before": len(agents), "seconds_to_none_left": round(max(seconds, time.monotonic() - t0), 2),
            "left": [f"{p.role} pid {p.pid}" for p in left],
            "within_target": seconds <= STOP_TARGET_S and not left}  # fmt: skip


def stale_trial(run: DemoRun, data_dir: Path) -> dict:
    """A second demo on `run`'s ports with another data dir: how fast it refuses, and what it says."""
    router = next(p for p in mesh_processes(run.data_dir) if p.role == "router")
    t0 = time.monotonic()
    second = subprocess.run([LCMESH, "demo", "--port", str(run.port), "--ui-port", str(run.ui_port), "--data-dir",
                             str(data_dir)], env=demo_env(run.roles), capture_output=True, text=True,
                            timeout=120)  # fmt: skip
    seconds = time.monotonic() - t0
    said = " ".join((second.stdout + second.stderr).split())
    names = f"pid {router.pid}" in said and str(run.data_dir) in said
    return {"seconds_to_exit": round(seconds, 2), "exit_code": second.returncode, "names_pid_and_data_dir": names,
            "message": said[-600:], "within_target": seconds <= STALE_TARGET_S and second.returncode != 0 and names}


def run_bench_lifecycle(say: Callable[[str], None] = print, root: Path | None = None,
                        roles: tuple[str, ...] = DEMO_ROLES) -> dict:  # fmt: skip
    """Every trial once on the demo's own agents; the figures for BENCHMARKS.md."""
    root = Path(root or tempfile.mkdtemp(prefix="lcmesh-lifecycle-"))
    trials = []
    extra: dict = {}
    for sig in (signal.SIGHUP, signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        run = start_demo(root / f"demo-{sig.name.lower()}", roles)
        try:
            if sig == signal.SIGHUP:
                extra["stale"] = stale_trial(run, root / "second")
                say(f"stale: {extra['stale']['seconds_to_exit']} s, exit {extra['stale']['exit_code']}")
                extra["orchestrator_kill"] = orchestrator_kill_trial(run)
                say(f"orchestrator SIGKILL: {extra['orchestrator_kill']['seconds_to_none_left']} s")
                start_deadline = time.monotonic() + START_TIMEOUT_S  # the demo starts a new orchestrator and agents
                while len(mesh_processes(run.data_dir)) < run.expected and time.monotonic() < start_deadline:
                    time.sleep(0.2)
            trials.append(signal_trial(run, sig))
            say(f"{sig.name}: {trials[-1]['seconds_to_none_left']} s, left {trials[-1]['left']}")
        finally:
            stop_everything(run)
    run = start_demo(root / "demo-kill-during-stop", roles)
    try:
        trials.append(signal_trial(run, signal.SIGTERM, kill_during_stop=True))
        say(f"SIGKILL during the stop: {trials[-1]['seconds_to_none_left']} s, left {trials[-1]['left']}")
    finally:
        stop_everything(run)
    return {"machine": machine_info(), "roles": list(roles),
            "targets": {"stop_s": STOP_TARGET_S, "stale_s": STALE_TARGET_S}, "signals": trials, **extra}


def ui_answers(port: int) -> bool:
    """Whether an HTTP server answers on 127.0.0.1:`port` (any status)."""
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=1.0).close()
    except urllib.error.HTTPError:
        return True
    except (OSError, ValueError):
        return False
    return True


def burners(n: int) -> list[subprocess.Popen]:
    """`n` processes that keep a core busy each (busy-loop Python), until killed."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
            for _ in range(n)]  # fmt: skip


def kill_after_ui_trial(data_dir: Path, roles: tuple[str, ...] = DEMO_ROLES) -> dict:
    """Start the demo, SIGKILL it the moment its UI first answers, count what of its data dir runs 10 s later."""
    t0 = time.monotonic()
    run = start_demo(data_dir, roles, wait=False)
    try:
        deadline = t0 + START_TIMEOUT_S
        while not ui_answers(run.ui_port):
            if time.monotonic() > deadline or run.popen.poll() is not None:
                raise RuntimeError(f"the demo's UI did not answer within {START_TIMEOUT_S:g} s:\n{run.text()[-3000:]}")
            time.sleep(0.05)
        ui_s = time.monotonic() - t0
        before = mesh_processes(run.data_dir)
        killed_at = time.monotonic()
        os.kill(run.popen.pid, signal.SIGKILL)
        left_at_target, gone_s = None, None
        while (since := time.monotonic() - killed_at) < 60.0:
            left = mesh_processes(run.data_dir)
            if left_at_target is None and since >= STOP_TARGET_S:
                left_at_target = left
            if not left:
                gone_s = since
                break
            time.sleep(0.1)
        left_at_target = left_at_target or []
        logs = {p.role: log_tail(run.data_dir / "logs" / f"{p.role}.log", 8) for p in left_at_target}
    finally:
        stop_everything(run)
    return {"ui_answered_s": round(ui_s, 2), "processes_at_kill": len(before),
            "seconds_to_none_left": None if gone_s is None else round(gone_s, 2),
            "left_after_10_s": [f"{p.role} pid {p.pid}" for p in left_at_target],
            "left_after_60_s": [] if gone_s is not None else [f"{p.role} pid {p.pid}" for p in left],
            "their_last_log_lines": logs}  # fmt: skip


def run_kill_after_ui(trials: int, load: int = 0, say: Callable[[str], None] = print, root: Path | None = None,
                      roles: tuple[str, ...] = DEMO_ROLES) -> dict:  # fmt: skip
    """`trials` of ``kill_after_ui_trial`` with `load` busy-loop processes running; the table and its sums."""
    root = Path(root or tempfile.mkdtemp(prefix="lcmesh-kill-race-"))
    busy = burners(load)
    results = []
    try:
        for i in range(trials):
            trial = kill_after_ui_trial(root / f"demo-{i + 1}", roles)
            results.append(trial)
            gone = trial["seconds_to_none_left"]
            say(f"trial {i + 1}/{trials}: UI after {trial['ui_answered_s']:.1f} s, {trial['processes_at_kill']} "
                f"processes killed with the demo, all gone after {'over 60' if gone is None else f'{gone:.1f}'} s, "
                f"left after 10 s: {trial['left_after_10_s'] or 'none'}")  # fmt: skip
    finally:
        for burner in busy:
            burner.kill()
            burner.wait()
    gone = sorted(t["seconds_to_none_left"] for t in results if t["seconds_to_none_left"] is not None)
    return {"machine": machine_info(), "roles": list(roles), "load": load, "trials": results,
            "trials_with_processes_left": sum(bool(t["left_after_10_s"]) for t in results),
            "processes_left": sum(len(t["left_after_10_s"]) for t in results),
            "seconds_to_none_left_max": gone[-1] if len(gone) == len(results) and gone else None}  # fmt: skip


def render_kill_after_ui(result: dict) -> str:
    """The kill-race table (markdown)."""
    lines = [f"SIGKILL of `lcmesh demo` as soon as its UI answers, {len(result['trials'])} trials, {result['load']} "
             f"busy-loop processes; {result['machine']['logical_cpus']} logical CPUs, commit "
             f"{result['machine']['commit']}.", "",
             "| trial | UI answered (s) | processes killed with the demo | all gone after (s) | left after 10 s |",
             "|---|---|---|---|---|"]  # fmt: skip
    for i, t in enumerate(result["trials"], 1):
        gone = "over 60" if t["seconds_to_none_left"] is None else f"{t['seconds_to_none_left']:.1f}"
        lines.append(f"| {i} | {t['ui_answered_s']:.1f} | {t['processes_at_kill']} | {gone} | "
                     f"{', '.join(t['left_after_10_s']) or 'none'} |")  # fmt: skip
    lines += ["", f"Trials with a process left after 10 s: {result['trials_with_processes_left']} of "
              f"{len(result['trials'])}."]  # fmt: skip
    return "\n".join(lines)


def render_lifecycle(result: dict) -> str:
    """The BENCHMARKS.md section."""
    m = result["machine"]
    lines = ["## Lifecycle (`lcmesh bench lifecycle --json runs/bench/lifecycle.json --markdown BENCHMARKS.md`)", "",
             f"Machine: {m['cpu']}, {m['logical_cpus']} logical CPUs; commit {m['commit']}; {m['date']}. "
             f"One run of each, the demo with its agents {', '.join(result['roles'])} (lcopt-5, Frontier day, 60x), "
             "quiet machine. `lcmesh stop`'s seconds include the command's own start-up.",
             "",
             f"Targets: nothing left within {result['targets']['stop_s']:g} s of a stop, a stale start refused within "
             f"{result['targets']['stale_s']:g} s (`lcmesh bench lifecycle`; real `lcmesh demo` process trees).", "",
             "| how the demo was stopped | processes | s until none left | left | ports still open | exit |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for t in result["signals"]:
        lines.append(f"| {t['how']} | {t['processes_before']} | {t['seconds_to_none_left']:.1f} | "
                     f"{len(t['left'])} | {len(t['ports_still_listening'])} | {t['exit_code']} |")  # fmt: skip
    if "orchestrator_kill" in result:
        o = result["orchestrator_kill"]
        lines.append(f"| kill -KILL the orchestrator (its {o['agents_before']} agents) | {o['agents_before']} | "
                     f"{o['seconds_to_none_left']:.1f} | {len(o['left'])} | - | - |")  # fmt: skip
    if "stale" in result:
        s = result["stale"]
        lines += ["", f"A second demo on the same ports: exit {s['exit_code']} after {s['seconds_to_exit']:.1f} s, "
                  f"naming the holder's pid and data dir: {'yes' if s['names_pid_and_data_dir'] else 'no'}."]
    return "\n".join(lines)
