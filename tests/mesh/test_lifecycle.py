"""The mesh starts and stops like a service: real `lcmesh demo` process trees on free loopback ports.

However the demo is stopped (a closed terminal's SIGHUP, Ctrl-C, `lcmesh stop`'s SIGTERM, a SIGKILL
of the demo alone), no process of its data dir is left and its ports are free; a killed orchestrator
takes its agents with it; a second demo on the same ports or data dir is refused with the holder's
pid and data dir, not looped on. The seconds each takes are `lcmesh bench lifecycle`'s figures:
here the limits are liveness limits for a busy machine.
"""

from __future__ import annotations

import signal
import subprocess

import pytest

from lcmesh.bench.lifecycle import (
    LCMESH, ROLES, kill_after_ui_trial, orchestrator_kill_trial, signal_trial, stale_trial, start_demo, stop_everything,
)  # fmt: skip
from lcmesh.mesh.service import mesh_processes, read_run_file


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT, signal.SIGKILL], ids=lambda s: s.name)
def test_a_stopped_demo_leaves_no_process_and_no_port(tmp_path, sig):
    run = start_demo(tmp_path / "mesh", ROLES + ("ui",) if sig == signal.SIGKILL else ROLES)
    try:
        trial = signal_trial(run, sig)
    finally:
        stop_everything(run)
    assert trial["left"] == [] and trial["ports_still_listening"] == [], trial
    if sig != signal.SIGKILL:
        assert trial["exit_code"] == 0 and run.text().rstrip().endswith("stopped"), run.text()
        assert read_run_file(run.data_dir) is None, "a clean stop removes mesh.json"


def test_a_demo_killed_as_soon_as_its_ui_answers_leaves_nothing(tmp_path):
    """The race `lcmesh bench lifecycle --trials N` repeats: SIGKILL while the agents still start (the Sensor in its
    spin-up). Once here; the bench counts what is left after 10 s, this test only that all of it goes."""
    trial = kill_after_ui_trial(tmp_path / "mesh", ROLES + ("sensor", "ui"))
    assert trial["processes_at_kill"] >= 4 and trial["left_after_60_s"] == [], trial


def test_status_stale_start_orchestrator_death_and_stop(tmp_path):
    run = start_demo(tmp_path / "mesh")
    try:
        status = subprocess.run([LCMESH, "status", "--data-dir", str(run.data_dir), "--json", str(tmp_path / "s.json")],
                                capture_output=True, text=True, timeout=60)  # fmt: skip
        assert status.returncode == 0, status.stdout + status.stderr
        assert f"demo pid {run.popen.pid} (running)" in status.stdout and f"router port {run.port}: listening" in \
            status.stdout, status.stdout  # fmt: skip
        assert {"router", "orchestration", "demo", *ROLES} <= {p.role for p in mesh_processes(run.data_dir)}

        stale = stale_trial(run, tmp_path / "second")
        assert stale["exit_code"] == 3 and stale["names_pid_and_data_dir"], stale
        assert "lcmesh stop --data-dir" in stale["message"], stale
        same_dir = subprocess.run([LCMESH, "demo", "--port", "1", "--data-dir", str(run.data_dir)], capture_output=True,
                                  text=True, timeout=120)  # fmt: skip
        said = " ".join((same_dir.stdout + same_dir.stderr).split())
        assert same_dir.returncode == 3 and f"a mesh already runs for {run.data_dir}: demo pid {run.popen.pid}" in said

        orchestrator = orchestrator_kill_trial(run)
        assert orchestrator["agents_before"] == len(ROLES) and orchestrator["left"] == [], orchestrator

        trial = signal_trial(run, signal.SIGTERM)  # through `lcmesh stop`
        assert trial["left"] == [] and trial["ports_still_listening"] == [] and trial["exit_code"] == 0, trial
    finally:
        stop_everything(run)
    after = subprocess.run([LCMESH, "status", "--data-dir", str(run.data_dir)], capture_output=True, text=True,
                           timeout=60)  # fmt: skip
    assert after.returncode == 3 and "not running" in after.stdout, after.stdout


def test_a_port_held_by_another_program_is_named(tmp_path):
    import socket

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        router = subprocess.run([LCMESH, "router", "--listen", f"tcp/127.0.0.1:{port}"], capture_output=True,
                                text=True, timeout=60)  # fmt: skip
    said = " ".join((router.stdout + router.stderr).split())
    assert router.returncode == 3 and f"port {port} (the router) is held by pid" in said and \
        "not an lc-mesh process" in said, said  # fmt: skip


def test_a_stop_that_hangs_still_ends_the_process():
    """A process whose clean stop hangs (here: it sleeps forever after starting its stop) ends anyway, says why, and
    exits with the code asked for: the watchdog the router and every agent arm when they start stopping."""
    import sys

    code = ("import time; from lcmesh.mesh.processes import exit_if_stuck; "
            "exit_if_stuck(0.5, 'hung-agent', 7); time.sleep(3600)")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 7, done.stderr
    assert "hung-agent: the stop took longer than 0.5 s; exiting now" in done.stderr
    # told to stop while it still starts (a connect, a slow start-up), which never looks at the stop event
    code = ("import os, signal, time; from lcmesh.mesh.processes import stop_on_signals; "
            "stop = stop_on_signals(0.5, 'starting-agent', 7); os.kill(os.getpid(), signal.SIGTERM); time.sleep(3600)")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 7, done.stderr
    assert "starting-agent: the stop took longer than 0.5 s; exiting now" in done.stderr


def _gone(pid: int) -> bool:
    import psutil

    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def test_a_process_that_ends_itself_by_force_takes_its_children_with_it(tmp_path):
    """`exit_if_stuck`'s forced exit SIGKILLs the children the process started (an orchestrator's agents), so none is
    left running on its own: here a child that is tied to nothing and would sleep for an hour."""
    import sys

    from tests.mesh.conftest import wait_until

    code = ("import sys, time; from pathlib import Path; from lcmesh.mesh.processes import Child, exit_if_stuck; "
            "c = Child('sleeper', [sys.executable, '-c', 'import time; time.sleep(3600)'], {}, Path(sys.argv[1])); "
            "print(c.start().pid, flush=True); exit_if_stuck(0.5, 'stuck-parent', 7); time.sleep(3600)")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "sleeper.log")], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 7, done.stderr
    child = int(done.stdout.split()[0])
    assert wait_until(lambda: _gone(child), 60), f"child pid {child} outlived its parent's forced exit"


def test_an_orphan_whose_stop_hangs_ends_within_the_orphan_grace(tmp_path):
    """A child tied to its parent (``tie_to_parent``) whose stop hangs: its parent is SIGKILLed, the kernel's SIGTERM
    finds it orphaned, and it ends after ``ORPHAN_STOP_GRACE_S`` instead of its own (here an hour's) grace."""
    import sys

    from tests.mesh.conftest import wait_until

    child_code = ("import time; from lcmesh.mesh.processes import stop_on_signals, tie_to_parent; tie_to_parent(); "
                  "stop = stop_on_signals(3600, 'hung-child', 7); print('ready', flush=True); stop.wait(); "
                  "time.sleep(3600)")  # fmt: skip
    parent_code = ("import sys, time; from pathlib import Path; from lcmesh.mesh.processes import Child; "
                   f"c = Child('hung', [sys.executable, '-c', {child_code!r}], dict(__import__('os').environ), "
                   "Path(sys.argv[1])); print(c.start().pid, flush=True); time.sleep(3600)")  # fmt: skip
    log = tmp_path / "hung.log"
    parent = subprocess.Popen([sys.executable, "-c", parent_code, str(log)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        assert wait_until(lambda: log.exists() and "ready" in log.read_text(), 60), f"child pid {child} never ready"
        parent.kill()
    finally:
        parent.wait(timeout=60)
        parent.stdout.close()
    assert wait_until(lambda: _gone(child), 60), f"orphan pid {child} still runs:\n{log.read_text()}"
    assert "hung-child (its parent is gone): the stop took longer than 5 s" in log.read_text()


def test_an_agent_told_to_stop_while_it_starts_ends_within_the_starting_grace():
    """A SIGTERM while an agent still starts (the Control agent merging its GGUF, say) ends it after
    ``STARTING_STOP_GRACE_S`` (5 s), not after the running agent's 30 s."""
    import sys

    code = ("import threading, time; from lcmesh.mesh.agents.runner import stop_signals; "
            "stop, started = stop_signals('slow-start', threading.Event()); print('starting', flush=True); "
            "time.sleep(3600)")  # a start that never looks at `stop`  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "starting"
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)  # generous on busy cores; the message says which grace ended it
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        err = proc.stderr.read()
        proc.stderr.close()
    assert code == 1 and "slow-start: the stop took longer than 5 s" in err, err
