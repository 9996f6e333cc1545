"""The operator tools (issue 24) on a recorded site, checked against the stored rows read with sqlite3 and numpy; the
question check that declines an answer to a neighbouring question; the rules that route the new questions."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest

from lcmesh.bench.chat import site_runner
from lcmesh.bench.chat_site import record_site
from lcmesh.assistant.engine import ChatEngine, uncovered
from lcmesh.assistant.plan import Plan, RulePlanner, ToolCall, split_parts

K0 = 273.15


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    path = tmp_path_factory.mktemp("operations-site") / "site.sqlite"
    record_site(path, minutes=24)
    data, run = site_runner(path)
    yield path, data, run
    run.runner.context.plant.close()
    data.close()


def rows(path, sql: str) -> list[tuple]:
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return db.execute(sql).fetchall()
    finally:
        db.close()


def payloads(path) -> list[dict]:
    return [json.loads(p) for (p,) in rows(path, "SELECT payload FROM plant_states WHERE payload IS NOT NULL ORDER BY "
                                                 "step")]  # fmt: skip


def result(run, tool: str, **args) -> dict:
    r = run(tool, args)
    assert r.ok, r.error
    return r.result


def test_energy_is_the_integral_of_the_stored_power(site):
    path, _, run = site
    got = result(run, "energy_used", what="pumps", minutes=10)
    last = rows(path, "SELECT max(step) FROM plant_states")[0][0]
    series = rows(path, f"SELECT time_s, pump_power_w FROM plant_states WHERE step >= {last - 40} ORDER BY step")
    t, p = np.asarray(series, dtype=float).T
    assert got["kwh"] == pytest.approx(np.trapezoid(p, t) / 3.6e6, rel=1e-9)
    assert got["minutes_covered"] == pytest.approx(10.0) and got["mean_kw"] * 10 / 60 == pytest.approx(got["kwh"])
    cooling = result(run, "energy_used", minutes=10)["kwh"]
    fans = result(run, "energy_used", what="tower_fans", minutes=10)["kwh"]
    assert cooling == pytest.approx(got["kwh"] + fans)


def test_tracking_gaps_are_measured_minus_setpoint_of_the_last_state(site):
    path, _, run = site
    out = payloads(path)[-1]["outputs"]
    gaps = result(run, "tracking_gap")
    expected = np.asarray(out["supply_temp_measured_k"]) - np.asarray(out["applied_supply_setpoint_k"])
    assert [g["gap_k"] for g in gaps["gaps"]] == pytest.approx(expected.tolist())
    assert gaps["largest"] == f"cabinet {int(np.argmax(np.abs(expected))) + 1}"
    towers = result(run, "tracking_gap", level="tower")["gaps"]
    assert [g["entity"] for g in towers] == ["tower 1", "tower 2"]
    assert result(run, "tracking_gap", cabinet=2)["gaps"][0]["gap_k"] == pytest.approx(expected[1])
    assert "no cabinet 9" in run("tracking_gap", {"cabinet": 9}).error


def test_the_peak_says_where_and_when(site):
    path, _, run = site
    states = payloads(path)
    window = [s for s in states if s["step"] >= states[-1]["step"] - 40]
    temps = np.asarray([s["outputs"]["branch_max_temp_k"] for s in window])
    k, i = np.unravel_index(np.argmax(temps), temps.shape)
    got = result(run, "peak", minutes=10)
    assert got["value"] == pytest.approx(temps[k, i] - K0)
    assert got["entity"] == f"branch {i % 3 + 1} of cabinet {i // 3 + 1}" and got["step"] == window[k]["step"]
    assert got["at"].startswith(window[k]["sent_at"][:19])
    low = result(run, "peak", quantity="wet_bulb", extreme="min", minutes=10)
    assert low["entity"] == "plant" and low["value"] == pytest.approx(min(s["wet_bulb_k"] for s in window) - K0)


def test_top_n_at_the_branch_level(site):
    path, _, run = site
    temps = np.asarray(payloads(path)[-1]["outputs"]["branch_max_temp_k"]) - K0
    got = result(run, "rank", level="branch", top=4)["ranked"]
    assert [v["value"] for v in got] == pytest.approx(sorted(temps, reverse=True)[:4])
    assert all(v["kind"] == "branch" for v in got)
    assert "cannot be ranked by branch" in run("rank", {"quantity": "approach", "level": "branch"}).error


def test_the_weather_on_the_towers(site):
    path, _, run = site
    got = result(run, "weather_effect", minutes=10)
    last = rows(path, "SELECT max(step) FROM plant_states")[0][0]
    wb = [w for (w,) in rows(path, f"SELECT wet_bulb_k FROM plant_states WHERE step >= {last - 40} ORDER BY step")]
    assert got["wet_bulb_change_k"] == pytest.approx(wb[-1] - wb[0])
    assert len(got["towers"]) == 2 and all(t["approach_k"] > 0 for t in got["towers"])
    assert got.get("fan_kw_per_k_wet_bulb", 0.0) >= 0.0  # absent: a tower could not hold it at full speed


def test_another_controller_on_the_twin_leaves_the_plant_as_it_was(site):
    _, data, run = site
    plant = run.runner.context.plant
    before = {k: np.array(v) for k, v in plant.out.items()}
    got = result(run, "whatif_controller", controller="g36", minutes=5)
    assert got["current"]["controller"] == data.config().config.controller == "tree"
    assert got["alternative"]["controller"] == "g36" and got["minutes"] == pytest.approx(5.0)
    assert got["cooling_kwh_saved"] == pytest.approx(got["current"]["cooling_kwh"] - got["alternative"]["cooling_kwh"])
    assert all(np.array_equal(before[k], plant.out[k]) for k in before)
    same = result(run, "whatif_controller", controller="tree", minutes=5)  # the same course twice: nothing saved
    assert same["cooling_kwh_saved"] == pytest.approx(0.0, abs=1e-9)


def test_why_gets_the_reasons_of_the_cabinet_asked_about_as_sentences(site):
    _, data, run = site
    for cabinet in range(1, 6):
        got = run("decision", {"cabinet": cabinet, "action": "supply"})
        if got.ok and got.result["found"]:
            r = got.result
            assert r["reasons"].startswith(f"Cabinet {cabinet}. ") and r["reasons_for"] == f"cabinet {cabinet}"
            assert "#" not in r["reasons"] and "**" not in r["reasons"] and "\n" not in r["reasons"]
            published = r["explanation"].split("Cabinet ", 1)[1].split(".")[0]
            assert r["reasons_source"] == ("published" if published == str(cabinet) else "rendered")
    engine = ChatEngine(data, planner=RulePlanner(), runner=run.runner)
    reply = engine.ask("why did the controller change the valves?")
    assert "EXPLANATION" not in reply["answer"] and "#" not in reply["answer"]


def test_an_answer_to_a_neighbouring_question_is_declined(site):
    _, data, run = site
    engine = ChatEngine(data, planner=RulePlanner(), runner=run.runner)
    cases = {  # question: (a neighbouring plan, what the reply must say is missing)
        "how much energy have the pumps used in the last hour?": (ToolCall("history_stat", {"quantity": "pump_power",
                                                                  "stat": "change"}), "energy"),  # fmt: skip
        "which cabinet has the biggest gap between supply setpoint and measured supply?": (
            ToolCall("rank", {"quantity": "supply_setpoint"}), "gap"),
        "list the three hottest blade groups": (ToolCall("rank", {}), "branch_level"),
        "what was the peak blade temperature in the last 30 minutes, and where?": (
            ToolCall("history_stat", {"quantity": "blade_temp", "minutes": 30, "stat": "max"}), "where"),
    }
    for question, (call, concept) in cases.items():
        reply = engine.answer(question, Plan([call], "test"))
        assert reply["declined"] and concept in reply["missing"] and not reply["grounded"], (question, reply)
        assert reply["answer"].startswith("I can't answer that as asked")
        routed = engine.ask(question)  # the rules plan the right tool, and that answer is sent grounded
        assert not routed["declined"] and routed["grounded"], (question, routed)


@pytest.mark.parametrize(("question", "tool", "args"), [
    ("how much energy did the pumps use in the last hour?", "energy_used", {"what": "pumps"}),
    ("¿Cuánta energía consumió la refrigeración en los últimos 30 minutos?", "energy_used", {"minutes": 30.0}),
    ("Wie weit liegt der Vorlauf von Schrank 2 vom Sollwert entfernt?", "tracking_gap", {"cabinet": 2}),
    ("écart entre la consigne et l'eau de sortie de la tour 1 ?", "tracking_gap", {"level": "tower", "tower": 1}),
    ("where and when was the blade temperature highest in the last 20 minutes?", "peak", {"minutes": 20.0}),
    ("top 4 hottest blade groups", "rank", {"quantity": "blade_temp", "order": "highest", "top": 4,
                                            "level": "branch"}),
    ("is the plant saving energy compared with G36 right now?", "whatif_controller", {"controller": "g36"}),
    ("quel effet a la météo sur les tours ?", "weather_effect", {}),
])  # fmt: skip
def test_the_rules_route_the_operator_questions(question, tool, args):
    calls = RulePlanner().plan(question).calls
    assert [(c.tool, c.args) for c in calls] == [(tool, args)], calls


def test_a_multi_part_question_is_planned_part_by_part():
    assert split_parts("compare cabinet 2 and cabinet 4") == ["compare cabinet 2 and cabinet 4"]
    calls = RulePlanner().plan("energy used by the pumps in the last hour and the hottest cabinet").calls
    assert [c.tool for c in calls] == ["energy_used", "rank"]
    assert not uncovered("energy used by the pumps in the last hour and the hottest cabinet", calls)
