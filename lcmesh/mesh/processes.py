"""Child processes of the mesh (router, agents) with their own logs, started and stopped cleanly.

Children run in a new session (their own process group), so Ctrl-C in a terminal reaches the
parent only and the parent stops them in order; ``stop`` sends SIGTERM, waits, then SIGKILLs
the whole group so nothing is left behind. A child also ends when its parent dies however it dies
(SIGKILL included): it calls ``tie_to_parent`` first thing, which asks the kernel for a SIGTERM on
the parent's death (``prctl(PR_SET_PDEATHSIG)``); its own handler then stops it cleanly.
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

PARENT_PID_ENV = "LC_MESH_PARENT_PID"  # each child's parent pid (not LCMESH_: it is no setting)
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


@dataclass
class Child:
    """A started child process and where its output goes."""

    name: str
    argv: list[str]
    env: dict[str, str]
    log_path: Path
    popen: subprocess.Popen | None = None
    started_at: float = field(default=0.0)

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen else None

    def start(self) -> "Child":
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        log = open(self.log_path, "ab", buffering=0)
        try:
            env = {**self.env, PARENT_PID_ENV: str(os.getpid())}
            self.popen = subprocess.Popen(self.argv, env=env, stdout=log, stderr=subprocess.STDOUT,
                                          stdin=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
        finally:
            log.close()
        self.started_at = time.monotonic()
        return self

    def running(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def signal(self, sig: int) -> None:
        if self.running():
            try:
                os.killpg(self.popen.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        """Ask the child to stop (SIGTERM; SIGCONT first, so a stopped child can handle it)."""
        self.signal(signal.SIGCONT)
        self.signal(signal.SIGTERM)

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """SIGTERM, wait up to `timeout_s`, then SIGKILL the group; the exit code."""
        if self.popen is None:
            return None
        if self.running():
            self.terminate()
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            return self.popen.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def log_tail(self, n_lines: int = 20) -> str:
        try:
            lines = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(lines[-n_lines:])


def tie_to_parent(sig: int = signal.SIGTERM) -> bool:
    """Have the kernel send `sig` to this process when the parent that started it as a ``Child`` dies.

    The parent is named by ``LC_MESH_PARENT_PID`` (absent: started by hand or by a service manager, nothing to
    do). If the parent already died before this call, the signal is sent now. Linux only; elsewhere a no-op.
    The kernel ties the signal to the parent *thread* that forked: `Child.start` is only called from threads
    that live as long as their children (the demo's main thread, the orchestrator's supervise thread).
    """
    expected = os.environ.pop(PARENT_PID_ENV, None)
    if not expected or not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return False
    if os.getppid() != int(expected):  # the parent died between our fork and the prctl
        os.kill(os.getpid(), sig)
    return True


def exit_if_stuck(grace_s: float, name: str, code: int = 1) -> threading.Timer:
    """From the moment a process starts stopping: if the clean stop has not ended it within ``grace_s`` (a zenoh
    close that waits on a peer that is dying too, on a machine whose cores are busy), end it anyway
    (``os._exit``, said on stderr). A clean stop is preferred; a process left behind is not accepted."""

    def _exit() -> None:
        sys.stderr.write(f"{name}: the stop took longer than {grace_s:g} s; exiting now\n")
        sys.stderr.flush()
        os._exit(code)

    timer = threading.Timer(grace_s, _exit)
    timer.daemon = True
    timer.start()
    return timer


def stop_on_signals(grace_s: float, name: str, code: int = 1) -> threading.Event:
    """An event set by SIGTERM or SIGINT; the first of them also arms ``exit_if_stuck``, so a process told to stop
    while it still connects or starts (which do not look at the event) ends within ``grace_s`` too."""
    stop = threading.Event()

    def _handler(*_) -> None:
        if not stop.is_set():
            exit_if_stuck(grace_s, name, code)
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, _handler)
    return stop


def child_env(base: dict[str, str] | None = None, **overrides: str) -> dict[str, str]:
    """The current environment (or `base`) with ``LCMESH_*`` overrides; unbuffered Python output."""
    env = dict(os.environ if base is None else base)
    env.update(overrides)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def router_child(env: dict[str, str], log_path: Path, name: str = "router") -> Child:
    return Child(name, [sys.executable, "-m", "lcmesh.mesh.router"], env, log_path)


def agent_child(role: str, agent_id: str, env: dict[str, str], log_path: Path) -> Child:
    return Child(agent_id, [sys.executable, "-m", "lcmesh.mesh.agents", role, "--id", agent_id], env, log_path)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now (the OS's choice)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_port(host: str, port: int, timeout_s: float = 10.0) -> bool:
    """True once something accepts TCP connections on host:port."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((host, port)) == 0:
                return True
        time.sleep(0.05)
    return False


def tcp_host_port(endpoint: str) -> tuple[str, int]:
    """('127.0.0.1', 7447) from 'tcp/127.0.0.1:7447'."""
    address = endpoint.split("/", 1)[1]
    host, _, port = address.rpartition(":")
    return host.strip("[]"), int(port)


def _stat(pid: int) -> tuple[str, int] | None:
    """(state letter, start time in clock ticks after boot) from /proc/PID/stat fields 3 and 22."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return fields[0], int(fields[19])
    except (OSError, ValueError, IndexError):
        return None


def start_ticks(pid: int) -> int | None:
    """The process's start time in clock ticks after boot: with the pid, its identity."""
    stat = _stat(pid)
    return stat[1] if stat else None


def same_process(pid: int, start: int | None) -> bool:
    """Whether `pid` runs now (a zombie counts as gone) and is the process that started at `start` (not a recycled
    pid)."""
    stat = _stat(pid)
    return start is not None and stat is not None and stat[0] != "Z" and stat[1] == start


def read_pidfile(path: Path) -> tuple[int, int | None] | None:
    """(pid, start ticks) from a pid file ``"PID START"``; None if it is missing or garbled."""
    try:
        fields = path.read_text().split()
        return int(fields[0]), int(fields[1]) if len(fields) > 1 else None
    except (OSError, ValueError, IndexError):
        return None
