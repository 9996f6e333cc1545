"""The page's and /api/state's word on who decided: the Control agent's `decided_by` rides on the state view."""

from __future__ import annotations

import json

import numpy as np

from lcmesh.mesh.agents.ui.live import EventHub, LiveStore
from lcmesh.mesh.messages import ActionModel, AgentStats, AppliedAction, observation_to_plant_state
from lcmesh.twin.controllers import Observation, make_controller


def test_the_state_view_carries_the_control_agents_decided_by(plant, lcopt5):
    store = LiveStore(lcopt5, EventHub())
    out = plant.reset()
    obs = Observation(out, 291.15, np.full(lcopt5.n_blade_groups, 60e3), 0.0)
    action = ActionModel.from_action(make_controller("g36", lcopt5).act(obs))
    store.on_applied(AppliedAction(source="sensor", run_id="r", step=0, time_s=0.0, source_controller="llm",
                                   source_version="v", action=action))  # fmt: skip
    report = {"controller": "llm", "llm_share": 0.98, "summary": "the LLM made 98 of 100 cabinet and tower "
              "decisions (98.0 %), every 11 plant steps; ppo served the other 2 (deadline 2)"}  # fmt: skip
    store.on_stats(AgentStats(source="control-1", role="control", agent_id="control-1", pid=1, host="h", uptime_s=1.0, cpu_pct=0.0,
                              rss_bytes=1, threads=1, details={"decided_by": report}))  # fmt: skip
    store.on_state(observation_to_plant_state(obs, lcopt5, source="sensor", run_id="r", step=1, period_s=0.25))
    view = json.loads(store.view_json)
    assert view["controller"]["source"] == "llm" and view["controller"]["decided_by"] == report
    store.on_stats(AgentStats(source="control-1", role="control", agent_id="control-1", pid=1, host="h", uptime_s=2.0, cpu_pct=0.0,
                              rss_bytes=1, threads=1, details={}))  # a controller that does not fall back: G36  # fmt: skip
    store.on_state(observation_to_plant_state(obs, lcopt5, source="sensor", run_id="r", step=2, period_s=0.25))
    assert "decided_by" not in json.loads(store.view_json)["controller"]


def test_who_wrote_the_explanations_rides_on_the_state_view_and_the_decision_feed(plant, lcopt5):
    from lcmesh.mesh.messages import Explanation

    store = LiveStore(lcopt5, EventHub())
    out = plant.reset()
    obs = Observation(out, 291.15, np.full(lcopt5.n_blade_groups, 60e3), 0.0)
    action = ActionModel.from_action(make_controller("g36", lcopt5).act(obs))
    store.on_explanation(Explanation(source="control-1", decision_id="d0", step=0, controller="tree", level="short",
                                     text="rendering\n\n## WHAT IF\n\nnear 30.1 °C", written_by="llm",
                                     llm_part="what-if"))  # fmt: skip
    store.on_applied(AppliedAction(source="sensor", run_id="r", step=0, time_s=0.0, decision_id="d0",
                                   source_controller="tree", source_version="v", action=action))  # fmt: skip
    store.on_applied(AppliedAction(source="sensor", run_id="r", step=1, time_s=15.0, decision_id="d1",
                                   source_controller="tree", source_version="v", action=action))  # fmt: skip
    rows = {r["decision_id"]: r for r in store.recent_decisions(5)}
    assert rows["d0"]["explanation_written_by"] == "llm" and rows["d0"]["explanation_llm_part"] == "what-if"
    assert rows["d1"]["explanation"] is None and rows["d1"]["explanation_written_by"] is None
    wrote = {"level": "short", "llm_texts": 9, "summary": "the LLM wrote its WHAT IF after the rendering in 9 of 10"}
    store.on_stats(AgentStats(source="control-1", role="control", agent_id="control-1", pid=1, host="h", uptime_s=1.0,
                              cpu_pct=0.0, rss_bytes=1, threads=1, details={"explained_by": wrote}))  # fmt: skip
    store.on_state(observation_to_plant_state(obs, lcopt5, source="sensor", run_id="r", step=2, period_s=0.25))
    assert json.loads(store.view_json)["controller"]["explained_by"] == wrote


def test_a_forged_decided_by_on_another_roles_key_never_reaches_the_page(ui_mesh):
    """A client holding the UI's password says "I am the Control agent, the LLM decided" on its own stats key: the
    UI takes the sender from the key, drops it and counts it, so /api/state shows no forged `decided_by`."""
    from lcmesh.mesh import keys
    from lcmesh.mesh.bus import Bus
    from tests.mesh.conftest import wait_until

    s, ui = ui_mesh.settings, ui_mesh.ui
    forged = {"controller": "llm", "llm_share": 1.0, "summary": "FORGED: the LLM made every decision"}
    bus = Bus.connect(s, "ui-forger", role="ui")
    try:
        stats = AgentStats(source="ui", role="control", agent_id="control", pid=1, host="h", uptime_s=1.0,
                           cpu_pct=0.0, rss_bytes=1, threads=1, details={"decided_by": forged})  # fmt: skip
        dropped = lambda: (ui.identity_mismatches or {}).get("stats", 0) >= 1  # noqa: E731
        assert wait_until(lambda: bus.publish(keys.agent_stats(s.site, "ui"), stats) or dropped(), 30), \
            ui.identity_mismatches
    finally:
        bus.close()
    assert ui.ctx.store.decided_by != forged
    with ui_mesh.client() as http:
        assert "FORGED" not in json.dumps(http.get("/api/state").json())
