"""100 scripted chat questions over the real mesh: every number in every answer is a fact, and every fact
matches the data it cites, re-read here independently (SQLite rows and stored plant states, the
system description, the question text)."""

from __future__ import annotations

import json
import re
import sqlite3

import numpy as np
import pytest

from lcmesh.mesh.agents.ui.facts import format_value, numbers_in
from lcmesh.mesh.messages import PlantState
from lcmesh.twin.system import PSI_TO_PA
from tests.mesh.conftest import wait_until

K0 = 273.15
CONVERT = {"c": lambda v: v - K0, "kw": lambda v: v / 1e3, "psi": lambda v: v / PSI_TO_PA, "pct": lambda v: v * 100,
           "raw": lambda v: v}  # fmt: skip
REDUCE = {"max": np.max, "min": np.min, "mean": np.mean, "sum": np.sum}


def scripted_questions() -> list[str]:
    """A fixed script covering every intent, cabinet, branch and tower of lcopt-5."""
    qs = ["which cabinet runs hottest?", "which cabinet is the coolest?", "status", "how is the plant now?",
          "tower power now vs an hour ago", "pump power now vs 10 minutes ago", "blade temperature over the last 30 min",
          "wet bulb compared to 5 minutes ago", "IT power trend over the last hour", "heat rejected since 2 hours ago",
          "what if I raise the supply setpoint 2 K?", "what if I lower the supply setpoint by 1.5 K?",
          "what if I set the dp setpoint to 30 psi?", "what if I raise the leaving water setpoint by 1 K?",
          "what would happen if I lower the dp by 2 psi on cabinet 4?", "what if I raise the supply setpoint 1 K in 5 minutes?",
          "what if I raise the supply setpoint by 30 K?", "any alerts?", "are all agents up?",
          "which controller is running?", "switch to g36", "switch to manual mode", "raise the dp setpoint by 1 psi",
          "lower the leaving water setpoint by 1 K", "why did the controller lower the supply setpoint?",
          "why was the supply setpoint raised?", "why did the tower setpoint change?", "why?", "hello",
          "what is the wet bulb?", "what is the cooling power?", "how much heat is rejected?", "what is the it power?",
          "what is the pump power?", "tower fan power", "leaving water temperature", "share of blades in band",
          "what is the supply temperature?", "what is the dp?", "total flow", "cabinet 9 temperature",
          "tower 3 fan power", "why did cabinet 2 open branch 7?"]  # fmt: skip
    for c in range(1, 6):
        qs += [f"blade temperature of cabinet {c}", f"supply temperature of cabinet {c}",
               f"valve split of cabinet {c}", f"why did cabinet {c} open branch {1 + c % 3}?",
               f"what if I lower the supply setpoint of cabinet {c} by 1 K?",
               f"set the supply setpoint of cabinet {c} to {27 + c} °C", f"IT power of cabinet {c}",
               f"pump power of cabinet {c}", f"return temperature of cabinet {c}", f"dp of cabinet {c}",
               f"why did cabinet {c} close branch {1 + (c + 1) % 3}?"]  # fmt: skip
    for t in (1, 2):
        qs += [f"tower {t} fan power", f"leaving water temperature of tower {t}", f"tower {t} leaving water setpoint"]
    return qs


class Data:
    """Independent reads of the history file."""

    def __init__(self, path):
        self.db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        self.db.row_factory = sqlite3.Row

    def state(self, run_id: str, step: int) -> PlantState:
        row = self.db.execute("SELECT payload FROM plant_states WHERE run_id=? AND step=?", (run_id, step)).fetchone()
        assert row is not None and row["payload"], f"no stored state for step {step}"
        return PlantState.model_validate_json(row["payload"])

    def summary(self, run_id: str, step: int, field: str) -> float:
        row = self.db.execute(f"SELECT {field} FROM plant_states WHERE run_id=? AND step=?", (run_id, step)).fetchone()
        return float(row[0])

    def summaries(self, run_id: str, first: int, last: int, field: str) -> list[float]:
        rows = self.db.execute(f"SELECT {field} FROM plant_states WHERE run_id=? AND step BETWEEN ? AND ?",
                               (run_id, first, last)).fetchall()  # fmt: skip
        return [float(r[0]) for r in rows]

    def action(self, run_id: str, step: int) -> dict:
        row = self.db.execute("SELECT * FROM actions WHERE run_id=? AND step=?", (run_id, step)).fetchone()
        assert row is not None, f"no applied action for step {step}"
        out = dict(row)
        out["action"], out["clamps"] = json.loads(out["action"]), json.loads(out["clamps"])
        return out


def expected_value(f: dict, data: Data, question: str, system):
    """The value the fact's reference points at, or None where the reference is not a re-readable datum."""
    ref, source = f["ref"], f["source"]
    if source == "state":
        state = data.state(ref["run_id"], ref["step"])
        if ref.get("field") == "step":
            return state.step
        if ref.get("field") == "time_s":
            return state.time_s * ref["scale"]
        if "sum_of" in ref:
            return sum(CONVERT[ref["convert"]](state.outputs[b][0]) for b in ref["sum_of"])
        raw = np.asarray([state.wet_bulb_k] if ref["block"] == "wet_bulb_k" else state.outputs[ref["block"]], float)
        if ref.get("reduce") == "in_band_pct":
            t = raw - K0
            return float(np.mean((t > ref["band_c"][0]) & (t < ref["band_c"][1])) * 100)
        if "per" in ref:  # an index fact: which cabinet / branch / tower owns raw[index]
            n = ref["index"] // ref["per"]
            return (n % ref["modulo"] if "modulo" in ref else n) + 1
        over = raw if ref.get("over") is None else raw[ref["over"]]
        if "index" in ref:
            if ref.get("reduce"):  # the fact claims raw[index] is the extreme
                assert raw[ref["index"]] == REDUCE[ref["reduce"]](over), f"{f['name']} is not the {ref['reduce']}"
            return CONVERT[ref["convert"]](raw[ref["index"]])
        return CONVERT[ref["convert"]](float(REDUCE[ref["reduce"]](over)))
    if source == "history":
        if "stat" in ref:
            values = data.summaries(ref["run_id"], ref["start_step"], ref["end_step"], ref["field"])
            return CONVERT[ref["convert"]]({"min": min, "max": max}[ref["stat"]](values))
        if ref.get("field") == "time_s" and "steps" in ref:
            a, b = (data.state(ref["run_id"], s).time_s for s in ref["steps"])
            return (b - a) * ref["scale"]
        if "step" in ref:
            return CONVERT[ref["convert"]](data.summary(ref["run_id"], ref["step"], ref["field"]))
        return None  # derived (now - then): checked through its parts
    if source == "decision":
        if "toolbox" in ref:
            from lcmesh.mesh.messages import ActionModel, plant_state_to_observation
            from lcmesh.mesh.tools.facts import cabinet_decision_facts

            state = data.state(ref["run_id"], ref["step"])
            now, prev = data.action(ref["run_id"], ref["step"]), data.action(ref["run_id"], ref["step"] - 1)
            facts = cabinet_decision_facts(system, plant_state_to_observation(state, system).out,
                                           ActionModel.model_validate(now["action"]).to_action(),
                                           ActionModel.model_validate(prev["action"]).to_action(), state.wet_bulb_k,
                                           ref["cabinet"])  # fmt: skip
            value = {x.name: x.value for x in facts}[ref["toolbox"]]
            return value * ref.get("scale", 1.0) if not isinstance(value, str) else value
        if "path" not in ref:
            return None
        row = data.action(ref["run_id"], ref["step"])
        path = ref["path"]
        if path[0] == "action":
            value = row["action"][path[1]]
            if "over" in ref:
                return float(np.mean([CONVERT[ref["convert"]](value[i]) for i in ref["over"]]))
            for key in path[2:]:
                value = value[key]
            return CONVERT[ref["convert"]](value)
        if path == ["clamps"]:
            return sum(1 for c in row["clamps"] if c["index"] and c["index"][0] == ref["cabinet"]
                       and c["field"] != "lw_setpoint_k")  # fmt: skip
        return row[path[0]]
    if source == "whatif":
        if "si" in ref:
            convert = CONVERT[ref["convert"]] if "convert" in ref else (lambda v: v * ref["scale"])
            return convert(ref["si"])
        return None
    if source == "question":
        words = ref["words"].lower()
        assert words in question.lower(), f"{f['name']}: {words!r} is not in the question"
        return None
    if source == "system":
        counts = {"cabinets": system.cabinets.count, "branches": system.cabinets.branches, "towers": system.towers.count}
        attribute = ref["attribute"]
        if attribute.endswith("_number"):  # an item number must exist
            assert 1 <= f["value"] <= counts[attribute.split("_")[0] + "s" if attribute.startswith(("cabinet", "tower")) else "branches"], f
            return f["value"]
        return {**counts, "numbering": 1, "blade_band_low_c": 20.0, "blade_band_high_c": 40.0}.get(attribute)
    return None


@pytest.fixture(scope="module")
def answers(ui_mesh):
    with ui_mesh.client() as http:
        assert wait_until(lambda: http.get("/api/state").json()["step"] >= 150, 60)
        out = []
        for q in scripted_questions():
            r = http.post("/api/chat", json={"message": q})
            assert r.status_code == 200, (q, r.status_code, r.text)
            out.append((q, r.json()))
        return out


def test_the_script_has_a_hundred_questions_over_every_intent(answers):
    assert len(answers) >= 100
    intents = {a["intent"] for _, a in answers}
    assert intents >= {"state", "rank", "compare", "why", "whatif", "command", "alerts", "agents", "controller", "help"}


def test_every_number_in_every_answer_is_a_fact(answers):
    for question, a in answers:
        assert a["grounded"], (question, a["answer"])
        allowed = set()
        for f in a["facts"]:
            allowed.update(numbers_in(f["display"]))
            if isinstance(f["value"], str):
                allowed.update(numbers_in(f["value"]))
        loose = [n for n in numbers_in(a["answer"]) if n not in allowed]
        assert not loose, (question, a["answer"], loose)


def test_every_fact_matches_the_data_it_cites(answers, ui_mesh, lcopt5):
    data = Data(ui_mesh.settings.history_file)
    checked = 0
    for question, a in answers:
        for f in a["facts"]:
            assert f["display"] == format_value(f["value"], f["unit"]), f
            expected = expected_value(f, data, question, lcopt5)
            if expected is None:
                continue
            if isinstance(expected, str) or isinstance(f["value"], str):
                assert str(expected) == str(f["value"]), (question, f)
            else:
                assert abs(float(expected) - float(f["value"])) <= 1e-3 + 1e-6 * abs(float(expected)), (question, f, expected)
            checked += 1
    assert checked >= 300, checked


def test_whatif_and_commands_carry_a_request_but_change_nothing(answers, ui_mesh):
    whatifs = [a for q, a in answers if a["intent"] == "whatif" and a["proposed_command"]]
    assert len(whatifs) >= 5
    for a in whatifs:
        names = {f["name"] for f in a["facts"]}
        assert {"baseline_blade", "predicted_blade", "horizon"} <= names
        assert a["proposed_command"]["path"] == "/api/control/setpoints"
    horizons = {f["value"] for _, a in answers if a["intent"] == "whatif" for f in a["facts"] if f["name"] == "horizon"}
    assert {1, 5} <= horizons, horizons  # the default one-minute look-ahead, and "in 5 minutes"
    commands = [a for _, a in answers if a["intent"] == "command"]
    assert all(re.search(r"Chat does not change the plant", a["answer"]) for a in commands)
    with ui_mesh.client() as http:
        assert http.get("/api/config").json()["config"]["mode"] == "auto"
