"""The semantic check: numbers bound to entity and quantity, rankings and directions against the data."""

from __future__ import annotations

import pytest

from lcmesh.mesh.tools.semantic import ENTITY, canonical_entity, check, rank_fact
from lcmesh.mesh.tools.semantic import value_fact as Bound
from lcmesh.mesh.tools.vocab import DIRECTION_WORDS

VALUES = [
    Bound("37.7", "cabinet 5", "blade_temp"), Bound("36.6", "cabinet 2", "blade_temp"),
    Bound("36.4", "cabinet 4", "blade_temp"), Bound("4.6", "plant", "wet_bulb"),
    Bound("0.1", "plant", "tower_power", signed=-0.06), Bound("1.032", "plant", "pue"),
]  # fmt: skip
RANKS = [rank_fact("blade_temp", "highest", "cabinet 5")]


def kinds(text: str) -> list[str]:
    """Each failed claim's flag, with its reason where the flag is an ungrounded number ("ungrounded_number:
    wrong_entity")."""
    return [_kind(c) for c in check(text, VALUES, RANKS)]


def _kind(c) -> str:
    reason = c.extra.get("reason")
    return f"{c.flag.kind}:{reason}" if reason else c.flag.kind


def test_a_true_text_passes():
    assert kinds("Cabinet 5 runs hottest at 37.7 °C. Next: cabinet 2 36.6 °C, cabinet 4 36.4 °C.") == []
    assert kinds("The wet bulb is 4.6 °C and the cooling PUE 1.032.") == []


def test_inverting_hottest_and_coolest_is_caught():
    assert kinds("Cabinet 5 runs coolest at 37.7 °C.") == ["wrong_ranking"]
    assert "wrong_ranking" in kinds("Cabinet 3 runs hottest.")


def test_a_value_moved_to_another_entity_is_caught():
    assert kinds("Cabinet 3 is at 36.6 °C.") == ["ungrounded_number:wrong_entity"]
    assert kinds("36.6 °C in cabinet 4.") == ["ungrounded_number:wrong_entity"]


def test_one_quantitys_value_given_for_another_is_caught():
    assert kinds("The wet bulb is 37.7 °C.") == ["ungrounded_number:wrong_quantity"]


def test_a_number_the_data_does_not_hold_is_caught():
    assert kinds("The wet bulb is 4.7 °C.") == ["ungrounded_number:no_value"]


def test_directions_must_match_the_sign_of_the_change():
    assert kinds("Tower fan power went down 0.1 kW.") == []
    assert kinds("Tower fan power went up 0.1 kW.") == ["wrong_direction"]
    problems = check("Raised the supply setpoint from 25.7 to 25.1.", [Bound("25.7"), Bound("25.1")])
    assert [p.flag.kind for p in problems] == ["wrong_direction"]


def test_entities_are_read_as_operators_write_them():
    assert canonical_entity("CDU", "3") == "cabinet 3"
    assert canonical_entity("branch", "2", "Cabinet", "03") == "branch 2 of cabinet 3"
    assert kinds("CDU 5 runs hottest at 37.7 °C.") == []


# --- the four languages (vocab.py, shared with the explanation judge) ------------------------------------------------
# (language, a true sentence, the same with another cabinet's value, with the ranking inverted, fan power the wrong way)
SENTENCES = [
    ("en", "Cabinet 5 runs hottest at 37.7 °C.", "Cabinet 3 is at 36.6 °C.", "Cabinet 2 runs hottest at 36.6 °C.",
     "Tower fan power went up 0.1 kW."),
    ("es", "El gabinete 5 es el más caliente con 37.7 °C.", "El gabinete 3 está a 36.6 °C.",
     "El gabinete 2 es el más caliente con 36.6 °C.", "La potencia de ventiladores subió 0.1 kW."),
    ("de", "Schrank 5 ist am heißesten mit 37.7 °C.", "Schrank 3 liegt bei 36.6 °C.",
     "Schrank 2 ist am heißesten mit 36.6 °C.", "Die Lüfterleistung stieg um 0.1 kW."),
    ("fr", "L'armoire 5 est la plus chaude à 37.7 °C.", "L'armoire 3 est à 36.6 °C.",
     "L'armoire 2 est la plus chaude à 36.6 °C.", "La puissance des ventilateurs a augmenté de 0.1 kW."),
]  # fmt: skip


@pytest.mark.parametrize(("lang", "true", "moved", "inverted", "wrong_way"), SENTENCES, ids=[s[0] for s in SENTENCES])
def test_the_guard_reads_each_language(lang, true, moved, inverted, wrong_way):
    assert kinds(true) == []
    assert kinds(moved) == ["ungrounded_number:wrong_entity"]
    assert kinds(inverted) == ["wrong_ranking"]
    assert kinds(wrong_way) == ["wrong_direction"]


def test_entity_words_of_every_language_and_blade_groups():
    names = {canonical_entity(*m.groups()) for m in ENTITY.finditer(
        "gabinete 2, Schrank 3, l'armoire 4, rama 1 del gabinete 2, Zweig 2 von Schrank 3, la branche 3 de l'armoire 4, "
        "torre 1, Turm 2, tour 3, grupo de blades 2 de la rama 1, Blade-Gruppe 3, blade group 4 of branch 2")}  # fmt: skip
    assert names == {"cabinet 2", "cabinet 3", "cabinet 4", "branch 1 of cabinet 2", "branch 2 of cabinet 3",
                     "branch 3 of cabinet 4", "tower 1", "tower 2", "tower 3", "blade group 2 of branch 1",
                     "blade group 3", "blade group 4 of branch 2"}  # fmt: skip
    # a value after an entity word is not the entity's number: "the hottest blade group 35.0 °C", "towers 48 kW"
    assert not list(ENTITY.finditer("the hottest blade group 35.0 °C; ventiladores de las torres 48 kW"))
    values = [Bound("41.2", "blade group 2 of branch 1 of cabinet 3", "blade_temp")]
    assert check("Blade group 2 of branch 1 of cabinet 3 is at 41.2 °C.", values) == []
    assert [_kind(p) for p in check("Blade group 3 of branch 1 is at 41.2 °C.", values)] == ["ungrounded_number:wrong_entity"]


@pytest.mark.parametrize("lang", ["es", "de", "fr"])
def test_every_up_and_down_word_is_read_its_way(lang):
    """The direction words the judge reads (vocab.DIRECTION_WORDS) are the guard's too: each checked against a
    change of +0.1."""
    raised = [Bound("0.1", "plant", "supply_setpoint", signed=0.1)]
    for pol in ("up", "down"):
        for word in DIRECTION_WORDS[pol][lang]:
            got = [_kind(p) for p in check(f"Supply {word} 0.1.", raised)]
            assert got == ([] if pol == "up" else ["wrong_direction"]), word
