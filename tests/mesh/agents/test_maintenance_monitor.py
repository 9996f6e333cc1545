"""Maintenance alerts from injected twin faults; the Agent Monitor's report."""

from __future__ import annotations

import pytest

from lcmesh.mesh import keys
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.maintenance import MaintenanceAgent
from lcmesh.mesh.agents.monitor import MonitorAgent, _said_busy_with, recommend
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import AgentHealth, AgentStats, Alert, CommandReply, FaultRequest, MonitorReport
from lcmesh.mesh.settings import MonitorConfig
from tests.mesh.conftest import wait_until

pytest.importorskip("lcmesh.mesh.tools.maintenance")


def test_an_injected_fault_raises_one_alert_and_clearing_it_clears_the_alert(start_agent, bus_as, mesh_settings):
    client = bus_as("ui")  # cmd/* is the orchestrator's and the UI's
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
    history = HistoryReader(mesh_settings.history_file)
    active = history.alerts(active_only=True)
    assert any(a["alert_id"] == alert.alert_id for a in active)
    client.request(keys.cmd(site, "sensor", "inject_fault"), CommandReply, FaultRequest(kind="clear"))
    cleared = lambda: [a for a in alerts if a.alert_id == alert.alert_id and a.state == "cleared"]  # noqa: E731
    assert wait_until(cleared, 60)
    assert not any(a["alert_id"] == alert.alert_id for a in history.alerts(active_only=True))


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
