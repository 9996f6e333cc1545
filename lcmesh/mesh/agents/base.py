"""What every agent shares: lifecycle, liveliness token, stats, events, config watching.

Construction does no I/O; ``start(bus)`` declares the token, subscriptions and threads;
``stop()`` undeclares them. A worker thread that dies of an unexpected exception reports it as
an event and ends the process (crash-only: the Orchestrator restarts it from a clean state).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any, ClassVar

import psutil

from lcmesh.mesh import keys
from lcmesh.mesh.bus import Bus, Declared
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import AgentEvent, AgentStats, ConfigDoc, MeshConfig
from lcmesh.mesh.ratelimit import TokenBuckets
from lcmesh.mesh.settings import MeshSettings

log = logging.getLogger("lcmesh.mesh.agents")


class LatestSlot:
    """A one-item mailbox: `put` replaces, `take` waits for something newer than the last take."""

    def __init__(self):
        self._cond = threading.Condition()
        self._item: Any = None
        self._fresh = False
        self.replaced = 0

    def put(self, item: Any) -> None:
        with self._cond:
            if self._fresh:
                self.replaced += 1
            self._item, self._fresh = item, True
            self._cond.notify_all()

    def take(self, timeout_s: float) -> Any:
        with self._cond:
            if not self._fresh and not self._cond.wait_for(lambda: self._fresh, timeout=timeout_s):
                return None
            self._fresh = False
            return self._item


def default_config(settings: MeshSettings) -> MeshConfig:
    """The configuration agents use until the Configuration agent answers (seeded from settings)."""
    return MeshConfig(controller=settings.controller, speed_factor=settings.speed_factor,
                      valve_exercise_s=settings.valve_exercise_s)


class Agent:
    """Base class of the mesh agents."""

    role: ClassVar[str] = ""

    def __init__(self, settings: MeshSettings, agent_id: str | None = None):
        self.settings = settings
        self.agent_id = keys.segment(agent_id or self.role, "agent id")
        self.site = settings.site
        self.bus: Bus | None = None
        self.config_doc: ConfigDoc | None = None
        self.config = default_config(settings)
        self.failed = threading.Event()
        self._stop = threading.Event()
        self._declared: list[Declared] = []
        self._threads: list[threading.Thread] = []
        self._started_at = time.monotonic()
        self._process = psutil.Process()
        self._last_event_s: dict[str, float] = {}
        self.history = None

    # --- lifecycle ------------------------------------------------------------------------------
    def start(self, bus: Bus) -> None:
        """Declare the liveliness token, then the agent's own subscriptions and threads."""
        self.bus = bus
        bus.on_error = self._on_handler_error
        self._started_at = time.monotonic()
        self._process.cpu_percent(None)
        self.on_start()
        self._declared.append(bus.declare_token(keys.alive(self.site, self.role, self.agent_id)))
        self.spawn("stats", self._stats_loop)
        log.info("%s %s started (pid %d)", self.role, self.agent_id, os.getpid())

    def stop(self) -> None:
        """Undeclare everything and join the threads."""
        self._stop.set()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=5.0)
        for declared in reversed(self._declared):
            declared.undeclare()
        self._declared.clear()
        self.on_stop()
        if self.history is not None:
            self.history.close()
            self.history = None
        log.info("%s %s stopped", self.role, self.agent_id)

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def on_start(self) -> None:
        """Subclasses declare their subscriptions, queryables and threads here."""

    def on_stop(self) -> None:
        """Subclasses release what they hold (the twin, files) here."""

    def details(self) -> dict:
        """Agent-specific figures for its stats message."""
        return {}

    # --- helpers --------------------------------------------------------------------------------
    def subscribe(self, key: str, model, handler: Callable, *, latest: bool = False) -> None:
        self._declared.append(self.bus.subscribe(key, model, handler, latest=latest))

    def serve(self, key: str, handler: Callable, *, limit: TokenBuckets | None = None) -> None:
        self._declared.append(self.bus.serve(key, handler, limit=limit))

    def spawn(self, name: str, target: Callable[[], None]) -> threading.Thread:
        """Run `target` in a thread; an exception escaping it is reported and ends the agent."""

        def run() -> None:
            try:
                target()
            except Exception as exc:
                log.exception("%s thread %s died", self.agent_id, name)
                self.emit_event("exception", f"thread {name} died: {type(exc).__name__}: {exc}\n"
                                + traceback.format_exc(limit=5))  # fmt: skip
                self.failed.set()

        thread = threading.Thread(target=run, name=f"{self.agent_id}-{name}", daemon=True)
        self._threads.append(thread)
        thread.start()
        return thread

    def wait(self, seconds: float) -> bool:
        """Sleep up to `seconds`; True if the agent is stopping."""
        return self._stop.wait(seconds)

    def emit_event(self, kind: str, detail: str = "", *, role: str | None = None, agent_id: str | None = None,
                   pid: int | None = None) -> None:  # fmt: skip
        """Publish an AgentEvent (and write it to history when this agent keeps one)."""
        if self.bus is None:
            return
        if pid is None and agent_id is None:
            pid = os.getpid()
        event = AgentEvent(source=self.agent_id, kind=kind, role=role or self.role, agent_id=agent_id or self.agent_id,
                           detail=detail[:4000], pid=pid)  # fmt: skip
        if self.history is not None:
            try:
                self.history.add_event(event)
            except Exception:
                log.exception("could not write event to history")
        self.bus.publish(keys.events(self.site), event, block=True)

    def watch_config(self, on_change: Callable[[MeshConfig, MeshConfig], None] | None = None) -> None:
        """Follow ``config/all``: the current version now (if the Configuration agent runs), then every change."""

        def handle(doc: ConfigDoc) -> None:
            if self.config_doc is not None and doc.version <= self.config_doc.version:
                return
            problem = self._unaudited(doc)
            if problem:
                log.warning("ignoring config version %d: %s", doc.version, problem)
                self.emit_event("warning", f"ignored config version {doc.version}: {problem}")
                return
            old, self.config_doc, self.config = self.config, doc, doc.config
            if on_change is not None:
                on_change(old, doc.config)

        self.subscribe(keys.config(self.site, "all"), ConfigDoc, handle, latest=True)

    def _unaudited(self, doc: ConfigDoc) -> str | None:
        """Why `doc` is not the Configuration agent's (not in the audited history), or None.

        The router already lets only the Configuration agent publish ``config/all``; this second check
        needs the history file, so an agent on a host without it relies on the router alone.
        """
        path = self.settings.history_file
        if not path.exists():
            return None
        try:
            reader = HistoryReader(path)
            try:
                rows = reader.config_changes(limit=20)
            finally:
                reader.close()
        except Exception as exc:  # an unreadable history must not stop configuration
            log.warning("could not check config version %d against history: %s", doc.version, exc)
            return None
        for row in rows:
            if row["version"] == doc.version:
                if row["config"] == doc.config.model_dump(mode="json"):
                    return None
                return "its content differs from the audited version in history"
        latest = rows[0]["version"] if rows else None
        return f"history has no such version (latest audited: {latest})"

    def _on_handler_error(self, where: str, exc: BaseException) -> None:
        now = time.monotonic()
        if now - self._last_event_s.get(where, -1e9) < 5.0:
            return
        self._last_event_s[where] = now
        self.emit_event("exception", f"{where}: {type(exc).__name__}: {exc}")

    def _stats_loop(self) -> None:
        key = keys.agent_stats(self.site, self.agent_id)
        host = socket.gethostname()
        while not self.wait(self.settings.stats_period_s):
            process = self._process
            with process.oneshot():
                cpu, rss, threads = process.cpu_percent(None), process.memory_info().rss, process.num_threads()
            counters = self.bus.counters.snapshot()
            stats = AgentStats(source=self.agent_id, role=self.role, agent_id=self.agent_id, pid=os.getpid(),
                               host=host, uptime_s=time.monotonic() - self._started_at, cpu_pct=cpu, rss_bytes=rss,
                               threads=threads, details=self.details(), **counters)  # fmt: skip
            self.bus.publish(key, stats)
