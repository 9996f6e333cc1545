"""Maintenance alerts from injected twin faults; the Agent Monitor's report."""

from __future__ import annotations

import pytest

from lcmesh.mesh import keys
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.maintenance import MaintenanceAgent
from lcmesh.mesh.agents.monitor import MonitorAgent, _said_busy_with, recommend
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import AgentEvent, AgentHealth, AgentStats, Alert, CommandReply, FaultRequest, MonitorReport
from lcmesh.mesh.settings import MonitorConfig
from tests.mesh.conftest import wait_until

pytest.importorskip("lcmesh.mesh.tools.maintenance")


def test_an_injected_fault_raises_one_alert_and_clearing_it_clears_the_alert(start_agent, bus_as, mesh_settings):
    client = bus_as("orchestration")  # cmd/* is the orchestrator's alone
    site = mesh_settings.site
    fast = mesh_settings.model_copy(update={"speed_factor": 900.0})  # 17 ms steps: the clear needs ~25 of them
    alerts: list[Alert] = []
    client.subscribe(keys.alerts(site), Alert, alerts.append)
    start_agent(ControlAgent, fast)
    sensor = start_agent(SensorAgent, fast)
    maintenance = start_agent(MaintenanceAgent, fast)
    assert wait_until(lambda: maintenance.tally["updates"] >= 20, 30)
    client.request(keys.cmd(site, "sensor", "inject_fault"), CommandReply,
                   FaultRequest(kind="pump_degradation", cabinet=2, value=0.6))  # fmt: skip
    raised = lambda: [a for a in alerts if a.kind == "pump_degradation" and a.state == "raised"]  # noqa: E731
    assert wait_until(raised, 30), [a.kind for a in alerts]
    alert = raised()[0]
    assert alert.location == "cabinet_2" and alert.prescription and alert.step is not None
    steps_now = sensor.tally["steps"]
    assert wait_until(lambda: sensor.tally["steps"] > steps_now + 10, 20)
    assert len(raised()) == 1  # one alert while the fault lasts, not one per step
    history = HistoryReader(mesh_settings.history_file)  # the Sensor records the alerts Maintenance publishes
    assert wait_until(lambda: any(a["alert_id"] == alert.alert_id for a in history.alerts(active_only=True)), 10)
    client.request(keys.cmd(site, "sensor", "inject_fault"), CommandReply, FaultRequest(kind="clear"))
    cleared = lambda: [a for a in alerts if a.alert_id == alert.alert_id and a.state == "cleared"]  # noqa: E731
    assert wait_until(cleared, 60)
    assert wait_until(lambda: not any(a["alert_id"] == alert.alert_id for a in history.alerts(active_only=True)), 10)


def test_monitor_reports_every_agent_and_notices_one_going(start_agent, client, mesh_settings):
    site = mesh_settings.site
    start_agent(ControlAgent)
    sensor = start_agent(SensorAgent)
    monitor = start_agent(MonitorAgent)
    reports: list[MonitorReport] = []
    client.subscribe(keys.monitor_report(site), MonitorReport, reports.append)

    def health(agent_id):
        return next((a for a in reports[-1].agents if a.agent_id == agent_id), None) if reports else None

    assert wait_until(lambda: health("sensor") and health("control") and health("sensor").msgs_out_per_s > 0, 15)
    s = health("sensor")
    assert s.alive and s.role == "sensor" and s.cpu_pct is not None and s.rss_bytes > 0 and s.pid
    sensor.stop()
    assert wait_until(lambda: health("sensor") and not health("sensor").alive, 10)
    assert any(r.agent_id == "sensor" and r.severity == "critical" for r in reports[-1].recommendations)
    late = []
    client.subscribe(keys.monitor_report(site), MonitorReport, late.append, latest=True)
    assert late and monitor.last_report is not None


def test_a_high_cpu_share_names_what_the_agent_says_keeps_it_busy():
    """The CPU advice names the agent's own account of its work (the Control agent's local LLM), and a malformed
    account from the bus is ignored, not trusted."""
    cfg = MonitorConfig()
    control = AgentHealth(agent_id="control", role="control", alive=True, cpu_pct=cfg.cpu_high_pct + 5)
    said = ["the local LLM writes short explanations on a thread of its own"]
    (rec,) = recommend([control], 0, 0.25, cfg, {"control": said})
    assert rec.severity == "warning" and f"({said[0]})" in rec.text and rec.text.endswith("its own core or host")
    (bare,) = recommend([control], 0, 0.25, cfg)
    assert "()" not in bare.text and "% CPU; give it" in bare.text
    stats = {"source": "control", "role": "control", "agent_id": "control", "pid": 1, "host": "h", "uptime_s": 1.0,
             "cpu_pct": 99.0, "rss_bytes": 1, "threads": 1}  # fmt: skip
    assert _said_busy_with(AgentStats(**stats, details={"busy_with": "not a list"})) == []
    assert _said_busy_with(AgentStats(**stats, details={"busy_with": [3, "x" * 500]})) == ["x" * 200]


def _stats(agent_id: str, role: str) -> AgentStats:
    return AgentStats(source=agent_id, role=role, agent_id=agent_id, pid=1, host="h", uptime_s=1.0, cpu_pct=0.0,
                      rss_bytes=1, threads=1)  # fmt: skip


def test_the_monitor_takes_who_an_agent_is_from_the_key_not_the_message(start_agent, bus_as, client, mesh_settings):
    """A client authenticated as `control` says "I am the Sensor, alive" on its own stats key, and declares a token
    naming the sensor under its own role: both are dropped and counted, and the report has no sensor in it."""
    site = mesh_settings.site
    monitor = start_agent(MonitorAgent)
    events: list[AgentEvent] = []
    client.subscribe(keys.events(site), AgentEvent, events.append)
    control = bus_as("control")
    control.declare_token(keys.alive(site, "control", "sensor"))
    assert wait_until(lambda: control.publish(keys.agent_stats(site, "control"), _stats("sensor", "sensor"))
                      or min(monitor.identity_mismatches.values()) >= 1, 30), monitor.identity_mismatches  # fmt: skip
    control.publish(keys.agent_stats(site, "control-2"), _stats("control-2", "control"))  # its own: passes
    assert wait_until(lambda: any(a.agent_id == "control-2" for a in monitor.report().agents), 30)
    assert not [a for a in monitor.report().agents if a.agent_id == "sensor" or a.role == "sensor"]
    assert wait_until(lambda: [e for e in events if e.kind == "warning" and "claim to be sensor" in e.detail], 10)
    assert wait_until(lambda: [e for e in events if e.kind == "warning" and "alive/control/sensor" in e.detail], 10)
    assert monitor._details_with_checks()["identity_mismatches"]["stats"] >= 1
