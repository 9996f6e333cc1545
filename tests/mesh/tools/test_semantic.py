"""The semantic check: numbers bound to entity and quantity, rankings and directions against the data."""

from __future__ import annotations

from lcmesh.mesh.tools.semantic import Bound, Ranking, canonical_entity, check

VALUES = [
    Bound("37.7", "cabinet 5", "blade_temp"), Bound("36.6", "cabinet 2", "blade_temp"),
    Bound("36.4", "cabinet 4", "blade_temp"), Bound("4.6", "plant", "wet_bulb"),
    Bound("0.1", "plant", "tower_power", signed=-0.06), Bound("1.032", "plant", "pue"),
]  # fmt: skip
RANKS = [Ranking("blade_temp", "highest", "cabinet 5")]


def kinds(text: str) -> list[str]:
    return [p.kind for p in check(text, VALUES, RANKS)]


def test_a_true_text_passes():
    assert kinds("Cabinet 5 runs hottest at 37.7 °C. Next: cabinet 2 36.6 °C, cabinet 4 36.4 °C.") == []
    assert kinds("The wet bulb is 4.6 °C and the cooling PUE 1.032.") == []


def test_inverting_hottest_and_coolest_is_caught():
    assert kinds("Cabinet 5 runs coolest at 37.7 °C.") == ["wrong_rank"]
    assert "wrong_rank" in kinds("Cabinet 3 runs hottest.")


def test_a_value_moved_to_another_entity_is_caught():
    assert kinds("Cabinet 3 is at 36.6 °C.") == ["wrong_entity"]
    assert kinds("36.6 °C in cabinet 4.") == ["wrong_entity"]


def test_one_quantitys_value_given_for_another_is_caught():
    assert kinds("The wet bulb is 37.7 °C.") == ["wrong_quantity"]


def test_a_number_the_data_does_not_hold_is_caught():
    assert kinds("The wet bulb is 4.7 °C.") == ["unbound_number"]


def test_directions_must_match_the_sign_of_the_change():
    assert kinds("Tower fan power went down 0.1 kW.") == []
    assert kinds("Tower fan power went up 0.1 kW.") == ["wrong_direction"]
    problems = check("Raised the supply setpoint from 25.7 to 25.1.", [Bound("25.7"), Bound("25.1")])
    assert [p.kind for p in problems] == ["wrong_direction"]


def test_entities_are_read_as_operators_write_them():
    assert canonical_entity("CDU", "3") == "cabinet 3"
    assert canonical_entity("branch", "2", "Cabinet", "03") == "branch 2 of cabinet 3"
    assert kinds("CDU 5 runs hottest at 37.7 °C.") == []
