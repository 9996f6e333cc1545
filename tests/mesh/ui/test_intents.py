"""The chat's deterministic intent classifier: examples of each rule, parsing of indices, windows and changes."""

from __future__ import annotations

import pytest

from lcmesh.assistant.intents import classify
from lcmesh.twin.system import PSI_TO_PA


@pytest.mark.parametrize(("text", "kind", "quantity"), [
    ("which cabinet runs hottest?", "rank", "blade_temp"),
    ("Which cabinet is the COOLEST?", "rank", "blade_temp"),
    ("tower power now vs an hour ago", "compare", "tower_power"),
    ("pump power over the last 30 minutes", "compare", "pump_power"),
    ("why did cabinet 3 open branch 2?", "why", "valve"),
    ("what if I raise the supply setpoint 2 K?", "whatif", "supply_setpoint"),
    ("what would happen if we lower the dp by 2 psi", "whatif", "dp"),
    ("set the supply setpoint of cabinet 2 to 30 °C", "command", "supply_setpoint"),
    ("please switch to g36", "command", None),
    ("any alerts?", "alerts", None),
    ("is something wrong with the pumps?", "alerts", "pump_power"),
    ("are all agents up?", "agents", None),
    ("which controller is running?", "controller", None),
    ("what is the wet bulb?", "state", "wet_bulb"),
    ("how much heat is rejected?", "state", "heat_rejected"),
    ("status", "state", None),
    ("tell me a joke", "help", None),
    ("", "help", None),
])  # fmt: skip
def test_intents_and_quantities(text, kind, quantity):
    intent = classify(text)
    assert (intent.kind, intent.quantity) == (kind, quantity)


def test_indices_windows_and_directions_are_read():
    intent = classify("why did cabinet 3 close branch 2?")
    assert (intent.cabinet, intent.branch, intent.direction) == (3, 2, "down")
    assert classify("why was the supply setpoint raised?").direction == "up"
    assert classify("tower 2 fan power").tower == 2
    assert classify("CDU 4 supply temperature").cabinet == 4
    assert classify("tower power now vs an hour ago").window_s == 3600
    assert classify("blade temperature over the last 15 min").window_s == 900
    assert classify("IT power trend over the last hour").window_s == 3600
    assert classify("heat rejected 2 hours ago").window_s == 7200


def test_changes_carry_sign_unit_and_kind():
    up = classify("what if I raise the supply setpoint 2 K?").change
    assert (up.quantity, up.amount, up.absolute) == ("supply_setpoint", 2.0, False)
    down = classify("what if I lower the supply setpoint of cabinet 3 by 1.5 K?").change
    assert down.amount == -1.5 and classify("what if I lower the supply setpoint of cabinet 3 by 1.5 K?").cabinet == 3
    to = classify("set the dp setpoint to 30 psi").change
    assert to.quantity == "dp" and to.absolute and to.amount == pytest.approx(30 * PSI_TO_PA)
    kpa = classify("what if I lower the dp by 10 kPa").change
    assert kpa.amount == pytest.approx(-10_000.0)
    lw = classify("lower the leaving water setpoint by 1 K").change
    assert (lw.quantity, lw.amount) == ("lw_setpoint", -1.0)
    assert classify("set the supply setpoint of cabinet 2 to 30 °C").change.amount == 30.0  # not the "2" of cabinet 2
    assert classify("what if I raise the supply setpoint?").change is None


def test_user_text_is_only_matched():
    intent = classify("__import__('os').system('rm -rf /'); set the supply setpoint to 30 °C")
    assert intent.kind in ("command", "state", "help") and (intent.change is None or intent.change.amount == 30.0)
    assert classify("switch to the static controller; DROP TABLE actions;").controller == "static"
