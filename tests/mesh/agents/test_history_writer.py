"""History has one writer, the Sensor: the others' rows reach it over the bus, each from the role its key allows."""

from __future__ import annotations

import pytest

from lcmesh.mesh import keys
from lcmesh.mesh.agents.configuration import ConfigurationAgent
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.maintenance import MaintenanceAgent
from lcmesh.mesh.agents.orchestration import OrchestrationAgent
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.history import HistoryReader, HistoryWriter
from lcmesh.mesh.messages import AgentEvent, Alert, ConfigDoc, ConfigUpdate, MeshConfig
from tests.mesh.conftest import wait_until


def _writers(agent) -> list[str]:
    """The attributes of `agent` that hold a HistoryWriter."""
    return [name for name, value in vars(agent).items() if isinstance(value, HistoryWriter)]


@pytest.fixture
def mesh(start_agent, mesh_settings):
    """The real agents that used to write history themselves, and the Sensor, on a loopback router."""
    quiet = mesh_settings.model_copy(deep=True)
    quiet.orchestration.supervise, quiet.orchestration.roles = False, []
    return {"configuration": start_agent(ConfigurationAgent), "sensor": start_agent(SensorAgent),
            "control": start_agent(ControlAgent), "maintenance": start_agent(MaintenanceAgent),
            "orchestration": start_agent(OrchestrationAgent, quiet)}  # fmt: skip


def test_only_the_sensor_writes_and_every_agents_rows_still_land(mesh, bus_as, mesh_settings):
    site = mesh_settings.site
    assert {role: _writers(agent) for role, agent in mesh.items() if _writers(agent)} == {"sensor": ["history"]}
    history = HistoryReader(mesh_settings.history_file)
    # configuration: a change is audited with its diff and who asked, from the document on config/all
    doc = bus_as("operator").request(keys.configure(site, "operator"), ConfigDoc,
                                     ConfigUpdate(changes={"speed_factor": 250.0}, by="alice", reason="faster"))
    audit = wait_until(lambda: [r for r in history.config_changes() if r["version"] == doc.version], 20)
    assert audit and audit[0]["changes"] == {"speed_factor": [300.0, 250.0]}
    assert audit[0]["changed_by"] == "operator/alice" and audit[0]["reason"] == "faster"
    # control: its explanations
    assert wait_until(lambda: history.explanations(limit=5), 30), "no explanation of Control's reached history"
    assert all(e["controller"] == "g36" and "EXPLANATION" in e["text"] for e in history.explanations(limit=5))
    # orchestration, control, maintenance: their events, each recorded with who sent it
    for role in ("orchestration", "control", "maintenance", "configuration"):
        mesh[role].emit_event("warning", f"marker from {role}")
    sent = lambda: {e["source"]: e["detail"] for e in history.agent_events(limit=200)  # noqa: E731
                    if e["detail"].startswith("marker from")}
    assert wait_until(lambda: len(sent()) == 4, 20), sent()
    assert sent() == {role: f"marker from {role}" for role in ("orchestration", "control", "maintenance",
                                                                "configuration")}
    # maintenance: its alerts (published as the Maintenance agent would; its detector's own: test_maintenance_monitor)
    alert = Alert(source="maintenance", alert_id="al-1", state="raised", kind="pump_degradation",
                  location="cabinet_2", message="pump 2 weak", step=3)
    bus_as("maintenance", "maintenance-2").publish(keys.alerts(site), alert, block=True)
    assert wait_until(lambda: [a for a in history.alerts() if a["alert_id"] == "al-1"], 20)
    assert mesh["sensor"].recorder.tally["foreign"] == 0


def test_rows_a_role_may_not_publish_never_reach_history(start_agent, bus_as, mesh_settings):
    """A compromised UI can only publish its own events: it can not pose as another role's agent, nor publish
    alerts, explanations or config documents, so none of it becomes a history row."""
    sensor = start_agent(SensorAgent)
    assert _writers(sensor) == ["history"]
    site, ui = mesh_settings.site, bus_as("ui")
    history = HistoryReader(mesh_settings.history_file)
    posing = AgentEvent(source="orchestration", kind="died", role="sensor", agent_id="sensor", detail="forged")
    ui.publish(keys.events(site, "ui"), posing, block=True)  # its own key, another role's name
    ui.publish(keys.events(site, "orchestration"), posing, block=True)  # another role's key: the router drops it
    coup = ConfigDoc(source="configuration", version=1000, config=MeshConfig(controller="static"),
                     changed_by="operator/alice", reason="forged", changes={"controller": ["g36", "static"]})
    ui.publish(keys.config(site, "all"), coup, block=True)
    ui.publish(keys.alerts(site), Alert(source="maintenance", alert_id="forged", state="raised", kind="x"), block=True)
    honest = AgentEvent(source="ui", kind="warning", role="ui", agent_id="ui", detail="the UI's own")
    ui.publish(keys.events(site, "ui"), honest, block=True)
    assert wait_until(lambda: any(e["detail"] == "the UI's own" for e in history.agent_events(limit=100)), 20)
    assert wait_until(lambda: sensor.recorder.tally["foreign"] == 1, 10), sensor.recorder.tally
    assert not [e for e in history.agent_events(limit=100) if e["detail"] == "forged"]
    assert all(r["version"] != 1000 for r in history.config_changes())
    assert not [a for a in history.alerts() if a["alert_id"] == "forged"]


def test_events_sent_while_the_writer_was_down_reach_history_once_it_starts(start_agent, bus_as, mesh_settings):
    """An agent's events from before the Sensor ran (the Orchestrator's 'started' of the agents it starts first)
    are fetched from its recent events when the Sensor starts; an event seen live and again there is one row."""
    quiet = mesh_settings.model_copy(deep=True)
    quiet.orchestration.supervise, quiet.orchestration.roles = False, []
    orchestration = start_agent(OrchestrationAgent, quiet)
    orchestration.emit_event("warning", "before the writer")
    sensor = start_agent(SensorAgent)
    history = HistoryReader(mesh_settings.history_file)
    rows = lambda text: [e for e in history.agent_events(limit=500) if e["detail"] == text]  # noqa: E731
    assert wait_until(lambda: rows("before the writer"), 20), "an event sent before the Sensor ran never landed"
    orchestration.emit_event("warning", "after the writer")
    assert wait_until(lambda: rows("after the writer"), 20)
    sensor.recorder._fetch_recent_events(sensor)  # both events again, as a restarted writer would fetch them
    assert wait_until(lambda: sensor.recorder._rows.empty(), 10)
    assert len(rows("before the writer")) == 1 and len(rows("after the writer")) == 1
