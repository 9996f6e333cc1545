"""``/metrics`` for Prometheus: plant gauges from the latest state, mesh counters, agents, API latency.

Names follow Prometheus conventions and pass ``promtool check metrics``: base units in the name
(``_celsius``, ``_watts``, ``_pascals``, ``_grams_per_second`` (the base unit of mass is the gram),
``_ratio``, ``_seconds``, ``_bytes``), counters end in ``_total``; labels ``cdu``, ``cabinet``,
``branch``, ``blade_group``, ``tower``, ``agent``, ``role``, ``source``, ``severity``, ``intent``. One CDU serves each cabinet in the twin, so ``cdu`` equals
``cabinet``; numbers count from 1. Plant gauges are computed at scrape time from the state the UI
holds, so a scrape costs nothing between scrapes. Counters count from the UI agent's start.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
from prometheus_client import CollectorRegistry, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from lcmesh.mesh.agents.ui.live import EventHub, LiveStore
from lcmesh.mesh.messages import plant_state_to_observation
from lcmesh.twin.system import SystemDescription

K0 = 273.15
P = "lcmesh_"


def _celsius(kelvin: float) -> float:
    return kelvin - K0


def _grams(kilograms: float) -> float:
    return kilograms * 1e3


def _same(value: float) -> float:
    return value


# (metric suffix, output block, SI -> the metric's unit, help), per cabinet
CDU_GAUGES = (
    ("cdu_supply_temperature_celsius", "supply_temp_k", _celsius, "CDU secondary supply temperature"),
    ("cdu_supply_setpoint_celsius", "applied_supply_setpoint_k", _celsius, "CDU supply temperature setpoint in force"),
    ("cdu_return_temperature_celsius", "return_temp_k", _celsius, "CDU secondary return temperature"),
    ("cdu_secondary_flow_grams_per_second", "secondary_flow_kg_s", _grams, "CDU secondary coolant flow"),
    ("cdu_differential_pressure_pascals", "cabinet_dp_pa", _same, "cabinet differential pressure"),
    ("cdu_differential_pressure_setpoint_pascals", "applied_dp_setpoint_pa", _same, "dp setpoint in force"),
    ("cdu_pump_power_watts", "cdu_pump_power_w", _same, "CDU pump electrical power"),
    ("cdu_heat_watts", "cdu_heat_w", _same, "heat removed by the CDU"),
)  # fmt: skip
TOWER_GAUGES = (
    ("tower_leaving_water_temperature_celsius", "ct_leaving_temp_k", _celsius, "cooling-tower leaving water temp"),
    ("tower_leaving_water_setpoint_celsius", "applied_lw_setpoint_k", _celsius, "leaving-water setpoint in force"),
    ("tower_approach_celsius", "approach_k", _same, "leaving water minus wet bulb"),
    ("tower_fan_speed_ratio", "fan_speed", _same, "fan speed as a fraction of nominal"),
    ("tower_cells_active", "cells_active", _same, "cells running"),
    ("tower_pump_power_watts", "ct_pump_power_w", _same, "tower pump electrical power"),
)  # fmt: skip
PLANT_GAUGES = (
    ("it_power_watts", "it_power_w", "IT power of all blade groups"),
    ("it_cooling_watts", "it_cooling_w", "heat removed at the CDUs"),
    ("cooling_tower_fan_power_watts", "ct_fan_power_w", "fan power of all cooling-tower cells"),
    ("pump_power_watts", "pump_power_w", "pump power of the plant (CDU, tower and hot-water pumps)"),
    ("heat_rejected_watts", "heat_rejected_w", "heat rejected by the towers"),
)  # fmt: skip


class UiCollector(Collector):
    """Reads the live store at each scrape."""

    def __init__(self, store: LiveStore, hub: EventHub, system: SystemDescription, chat=None):
        self.store, self.hub, self.system, self.chat = store, hub, system, chat

    def collect(self) -> Iterator:
        yield from self._plant()
        yield from self._mesh()
        yield from self._agents()
        yield from self._ui()

    def _plant(self) -> Iterator:
        state = self.store.state
        if state is None:
            return
        try:
            out = plant_state_to_observation(state, self.system).out
        except ValueError:
            return
        C, B = self.system.cabinets.count, self.system.cabinets.branches
        per = self.system.n_blade_groups // C
        blade = GaugeMetricFamily(P + "blade_temperature_celsius", "blade group temperature",
                                  labels=["cdu", "cabinet", "blade_group"])  # fmt: skip
        temps = np.asarray(out["blade_temp_k"]).reshape(C, per) - K0
        branch_t = GaugeMetricFamily(P + "branch_temperature_celsius", "branch temperature",
                                     labels=["cdu", "cabinet", "branch"])  # fmt: skip
        valve = GaugeMetricFamily(P + "valve_fraction_ratio", "branch valve fraction in force",
                                  labels=["cdu", "cabinet", "branch"])  # fmt: skip
        for i in range(C):
            cab = str(i + 1)
            for k in range(per):
                blade.add_metric([cab, cab, str(k + 1)], float(temps[i, k]))
            for j in range(B):
                branch_t.add_metric([cab, cab, str(j + 1)], float(out["branch_temp_k"][i, j]) - K0)
                valve.add_metric([cab, cab, str(j + 1)], float(out["applied_valve_fraction"][i, j]))
        yield from (blade, branch_t, valve)
        for suffix, block, convert, help_text in CDU_GAUGES:
            g = GaugeMetricFamily(P + suffix, help_text, labels=["cdu", "cabinet"])
            for i, v in enumerate(np.asarray(out[block], dtype=float).ravel()):
                g.add_metric([str(i + 1), str(i + 1)], convert(float(v)))
            yield g
        fans = np.asarray(out["cell_fan_power_w"], dtype=float)
        g = GaugeMetricFamily(P + "tower_fan_power_watts", "fan power of one tower", labels=["tower"])
        for t in range(fans.shape[0]):
            g.add_metric([str(t + 1)], float(fans[t].sum()))
        yield g
        for suffix, block, convert, help_text in TOWER_GAUGES:
            g = GaugeMetricFamily(P + suffix, help_text, labels=["tower"])
            for t, v in enumerate(np.asarray(out[block], dtype=float).ravel()):
                g.add_metric([str(t + 1)], convert(float(v)))
            yield g
        for suffix, block, help_text in PLANT_GAUGES:
            yield GaugeMetricFamily(P + suffix, help_text, value=float(np.asarray(out[block]).sum()))
        all_t = np.asarray(out["blade_temp_k"], dtype=float) - K0
        yield GaugeMetricFamily(P + "blade_in_band_ratio", "share of blade groups inside 20-40 °C",
                                value=float(np.mean((all_t > 20.0) & (all_t < 40.0))))  # fmt: skip
        yield GaugeMetricFamily(P + "wet_bulb_temperature_celsius", "outside wet bulb", value=state.wet_bulb_k - K0)
        yield GaugeMetricFamily(P + "plant_step", "plant step of the latest state", value=state.step)
        yield GaugeMetricFamily(P + "plant_time_seconds", "simulated time of the latest state", value=state.time_s)
        yield GaugeMetricFamily(P + "plant_faults_active", "1 while an injected fault is active",
                                value=float(state.faults_active))  # fmt: skip
        age = self.store.state_age_s()
        if age is not None:
            yield GaugeMetricFamily(P + "plant_state_age_seconds", "wall seconds since the latest state", value=age)

    def _mesh(self) -> Iterator:
        s = self.store
        counts = dict(s.counts)
        for name, key, help_text in (("plant_states_received_total", "states", "plant states the UI received"),
                                     ("fallback_steps_total", "fallbacks", "steps applied from a fallback"),
                                     ("guardrail_clamps_total", "clamps", "values the guardrails clamped"),
                                     ("explanations_total", "explanations", "decision explanations received")):  # fmt: skip
            yield CounterMetricFamily(P + name.removesuffix("_total"), help_text, value=counts.get(key, 0))
        decisions = CounterMetricFamily(P + "decisions", "applied actions by source", labels=["source"])
        for source, n in sorted(dict(s.decisions_by_source).items()):
            decisions.add_metric([source], n)
        yield decisions
        raised = CounterMetricFamily(P + "alerts_raised", "alerts raised", labels=["severity"])
        for severity, n in sorted(dict(s.alerts_raised).items()):
            raised.add_metric([severity], n)
        yield raised
        active = GaugeMetricFamily(P + "alerts_active", "alerts raised and not cleared", labels=["severity"])
        by_severity: dict[str, int] = {"info": 0, "warning": 0, "critical": 0}
        for alert in s.active_alerts():
            by_severity[alert.severity] = by_severity.get(alert.severity, 0) + 1
        for severity, n in by_severity.items():
            active.add_metric([severity], n)
        yield active

    def _agents(self) -> Iterator:
        labels = ["agent", "role"]
        up = GaugeMetricFamily(P + "agent_up", "1 while the agent's liveliness token is present", labels=labels)
        for row in self.store.agents_view():
            up.add_metric([row["agent_id"], row["role"]], float(row["alive"]))
        yield up
        families = {
            "cpu": GaugeMetricFamily(P + "agent_cpu_usage_ratio", "CPU use (1 = one core)", labels=labels),
            "rss": GaugeMetricFamily(P + "agent_resident_memory_bytes", "resident memory", labels=labels),
            "uptime": GaugeMetricFamily(P + "agent_uptime_seconds", "seconds since the agent started", labels=labels),
            "in": CounterMetricFamily(P + "agent_messages_received", "bus messages received", labels=labels),
            "out": CounterMetricFamily(P + "agent_messages_sent", "bus messages sent", labels=labels),
            "invalid": CounterMetricFamily(P + "agent_invalid_messages", "invalid messages dropped", labels=labels),
            "errors": CounterMetricFamily(P + "agent_handler_errors", "handler exceptions", labels=labels),
        }  # fmt: skip
        for st in self.store.snapshot_stats():
            key = [st.agent_id, st.role]
            families["cpu"].add_metric(key, st.cpu_pct / 100.0)
            families["rss"].add_metric(key, st.rss_bytes)
            families["uptime"].add_metric(key, st.uptime_s)
            families["in"].add_metric(key, sum(st.msgs_in.values()))
            families["out"].add_metric(key, sum(st.msgs_out.values()))
            families["invalid"].add_metric(key, sum(st.invalid.values()))
            families["errors"].add_metric(key, st.handler_errors)
        yield from families.values()

    def _ui(self) -> Iterator:
        yield GaugeMetricFamily(P + "ui_live_clients", "connected live pages (server-sent events)", value=self.hub.clients)
        yield CounterMetricFamily(P + "ui_dropped_events", "live events dropped for slow clients", value=self.hub.dropped)
        if self.chat is not None:
            intents = CounterMetricFamily(P + "chat_requests", "chat tool calls by tool ('refuse': none)",
                                          labels=["intent"])  # fmt: skip
            for intent, n in sorted(dict(self.chat.intents).items()):
                intents.add_metric([intent], n)
            yield intents
            planned = CounterMetricFamily(P + "chat_plans", "chat plans by planner (llm, openai, rules)", labels=["by"])
            for by, n in sorted(dict(self.chat.planned_by).items()):
                planned.add_metric([by], n)
            yield planned
            yield CounterMetricFamily(P + "chat_ungrounded_answers", "written answers the semantic guard refused",
                                      value=self.chat.ungrounded)  # fmt: skip
            yield CounterMetricFamily(P + "chat_rejected_phrasings", "LLM rephrasings the guard refused (draft sent)",
                                      value=self.chat.rejected_phrasings)  # fmt: skip


def make_registry(collector: UiCollector) -> tuple[CollectorRegistry, Histogram]:
    """A registry of its own (several UIs in one test process do not collide) and the API latency histogram."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(collector)
    latency = Histogram(P + "api_request_duration_seconds", "API request latency by route", ["route", "method"],
                        registry=registry, buckets=(0.001, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5))  # fmt: skip
    return registry, latency


# Label values come from closed sets, so a client can not add series: a made-up method or an unknown path is `other`.
KNOWN_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})
OTHER = "other"


def request_labels(scope) -> tuple[str, str]:
    """(route template, method) of a finished request, each from a closed set (`other` for anything else)."""
    route = getattr(scope.get("route"), "path", None)  # the template (``/api/cabinets/{cabinet}``), never the raw path
    if route is None:
        route = "/static" if scope["path"].startswith("/static/") else OTHER
    method = scope["method"] if scope["method"] in KNOWN_METHODS else OTHER
    return route, method


class LatencyMiddleware:
    """Pure ASGI middleware observing request duration by route template and method (closed label sets)."""

    def __init__(self, app, histogram: Histogram, skip: tuple[str, ...] = ("/api/events",)):
        self.app, self.histogram, self.skip = app, histogram, skip

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["path"] in self.skip:
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        try:
            await self.app(scope, receive, send)
        finally:
            self.histogram.labels(*request_labels(scope)).observe(time.perf_counter() - t0)
