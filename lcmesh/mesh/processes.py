"""Child processes of the mesh (router, agents) with their own logs, started and stopped cleanly.

Children run in a new session (their own process group), so Ctrl-C in a terminal reaches the
parent only and the parent stops them in order; ``stop`` sends SIGTERM, waits, then SIGKILLs
the whole group so nothing is left behind. A child also ends when its parent dies however it dies
(SIGKILL included): it calls ``tie_to_parent`` first thing, which asks the kernel for a SIGTERM on
the parent's death (``prctl(PR_SET_PDEATHSIG)``); its own handler then stops it cleanly, within
``ORPHAN_STOP_GRACE_S`` (nobody is left to wait for it). A process that ends itself by force
(``exit_if_stuck``) SIGKILLs the children it started first, so none outlives it.
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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from lcmesh.mesh.security import LLM_KEY_ROLES, SecretPaths

PARENT_PID_ENV = "LC_MESH_PARENT_PID"  # each child's parent pid (not LCMESH_: it is no setting)
_PR_SET_PDEATHSIG = 1  # linux/prctl.h
# a process whose parent died stops within this, clean or not: with the orchestrator's agents (killed when it ends by
# force), a killed demo's tree is gone within about this, well inside `lcmesh bench lifecycle`'s 10 s
ORPHAN_STOP_GRACE_S = 5.0
_tied_parent: int | None = None  # the pid `tie_to_parent` tied this process to
_started: list["Child"] = []  # the children this process started (and may still have to kill)


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
        _started[:] = [c for c in _started if c is not self and c.popen is not None and c.popen.returncode is None]
        _started.append(self)
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

    def kill_now(self) -> None:
        """SIGKILL the child's group without waiting or reaping (safe from a timer thread: no pid is recycled
        before the child is reaped, and only a wait reaps it)."""
        if self.popen is not None and self.popen.returncode is None:
            try:
                os.killpg(self.popen.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    def log_tail(self, n_lines: int = 20) -> str:
        return log_tail(self.log_path, n_lines)


def log_tail(path: Path, n_lines: int = 20) -> str:
    """The last `n_lines` of a log file ("" if it can not be read)."""
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    return "\n".join(lines[-n_lines:])


def stop_children(children: list[Child], timeout_s: float) -> None:
    """Stop `children` together: all asked at once (SIGTERM), all given the same `timeout_s`, the rest SIGKILLed.

    One deadline for all, not one each: stopped in turn, two slow children would take twice the time.
    """
    for child in children:
        child.terminate()
    deadline = time.monotonic() + timeout_s
    for child in children:
        if child.popen is not None:
            try:
                child.popen.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
    for child in children:
        child.stop(timeout_s=2.0)  # SIGKILLs the group of one still running (and any grandchild left in it)


def orphaned() -> bool:
    """Whether the parent `tie_to_parent` tied this process to has died (the kernel reparented it)."""
    return _tied_parent is not None and os.getppid() != _tied_parent


def tie_to_parent(sig: int = signal.SIGTERM) -> bool:
    """Have the kernel send `sig` to this process when the parent that started it as a ``Child`` dies.

    The parent is named by ``LC_MESH_PARENT_PID`` (absent: started by hand or by a service manager, nothing to
    do). If the parent already died before this call, the signal is sent now. Linux only; elsewhere a no-op.
    The kernel ties the signal to the parent *thread* that forked: `Child.start` is only called from threads
    that live as long as their children (the demo's main thread, the orchestrator's supervise thread).
    """
    global _tied_parent
    expected = os.environ.pop(PARENT_PID_ENV, None)
    if not expected or not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return False
    _tied_parent = int(expected)
    if orphaned():  # the parent died between our fork and the prctl: no signal will come, send it now
        os.kill(os.getpid(), sig)
    return True


def exit_if_stuck(grace_s: float, name: str, code: int = 1) -> threading.Timer:
    """From the moment a process starts stopping: if the clean stop has not ended it within ``grace_s`` (a zenoh
    close that waits on a peer that is dying too, on a machine whose cores are busy), end it anyway
    (``os._exit``, said on stderr). A clean stop is preferred; a process left behind is not accepted."""

    def _exit() -> None:
        sys.stderr.write(f"{name}: the stop took longer than {grace_s:g} s; exiting now\n")
        sys.stderr.flush()
        for child in _started:  # not left behind by our forced exit
            child.kill_now()
        os._exit(code)

    timer = threading.Timer(grace_s, _exit)
    timer.daemon = True
    timer.start()
    return timer


def stop_on_signals(grace_s: float | Callable[[], float], name: str, code: int = 1,
                    event: threading.Event | None = None) -> threading.Event:  # fmt: skip
    """`event` (or a new one) set by SIGTERM or SIGINT; the first of them also arms ``exit_if_stuck``, so a process
    told to stop while it still connects or starts ends within ``grace_s`` too (a callable: read when the signal
    comes, e.g. shorter while the process starts). A signal that finds the parent gone (``tie_to_parent``'s
    SIGTERM, first or after an earlier one) arms it again with ``ORPHAN_STOP_GRACE_S``."""
    stop = event if event is not None else threading.Event()
    armed: list[float] = []  # the graces armed so far

    def _handler(*_) -> None:
        full = grace_s() if callable(grace_s) else grace_s
        grace = min(full, ORPHAN_STOP_GRACE_S) if orphaned() else full
        if not armed or grace < min(armed):
            armed.append(grace)
            exit_if_stuck(grace, f"{name} (its parent is gone)" if grace < full else name, code)
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, _handler)
    return stop


# secret variables and the roles whose processes may inherit them; every other child gets none of them
SECRET_VARIABLES: dict[str, tuple[str, ...]] = {
    "LCMESH_BUS_PASSWORD": (),  # one process's own; a child reads its role's file (LCMESH_BUS_PASSWORD_FILE)
    "LCMESH_BUS_PASSWORD_FILE": (),  # set for each child by agent_env
    "LCMESH_API_TOKEN": ("ui",),
    "LCMESH_API_TOKEN_FILE": ("ui",),
    "LCMESH_LLM_API_KEY": LLM_KEY_ROLES,
}


def child_env(base: dict[str, str] | None = None, role: str | None = None, **overrides: str) -> dict[str, str]:
    """The current environment (or `base`) with ``LCMESH_*`` overrides, less every secret variable `role` does
    not need (``SECRET_VARIABLES``; no role: all of them); unbuffered Python output."""
    env = dict(os.environ if base is None else base)
    env.update(overrides)
    for name, roles in SECRET_VARIABLES.items():
        if role not in roles:
            env.pop(name, None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def agent_env(base: dict[str, str], role: str, secrets_dir: Path | None) -> dict[str, str]:
    """An agent child's environment: `base` less the secrets its role does not need, plus its own role's files.

    Its bus password comes from ``SECRETS_DIR/{role}/bus.password`` (``LCMESH_BUS_PASSWORD_FILE``), the UI's
    API token and the LLM key from what ``security.store_env_secrets`` put in the role's folder. No
    `secrets_dir` (bus authentication off): the environment alone, stripped.
    """
    env = child_env(base, role)
    if secrets_dir is None:
        return env
    paths = SecretPaths(secrets_dir)
    env["LCMESH_BUS_PASSWORD_FILE"] = str(paths.password(role))
    if role == "ui" and not {"LCMESH_API_TOKEN", "LCMESH_API_TOKEN_FILE"} & env.keys() and paths.api_token.exists():
        env["LCMESH_API_TOKEN_FILE"] = str(paths.api_token)
    if role in LLM_KEY_ROLES and "LCMESH_LLM_API_KEY" not in env:
        try:
            env["LCMESH_LLM_API_KEY"] = paths.llm_api_key(role).read_text().strip()
        except FileNotFoundError:
            pass
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
