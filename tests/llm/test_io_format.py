"""The controller prompt renders the observation; the strict parser accepts good answers and says why it rejects."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.llm.io_format import (
    CabinetDecision, CabinetView, ParseFailure, answer_text, cabinet_views, controller_messages, parse_cabinet_answer,
)  # fmt: skip
from lcmesh.twin.system import PSI_TO_PA

VIEW = CabinetView((30.14, 31.2, 29.0), (33.0, 34.55, 31.0), (50.0, 60.0, 90.0), 21.04, 24.5, 18.3)


def test_prompt_shows_every_observed_number_and_no_placeholder():
    system, user = controller_messages(VIEW)
    assert system["role"] == "system" and user["role"] == "user"
    text = system["content"] + user["content"]
    assert "$" not in text
    for shown in ("30.1/33.0", "31.2/34.5", "29.0/31.0", "50.0", "90.0", "21.0", "24.5", "18.3", "0.45",
                  "cabinet 200.0 kW", "hottest 34.5"):
        assert shown in user["content"], shown
    assert "3 fractions" in system["content"]


def test_one_blade_group_per_branch_shows_one_temperature():
    view = CabinetView((30.0, 31.0, 32.0), (30.0, 31.0, 32.0), (10.0, 10.0, 20.0), 21.0, 24.5, 18.3)
    user = controller_messages(view)[1]["content"]
    assert "1, 30.0, 10.0, 0.25" in user and "/" not in user


def test_good_answer_parses_to_si_and_normalized_valves():
    d = parse_cabinet_answer(' {"supply_c": 27.5, "dp_psi": 30, "valves": [0.5, 0.3, 0.21]}\n', 3)
    assert isinstance(d, CabinetDecision)
    assert d.supply_temp_setpoint_k == pytest.approx(300.65)
    assert d.dp_setpoint_pa == pytest.approx(30 * PSI_TO_PA)
    assert sum(d.valve_fractions) == pytest.approx(1.0)
    assert d.valve_fractions[0] == pytest.approx(0.5 / 1.01)


def test_answer_text_round_trips_within_its_precision():
    valves = np.array([0.812, 0.127, 0.061])
    d = parse_cabinet_answer(answer_text(294.12, 33.4 * PSI_TO_PA, valves), 3)
    assert isinstance(d, CabinetDecision)
    assert d.supply_temp_setpoint_k == pytest.approx(294.12, abs=0.051)
    assert d.dp_setpoint_pa / PSI_TO_PA == pytest.approx(33.4, abs=0.06)
    np.testing.assert_allclose(d.valve_fractions, valves, atol=0.01)


@pytest.mark.parametrize(
    "text, reason, field",
    [
        ("", "empty", ""),
        ("Sure! Here is the action", "not_json", ""),
        ('{"supply_c": 27, "dp_psi": 30, "valves": [0.4, 0.3, 0.3]} thanks', "not_json", ""),
        ('```json\n{"supply_c": 27, "dp_psi": 30, "valves": [0.4, 0.3, 0.3]}\n```', "not_json", ""),
        ("[27, 30, 0.4, 0.3, 0.3]", "not_json", ""),
        ('{"supply_c": NaN, "dp_psi": 30, "valves": [0.4, 0.3, 0.3]}', "not_json", ""),
        ('{"supply_c": 27, "dp_psi": 30}', "schema", "valves"),
        ('{"supply_c": "27", "dp_psi": 30, "valves": [0.4, 0.3, 0.3]}', "schema", "supply_c"),
        ('{"supply_c": 27, "dp_psi": 30, "valves": [0.4, 0.3, 0.3], "note": "hi"}', "schema", "note"),
        ('{"supply_c": 45.2, "dp_psi": 30, "valves": [0.4, 0.3, 0.3]}', "out_of_bounds", "supply_c"),
        ('{"supply_c": 27, "dp_psi": 12, "valves": [0.4, 0.3, 0.3]}', "out_of_bounds", "dp_psi"),
        ('{"supply_c": 27, "dp_psi": 30, "valves": [0.5, 0.5]}', "valves_count", "valves"),
        ('{"supply_c": 27, "dp_psi": 30, "valves": [1.2, -0.2, 0.0]}', "valves_negative", "valves"),
        ('{"supply_c": 27, "dp_psi": 30, "valves": [0.6, 0.6, 0.6]}', "valves_sum", "valves"),
    ],
)
def test_bad_answers_are_rejected_with_a_reason(text, reason, field):
    result = parse_cabinet_answer(text, 3)
    assert isinstance(result, ParseFailure)
    assert result.reason == reason
    assert field in result.detail


def test_views_come_from_plant_outputs(plant, lcopt5):
    out = plant.reset()
    power = np.arange(15, dtype=float).reshape(5, 3) * 1e3
    views = cabinet_views(out, power, 290.15)
    assert len(views) == lcopt5.cabinets.count
    assert views[2].branch_power_kw == (6.0, 7.0, 8.0)
    assert views[0].wet_bulb_c == pytest.approx(17.0)
    assert views[1].branch_temp_c[0] == pytest.approx(out["branch_temp_k"][1, 0] - 273.15)


def test_tower_prompt_shows_the_tower_from_1_and_its_answer_parses_strictly():
    from lcmesh.llm.io_format import TowerDecision, parse_tower_answer, tower_answer_text, tower_messages, tower_views

    out = {"ct_leaving_temp_k": np.array([297.15, 299.15]), "cell_fan_power_w": np.array([[30e3, 0.0], [60e3, 60e3]]),
           "applied_lw_setpoint_k": np.array([296.15, 296.15]), "branch_max_temp_k": np.array([[310.15, 311.65]]),
           "htw_return_temp_k": np.array([303.15])}  # fmt: skip
    views = tower_views(out, 291.15, fan_nominal_w=60e3)
    assert [v.tower for v in views] == [1, 2]
    user = tower_messages(views[1])[1]["content"]
    assert "tower 2: fans 100/100 %" in user and "approach now 5.0 K" in user and "hottest blade 38.5" in user
    assert parse_tower_answer(tower_answer_text(3.5)) == TowerDecision(3.5)
    for bad, reason in (("", "empty"), ("approach 4", "not_json"), ("[4]", "not_json"), ('{"approach_k": 8.5}', "out_of_bounds"),
                        ('{"approach_k": 4, "x": 1}', "schema"), ('{"approach_k": NaN}', "not_json")):  # fmt: skip
        failure = parse_tower_answer(bad)
        assert failure.reason == reason, (bad, failure)
