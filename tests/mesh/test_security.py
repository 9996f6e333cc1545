"""The bus from the outside: real routers on loopback with per-role passwords and access control.

An attacker here is a zenoh client with no credentials, wrong ones, or the credentials of a role
that is not allowed what it tries (the UI's, say). Each forgery below is one the outside tester of
issue 16 got through before: a proposal, a config document, a config change claiming another
identity, a fault injection, a stats message naming another agent's pid.
"""

from __future__ import annotations

import json
import os
import stat
import time
from pathlib import Path

import pytest
from pydantic import SecretStr

from lcmesh.mesh import keys, security
from lcmesh.mesh.agents.base import Agent
from lcmesh.mesh.agents.configuration import ConfigurationAgent
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.orchestration import OrchestrationAgent
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.bus import Bus, BusError, client_config
from lcmesh.mesh.demo import Demo
from lcmesh.mesh.history import HistoryReader, HistoryWriter
from lcmesh.mesh.messages import (
    ActionModel, AgentEvent, AgentStats, CommandReply, ConfigDoc, ConfigUpdate, FaultRequest, MeshConfig, PlantState,
    Proposal,
)  # fmt: skip
from lcmesh.mesh.processes import agent_env
from tests.mesh.conftest import free_port, make_settings, wait_until


def test_secrets_are_private_and_kept_across_restarts(tmp_path):
    paths = security.ensure_secrets(tmp_path / "s", tls_hosts=["127.0.0.1", "localhost"])
    files = [paths.dictionary, paths.password("ui"), paths.router_key, paths.ca_key, paths.router_cert,
             paths.config_signing_key]  # fmt: skip
    assert all(stat.S_IMODE(os.stat(f).st_mode) == 0o600 for f in files)
    assert stat.S_IMODE(os.stat(paths.root).st_mode) == 0o711, "reach a folder handed to you, list none"
    assert all(stat.S_IMODE(os.stat(paths.role_dir(r)).st_mode) == 0o700 for r in (*security.ROLES, "router"))
    assert stat.S_IMODE(os.stat(paths.config_verify_key).st_mode) == 0o644
    files += [paths.config_verify_key, paths.public_ca_cert]
    before = {f: f.read_bytes() for f in files}
    security.ensure_secrets(tmp_path / "s", tls_hosts=["127.0.0.1", "localhost"])
    assert {f: f.read_bytes() for f in files} == before, "a restarted router must find the same secrets"
    lines = paths.dictionary.read_text().splitlines()
    assert sorted(line.split(":")[0] for line in lines) == sorted((*security.ROLES, security.ROUTER_USER))
    assert len({line.split(":", 1)[1] for line in lines}) == len(lines), "one password per role"


def test_the_acl_grants_each_role_only_its_writes():
    acl = security.acl_config()
    assert acl["default_permission"] == "deny" and acl["enabled"]
    puts = {role: sorted(k for k, kinds in security.grants(role).items() if "put" in kinds) for role in security.ROLES}
    assert [r for r, ks in puts.items() if "control/*/proposal" in ks] == ["control"]
    assert [r for r, ks in puts.items() if "config/*" in ks] == ["configuration"]
    assert [r for r, ks in puts.items() if "plant/state" in ks] == ["sensor"]
    cmd = [r for r in security.ROLES if "query" in security.grants(r).get("cmd/*/*", ())]
    assert cmd == ["orchestration"]
    with pytest.raises(ValueError, match="unknown bus role 'intruder'"):
        security.grants("intruder")


def test_a_client_without_or_with_wrong_credentials_gets_no_session(router, mesh_settings):
    anonymous = mesh_settings.model_copy(update={"bus_auth": False})
    with pytest.raises(BusError, match="could not reach a router"):
        Bus.connect(anonymous, "intruder", timeout_s=0.5)
    wrong = mesh_settings.model_copy(update={"bus_password": SecretStr("guessed-password-123")})
    with pytest.raises(BusError, match="check that this role's password"):
        Bus.connect(wrong, "intruder", role="control", timeout_s=0.5)
    with pytest.raises(BusError, match="no bus password for role 'nobody'"):
        client_config(mesh_settings, "nobody")


def test_forged_proposals_from_another_role_are_never_applied(start_agent, bus_as, mesh_settings, lcopt5):
    sensor = start_agent(SensorAgent)
    C, B, N = lcopt5.cabinets.count, lcopt5.cabinets.branches, lcopt5.towers.count
    forged = ActionModel(supply_temp_setpoint_k=[313.0] * C, dp_setpoint_pa=[262e3] * C,
                         valve_fractions=[[1 / B] * B] * C, lw_setpoint_k=[318.0] * N)  # fmt: skip
    attempts = []
    forgers = [bus_as(role) for role in ("ui", "operator", "maintenance", "monitor", "sensor")]

    def forge(state: PlantState) -> None:  # the right step and state id: only the credentials are wrong
        for bus in forgers:
            bus.publish(keys.proposal(mesh_settings.site), Proposal(
                source="control", step=state.step, state_id=state.id, controller="g36", controller_version="1",
                action=forged), block=True)
            attempts.append(state.step)

    forgers[0].subscribe(keys.plant_state(mesh_settings.site), PlantState, forge)
    assert wait_until(lambda: len(attempts) >= 12 * len(forgers), 120)
    assert sensor.tally["proposals_applied"] == 0
    assert sensor.tally["stale_proposals"] + sensor.tally["duplicate_proposals"] == 0, "dropped at the router"
    decisions = HistoryReader(mesh_settings.history_file).decisions(limit=200)
    assert decisions and all(d["source_controller"] in ("hold", "g36") for d in decisions)


def test_the_sensor_applies_the_control_roles_proposals_only_for_its_own_state(start_agent, bus_as, mesh_settings):
    sensor = start_agent(SensorAgent)
    control = bus_as("control")
    def latest_state():
        try:
            return control.request(keys.plant_state(mesh_settings.site), PlantState)
        except BusError:  # the Sensor is still starting
            return None

    state = wait_until(latest_state, 60)
    assert state is not None
    wrong_id = Proposal(source="control", step=state.step + 1, state_id="not-the-published-state", controller="g36",
                        controller_version="1", action=ActionModel.from_action(sensor.last_safe))  # fmt: skip
    def send() -> bool:  # the right step, a state id the Sensor never published
        control.publish(keys.proposal(mesh_settings.site), wrong_id.model_copy(update={"step": sensor.twin.step}),
                        block=True)  # fmt: skip
        return sensor.tally["foreign_proposals"] >= 1

    assert wait_until(send, 60)
    assert sensor.tally["proposals_applied"] == 0


def test_config_documents_and_changes_from_outsiders_change_nothing(start_agent, bus_as, mesh_settings):
    start_agent(ConfigurationAgent)
    control = start_agent(ControlAgent)
    start_agent(SensorAgent)  # history's only writer: it audits the documents on config/all it would adopt
    site = mesh_settings.site
    assert wait_until(lambda: control.config_doc is not None and control.config_doc.version == 1, 60)
    coup = ConfigDoc(source="configuration", version=1_000_000, changed_by="api@127.0.0.1", reason="coup",
                     config=MeshConfig(controller="static", mode="auto", speed_factor=1.0))  # fmt: skip
    for role in ("ui", "operator", "sensor", "control"):  # none may publish config documents
        bus_as(role).publish(keys.config(site, "all"), coup, block=True)
    # the configuration role's own password, but a document the Configuration agent never audited
    bus_as("configuration", "configuration-thief").publish(keys.config(site, "all"), coup, block=True)
    change = ConfigUpdate(changes={"controller": "static"}, by="api@127.0.0.1", reason="claimed to be the UI")
    maintenance = bus_as("maintenance")
    assert maintenance.query(keys.configure(site, "ui"), change.model_dump_json(), timeout_s=1.0) == []
    assert maintenance.query(keys.configure(site, "operator"), change.model_dump_json(), timeout_s=1.0) == []
    with pytest.raises(BusError, match="only answers the current document"):
        maintenance.request(keys.config(site, "all"), ConfigDoc, change)
    assert bus_as("operator").query(keys.configure(site, "ui"), change.model_dump_json(), timeout_s=1.0) == [], \
        "the operator's password does not reach the UI's key"
    time.sleep(0.5)
    assert control.config_doc.version == 1 and control.config.controller == "g36"
    # a genuine operator change still lands, audited with the authenticated role
    ui = bus_as("ui")
    doc = ui.request(keys.configure(site, "ui"), ConfigDoc, ConfigUpdate(changes={"speed_factor": 250.0}, by="api@x"))
    assert doc.version == 2
    assert wait_until(lambda: control.config_doc.version == 2, 60)
    history = HistoryReader(mesh_settings.history_file)
    audit = wait_until(lambda: [r for r in history.config_changes() if r["version"] == 2] and history.config_changes())
    assert audit[0]["changed_by"] == "ui/api@x" and [r["version"] for r in audit] == [2, 1]
    assert wait_until(lambda: any("ignored config version 1000000" in (e["detail"] or "")
                                  for e in history.agent_events(limit=50)), 60)  # fmt: skip


def test_commands_and_stats_are_refused_to_the_wrong_roles(start_agent, bus_as, mesh_settings):
    sensor = start_agent(SensorAgent)
    site = mesh_settings.site
    inject = FaultRequest(kind="pump_degradation", cabinet=1, value=0.9).model_dump_json()
    for role in ("control", "maintenance", "monitor", "configuration", "operator", "ui"):
        assert bus_as(role).query(keys.cmd(site, "sensor", "inject_fault"), inject, timeout_s=1.0) == [], role
    assert not sensor.twin.plant.faults.active, "no fault was injected"
    assert bus_as("orchestration").request(keys.cmd(site, "sensor", "status"), CommandReply).ok
    seen = []
    bus_as("monitor").subscribe(keys.agent_stats_all(site), AgentStats, seen.append)
    forged = AgentStats(source="orchestration", role="orchestration", agent_id="orchestration", pid=1, host="h",
                        uptime_s=1.0, cpu_pct=0.0, rss_bytes=1, threads=1)  # fmt: skip
    bus_as("ui").publish(keys.agent_stats(site, "orchestration"), forged, block=True)
    bus_as("control").publish(keys.agent_stats(site, "orchestration"), forged, block=True)
    own = forged.model_copy(update={"agent_id": "control-2", "role": "control"})
    bus_as("control").publish(keys.agent_stats(site, "control-2"), own, block=True)
    assert wait_until(lambda: any(s.agent_id == "control-2" for s in seen), 30), "a role's own stats pass"
    assert not [s for s in seen if s.agent_id == "orchestration"]


def test_tls_endpoints_carry_the_mesh_and_refuse_plain_tcp(tmp_path):
    port = free_port()
    settings = make_settings(tmp_path / "mesh", router_endpoints=[f"tls/127.0.0.1:{port}"],
                             listen_endpoints=[f"tls/127.0.0.1:{port}"])  # fmt: skip
    router = Bus.open_router(settings)
    try:
        paths = security.SecretPaths(settings.secrets_path)
        assert paths.router_cert.exists() and paths.ca_cert.exists()
        sensor = Bus.connect(settings, "sensor", timeout_s=10)
        control = Bus.connect(settings, "control", timeout_s=10)
        try:
            got = []
            sensor.subscribe(keys.proposal(settings.site), Proposal, got.append)
            time.sleep(0.3)
            msg = Proposal(source="control", step=1, state_id="s", controller="g36", controller_version="1",
                           action=ActionModel(supply_temp_setpoint_k=[300.0], dp_setpoint_pa=[2e5],
                                              valve_fractions=[[1.0]], lw_setpoint_k=[300.0]))  # fmt: skip
            assert wait_until(lambda: control.publish(keys.proposal(settings.site), msg) or got, 30)
        finally:
            control.close()
            sensor.close()
        plain = settings.model_copy(update={"router_endpoints": [f"tcp/127.0.0.1:{port}"]})
        with pytest.raises(BusError):
            Bus.connect(plain, "control", timeout_s=0.5)
    finally:
        router.close()


def test_a_router_beyond_loopback_needs_authentication(tmp_path):
    settings = make_settings(tmp_path, listen_endpoints=[f"tcp/0.0.0.0:{free_port()}"], bus_auth=False)
    with pytest.raises(BusError, match="refusing to listen on tcp/0.0.0.0:.* without bus authentication"):
        Bus.open_router(settings)


def test_child_processes_never_get_the_password_in_their_environment(tmp_path):
    settings = make_settings(tmp_path, bus_password="s3cret-value-for-this-agent", bus_password_file=tmp_path / "pw")
    env = settings.to_env()
    assert "LCMESH_BUS_PASSWORD" not in env and "s3cret" not in json.dumps(env)
    assert "LCMESH_BUS_PASSWORD_FILE" not in env, "each child is given its own role's file, not this process's"


def test_each_role_folder_holds_that_roles_secrets_alone(tmp_path):
    """A deployment hands each role its own folder: nothing in it is another role's (or every role's) secret."""
    root = tmp_path / "s"
    (root / "bus").mkdir(parents=True)  # a run from before per-role folders: every password in one place
    (root / "bus" / "control.password").write_text("kept-from-the-last-run")
    paths = security.ensure_secrets(root)
    assert security.read_password(root, "control") == "kept-from-the-last-run", "agents elsewhere keep working"
    assert not (root / "bus").exists(), "the folder holding every password is gone"
    passwords = {r: paths.password(r).read_text() for r in (*security.ROLES, "router")}
    for role in security.ROLES:
        held = " ".join(p.read_text(errors="replace") for p in paths.role_dir(role).rglob("*") if p.is_file())
        assert [r for r, pw in passwords.items() if pw in held] == [role], role
    assert sorted(p.name for p in paths.public_dir.iterdir()) == ["config-signing.pub"]


def test_config_signatures_cover_the_version_and_the_config(tmp_path):
    security.ensure_secrets(tmp_path)
    signer, verifier = security.load_config_signer(tmp_path), security.load_config_verifier(tmp_path)
    config = MeshConfig(controller="g36").model_dump(mode="json")
    signature = signer.sign(7, config)
    assert verifier.valid(7, config, signature)
    assert not verifier.valid(8, config, signature), "a signature is not valid for another version"
    wider = {**config, "speed_factor": config["speed_factor"] * 2}
    assert not verifier.valid(7, wider, signature), "nor for other content"
    assert not verifier.valid(7, config, "not base64!") and not verifier.valid(7, config, "")
    security.ensure_secrets(tmp_path / "other")  # another run's key: its signatures do not pass here
    assert not verifier.valid(7, config, security.load_config_signer(tmp_path / "other").sign(7, config))


class _Follower(Agent):
    """The smallest agent that follows the configuration (what the Sensor, Control and UI do)."""

    role = "monitor"

    def on_start(self) -> None:
        self.watch_config()


def test_a_forged_config_doc_with_a_matching_history_row_is_refused(start_agent, bus_as, mesh_settings):
    """The configuration role's password and a history row that audits the forgery: still refused (no signature by
    the Configuration agent's key); the same document signed with that key is adopted."""
    follower = start_agent(_Follower)
    wide = MeshConfig(controller="static", speed_factor=1.0).model_dump(mode="json")
    wide["guardrails"] = {**wide["guardrails"], "supply_temp_max_k": 353.15, "supply_temp_rate_k": 30.0}
    forged = ConfigDoc(source="configuration", version=1_000_000, changed_by="ui/api@x", reason="coup",
                       config=MeshConfig.model_validate(wide))  # fmt: skip
    writer = HistoryWriter(mesh_settings.history_file)
    writer.add_config_change(forged, {"guardrails.supply_temp_rate_k": [2.0, 30.0]})  # what _unaudited checked
    writer.close()
    thief = bus_as("configuration", "configuration-thief")
    seen = []
    thief.subscribe(keys.events(mesh_settings.site, "monitor"), AgentEvent, seen.append)
    time.sleep(0.3)  # the subscription reaches the router
    thief.publish(keys.config(mesh_settings.site, "all"), forged, block=True)
    assert wait_until(lambda: any("1000000" in e.detail and "not signed" in e.detail for e in seen), 60), seen
    assert follower.config_doc is None and follower.config.controller == "g36"
    signed = forged.model_copy(update={"version": 1_000_001, "signature": security.load_config_signer(
        mesh_settings.secrets_path).sign(1_000_001, forged.config.model_dump(mode="json"))})
    thief.publish(keys.config(mesh_settings.site, "all"), signed, block=True)
    assert wait_until(lambda: follower.config_doc is not None and follower.config_doc.version == 1_000_001, 60)
    assert follower.config.controller == "static"


def test_a_bus_password_file_names_one_roles_password(router, mesh_settings):
    paths = security.SecretPaths(mesh_settings.secrets_path)
    own = mesh_settings.model_copy(update={"bus_password_file": paths.password("control")})
    Bus.connect(own, "control-file", role="control", timeout_s=10).close()
    other = mesh_settings.model_copy(update={"bus_password_file": paths.password("ui")})
    with pytest.raises(BusError, match="check that this role's password"):
        Bus.connect(other, "control-file", role="control", timeout_s=0.5)
    missing = mesh_settings.model_copy(update={"bus_password_file": paths.root / "nowhere"})
    with pytest.raises(BusError, match="`LCMESH_BUS_PASSWORD_FILE` = .*nowhere can not be read"):
        client_config(missing, "control")


SECRET_ENV = {"LCMESH_BUS_PASSWORD": "pw-of-the-demo-process", "LCMESH_API_TOKEN": "the-ui-api-token-0123456789",
              "LCMESH_LLM_API_KEY": "sk-the-llm-endpoint-key"}  # fmt: skip


def test_each_child_gets_only_its_own_roles_secrets(tmp_path, monkeypatch):
    """`lcmesh demo` (and the systemd unit that runs it): the router and the orchestrator get no secret in their
    environment; each agent its own role's password file, the UI alone the API token, control and UI the LLM key."""
    for name, value in SECRET_ENV.items():
        monkeypatch.setenv(name, value)
    settings = make_settings(tmp_path)
    demo = Demo(settings, say=lambda _: None)
    paths = security.ensure_secrets(settings.secrets_path)
    security.store_env_secrets(settings.secrets_path, dict(os.environ))
    assert not set(SECRET_ENV.values()) & set(demo.env.values()), "the router's environment and the children's base"
    orchestration = agent_env(demo.env, "orchestration", settings.secrets_path)
    assert not set(SECRET_ENV.values()) & set(orchestration.values())
    for name in SECRET_ENV:  # the orchestrator's own process has none of them (asserted above)
        monkeypatch.delenv(name)
    orchestrator = OrchestrationAgent(settings)
    for role in ("configuration", "sensor", "control", "maintenance", "monitor", "ui"):
        env = orchestrator.child_env(role)
        assert env["LCMESH_BUS_PASSWORD_FILE"] == str(paths.password(role))
        assert "LCMESH_BUS_PASSWORD" not in env
        assert ("LCMESH_LLM_API_KEY" in env) == (role in ("control", "ui")), role
        assert ("LCMESH_API_TOKEN_FILE" in env) == (role == "ui"), role
        leaked = {k for k, v in env.items() if v in SECRET_ENV.values()}
        assert leaked <= ({"LCMESH_LLM_API_KEY"} if role in ("control", "ui") else set()), (role, leaked)
    assert Path(orchestrator.child_env("ui")["LCMESH_API_TOKEN_FILE"]).read_text() == SECRET_ENV["LCMESH_API_TOKEN"]
    security.store_env_secrets(settings.secrets_path, dict(os.environ))  # the next start, no token set
    assert not paths.api_token.exists(), "a token taken away is gone at the next start"
