"""The Configuration agent: versions, validation that names the field, persistence, audit, and who follows it."""

from __future__ import annotations

import json

import pytest

from lcmesh.mesh import keys, security
from lcmesh.mesh.agents.configuration import ConfigStore, ConfigurationAgent
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.bus import BusError
from lcmesh.mesh.history import HistoryReader, HistoryWriter
from lcmesh.mesh.messages import ConfigDoc, ConfigUpdate, MeshConfig
from tests.mesh.conftest import wait_until


def _update(client, site, section="all", **kw):
    return client.request(keys.configure(site, "operator", section), ConfigDoc, ConfigUpdate(by="alice", **kw))


def test_changes_are_versioned_persisted_and_audited(start_agent, client, mesh_settings):
    start_agent(ConfigurationAgent)
    start_agent(SensorAgent)  # history's writer: it audits each version the Configuration agent publishes
    site = mesh_settings.site
    doc = client.request(keys.config(site, "all"), ConfigDoc)
    assert doc.version == 1 and doc.config.controller == "g36" and doc.config.speed_factor == 300.0
    seen = []
    client.subscribe(keys.config(site, "all"), ConfigDoc, seen.append)
    new = _update(client, site, "guardrails", changes={"guardrails": {"supply_temp_max_k": 305.0}}, reason="summer")
    assert new.version == 2 and new.config.guardrails.supply_temp_max_k == 305.0
    assert new.config.guardrails.dp_max_pa == doc.config.guardrails.dp_max_pa  # nested dicts merge
    assert wait_until(lambda: any(d.version == 2 for d in seen), 5)
    stored = json.loads((mesh_settings.data_dir / "config.json").read_text())
    assert stored["version"] == 2
    history = HistoryReader(mesh_settings.history_file)
    audit = wait_until(lambda: [r for r in history.config_changes() if r["version"] == 2], 10)
    assert audit and audit[0]["changed_by"] == "operator/alice" and audit[0]["reason"] == "summer"
    assert audit[0]["changes"] == {"guardrails.supply_temp_max_k": [313.15, 305.0]}
    assert _update(client, site, changes={"guardrails": {"supply_temp_max_k": 305.0}}).version == 2  # no-op


@pytest.mark.parametrize(
    ("section", "changes", "message"),
    [
        ("all", {"controller": "gg36"}, r"`controller` must be one of .*did you mean 'g36'"),
        ("all", {"speed_factor": -1}, r"`speed_factor` Input should be greater than 0"),
        ("all", {"guardrails": {"dp_min_pa": 9e9}}, r"`dp_min_pa`"),
        ("all", {"guardrails": {"valve_fraction_min": 0.5}}, r"`guardrails`: `valve_fraction_min` = 0.5"),
        ("all", {"colour": "red"}, r"`colour` is not a configuration field"),
        ("all", {"mode": "manual"}, r"`mode` 'manual' needs `manual_action`"),
        ("controller", {"speed_factor": 10}, r"through config/controller only `controller` may change"),
    ],
)
def test_invalid_changes_are_refused_with_the_field_named(start_agent, client, mesh_settings, section, changes, message):
    start_agent(ConfigurationAgent)
    with pytest.raises(BusError, match=message):
        _update(client, mesh_settings.site, section, changes=changes)
    assert client.request(keys.config(mesh_settings.site, "all"), ConfigDoc).version == 1


def test_stale_writers_and_garbage_requests_are_refused(start_agent, client, mesh_settings):
    start_agent(ConfigurationAgent)
    site = mesh_settings.site
    _update(client, site, changes={"speed_factor": 100})
    with pytest.raises(BusError, match="`expected_version` is 1 but the current version is 2"):
        _update(client, site, changes={"speed_factor": 200}, expected_version=1)
    with pytest.raises(BusError, match="invalid ConfigUpdate"):
        client.request(keys.configure(site, "operator"), ConfigDoc, b'{"changes": {}}')
    with pytest.raises(BusError, match="not JSON|invalid ConfigUpdate"):
        client.request(keys.configure(site, "operator"), ConfigDoc, b"\x00garbage")
    with pytest.raises(BusError, match="only answers the current document; changes go to configure/"):
        client.request(keys.config(site, "all"), ConfigDoc, ConfigUpdate(by="x", changes={"speed_factor": 9}))


def test_a_restarted_configuration_agent_keeps_its_version(start_agent, client, mesh_settings):
    first = start_agent(ConfigurationAgent)
    _update(client, mesh_settings.site, changes={"speed_factor": 150})
    first.stop()
    start_agent(ConfigurationAgent)
    doc = client.request(keys.config(mesh_settings.site, "all"), ConfigDoc)
    assert doc.version == 2 and doc.config.speed_factor == 150


def test_sensor_and_control_follow_the_configuration(start_agent, client, mesh_settings, lcopt5):
    start_agent(ConfigurationAgent)
    control = start_agent(ControlAgent)
    sensor = start_agent(SensorAgent)
    site = mesh_settings.site
    assert wait_until(lambda: sensor.tally["proposals_applied"] >= 3, 20)
    _update(client, site, changes={"controller": "static", "speed_factor": 200})
    assert wait_until(lambda: getattr(control.controller, "name", "") == "static", 10)
    assert wait_until(lambda: sensor.config.speed_factor == 200, 5)
    C, B, N = lcopt5.cabinets.count, lcopt5.cabinets.branches, lcopt5.towers.count
    manual = {"supply_temp_setpoint_k": [300.0] * C, "dp_setpoint_pa": [190e3] * C,
              "valve_fractions": [[1 / B] * B] * C, "lw_setpoint_k": [305.0] * N}  # fmt: skip
    doc = _update(client, site, changes={"mode": "manual", "manual_action": manual})
    history = HistoryReader(mesh_settings.history_file)
    assert wait_until(lambda: any(r["source_controller"] == "manual" for r in history.decisions(limit=5)), 10)
    row = next(r for r in history.decisions(limit=5) if r["source_controller"] == "manual")
    assert row["source_version"] == f"config-v{doc.version}" and not row["fallback"]
    assert any(r["source_controller"] == "static" for r in history.decisions(limit=200))


def _signed_by_the_run(doc: ConfigDoc, settings) -> bool:
    verifier = security.load_config_verifier(settings.secrets_path)
    return verifier.valid(doc.version, doc.config.model_dump(mode="json"), doc.signature)


def test_every_published_version_is_signed(start_agent, client, mesh_settings):
    start_agent(ConfigurationAgent)
    site = mesh_settings.site
    first = client.request(keys.config(site, "all"), ConfigDoc)
    assert first.signature and _signed_by_the_run(first, mesh_settings)
    new = _update(client, site, changes={"speed_factor": 120.0})
    assert new.version == 2 and _signed_by_the_run(new, mesh_settings)
    assert not _signed_by_the_run(new.model_copy(update={"version": 3}), mesh_settings)


def test_a_history_row_the_store_does_not_hold_is_never_adopted(tmp_path):
    """A history writer (or anyone who can write the file) adds a newer version with wide guardrails: a restarted
    store keeps its own content, issues it after that version (versions never go back) and signs it."""
    security.ensure_secrets(tmp_path / "secrets")
    signer = security.load_config_signer(tmp_path / "secrets")
    store_path, history = tmp_path / "config.json", tmp_path / "history.sqlite"
    store = ConfigStore(store_path, MeshConfig(controller="g36"), None, history, signer=signer)
    writer = HistoryWriter(history)
    writer.add_config_change(store.doc, {"*": [None, "initial"]})  # what the Sensor records from config/all
    wide = MeshConfig(controller="static").model_dump(mode="json")
    wide["guardrails"].update(supply_temp_max_k=353.15, supply_temp_rate_k=30.0)
    forged = ConfigDoc(source="configuration", version=2, config=MeshConfig.model_validate(wide), changed_by="ui/x")
    writer.add_config_change(forged, {"guardrails.supply_temp_rate_k": [2.0, 30.0]})
    writer.close()
    again = ConfigStore(store_path, MeshConfig(controller="g36"), None, history, signer=signer)
    assert again.doc.config == store.doc.config and again.doc.config.guardrails.supply_temp_rate_k == 2.0
    assert again.doc.version == 3, "after history's version: no agent that saw 2 refuses it as old"
    verifier = security.load_config_verifier(tmp_path / "secrets")
    assert verifier.valid(3, again.doc.config.model_dump(mode="json"), again.doc.signature)
    assert json.loads(store_path.read_text())["version"] == 3
