"""``lcmesh demo``: a router and every agent as processes, on the Frontier day, until stopped.

The demo process starts the router and the Orchestration agent (which starts and supervises the
others), restarts either if it dies, prints agent events as they happen, and on Ctrl-C (or
SIGTERM, SIGHUP from a closed terminal, ``lcmesh stop``, or after ``duration_s``) stops the
orchestrator (which stops its agents), then the router, then anything a killed orchestrator left
behind (its pid files). Should the demo itself be killed, its children end with it (they are tied
to it: ``processes.tie_to_parent``).

Before starting it refuses, with a message naming the process and how to stop it, a data dir whose
mesh still runs and router or UI ports that another process holds; a router that later finds its
port taken ends the demo the same way instead of being restarted in a loop. ``DATA_DIR/mesh.json``
says what runs (``lcmesh status``).

No child inherits a secret from the demo's environment: ``LCMESH_API_TOKEN`` and ``LCMESH_LLM_API_KEY``
move into their roles' folders under ``SECRETS_DIR`` (``security.store_env_secrets``), and each agent
is given its own role's files alone (``processes.agent_env``; docs/mesh.md, Security).
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

from lcmesh.mesh import keys
from lcmesh.mesh.agents.registry import unavailable_reason
from lcmesh.mesh.bus import Bus, BusError
from lcmesh.mesh.history import HistoryWriter
from lcmesh.mesh.messages import AgentEvent, ConfigDoc, ConfigUpdate
from lcmesh.mesh.processes import (
    Child, agent_child, agent_env, child_env, read_pidfile, router_child, same_process, tcp_host_port, wait_for_port,
)  # fmt: skip
from lcmesh.mesh.security import ensure_secrets, private_dir, store_env_secrets
from lcmesh.mesh.service import (
    EXIT_BUSY, busy_reason, new_run_file, port_held_message, remove_run_file, write_run_file,
)  # fmt: skip
from lcmesh.mesh.settings import MeshSettings

log = logging.getLogger("lcmesh.mesh.demo")
ORCHESTRATOR_GRACE_S = 5.0  # token gone this long with the router reachable: the orchestrator is hung
ROUTER_CANNOT_LISTEN = 3  # lcmesh.mesh.router's exit code when its endpoint can not be opened


class MeshBusy(RuntimeError):
    """The data dir or a port is held by another process; the message names it and how to stop it."""


class Demo:
    """The demo's processes and their supervision (also used by tests and the benchmark)."""

    def __init__(self, settings: MeshSettings, say: Callable[[str], None] = print):
        self.settings, self.say = settings, say
        self.env = child_env(None, **settings.to_env())  # no secret: each child gets its own role's files
        self.router: Child | None = None
        self.orchestrator: Child | None = None
        self.bus: Bus | None = None
        self.restarts = {"router": 0, "orchestration": 0}
        self._orchestrator_lost_at: float | None = None
        self._link_up_since: float | None = None

    def ports(self) -> dict[int, str]:
        """The TCP ports this mesh listens on: {port: what}."""
        s = self.settings
        ports = {}
        for endpoint in s.listen_endpoints:
            if endpoint.startswith("tcp/"):
                ports[tcp_host_port(endpoint)[1]] = "the router"
        if "ui" in s.orchestration.roles and unavailable_reason("ui") is None:
            ports[s.ui_port] = "the UI"
        return ports

    def check_free(self) -> None:
        """MeshBusy if this data dir's mesh still runs or another process holds one of the ports."""
        reason = busy_reason(self.settings.data_dir, self.ports())
        if reason is not None:
            raise MeshBusy(reason)

    def start(self) -> None:
        s = self.settings
        private_dir(s.data_dir)  # history, config, logs and secrets: the run's owner only
        s.log_dir.mkdir(parents=True, exist_ok=True)
        if s.bus_auth:  # before any process needs them; the router would create them too
            ensure_secrets(s.secrets_path)
        # the API token and the LLM key, from this process's environment or one a caller set: into their roles' folders
        store_env_secrets(s.secrets_path, {**os.environ, **self.env})
        self.router = router_child(child_env(self.env, "router"), s.log_dir / "router.log").start()
        host, port = tcp_host_port(s.listen_endpoints[0])
        if not wait_for_port(host, port, timeout_s=15.0):
            tail = self.router.log_tail()
            self.stop()
            raise BusError(f"the router did not open {s.listen_endpoints[0]}:\n{tail}")
        env = agent_env(self.env, "orchestration", s.secrets_path)  # no secret but its own password file
        self.orchestrator = agent_child("orchestration", "orchestration", env, s.log_dir / "orchestration.log")
        self.orchestrator.start()
        self._write_run_file()
        try:
            self.bus = Bus.connect(s, "demo", timeout_s=10.0)
            self.bus.subscribe(keys.events(s.site), AgentEvent, self._on_event)
            self.bus.watch_liveliness(keys.alive(s.site, "orchestration", "orchestration"), self._on_orchestrator)
        except BusError as exc:
            self.say(f"note: not following agent events ({exc})")

    def _on_orchestrator(self, _key: str, alive: bool) -> None:
        # dead or hung (a stopped process keeps running but loses its session after the lease), or the router went
        self._orchestrator_lost_at = None if alive else time.monotonic()

    def _on_event(self, event: AgentEvent) -> None:
        first_line = event.detail.splitlines()[0] if event.detail else ""
        self.say(f"[{event.sent_at:%H:%M:%S}] {event.agent_id}: {event.kind} {first_line}")

    def configure(self, changes: dict, stop: threading.Event, timeout_s: float = 60.0) -> None:
        """Apply `changes` through the Configuration agent (retried until it answers)."""
        key = keys.configure(self.settings.site, self.bus.role if self.bus is not None else "operator", "all")
        update = ConfigUpdate(changes=changes, by="lcmesh demo", reason="command-line options")
        deadline = time.monotonic() + timeout_s
        while self.bus is not None and not stop.is_set():
            try:
                doc = self.bus.request(key, ConfigDoc, update, timeout_s=2.0)
            except BusError as exc:
                if "nobody serves it" not in str(exc) or time.monotonic() > deadline:
                    self.say(f"could not apply {changes}: {exc}")
                    return
                self.watch()
                stop.wait(0.2)
                continue
            self.say(f"configuration version {doc.version}: {', '.join(f'{k} = {v}' for k, v in changes.items())}")
            return

    def watch(self) -> None:
        """Restart the router or the orchestrator if either died or hung (call periodically)."""
        lost_at = self._orchestrator_lost_at
        if lost_at is not None and self._orchestrator_hung(lost_at):
            self._orchestrator_lost_at = None
            if self.orchestrator is not None and self.orchestrator.running():
                self.say("the orchestrator lost its session (hung?); killing it")
                self.orchestrator.signal(signal.SIGKILL)
                self.orchestrator.popen.wait(timeout=5)
        for name in ("router", "orchestrator"):
            child = getattr(self, name)
            if child is not None and not child.running():
                code = child.popen.returncode
                if name == "router" and code == ROUTER_CANNOT_LISTEN:
                    port = tcp_host_port(self.settings.listen_endpoints[0])[1]
                    held = port_held_message(port, "the router")
                    raise MeshBusy(held or f"the router can not listen on {self.settings.listen_endpoints[0]}:\n"
                                   f"{child.log_tail(8)}")  # fmt: skip
                self.say(f"{name} exited with code {code}; restarting\n{child.log_tail(8)}")
                child.start()
                self.restarts["router" if name == "router" else "orchestration"] += 1
                self._write_run_file()

    def _write_run_file(self) -> None:
        s = self.settings
        ui = f"http://{s.ui_host}:{s.ui_port}" if s.ui_port in self.ports() else None
        write_run_file(s.data_dir, new_run_file(
            s.data_dir, router_endpoint=s.listen_endpoints[0], ui_url=ui, system=s.system, trace=s.trace,
            controller=s.controller, router_pid=self.router.pid if self.router else None,
            orchestrator_pid=self.orchestrator.pid if self.orchestrator else None))  # fmt: skip

    def _orchestrator_hung(self, lost_at: float) -> bool:
        """Its token has been gone for ORCHESTRATOR_GRACE_S while our own link to the router was up all along.

        A dead or restarted router takes every token with it; the orchestrator reconnects by itself then.
        """
        now = time.monotonic()
        if self.bus is None or not self.bus.connected() or (self.router is not None and not self.router.running()):
            self._link_up_since = None
            return False
        if self._link_up_since is None:
            self._link_up_since = now
        return now - max(lost_at, self._link_up_since) > ORCHESTRATOR_GRACE_S

    def stop(self) -> None:
        """Orchestrator (and its agents), then the router, then leftovers from pid files."""
        timeout = self.settings.orchestration.stop_timeout_s
        if self.orchestrator is not None:
            self.orchestrator.stop(timeout_s=timeout * 3)
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        for pid in _leftover_pids(self.settings.data_dir / "pids"):
            self.say(f"stopping leftover agent pid {pid}")
            _kill(pid)
        if self.router is not None:
            self.router.stop(timeout_s=timeout)
        remove_run_file(self.settings.data_dir, os.getpid())


def prepare_llm(say) -> None:
    """Write the LLM runtime's files into the model cache before the agents start (a first run: about half a minute),
    so the planner answers from its first question instead of falling back while it converts its adapter."""
    try:
        from lcmesh.llm.gguf_lora import PACKAGED, resolve_folder, runtime_files
        from lcmesh.llm.llama_backend import llama_available

        if not llama_available():
            say("note: llama-cpp-python is not installed (make setup builds it); the LLM runs on transformers")
            return
        for kind in PACKAGED:
            if resolve_folder("default", kind) is not None:
                runtime_files("default", kind)
    except Exception as exc:  # the agents report what fails on their own; the demo still starts
        say(f"note: preparing the LLM runtime files failed ({type(exc).__name__}: {exc})")


def run_demo(settings: MeshSettings, *, duration_s: float = 0.0, config_changes: dict | None = None,
             resume: bool = False, say: Callable[[str], None] = print) -> int:  # fmt: skip
    """Run until Ctrl-C/SIGTERM/SIGHUP (or `duration_s` > 0 seconds); 0 on a clean stop, 3 if busy.

    A new run of the plant starts unless `resume` (then the Sensor continues the last unfinished
    run of the same system and trace from its checkpoint).

    `config_changes` (e.g. a speed factor given on the command line) are sent to the Configuration
    agent once it answers, as an audited change: a persisted configuration from an earlier run would
    otherwise win over the settings that only seed its first version.
    """
    stop = threading.Event()
    # a closed terminal or dropped SSH session sends SIGHUP: the same clean stop as Ctrl-C
    stop_signals = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in stop_signals}
    # one absolute data dir for every child and for `lcmesh status` (a relative one depends on each one's cwd)
    settings = settings.model_copy(update={"data_dir": settings.data_dir.resolve()})
    demo = Demo(settings, say)
    busy = None
    try:
        demo.check_free()  # before touching the history another mesh may be writing
        if not resume and settings.history_file.exists():
            writer = HistoryWriter(settings.history_file)
            if writer.end_open_runs():
                say("starting a new run (--resume continues the last one)")
            writer.close()
        prepare_llm(say)
        demo.start()
        ui = unavailable_reason("ui")
        with_ui = ui is None and "ui" in settings.orchestration.roles
        where = f"UI on http://{settings.ui_host}:{settings.ui_port}"
        if not with_ui:
            where = f"no UI ({ui or 'not in the roles'})"
        say(f"lc-mesh demo: {settings.system} on {settings.trace} at {settings.speed_factor:g}x, controller "
            f"{settings.controller}; router {settings.listen_endpoints[0]}; {where}; history {settings.history_file}; "
            f"logs {settings.log_dir}. Ctrl-C stops.")  # fmt: skip
        if config_changes:
            demo.configure(config_changes, stop)
        deadline = time.monotonic() + duration_s if duration_s > 0 else None
        while not stop.wait(0.2):
            demo.watch()
            if deadline is not None and time.monotonic() > deadline:
                break
    except MeshBusy as exc:
        busy = str(exc)
    finally:
        if busy is None or demo.router is not None:
            say("stopping the mesh ...")
            demo.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if busy is not None:
        say(f"lcmesh demo can not run: {busy}")
        return EXIT_BUSY
    say("stopped")
    return 0


def _leftover_pids(folder: Path) -> list[int]:
    """Agents a killed orchestrator started: each pid file's process, if it is still that very process."""
    pids = []
    for path in folder.glob("*.pid") if folder.exists() else []:
        found = read_pidfile(path)
        if found is not None and same_process(*found) and _is_agent(found[0]):
            pids.append(found[0])
        path.unlink(missing_ok=True)
    return pids


def _is_agent(pid: int) -> bool:
    try:
        return b"lcmesh.mesh.agents" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def _kill(pid: int) -> None:
    for sig in (signal.SIGCONT, signal.SIGTERM):
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            return
    deadline = time.monotonic() + 5.0
    while _is_agent(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
