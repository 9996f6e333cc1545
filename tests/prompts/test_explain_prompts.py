"""The packaged explanation prompts render with real facts from the twin."""

from __future__ import annotations

from importlib import resources

import pytest

from lcmesh.mesh.tools.explain import PROMPT_NAMES, explanation_messages, load_prompt
from lcmesh.mesh.tools.explain_eval import LEVEL_SECTIONS
from lcmesh.mesh.tools.facts import cabinet_decision_facts
from tests.conftest import g36_decision_state


@pytest.fixture(scope="module")
def facts(lcopt5):
    """Facts of cabinet 3's decision half an hour into the Frontier day (G36)."""
    out, action, previous, wet_bulb = g36_decision_state(lcopt5, 120)
    return cabinet_decision_facts(lcopt5, out, action, previous, wet_bulb, 2)


def test_prompts_ship_as_package_data():
    shipped = {p.name for p in resources.files("lcmesh.prompts").iterdir()}
    assert {f"{name}.md" for name in PROMPT_NAMES} <= shipped


@pytest.mark.parametrize("name", PROMPT_NAMES)
def test_prompt_renders_with_real_facts(facts, name):
    messages = load_prompt(name).render(facts)
    assert [m["role"] for m in messages] == ["system", "user"]
    system, user = messages[0]["content"], messages[1]["content"]
    assert "$" not in system + user  # every placeholder filled
    assert "Cite only numbers that appear in the facts" in system
    for heading in LEVEL_SECTIONS[name.removeprefix("explain_")]:
        assert f"## {heading}" in user
    for fact in facts:  # the facts block carries every fact at its display precision
        assert f"- {fact.name} = {fact.display} (" in user
    for b in (1, 2, 3):
        assert f"- branch {b} valve fraction: " in user
    assert "Explain the decision for cabinet 3." in user
    assert "CDU supply temperature setpoint" in user and "leaving-water setpoint" in user


def test_level_helper_and_unknown_names(facts):
    assert explanation_messages(facts, "detailed") == load_prompt("explain_detailed").render(facts)
    with pytest.raises(ValueError, match="did you mean 'explain_short'"):
        load_prompt("explain_shrt")
