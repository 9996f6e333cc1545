"""Sensor and Control agents in-process, on a real router and a real FMU, with history in SQLite."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.mesh import keys
from lcmesh.mesh.agents.control import ControlAgent
from lcmesh.mesh.agents.sensor import SensorAgent
from lcmesh.mesh.bus import BusError
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.messages import ActionModel, AgentStats, CommandReply, FaultRequest, PlantState, Proposal
from lcmesh.mesh.settings import SensorConfig
from tests.mesh.conftest import wait_until


def test_proposals_are_applied_with_latency_audit_and_explanations(start_agent, mesh_settings):
    start_agent(ControlAgent)
    sensor = start_agent(SensorAgent)
    assert wait_until(lambda: sensor.tally["proposals_applied"] >= 15, 60)
    history = HistoryReader(mesh_settings.history_file)

    def applied_in_history():  # the tally counts a proposal when decided, history has it once the step is written
        return [d for d in history.decisions(limit=200) if not d["fallback"]]

    decisions = wait_until(lambda: len(applied_in_history()) >= 15 and applied_in_history(), 30)
    assert decisions, f"{len(applied_in_history())} applied proposals in history"
    assert all(d["source_controller"] == "g36" and d["source_version"] == "1" for d in decisions)
    assert all(d["decision_id"] and d["latency_ms"] > 0 for d in decisions)  # how small: `lcmesh bench mesh`
    # explanations follow their decision asynchronously: the newest may not have one yet
    explained_decisions = [d for d in decisions if d["explanation"]]
    assert explained_decisions, "no decision got its explanation"
    d = explained_decisions[0]
    assert "EXPLANATION" in d["explanation"]
    explained = history.explanations(decision_id=d["decision_id"])
    assert explained and any(f["name"] == "cabinet" for f in explained[0]["facts"])
    assert history.step_gaps("plant_states") == [] and history.step_gaps("actions") == []


def test_without_proposals_the_sensor_holds_then_falls_back_to_g36(start_agent, mesh_settings):
    sensor = start_agent(SensorAgent)
    assert wait_until(lambda: sensor.tally["steps"] >= 6, 20)
    rows = sorted(HistoryReader(mesh_settings.history_file).decisions(limit=50), key=lambda r: r["step"])
    hold = mesh_settings.sensor.hold_periods
    assert [r["source_controller"] for r in rows[: hold + 2]] == ["hold"] * hold + ["g36", "g36"]
    assert all(r["fallback"] and "no proposal" in r["fallback_reason"] for r in rows)
    assert [r["step"] for r in rows] == list(range(rows[0]["step"], rows[0]["step"] + len(rows)))


def _answer_with(client, site, make_action):
    """A stand-in controller on the bus: answers every plant state with `make_action(state)`."""

    def on_state(state: PlantState):
        action = make_action(state)
        client.publish(keys.proposal(site), Proposal(source="tester", step=state.step, state_id=state.id,
                                                     controller="test", controller_version="0", action=action))

    client.subscribe(keys.plant_state(site), PlantState, on_state)


def test_out_of_range_proposals_are_clamped_and_malformed_ones_rejected(start_agent, bus_as, mesh_settings, lcopt5):
    sensor = start_agent(SensorAgent)
    C, B, N = lcopt5.cabinets.count, lcopt5.cabinets.branches, lcopt5.towers.count

    def action(state):
        if state.step % 2:  # malformed: two branches instead of three
            return ActionModel(supply_temp_setpoint_k=[300.0] * C, dp_setpoint_pa=[190e3] * C,
                               valve_fractions=[[0.5, 0.5]] * C, lw_setpoint_k=[300.0] * N)  # fmt: skip
        return ActionModel(supply_temp_setpoint_k=[400.0] * C, dp_setpoint_pa=[190e3] * C,
                           valve_fractions=[[1 / B] * B] * C, lw_setpoint_k=[300.0] * N)  # fmt: skip

    _answer_with(bus_as("control"), mesh_settings.site, action)
    assert wait_until(lambda: sensor.tally["rejected"] >= 3 and sensor.tally["proposals_applied"] >= 3, 20)
    rows = HistoryReader(mesh_settings.history_file).decisions(limit=100)
    clamped = [r for r in rows if r["source_controller"] == "test"]
    assert clamped and all(not r["fallback"] for r in clamped)
    assert any(c["field"] == "supply_temp_setpoint_k" and c["proposed"] == 400.0 for c in clamped[0]["clamps"])
    rejected = [r for r in rows if r["rejected_reason"]]
    assert rejected and all(r["fallback"] for r in rejected)
    assert "`valve_fractions` must have shape (5, 3)" in rejected[0]["rejected_reason"]


def test_valve_exercise_strokes_each_cabinet_and_audits_it(start_agent, mesh_settings, lcopt5):
    settings = mesh_settings.model_copy(update={"valve_exercise_s": 4 * 15.0 * lcopt5.cabinets.count})
    start_agent(ControlAgent, settings)
    sensor = start_agent(SensorAgent, settings)
    history = HistoryReader(settings.history_file)

    def whole_strokes() -> dict[int, list[tuple[int, dict]]] | None:
        """{cabinet: [(step, clamp), ...]} once history holds a whole 4-step stroke of every cabinet."""
        by_cabinet: dict[int, list[tuple[int, dict]]] = {}
        for row in sorted(history.decisions(limit=1000), key=lambda r: r["step"]):
            for clamp in row["clamps"]:
                if clamp["reason"].startswith("valve exercise"):
                    by_cabinet.setdefault(clamp["index"][0], []).append((row["step"], clamp))
        whole = len(by_cabinet) == lcopt5.cabinets.count and all(len(v) >= 4 for v in by_cabinet.values())
        return by_cabinet if whole else None

    # wait for the strokes themselves (in history), not for a step count: a busy machine writes later
    strokes = wait_until(whole_strokes, 120, 0.2)
    assert strokes, f"strokes so far: {sensor.tally['valve_strokes']}"
    assert set(strokes) == set(range(lcopt5.cabinets.count))
    for cabinet, seq in strokes.items():
        first = seq[0][1]
        assert first["field"] == "supply_temp_setpoint_k" and abs(first["applied"] - first["proposed"]) >= 1.5 - 1e-6, \
            (cabinet, first)  # the stroke's first step: 1.5 K from both the setpoint and the measured supply
        for (step_a, a), (step_b, b) in zip(seq, seq[1:]):
            if step_b == step_a + 1:  # the target is held for the stroke, whatever the controller proposes meanwhile
                assert b["applied"] == a["applied"], (cabinet, step_a, a, b)
    assert sensor.tally["valve_strokes"] >= sum(map(len, strokes.values())) and history_has_no_gaps(settings)


def history_has_no_gaps(settings) -> bool:
    history = HistoryReader(settings.history_file)
    return history.step_gaps("plant_states") == [] and history.step_gaps("actions") == []


def test_late_joiners_get_the_latest_state(start_agent, client, mesh_settings):
    sensor = start_agent(SensorAgent)
    assert wait_until(lambda: sensor.tally["steps"] >= 2, 20)
    got = []
    client.subscribe(keys.plant_state(mesh_settings.site), PlantState, got.append, latest=True)
    assert got and got[0].system == "lcopt-5" and got[0].step >= 1


def test_fault_injection_status_and_toolbox_queryables(start_agent, bus_as, mesh_settings):
    commands, client = bus_as("orchestration"), bus_as("ui")  # cmd/* is the orchestrator's alone, tools/* anyone's
    sensor = start_agent(SensorAgent)
    assert wait_until(lambda: sensor.tally["steps"] >= 1, 20)
    key = keys.cmd(mesh_settings.site, "sensor", "inject_fault")
    inject = FaultRequest(kind="pump_degradation", cabinet=2, value=0.5)
    assert client.query(key, inject.model_dump_json(), timeout_s=1.0) == [], "the router keeps the UI role out of cmd/*"
    assert not sensor.twin.plant.faults.active
    reply = commands.request(key, CommandReply, inject)
    assert reply.ok and reply.data["pump_degradation"][1] == 0.5 and reply.data["active"]  # cabinet 2: index 1
    assert wait_until(lambda: sensor.twin.plant.faults.active, 5)
    with pytest.raises(BusError, match=r"`cabinet` must be in 1\.\.5 \(numbered from 1\), got 9"):
        commands.request(key, CommandReply, FaultRequest(kind="valve_stuck", cabinet=9))
    with pytest.raises(BusError, match="kind"):
        commands.request(key, CommandReply, b'{"kind": "meltdown"}')
    status = commands.request(keys.cmd(mesh_settings.site, "sensor", "status"), CommandReply)
    assert status.data["step"] >= 1 and status.data["run_id"] == sensor.twin.run_id
    registry = pytest.importorskip("lcmesh.mesh.tools.registry")
    for name in registry.served_tools(data=False):  # the data tools are the UI agent's (tests/mesh/ui)
        assert client.query(keys.tool(mesh_settings.site, name, "ui"), b"{}", timeout_s=5.0), name
    assert "whatif_setpoint" in registry.served_tools(data=False) and "plant_state" not in registry.served_tools(
        data=False)
    replies = client.query(keys.tool(mesh_settings.site, "whatif", "ui"),
                           b'{"supply_temp_setpoint_delta_k": -2, "steps": 4}', timeout_s=10.0)  # fmt: skip
    assert replies and replies[0].ok, replies
    assert b"predicted" in replies[0].payload


class FrozenClock:
    """A clock that moves only when told (the tools' rate limits read it)."""

    def __init__(self, now_s: float = 1000.0):
        self.now_s = now_s

    def __call__(self) -> float:
        return self.now_s


def test_a_flood_of_what_ifs_is_answered_rate_limited_and_counted(start_agent, bus_as, mesh_settings):
    class Sensor(SensorAgent):
        clock = FrozenClock()  # an instance, not a function: not bound as a method

    clock = Sensor.clock
    limited = mesh_settings.model_copy(update={"sensor": SensorConfig(tools_rate_per_s=0.5, tools_burst=2)})
    sensor = start_agent(Sensor, limited)
    client = bus_as("ui")
    stats: list[AgentStats] = []
    client.subscribe(keys.agent_stats(mesh_settings.site, sensor.agent_id), AgentStats, stats.append)
    whatif, body = keys.tool(mesh_settings.site, "whatif", "ui"), b'{"supply_temp_setpoint_delta_k": 1, "steps": 2}'
    answers = [client.query(whatif, body, timeout_s=10.0) for _ in range(3)]
    assert all(len(replies) == 1 for replies in answers), answers
    assert [replies[0].ok for replies in answers] == [True, True, False]  # the burst of 2, then the limit
    assert answers[2][0].payload.decode() == "rate limited: 0.5 queries/s for tools/whatif/ui; retry in 2.0 s"
    other = client.query(keys.tool(mesh_settings.site, "approach", "ui"),
                         b'{"leaving_water_k": 300, "wet_bulb_k": 295}', timeout_s=5.0)  # fmt: skip
    assert other[0].ok, other  # each queryable has a bucket of its own
    clock.now_s += 2.0  # one token back
    assert client.query(whatif, body, timeout_s=10.0)[0].ok
    assert sensor.bus.counters.snapshot()["rate_limited"] == {"tools/whatif/ui": 1}
    assert wait_until(lambda: stats and stats[-1].rate_limited == {"tools/whatif/ui": 1}, 10), stats[-1:]


def test_a_restarted_sensor_resumes_its_run_without_a_gap(start_agent, mesh_settings):
    first = start_agent(SensorAgent)
    assert wait_until(lambda: first.tally["steps"] >= 5, 20)
    first.stop()  # (the SIGKILL case: tests/mesh/test_faults.py)
    history = HistoryReader(mesh_settings.history_file)
    run_id = history.latest_run_id()
    step = max(r["step"] for r in history.states(fields=()))
    again = start_agent(SensorAgent, agent_id="sensor")
    assert again.twin.run_id == run_id  # its loop may already have stepped on: where it resumed is in its event
    # its event reaches history over the bus (the Sensor records what is published, its own events too)
    resumed = wait_until(lambda: [e for e in history.agent_events(limit=20) if e["detail"].startswith("resumed run")])
    assert resumed and resumed[0]["detail"] == f"resumed run {run_id} at step {step}"
    assert wait_until(lambda: again.tally["steps"] >= 3, 60)
    assert history.step_gaps("plant_states") == [] and history.step_gaps("actions") == []
    states = history.states(fields=("blade_temp_max_k",))
    assert np.all(np.isfinite([s["blade_temp_max_k"] for s in states]))


# the slow-policy test's speed: a 15 s plant step at 60x is a 0.25 s period, so the sensor waits 200 ms for each
# (repeated) proposal; at the suite's 300x it waited 40 ms, which two busy cores can miss, and the sensor then holds
SLOW_SPEED = 60.0


class SlowController:
    """G36 that needs 2.5 control periods per decision (as an LLM might)."""

    name, version = "slow-g36", "0"

    def __init__(self, system, period_s: float = 15.0 / SLOW_SPEED):
        from lcmesh.twin.controllers.g36 import G36Controller

        self._inner, self._period_s = G36Controller(system), period_s

    def reset(self) -> None:
        self._inner.reset()

    def act(self, obs):
        import time

        time.sleep(2.5 * self._period_s)
        return self._inner.act(obs)


def test_a_slow_policy_in_worker_mode_repeats_its_last_action_instead_of_a_fallback(start_agent, mesh_settings,
                                                                                      monkeypatch):  # fmt: skip
    from lcmesh.twin import controllers

    monkeypatch.setitem(controllers.REGISTRY, "slow-g36", f"{__name__}:SlowController")
    settings = mesh_settings.model_copy(update={"controller": "slow-g36", "speed_factor": SLOW_SPEED,
                                                "control": mesh_settings.control.model_copy(update={"inline": False})})
    control = start_agent(ControlAgent, settings)
    sensor = start_agent(SensorAgent, settings)
    history = HistoryReader(settings.history_file)

    def since_first_decision():
        rows = sorted(history.decisions(limit=200), key=lambda r: r["step"])
        first = next((i for i, r in enumerate(rows) if r["source_controller"] == "slow-g36"), len(rows))
        return rows[first:]

    assert wait_until(lambda: len(since_first_decision()) >= 10, 30), control.tally
    later = since_first_decision()
    assert control.tally["repeats"] >= 4, control.tally
    assert not any(r["fallback"] for r in later), [r["source_controller"] for r in later]
    assert sensor.tally["proposals_applied"] >= 10


# the detailed level (transformers, whose texts run out of their 10 s on 2 cores) in the slow tier: the default tier
# has its explainer tests (tests/llm/test_explainer.py); the mesh's default, the short level, runs here
@pytest.mark.parametrize("level, heading", [("short", "## EXPLANATION"),
                                            pytest.param("detailed", "## EXECUTIVE SUMMARY", marks=pytest.mark.slow)])
def test_the_llm_explainer_publishes_a_judged_text_over_the_rendering(start_agent, mesh_settings, level, heading):
    """Every decision gets the rendering; the LLM's text for the newest one replaces it where it adds a verified
    what-if claim (real model: llama.cpp with the short adapter, or transformers at the detailed level)."""
    mesh_settings.control.explainer, mesh_settings.control.explain_level = "llm", level
    control = start_agent(ControlAgent)
    start_agent(SensorAgent)
    assert wait_until(lambda: control.tally["llm_texts"] + control.tally["llm_fallbacks"] >= 2, 120)
    published = control.tally["llm_texts"]  # read before the history and the stats: one may finish in between
    history = HistoryReader(mesh_settings.history_file)

    def caught_up():  # the Sensor records what Control published: history catches up with the count
        rows = history.explanations(limit=1000)
        return rows if sum(e["written_by"] == "llm" for e in rows) >= published else None

    rows = wait_until(caught_up, 30) or history.explanations(limit=1000)
    renderings = [e for e in rows if e["written_by"] == "renderer"]
    by_llm = [e for e in rows if e["written_by"] == "llm"]
    assert len(renderings) >= 2 and all("## WHAT IF" not in e["text"] for e in renderings)
    assert len(by_llm) >= published
    rendered_ids = {e["decision_id"] for e in renderings}
    for e in by_llm:  # over a rendering of the same decision, at the asked level, with the what-if facts it was judged on
        assert e["decision_id"] in rendered_ids and e["level"] == level and heading in e["text"]
        assert "## WHAT IF" in e["text"] and e["llm_part"] == ("what-if" if level == "short" else "whole")
        assert {"hottest_branch_expected", "top_input"} <= {f["name"] for f in e["facts"]}
    stats = control._llm_explainer.stats
    assert stats["explanations"] == stats["llm"] + stats["renderer"] >= 2
    assert published <= stats["llm_with_whatif_claim"] <= published + 1, (control.tally, stats)
    said = control.details()["explained_by"]
    assert said["level"] == level and said["llm_texts"] >= published and "asked for" in said["summary"]
    assert any(f"writes {level} explanations" in w for w in control.details()["busy_with"]), "for the Agent Monitor"


def test_the_llm_controller_runs_paced_in_the_mesh_and_says_who_decided(start_agent, mesh_settings):
    """The real LLM controller in the Control agent: worker mode, a period paced to the mesh's speed, and its
    share of decisions in the agent's stats (what /api/state and the page show)."""
    settings = mesh_settings.model_copy(update={"controller": "llm"})
    control = start_agent(ControlAgent, settings)
    sensor = start_agent(SensorAgent, settings)
    report = wait_until(lambda: (control.details().get("decided_by") or {}).get("answers", 0) >= 14
                        and control.details()["decided_by"], 120)  # fmt: skip
    assert report, control.details()
    assert control.controller.name == "llm" and not control.controller_note
    snap = control.controller.stats_snapshot()
    assert report["period_steps"] >= 4  # MeshConfig.llm.control_period_steps, paced up from there
    assert snap["decision_budget_s"] == pytest.approx(report["period_steps"] * sensor.period_s * 0.8, rel=0.01) or \
        snap["period_steps"] != report["period_steps"]  # the budget is the paced period's (unless it just changed)
    assert report["llm_share"] is not None and "cabinet and tower decisions" in report["summary"]
    history = HistoryReader(settings.history_file)
    rows = wait_until(lambda: [d for d in history.decisions(limit=200) if d["source_controller"] == "llm"], 30)
    assert rows, "no decision of the LLM controller was applied"


def test_a_sensor_told_to_stop_during_its_spin_up_stops_there(mesh_settings, router, client):
    """A SIGTERM while the twin warms up (the runner sets the agent's stop event) ends the spin-up between two steps:
    `start` returns with no run begun, no liveliness token and no loop, and `stop` undoes the rest."""
    from lcmesh.mesh.bus import Bus
    from tests.mesh.agents.test_twin_host import SetOnCheck

    class StoppedWhileWarming(SensorAgent):
        def __init__(self, settings, agent_id=None):
            super().__init__(settings, agent_id)
            self._stop = SetOnCheck(30)  # of the spin-up's 240 steps, a few in

    sensor = StoppedWhileWarming(mesh_settings)
    bus = Bus.connect(mesh_settings, sensor.agent_id)
    try:
        sensor.start(bus)
        assert sensor.stopping and sensor.twin.run_id == "" and sensor.tally["steps"] == 0
        assert 0 < sensor.twin.plant.n_steps_done < 30, "stopped within the spin-up, between steps"
        assert client.alive(keys.alive(mesh_settings.site, "sensor", "sensor"), timeout_s=1.0) == []
        assert not [t for t in sensor._threads if t.name.endswith("-loop")]
    finally:
        sensor.stop()
        bus.close()
    assert sensor.twin is None
