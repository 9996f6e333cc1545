"""What the UI keeps in memory from the bus, and the hub that streams it to live pages.

Bus callbacks (zenoh threads) write here; HTTP handlers (the uvicorn loop and its thread pool)
read. The latest plant state is kept as its UI view and as ready-made JSON bytes, so
``GET /api/state`` costs one dictionary lookup. The hub hands events to every connected
server-sent-events client through the server's event loop; a slow client loses its oldest
events, never blocks the bus.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections import Counter, OrderedDict, deque
from datetime import datetime
from typing import Any

from lcmesh.mesh.messages import AgentEvent, AgentStats, Alert, AppliedAction, Explanation, MonitorReport, PlantState
from lcmesh.mesh.agents.ui.views import decision_view, state_view
from lcmesh.twin.system import SystemDescription

log = logging.getLogger("lcmesh.mesh.agents.ui")


END = "__end__"
MAX_AGENTS = 64  # agents the table (and /metrics) keeps; the demo runs 7, a scaled-out mesh a few dozen


def dumps(data: Any) -> bytes:
    return json.dumps(data, separators=(",", ":"), default=str).encode()


class HubFull(RuntimeError):
    """Every one of the hub's `max_clients` places is taken."""


class EventHub:
    """Fan-out of (event name, JSON bytes) to at most `max_clients` SSE clients' queues on the server loop."""

    def __init__(self, queue_size: int = 256, max_clients: int = 64):
        self.queue_size, self.max_clients = queue_size, max_clients
        self.loop: asyncio.AbstractEventLoop | None = None
        self._queues: set[asyncio.Queue] = set()
        self.dropped = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    @property
    def clients(self) -> int:
        return len(self._queues)

    def open(self) -> asyncio.Queue:
        """A new client queue (call on the server loop); HubFull when `max_clients` are connected."""
        if len(self._queues) >= self.max_clients:
            raise HubFull(f"{self.max_clients} live clients are connected, the most LCMESH_UI_SSE_MAX_CLIENTS allows")
        queue: asyncio.Queue = asyncio.Queue(self.queue_size)
        self._queues.add(queue)
        return queue

    def close(self, queue: asyncio.Queue) -> None:
        self._queues.discard(queue)

    def publish(self, event: str, data: bytes) -> None:
        """Queue an event for every client (safe from any thread)."""
        loop = self.loop
        if loop is None or not self._queues or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(self._deliver, event, data)
        except RuntimeError:  # the loop closed between the check and the call
            pass

    def end(self) -> None:
        """Tell every client stream to finish (the server is stopping)."""
        self.publish(END, b"")

    def _deliver(self, event: str, data: bytes) -> None:
        for queue in list(self._queues):
            if queue.full():
                queue.get_nowait()
                self.dropped += 1
            queue.put_nowait((event, data))


def _same_run(previous: AppliedAction | None, applied: AppliedAction) -> AppliedAction | None:
    """`previous` if it is the decision before `applied` in the same run (what a change is measured from)."""
    return previous if previous is not None and previous.run_id == applied.run_id else None


class LiveStore:
    """The latest plant state, decisions, explanations, alerts, agents and events seen on the bus."""

    def __init__(self, system: SystemDescription, hub: EventHub, *, keep: int = 500, state_hz: float = 4.0,
                 max_agents: int = MAX_AGENTS):
        self.system, self.hub, self.keep, self.max_agents = system, hub, keep, max_agents
        self._lock = threading.Lock()
        self.state: PlantState | None = None
        self.view: dict | None = None
        self.view_json: bytes | None = None
        self.state_received_at: float | None = None
        self.applied: deque[AppliedAction] = deque(maxlen=keep)
        self.explanations: OrderedDict[str, Explanation] = OrderedDict()
        self.alerts: dict[str, Alert] = {}
        self.monitor: MonitorReport | None = None
        self.events: deque[AgentEvent] = deque(maxlen=200)
        self.agents: dict[str, dict] = {}
        self.decided_by: dict | None = None  # the Control agent's word on who decided (a controller that falls back)
        self.explained_by: dict | None = None  # and on who wrote the explanations (with the LLM explaining)
        self.counts: Counter = Counter()
        self.decisions_by_source: Counter = Counter()
        self.alerts_raised: Counter = Counter()
        self._min_sse_gap_s = 1.0 / state_hz
        self._last_sse_state = 0.0

    # --- plant ------------------------------------------------------------------------------------
    def on_state(self, state: PlantState) -> None:
        try:
            with self._lock:
                latest = self.applied[-1] if self.applied else None
            view = state_view(state, self.system, latest)
            if view.get("controller") is not None and self.decided_by is not None:
                view["controller"]["decided_by"] = self.decided_by
            if view.get("controller") is not None and self.explained_by is not None:
                view["controller"]["explained_by"] = self.explained_by
        except ValueError as exc:
            self.counts["bad_states"] += 1
            log.warning("dropped plant state %s: %s", state.id, exc)
            return
        data = dumps(view)
        with self._lock:
            if self.state is not None and state.run_id == self.state.run_id and state.step < self.state.step:
                self.counts["stale_states"] += 1
                return
            self.state, self.view, self.view_json = state, view, data
            self.state_received_at = time.monotonic()
            self.counts["states"] += 1
        now = time.monotonic()
        if now - self._last_sse_state >= self._min_sse_gap_s:
            self._last_sse_state = now
            self.hub.publish("state", data)

    def state_age_s(self) -> float | None:
        at = self.state_received_at
        return None if at is None else time.monotonic() - at

    def latest_applied(self) -> AppliedAction | None:
        with self._lock:
            return self.applied[-1] if self.applied else None

    # --- decisions -----------------------------------------------------------------------------------
    def on_applied(self, applied: AppliedAction) -> None:
        with self._lock:
            previous = _same_run(self.applied[-1] if self.applied else None, applied)
            self.applied.append(applied)
            self.counts["decisions"] += 1
            self.decisions_by_source[applied.source_controller] += 1
            if applied.fallback:
                self.counts["fallbacks"] += 1
            self.counts["clamps"] += len(applied.clamps)
            explanation = self.explanations.get(applied.decision_id) if applied.decision_id else None
        self.hub.publish("decision", dumps(decision_view(applied, explanation, previous)))

    def on_explanation(self, explanation: Explanation) -> None:
        with self._lock:
            self.explanations[explanation.decision_id] = explanation
            while len(self.explanations) > self.keep:
                self.explanations.popitem(last=False)
            self.counts["explanations"] += 1
        self.hub.publish("explanation", dumps({"decision_id": explanation.decision_id, "step": explanation.step,
                                                "controller": explanation.controller, "level": explanation.level,
                                                "text": explanation.text, "written_by": explanation.written_by,
                                                "why_renderer": explanation.why_renderer,
                                                "llm_part": explanation.llm_part}))  # fmt: skip

    def recent_decisions(self, limit: int) -> list[dict]:
        """The newest `limit` decisions, newest first, each with what it changed from the one before it."""
        with self._lock:
            items = list(self.applied)[-limit - 1:]
            texts = {a.decision_id: self.explanations.get(a.decision_id) for a in items if a.decision_id}
        pairs = list(zip([None, *items[:-1]], items))[-limit:][::-1]
        return [decision_view(a, texts.get(a.decision_id), _same_run(b, a)) for b, a in pairs]

    # --- alerts, monitor, agents, events -----------------------------------------------------------------
    def on_alert(self, alert: Alert) -> None:
        with self._lock:
            self.alerts[alert.alert_id] = alert
            if alert.state == "raised":
                self.alerts_raised[alert.severity] += 1
            if len(self.alerts) > self.keep:  # forget the oldest cleared ones
                for alert_id in [k for k, a in self.alerts.items() if a.state == "cleared"][: len(self.alerts) - self.keep]:
                    del self.alerts[alert_id]
        self.hub.publish("alert", alert.model_dump_json().encode())

    def active_alerts(self) -> list[Alert]:
        with self._lock:
            return [a for a in self.alerts.values() if a.state == "raised"]

    def on_monitor(self, report: MonitorReport) -> None:
        with self._lock:
            self.monitor = report

    def on_event(self, event: AgentEvent) -> None:
        with self._lock:
            self.events.append(event)
        self.hub.publish("event", event.model_dump_json().encode())

    def _agent_entry(self, agent_id: str, role: str) -> dict | None:
        """The table row of `agent_id` (created if there is room; None past ``max_agents``: counted, not kept, so a
        role that makes up agent ids can not grow the table or the metrics' series). Call under the lock."""
        entry = self.agents.get(agent_id)
        if entry is None:
            if len(self.agents) >= self.max_agents:
                self.counts["agents_over_cap"] += 1
                return None
            entry = self.agents[agent_id] = {"agent_id": agent_id, "role": role, "stats": None, "stats_at": None,
                                             "alive": False, "since": None}  # fmt: skip
        return entry

    def on_liveliness(self, role: str, agent_id: str, alive: bool, at: datetime) -> None:
        with self._lock:
            entry = self._agent_entry(agent_id, role)
            if entry is None:
                return
            entry.update(role=role, alive=alive, since=at)
        self.hub.publish("agents", dumps(self.agents_view()))

    def on_stats(self, stats: AgentStats) -> None:
        with self._lock:
            entry = self._agent_entry(stats.agent_id, stats.role)
            if entry is None:
                return
            entry["stats"], entry["stats_at"] = stats, time.monotonic()
            if stats.role == "control":
                self.decided_by = stats.details.get("decided_by")
                self.explained_by = stats.details.get("explained_by")

    def agents_view(self) -> list[dict]:
        """Every agent seen: alive (liveliness token), last stats, and the monitor's advice about it."""
        now = time.monotonic()
        with self._lock:
            entries = [dict(e) for e in self.agents.values()]
            report = self.monitor
        advice: dict[str, list[str]] = {}
        if report is not None:
            for rec in report.recommendations:
                if rec.agent_id:
                    advice.setdefault(rec.agent_id, []).append(f"{rec.severity}: {rec.text}")
        rows = []
        for e in sorted(entries, key=lambda e: (e["role"], e["agent_id"])):
            s: AgentStats | None = e.get("stats")
            rows.append({
                "agent_id": e["agent_id"], "role": e["role"], "alive": bool(e.get("alive")),
                "since": e["since"].isoformat() if e.get("since") else None,
                "pid": s.pid if s else None, "uptime_s": round(s.uptime_s, 1) if s else None,
                "cpu_pct": s.cpu_pct if s else None, "rss_bytes": s.rss_bytes if s else None,
                "msgs_in": sum(s.msgs_in.values()) if s else 0, "msgs_out": sum(s.msgs_out.values()) if s else 0,
                "invalid": sum(s.invalid.values()) if s else 0, "handler_errors": s.handler_errors if s else 0,
                "latency_ms_p99": s.latency_ms_p99 if s else None,
                "stats_age_s": round(now - e["stats_at"], 2) if e.get("stats_at") else None,
                "advice": advice.get(e["agent_id"], []),
            })  # fmt: skip
        return rows

    def snapshot_stats(self) -> list[AgentStats]:
        with self._lock:
            return [e["stats"] for e in self.agents.values() if e.get("stats") is not None]
