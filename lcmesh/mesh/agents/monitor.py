"""The Agent Monitor: liveliness, message rates, processing latency, CPU and memory of every agent.

It watches the liveliness tokens (``alive/*/*``), each agent's stats (``monitor/stats/*``) and the
applied actions (fallback steps), and publishes a ``MonitorReport`` with recommendations on
``monitor/report`` every ``report_period_s`` (GETs on that key answer the latest report). Who sent
a token or stats is read from its key, never from the message (``Agent.subscribe_stats``).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from datetime import datetime

from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent
from lcmesh.mesh.messages import AgentHealth, AgentStats, AppliedAction, MonitorReport, Recommendation, utc_now

FALLBACK_WINDOW_S = 60.0


def recommend(agents: list[AgentHealth], fallback_steps: int, period_s: float | None, cfg,
              busy_with: dict[str, list[str]] | None = None) -> list[Recommendation]:  # fmt: skip
    """Plain-language advice from the agents' health and the recent fallback steps. ``busy_with``: what an agent
    says keeps it busy (its stats' ``details["busy_with"]``), named beside a high CPU share."""
    recs: list[Recommendation] = []
    busy_with = busy_with or {}

    def add(severity: str, agent_id: str | None, text: str) -> None:
        recs.append(Recommendation(severity=severity, agent_id=agent_id, text=text))

    for a in agents:
        who = a.agent_id
        if not a.alive:
            add("critical", who, f"{who} ({a.role}) is down; the Orchestrator restarts it, check its log if it "
                "keeps dying")  # fmt: skip
            continue
        if a.stats_age_s is not None and a.stats_age_s > cfg.stale_after_s:
            add("warning", who, f"{who} is alive but silent for {a.stats_age_s:.1f} s: possibly hung")
        if a.latency_ms_p99 is not None and period_s and a.latency_ms_p99 > 0.5e3 * period_s:
            add("warning", who, f"{who} needs {a.latency_ms_p99:.1f} ms (p99) per message, over half the "
                f"{period_s * 1e3:.0f} ms control period: lower the speed factor or choose a faster controller")
        if a.cpu_pct is not None and a.cpu_pct > cfg.cpu_high_pct:
            why = "; ".join(busy_with.get(who) or [])
            add("warning", who, f"{who} uses {a.cpu_pct:.0f} % CPU{f' ({why})' if why else ''}; give it its own core "
                "or host")  # fmt: skip
        if a.rss_bytes is not None and a.rss_bytes > cfg.rss_high_bytes:
            add("warning", who, f"{who} holds {a.rss_bytes / 2**20:.0f} MiB of memory")
        if a.invalid_total:
            add("info", who, f"{who} dropped {a.invalid_total} invalid message(s); check what publishes on its keys")
        if a.handler_errors:
            add("warning", who, f"{who} had {a.handler_errors} handler error(s); see its log")
    if fallback_steps:
        add("warning", None, f"{fallback_steps} step(s) in the last minute ran on a fallback (hold or G36): "
            "proposals are late or rejected")  # fmt: skip
    return recs


def _said_busy_with(stats: AgentStats) -> list[str]:
    """An agent's ``details["busy_with"]``: a list of short strings, anything else ignored."""
    said = stats.details.get("busy_with")
    return [x[:200] for x in said if isinstance(x, str)][:4] if isinstance(said, list) else []


class MonitorAgent(Agent):
    role = "monitor"

    def __init__(self, settings, agent_id: str | None = None):
        super().__init__(settings, agent_id)
        self.cfg = settings.monitor
        self._lock = threading.Lock()
        self._alive: dict[str, tuple[str, bool, datetime]] = {}
        self._stats: dict[str, tuple[float, AgentStats]] = {}
        self._rates: dict[str, tuple[float, float]] = {}
        self._fallbacks: deque[float] = deque()
        self._period_s: float | None = None
        self.last_report: MonitorReport | None = None

    def on_start(self) -> None:
        self.watch_agents(self._on_liveliness)
        self.subscribe_stats(self._on_stats)
        self.subscribe(keys.applied_all(self.site), AppliedAction, self._on_applied)
        self.spawn("report", self._loop)

    def _on_liveliness(self, role: str, agent_id: str, alive: bool) -> None:
        with self._lock:
            self._alive[agent_id] = (role, alive, utc_now())

    def _on_stats(self, stats: AgentStats) -> None:
        now = time.monotonic()
        with self._lock:
            previous = self._stats.get(stats.agent_id)
            if previous is not None and now > previous[0]:
                dt = now - previous[0]
                rate_in = (sum(stats.msgs_in.values()) - sum(previous[1].msgs_in.values())) / dt
                rate_out = (sum(stats.msgs_out.values()) - sum(previous[1].msgs_out.values())) / dt
                self._rates[stats.agent_id] = (max(rate_in, 0.0), max(rate_out, 0.0))
            self._stats[stats.agent_id] = (now, stats)

    def _on_applied(self, applied: AppliedAction) -> None:
        now = time.monotonic()
        with self._lock:
            if applied.fallback:
                self._fallbacks.append(now)
            while self._fallbacks and self._fallbacks[0] < now - FALLBACK_WINDOW_S:
                self._fallbacks.popleft()

    def report(self) -> MonitorReport:
        """The current report (what the loop publishes)."""
        now = time.monotonic()
        with self._lock:
            agents = []
            for agent_id in sorted(set(self._alive) | set(self._stats)):
                role, alive, since = self._alive.get(agent_id, (None, False, None))
                seen, stats = self._stats.get(agent_id, (None, None))
                rate_in, rate_out = self._rates.get(agent_id, (0.0, 0.0))
                agents.append(AgentHealth(
                    agent_id=agent_id, role=role or (stats.role if stats else "?"), alive=alive, since=since,
                    pid=stats.pid if stats else None, msgs_in_per_s=rate_in, msgs_out_per_s=rate_out,
                    invalid_total=sum(stats.invalid.values()) if stats else 0,
                    handler_errors=stats.handler_errors if stats else 0,
                    latency_ms_p50=stats.latency_ms_p50 if stats else None,
                    latency_ms_p99=stats.latency_ms_p99 if stats else None,
                    cpu_pct=stats.cpu_pct if stats else None, rss_bytes=stats.rss_bytes if stats else None,
                    stats_age_s=(now - seen) if seen is not None else None,
                ))  # fmt: skip
            while self._fallbacks and self._fallbacks[0] < now - FALLBACK_WINDOW_S:
                self._fallbacks.popleft()
            fallbacks = len(self._fallbacks)
            sensor = next((s for _, s in self._stats.values() if s.role == "sensor"), None)
            busy_with = {a: _said_busy_with(s) for a, (_, s) in self._stats.items()}
        period = sensor.details.get("period_s") if sensor is not None else None
        return MonitorReport(source=self.agent_id, agents=agents, fallback_steps_last_minute=fallbacks,
                             recommendations=recommend(agents, fallbacks, period, self.cfg, busy_with))  # fmt: skip

    def _loop(self) -> None:
        key = keys.monitor_report(self.site)
        while not self.wait(self.cfg.report_period_s):
            self.last_report = self.report()
            self.bus.publish(key, self.last_report, latest=True)
