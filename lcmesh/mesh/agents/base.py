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
from collections import deque
from collections.abc import Callable
from typing import Any, ClassVar

import psutil

from lcmesh.mesh import keys, security
from lcmesh.mesh.bus import Bus, Declared
from lcmesh.mesh.messages import RECENT_EVENTS, AgentEvent, AgentStats, ConfigDoc, MeshConfig, RecentEvents
from lcmesh.mesh.ratelimit import TokenBuckets
from lcmesh.mesh.security import role_of_agent_id
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
        self._recent_events: deque[AgentEvent] = deque(maxlen=RECENT_EVENTS)
        self.history = None
        self._config_verifier: security.ConfigVerifier | None = None
        # {"stats" or "tokens": how many claimed another identity than their key's}, once the agent follows them
        self.identity_mismatches: dict[str, int] | None = None

    # --- lifecycle ------------------------------------------------------------------------------
    def start(self, bus: Bus) -> None:
        """Declare the liveliness token, then the agent's own subscriptions and threads."""
        self.bus = bus
        bus.on_error = self._on_handler_error
        self._started_at = time.monotonic()
        self._process.cpu_percent(None)
        self.serve(keys.recent_events(self.site, self.role),
                   lambda _payload: RecentEvents(source=self.agent_id, events=list(self._recent_events)))
        self.on_start()
        if self.stopping:  # told to stop during a long start-up (the Sensor's spin-up): no token, no stats
            return
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

    @property
    def stop_event(self) -> threading.Event:
        """Set when the agent is to stop; a signal handler may set it (``runner``), even while it starts."""
        return self._stop

    def on_start(self) -> None:
        """Subclasses declare their subscriptions, queryables and threads here."""

    def on_stop(self) -> None:
        """Subclasses release what they hold (the twin, files) here."""

    def details(self) -> dict:
        """Agent-specific figures for its stats message."""
        return {}

    # --- helpers --------------------------------------------------------------------------------
    def subscribe(self, key: str, model, handler: Callable, *, latest: bool = False, keyed: bool = False) -> None:
        self._declared.append(self.bus.subscribe(key, model, handler, latest=latest, keyed=keyed))

    def serve(self, key: str, handler: Callable, *, limit: TokenBuckets | None = None) -> None:
        self._declared.append(self.bus.serve(key, handler, limit=limit))

    def subscribe_stats(self, handler: Callable[[AgentStats], None]) -> None:
        """Every agent's stats, each from the agent its key names: the router lets role R publish only on
        ``monitor/stats/R*``, so a message whose `agent_id` or `role` disagrees with its key is dropped and counted."""
        self.identity_mismatches = {**(self.identity_mismatches or {}), "stats": 0}

        def check(stats: AgentStats, key: str) -> None:
            agent_id = key.rsplit("/", 1)[-1]
            role = role_of_agent_id(agent_id)
            if stats.agent_id != agent_id or stats.role != role:
                self._mismatch("stats", f"stats on monitor/stats/{agent_id} (sent by the {role} role) claim to be "
                               f"{stats.role} {stats.agent_id!r}")  # fmt: skip
                return
            handler(stats)

        self.subscribe(keys.agent_stats_all(self.site), AgentStats, check, keyed=True)

    def watch_agents(self, on_change: Callable[[str, str, bool], None]) -> None:
        """``on_change(role, agent_id, alive)`` for every agent's liveliness token; the router lets role R declare
        only ``alive/R/*``, and a token whose agent id is not one of R's (``alive/ui/sensor``) is dropped, counted."""
        self.identity_mismatches = {**(self.identity_mismatches or {}), "tokens": 0}

        def check(key: str, alive: bool) -> None:
            parsed = keys.parse_alive(key)
            if parsed is None:
                return
            role, agent_id = parsed
            if role_of_agent_id(agent_id) != role:
                if alive:
                    self._mismatch("tokens", f"liveliness token alive/{role}/{agent_id}: {agent_id!r} is no {role} "
                                   "agent id")  # fmt: skip
                return
            on_change(role, agent_id, alive)

        self._declared.append(self.bus.watch_liveliness(keys.alive_all(self.site), check))

    def _mismatch(self, kind: str, what: str) -> None:
        """Count a message whose claimed identity disagrees with its key; say so at the 1st, 10th, 100th, every 1000th
        of each `kind`."""
        self.identity_mismatches[kind] += 1
        n = self.identity_mismatches[kind]
        if n in (1, 10, 100) or n % 1000 == 0:
            log.warning("dropped %s (%d so far)", what, n)
            self.emit_event("warning", f"dropped {what}: identity is taken from the key ({n} so far)")

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
        """Publish an AgentEvent on this role's ``events/{role}`` (the Sensor records it in history)."""
        if self.bus is None:
            return
        if pid is None and agent_id is None:
            pid = os.getpid()
        event = AgentEvent(source=self.agent_id, kind=kind, role=role or self.role, agent_id=agent_id or self.agent_id,
                           detail=detail[:4000], pid=pid)  # fmt: skip
        self._recent_events.append(event)
        self.bus.publish(keys.events(self.site, self.role), event, block=True)

    def watch_config(self, on_change: Callable[[MeshConfig, MeshConfig], None] | None = None) -> None:
        """Follow ``config/all``: the current version now (if the Configuration agent runs), then every change.

        A document is adopted only with the Configuration agent's valid signature (``_unsigned``).
        """

        def handle(doc: ConfigDoc) -> None:
            if self.config_doc is not None and doc.version <= self.config_doc.version:
                return
            problem = self._unsigned(doc)
            if problem:
                log.warning("ignoring config version %d: %s", doc.version, problem)
                self.emit_event("warning", f"ignored config version {doc.version}: {problem}")
                return
            old, self.config_doc, self.config = self.config, doc, doc.config
            if on_change is not None:
                on_change(old, doc.config)

        self.subscribe(keys.config(self.site, "all"), ConfigDoc, handle, latest=True)

    def _unsigned(self, doc: ConfigDoc) -> str | None:
        """Why `doc` is not the Configuration agent's (no valid signature by its key), or None.

        The router already lets only the configuration role publish ``config/all``; the signature also
        stops a document from anyone who holds that role's password (or writes the history file) but
        not the Configuration agent's private key. The public key is ``SECRETS_DIR/public/config-signing.pub``;
        without it a mesh with bus authentication adopts nothing, one without (bus experiments) adopts all.
        """
        path = security.SecretPaths(self.settings.secrets_path).config_verify_key
        if self._config_verifier is None:
            try:
                self._config_verifier = security.load_config_verifier(self.settings.secrets_path)
            except ValueError as exc:
                return f"the config verify key {path} is not usable: {exc}"
        if self._config_verifier is None:
            if not self.settings.bus_auth:
                return None
            return f"no config verify key at {path} to check its signature with (the router creates it)"
        if not doc.signature:
            return "it is not signed"
        if not self._config_verifier.valid(doc.version, doc.config.model_dump(mode="json"), doc.signature):
            return f"its signature is not the Configuration agent's (checked with {path})"
        return None

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
                               threads=threads, details=self._details_with_checks(), **counters)  # fmt: skip
            self.bus.publish(key, stats)

    def _details_with_checks(self) -> dict:
        details = self.details()
        if self.identity_mismatches is not None:
            details = {**details, "identity_mismatches": dict(self.identity_mismatches)}
        return details
