"""The REST API over a real mesh on loopback: reads, errors, authenticated writes, events, OpenAPI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lcmesh.mesh.history import HistoryReader
from tests.mesh.conftest import wait_until

K0 = 273.15


def test_health_and_state_match_the_sensor(api, ui_mesh, lcopt5):
    health = api.get("/api/health").json()
    assert health["ready"] and health["system"] == "lcopt-5" and health["history"]
    state = api.get("/api/state").json()
    assert len(state["cabinets"]) == lcopt5.cabinets.count and len(state["towers"]) == lcopt5.towers.count
    assert len(state["cabinets"][0]["blade_temps_c"]) == lcopt5.n_blade_groups // lcopt5.cabinets.count
    # the view is the stored plant state in °C / kW (history keeps the same step's payload)
    stored = HistoryReader(ui_mesh.settings.history_file).state_at(state["step"], state["run_id"])
    assert stored is not None
    np.testing.assert_allclose([b for c in state["cabinets"] for b in c["blade_temps_c"]],
                               np.asarray(stored.outputs["blade_temp_k"]) - K0, atol=1e-3)  # fmt: skip
    assert abs(state["totals"]["ct_fan_power_kw"] - stored.outputs["ct_fan_power_w"][0] / 1e3) < 1e-3
    it_w, fan_w, pump_w = (stored.outputs[k][0] for k in ("it_power_w", "ct_fan_power_w", "pump_power_w"))
    assert state["totals"]["cooling_pue"] == pytest.approx((it_w + fan_w + pump_w) / it_w, abs=1e-4)
    np.testing.assert_allclose([t["approach_k"] for t in state["towers"]], stored.outputs["approach_k"], atol=1e-3)
    np.testing.assert_allclose([c["supply_temp_measured_c"] for c in state["cabinets"]],
                               np.asarray(stored.outputs["supply_temp_measured_k"]) - K0, atol=1e-3)  # fmt: skip
    assert (state["scenario"], state["wet_bulb_offset_k"], state["wet_bulb_note"]) == ("frontier", 0.0, None)
    assert state["controller"]["source"] in ("g36", "hold")
    cabinet = api.get("/api/state/cabinets/2").json()
    assert cabinet["cabinet"] == 2 and set(cabinet) >= {"supply_temp_c", "valve_fractions", "dp_psi"}
    assert api.get("/api/state/towers/1").json()["tower"] == 1


def test_unknown_cabinet_and_tower_are_404_with_the_valid_range(api):
    r = api.get("/api/state/cabinets/9")
    assert r.status_code == 404 and "cabinet 9 does not exist" in r.json()["detail"] and "1..5" in r.json()["detail"]
    r = api.get("/api/state/towers/0")
    assert r.status_code == 404 and "1..2" in r.json()["detail"]
    r = api.get("/api/state/cabinets/two")
    assert r.status_code == 422 and "`path.cabinet`" in r.json()["detail"]


def test_history_selects_fields_and_ranges(api, ui_mesh):
    r = api.get("/api/history", params={"fields": "blade_temp_max_c,ct_fan_power_kw", "last_s": 300})
    assert r.status_code == 200, r.text
    h = r.json()
    assert h["fields"] == ["blade_temp_max_c", "ct_fan_power_kw"] and h["units"]["ct_fan_power_kw"] == "kW"
    assert set(h["rows"][0]) == {"step", "time_s", "blade_temp_max_c", "ct_fan_power_kw"}
    steps = [row["step"] for row in h["rows"]]
    assert steps == sorted(steps) and steps[-1] - steps[0] <= 300 / 15
    raw = HistoryReader(ui_mesh.settings.history_file).states(start_step=steps[0], end_step=steps[0],
                                                              fields=("ct_fan_power_w",))  # fmt: skip
    assert abs(h["rows"][0]["ct_fan_power_kw"] - raw[0]["ct_fan_power_w"] / 1e3) < 1e-3
    assert wait_until(lambda: api.get("/api/state").json()["step"] > 11, 30)  # the range below must be complete
    ranged = api.get("/api/history", params={"fields": "wet_bulb_c", "start_s": 0, "end_s": 150}).json()
    assert [r["step"] for r in ranged["rows"]] == list(range(0, 11))
    assert wait_until(lambda: api.get("/api/state").json()["step"] > 100, 30)
    thin = api.get("/api/history", params={"start_step": 0, "end_step": 99, "max_points": 10}).json()
    assert thin["every"] == 10 and len(thin["rows"]) == 10
    both = api.get("/api/history", params={"fields": "wet_bulb_c", "start_s": 30, "end_s": 600, "end_step": 20}).json()
    assert [r["step"] for r in both["rows"]] == list(range(2, 21)), "every bound given applies"
    assert (both["start_step"], both["end_step"]) == (2, 20)
    empty = api.get("/api/history", params={"start_step": 50, "end_step": 40}).json()
    assert empty["rows"] == [] and (empty["start_step"], empty["end_step"]) == (50, 40)


def test_history_errors_name_the_field(api):
    r = api.get("/api/history", params={"fields": "blade_tmp_max_c"})
    assert r.status_code == 422 and "blade_temp_max_c" in r.json()["detail"] and "`fields`" in r.json()["detail"]
    r = api.get("/api/history", params={"last_s": -5})
    assert r.status_code == 422 and "`query.last_s`" in r.json()["detail"]
    r = api.get("/api/history", params={"fields": "blade_temp_max_c, it_power_kw"})
    assert r.status_code == 422 and "without spaces" in r.json()["detail"], "exactly what the OpenAPI pattern says"
    r = api.get("/api/history", params={"run_id": "nope"})
    assert r.status_code == 404


def test_agents_decisions_alerts_config(api, ui_mesh):
    assert wait_until(lambda: {a["role"] for a in api.get("/api/agents").json()["agents"] if a["alive"]}
                      >= {"sensor", "control", "configuration", "monitor", "ui"}, 10)  # fmt: skip
    rows = api.get("/api/decisions", params={"limit": 5}).json()["decisions"]
    assert len(rows) == 5 and rows[0]["step"] > rows[-1]["step"]
    assert {"source_controller", "source_version", "clamps", "explanation", "fallback", "changes"} <= set(rows[0])
    assert all(isinstance(r["changes"], list) for r in rows), "each row says what changed from the one before it"
    assert any(r["explanation"] for r in rows), "the Control agent's explanations join the decisions"
    assert {r["explanation_written_by"] for r in rows if r["explanation"]} == {"renderer"}, "who wrote each text"
    assert len(rows[0]["action"]["supply_temp_setpoint_c"]) == 5
    doc = api.get("/api/config").json()
    assert doc["version"] >= 1 and doc["config"]["controller"] in ("g36", "static")


def test_writes_need_the_token(api):
    for method, path, body in (("PUT", "/api/config", {"changes": {"speed_factor": 300}}),
                               ("POST", "/api/control/mode", {"controller": "g36"}),
                               ("POST", "/api/control/setpoints", {"supply_temp_setpoint_c": 30})):  # fmt: skip
        r = api.request(method, path, json=body)
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", (path, r.text)
        r = api.request(method, path, json=body, headers={"Authorization": "Bearer wrong-token-1234567"})
        assert r.status_code == 401


def test_config_changes_are_validated_versioned_and_conflicts_refused(api, ui_mesh):
    auth = ui_mesh.auth()
    r = api.put("/api/config", json={"changes": {"guardrails": {"valve_fraction_min": 0.9}}}, headers=auth)
    assert r.status_code == 422 and "valve_fraction_min" in r.json()["detail"]
    r = api.put("/api/config", json={"changes": {"speed_factr": 10}}, headers=auth)
    assert r.status_code == 422 and "speed_factr" in r.json()["detail"]
    r = api.put("/api/config", json={"changes": {}, "colour": "red"}, headers=auth)
    assert r.status_code == 422 and "`colour` is not a known field" in r.json()["detail"]
    before = api.get("/api/config").json()["version"]
    change = {"changes": {"llm": {"max_new_tokens": 200 + before}}, "reason": "test", "expected_version": before}
    r = api.put("/api/config", json=change, headers=auth)
    assert r.status_code == 200 and r.json()["version"] == before + 1 and "api@127.0.0.1" in r.json()["changed_by"]
    r = api.put("/api/config", json=change, headers=auth)
    assert r.status_code == 409 and "expected_version" in r.json()["detail"]
    assert wait_until(lambda: api.get("/api/config").json()["version"] == before + 1, 5)


def test_controller_switch_and_manual_setpoints_reach_the_plant(api, ui_mesh):
    auth = ui_mesh.auth()
    r = api.post("/api/control/mode", json={"controller": "g63"}, headers=auth)
    assert r.status_code == 422 and "did you mean 'g36'" in r.json()["detail"]
    r = api.post("/api/control/mode", json={}, headers=auth)
    assert r.status_code == 422 and "give `controller`, `mode` or both" in r.json()["detail"]
    r = api.post("/api/control/setpoints", json={"supply_temp_setpoint_c": [30, 31]}, headers=auth)
    assert r.status_code == 422 and "`supply_temp_setpoint_c` must hold 5 values" in r.json()["detail"]
    r = api.post("/api/control/setpoints", json={"valve_fractions": [0.5, -0.1, 0.6]}, headers=auth)
    assert r.status_code == 422 and "`valve_fractions" in r.json()["detail"]
    r = api.post("/api/control/setpoints", json={"valve_fractions": [[0.5, 0.5]] * 5}, headers=auth)
    assert r.status_code == 422 and "5 rows of [2]" in r.json()["detail"]
    # a split that does not sum to 1 is the guardrails' to rescale, and the answer says so
    r = api.post("/api/control/setpoints", json={"valve_fractions": [0.5, 0.6, 0.1], "cabinets": [4]}, headers=auth)
    assert r.status_code == 200, r.text
    assert any(c["field"] == "valve_fractions" and c["index"][0] == 4 for c in r.json()["clamps_expected"])  # from 1
    r = api.post("/api/control/setpoints", json={"supply_temp_setpoint_c": 30, "cabinets": [7]}, headers=auth)
    assert r.status_code == 404
    split = [0.6, 0.25, 0.15]
    r = api.post("/api/control/setpoints", headers=auth,
                 json={"supply_temp_setpoint_c": 45.0, "valve_fractions": split, "cabinets": [2], "reason": "test"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["mode"] == "manual" and body["manual_action"]["valve_fractions"][1] == split
    assert any(c["field"] == "supply_temp_setpoint_k" for c in body["clamps_expected"]), "45 °C is above the limit"

    def manual_applied():  # these setpoints, not the split above: the 45 °C is clamped
        rows = api.get("/api/decisions", params={"limit": 10}).json()["decisions"]
        return next((d for d in rows if d["source_controller"] == "manual" and
                     any(c["field"] == "supply_temp_setpoint_k" for c in d["clamps"])), None)  # fmt: skip

    applied = wait_until(manual_applied, 10)
    assert applied, "the manual setpoints are applied, clamped by the guardrails"
    assert {tuple(c["index"]) for c in applied["clamps"] if c["field"] == "supply_temp_setpoint_k"} == {(2,)}, \
        "the clamp names cabinet 2 as the operator does: counted from 1"
    assert wait_until(lambda: api.get("/api/state/cabinets/2").json()["valve_fractions"][0] > 0.5, 10)
    # the chat explains the operator's own decision from the stored facts
    answer = api.post("/api/chat", json={"message": "why did cabinet 2 open branch 1?"}).json()
    assert answer["intent"] == "decision", answer
    assert "manual): opened the valve of branch 1 of cabinet 2 from " in answer["answer"], answer["answer"]
    assert "manual" in answer["answer"] and answer["grounded"]
    r = api.post("/api/control/mode", json={"controller": "g36", "mode": "auto"}, headers=auth)
    assert r.status_code == 200 and r.json()["mode"] == "auto"
    assert wait_until(lambda: api.get("/api/state").json()["controller"]["source"] in ("g36", "hold"), 10)


def test_chat_contract_and_input_errors(api):
    r = api.post("/api/chat", json={"message": "which cabinet runs hottest?"})
    assert r.status_code == 200
    body = r.json()
    assert set(body) >= {"answer", "facts"} and body["facts"] and body["intent"] == "rank" and body["grounded"]
    first = next(f for f in body["facts"] if f["ref"].get("rank") == 1)
    assert f"{first['entity'].capitalize()} has the highest blade temperature: {first['display']}" in body["answer"]
    assert first["source"] == "tool" and first["quantity"] == "blade_temp" and first["unit"] == "degC"
    assert body["plan"] == [{"tool": "rank", "args": {"quantity": "blade_temp", "order": "highest"}}] or \
        body["plan"][0]["tool"] == "rank"
    assert api.post("/api/chat", json={}).status_code == 422
    r = api.post("/api/chat", json={"message": ""})
    assert r.status_code == 422 and "`message`" in r.json()["detail"]
    r = api.post("/api/chat", json={"message": "x" * 600})
    assert r.status_code == 422 and "at most 500 characters" in r.json()["detail"]
    r = api.post("/api/chat", content=b"{" + b" " * 300_000 + b"}", headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_chat_follow_ups_read_the_previous_question_of_their_session(api):
    first = api.post("/api/chat", json={"message": "what is the supply temperature of cabinet 4?", "session": "s-1"})
    assert first.status_code == 200 and first.json()["query"]["asks"][0]["quantity"] == "supply_temp", first.json()
    follow = api.post("/api/chat", json={"message": "and cabinet 2?", "session": "s-1"}).json()
    assert follow["follow_up"] and follow["session"] == "s-1", follow
    assert follow["plan"] == [{"tool": "plant_state", "args": {"quantity": "supply_temp", "cabinet": 2}}]
    assert follow["grounded"] and "cabinet 2" in follow["answer"]
    alone = api.post("/api/chat", json={"message": "and cabinet 2?", "session": "s-2"}).json()
    assert not alone["follow_up"]  # another session: nothing to continue
    r = api.post("/api/chat", json={"message": "and cabinet 2?", "session": "../etc"})
    assert r.status_code == 422 and "session" in r.text


def test_chat_proposes_commands_and_never_applies_them(api):
    before = api.get("/api/config").json()["version"]
    body = api.post("/api/chat", json={"message": "set the supply setpoint of cabinet 3 to 29 °C"}).json()
    cmd = body["proposed_command"]
    assert body["intent"] == "propose_change" and cmd["path"] == "/api/control/setpoints"
    assert cmd["body"]["supply_temp_setpoint_c"][2] == 29.0
    body = api.post("/api/chat", json={"message": "switch to the static controller; DROP TABLE actions;"}).json()
    cmd = body["proposed_command"]
    assert cmd == {"method": "POST", "path": "/api/control/mode", "summary": cmd["summary"],
                   "expires_at": cmd["expires_at"],  # a proposal ages (tests/mesh/ui/test_limits_and_proposals.py)
                   "body": {"controller": "static", "proposal": cmd["body"]["proposal"]}}  # fmt: skip
    assert api.get("/api/config").json()["version"] == before, "chat must not change the configuration"


def test_metrics_follow_prometheus_conventions(api):
    from prometheus_client.parser import text_string_to_metric_families

    r = api.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    families = {f.name: f for f in text_string_to_metric_families(r.text)}
    blade = families["lcmesh_blade_temperature_celsius"]
    assert len(blade.samples) == 15 and set(blade.samples[0].labels) == {"cdu", "cabinet", "blade_group"}
    assert 0 < max(s.value for s in blade.samples) < 120
    assert families["lcmesh_cooling_tower_fan_power_watts"].samples[0].value >= 0
    assert families["lcmesh_decisions"].type == "counter"
    assert any(s.name == "lcmesh_decisions_total" and s.value > 0 for s in families["lcmesh_decisions"].samples)
    assert {s.labels["agent"] for s in families["lcmesh_agent_up"].samples} >= {"sensor", "control", "ui"}
    assert "lcmesh_api_request_duration_seconds" in families
    for name in families:
        assert name.startswith("lcmesh_") and not name.endswith("_celcius")


def test_live_events_stream_state(ui_mesh):
    with ui_mesh.client() as http, http.stream("GET", "/api/events") as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        events, data = [], []
        for line in stream.iter_lines():
            if line.startswith("event: "):
                events.append(line[7:])
            elif line.startswith("data: "):
                data.append(line[6:])
            if events.count("state") >= 2:
                break
    assert events[0] == "hello"
    hello = json.loads(data[0])
    assert hello["system"]["cabinets"] == 5 and hello["state"]["step"] >= 0
    state = json.loads(data[events.index("state", 1)])
    assert state["step"] >= hello["state"]["step"]


def test_openapi_documents_the_contract(api):
    doc = api.get("/openapi.json").json()
    for path in ("/api/health", "/api/state", "/api/history", "/api/agents", "/api/decisions", "/api/alerts",
                 "/api/config", "/api/control/mode", "/api/control/setpoints", "/api/chat", "/metrics"):
        assert path in doc["paths"], path
    assert "put" in doc["paths"]["/api/config"] and doc["paths"]["/api/config"]["put"]["security"]
    assert doc["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    text = json.dumps(doc)
    assert not any(f'"{k}":' in text for k in ("ge", "le", "gt", "lt")), "constraints must be JSON Schema keywords"
    setpoints = doc["components"]["schemas"]["SetpointsRequest"]["properties"]
    assert {"type": "array", "items": {"type": "number", "minimum": 0.0, "maximum": 80.0}, "minItems": 5,
            "maxItems": 5} in setpoints["supply_temp_setpoint_c"]["anyOf"], "one value per cabinet of this site"
    assert set(doc["paths"]["/api/control/setpoints"]["post"]["responses"]) == {
        "200", "400", "401", "404", "409", "410", "413", "422", "503"}  # 409, 410: a chat proposal aged  # fmt: skip
    assert api.get("/").headers["content-security-policy"].startswith("default-src 'self'")


def test_cors_allows_only_the_pages_origin(api, ui_mesh):
    own = f"http://127.0.0.1:{ui_mesh.settings.ui_port}"
    for origin, allowed in ((own, True), ("http://evil.example", False)):
        r = api.options("/api/config", headers={"Origin": origin, "Access-Control-Request-Method": "PUT"})
        assert (r.headers.get("access-control-allow-origin") == origin) == allowed, origin


def test_a_ui_without_a_mesh_answers_503_with_reasons(empty_ui):
    with empty_ui.client() as http:
        health = http.get("/api/health").json()
        assert health["status"] == "starting" and not health["ready"] and health["reasons"]
        for path in ("/api/state", "/api/history", "/api/state/cabinets/1", "/api/config"):
            r = http.get(path)
            assert r.status_code == 503 and r.json()["detail"], path
        assert "Sensor" in http.get("/api/state").json()["detail"]
        r = http.put("/api/config", json={"changes": {"speed_factor": 10}}, headers=empty_ui.auth())
        assert r.status_code == 503 and "Configuration agent" in r.json()["detail"]
        codes = [http.post("/api/chat", json={"message": "status"}).status_code for _ in range(3)]
        assert codes[:2] == [503, 503] and codes[2] == 429, codes
        r = http.post("/api/chat", json={"message": "status"})
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1


def test_an_injected_fault_shows_as_alert_metric_and_chat_answer(api, ui_mesh):
    from prometheus_client.parser import text_string_to_metric_families

    from lcmesh.mesh import keys
    from lcmesh.mesh.bus import Bus
    from lcmesh.mesh.messages import CommandReply, FaultRequest

    site = ui_mesh.settings.site
    bus = Bus.connect(ui_mesh.settings, "fault-tester", role="orchestration")  # cmd/* is the orchestrator's alone
    try:
        bus.request(keys.cmd(site, "sensor", "inject_fault"), CommandReply,
                    FaultRequest(kind="pump_degradation", cabinet=1, value=0.6))  # fmt: skip

        def pump_alert():
            rows = api.get("/api/alerts", params={"active": True}).json()["alerts"]
            return next((a for a in rows if a["kind"] == "pump_degradation" and a["location"] == "cabinet_1"), None)

        alert = wait_until(pump_alert, 40)
        assert alert and alert["severity"] in ("warning", "critical") and alert["prescription"]
        metrics = {f.name: f for f in text_string_to_metric_families(api.get("/metrics").text)}
        assert sum(s.value for s in metrics["lcmesh_alerts_active"].samples) >= 1
        answer = api.post("/api/chat", json={"message": "any alerts?"}).json()
        assert answer["intent"] == "alerts" and "pump_degradation at cabinet_1" in answer["answer"]
        assert answer["grounded"] and any(f["ref"].get("alert_id") == alert["alert_id"] for f in answer["facts"])
    finally:
        bus.request(keys.cmd(site, "sensor", "inject_fault"), CommandReply, FaultRequest(kind="clear"))
        bus.close()


def test_the_ui_serves_the_assistants_data_tools_on_the_bus(ui_mesh):
    """One registry: the tools the chat plans with are the ones any agent can query on tools/{name}/{role}."""
    import json

    from lcmesh.mesh import keys

    other = next(a for a in ui_mesh.agents if a.role == "control")  # a role allowed to query tools
    site = ui_mesh.settings.site
    replies = other.bus.query(keys.tool(site, "rank", "control"), b'{"quantity": "blade_temp", "top": 2}',
                              timeout_s=5.0)  # fmt: skip
    assert replies and replies[0].ok, replies
    result = json.loads(replies[0].payload)["result"]
    assert [v["kind"] for v in result["ranked"]] == ["cabinet", "cabinet"] and result["count"] == 5
    replies = other.bus.query(keys.tool(site, "plant_state", "control"), b'{"quantity": "valve", "cabinet": 9}',
                              timeout_s=5.0)  # fmt: skip
    assert replies and not replies[0].ok and b"there is no cabinet 9" in replies[0].payload
