"""Decision facts on a real lcopt-5 twin state (G36, an hour into the Frontier day)."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.mesh.tools.explain_eval import evaluate_record
from lcmesh.mesh.tools.facts import (
    K0,
    cabinet_decision_facts,
    efficiency_score,
    facts_by_name,
    spearman_rho,
    stability_score,
    tower_decision_facts,
)
from tests.conftest import g36_decision_state
from lcmesh.twin.system import PSI_TO_PA


@pytest.fixture(scope="module")
def state(lcopt5):
    """(system, out, action, previous action, wet bulb) after 240 G36 steps; `out` is a copy."""
    return (lcopt5, *g36_decision_state(lcopt5, 240))


def test_branch_rankings_follow_the_observation(state):
    system, out, action, previous, wb = state
    for c in range(system.cabinets.count):
        f = facts_by_name(cabinet_decision_facts(system, out, action, previous, wb, c))
        temps_c, power_w = out["branch_temp_k"][c] - K0, out["branch_power_w"][c]
        assert f["cabinet"].value == c + 1
        assert f["hottest_branch"].value == int(temps_c.argmax()) + 1  # facts count branches from 1
        assert f["coolest_branch"].value == int(temps_c.argmin()) + 1
        assert f["most_loaded_branch"].value == int(power_w.argmax()) + 1
        assert f["hottest_branch_temp"].value == pytest.approx(temps_c.max(), abs=1e-3)
        assert f["cabinet_power"].value == pytest.approx(power_w.sum() / 1e3, abs=1e-2)
        shares = [f[f"branch_{j}_power_share"].value for j in (1, 2, 3)]
        assert sum(shares) == pytest.approx(1.0, abs=1e-3)
        valves = [f[f"branch_{j}_valve_fraction"].value for j in (1, 2, 3)]
        assert valves == pytest.approx(action.valve_fractions[c], abs=1e-4)


def test_valve_split_alignment(state):
    system, out, action, previous, wb = state
    shares = out["branch_power_w"][0] / out["branch_power_w"][0].sum()
    follows, against = action.copy(), action.copy()
    follows.valve_fractions[0] = shares
    order = np.argsort(shares)
    against.valve_fractions[0][order] = shares[order[::-1]]  # the most loaded branch gets the smallest valve, ...
    eq = facts_by_name(cabinet_decision_facts(system, out, action, previous, wb, 0))  # G36: equal split
    assert (eq["valve_split"].value, eq["valve_power_spearman"].value) == ("equal", 0.0)
    fo = facts_by_name(cabinet_decision_facts(system, out, follows, previous, wb, 0))
    assert fo["valve_split"].value == "follows load"
    assert fo["valve_power_spearman"].value == pytest.approx(1.0)
    assert fo["valve_power_l1"].value == pytest.approx(0.0, abs=1e-6)
    assert fo["most_opened_branch"].value == fo["most_loaded_branch"].value
    ag = facts_by_name(cabinet_decision_facts(system, out, against, previous, wb, 0))
    assert ag["valve_power_spearman"].value < 0 and ag["valve_split"].value == "against load"


def test_spearman_handles_ties():
    assert spearman_rho(np.array([1.0, 2.0, 3.0]), np.array([10.0, 20.0, 30.0])) == pytest.approx(1.0)
    assert spearman_rho(np.array([1.0, 1.0, 1.0]), np.array([1.0, 2.0, 3.0])) == 0.0
    assert spearman_rho(np.array([1.0, 1.0, 2.0]), np.array([1.0, 2.0, 3.0])) == pytest.approx(0.866, abs=1e-3)


def test_setpoint_changes_against_the_previous_action(state):
    system, out, action, previous, wb = state
    prev = action.copy()
    prev.supply_temp_setpoint_k[2] += 0.5
    prev.dp_setpoint_pa[2] -= 1.0 * PSI_TO_PA
    prev.lw_setpoint_k[:] -= 0.3
    prev.valve_fractions[2] = [0.5, 0.25, 0.25]
    f = facts_by_name(cabinet_decision_facts(system, out, action, prev, wb, 2))
    assert (f["supply_setpoint_change"].value, f["supply_setpoint_direction"].value) == (pytest.approx(-0.5), "lowered")
    assert (f["dp_setpoint_change"].value, f["dp_setpoint_direction"].value) == (pytest.approx(1.0), "raised")
    assert (f["tower_lw_change"].value, f["tower_lw_direction"].value) == (pytest.approx(0.3), "raised")
    assert f["branch_1_valve_change"].value == pytest.approx(1 / 3 - 0.5, abs=1e-4)
    same = facts_by_name(cabinet_decision_facts(system, out, action, action, wb, 2))
    assert same["supply_setpoint_direction"].value == "held" and same["tower_lw_direction"].value == "held"
    none = facts_by_name(cabinet_decision_facts(system, out, action, None, wb, 2))
    assert none["supply_setpoint_direction"].value == "set" and "supply_setpoint_change" not in none


def test_tower_approach_and_cdu_heat_balance(state):
    system, out, action, previous, wb = state
    f = facts_by_name(cabinet_decision_facts(system, out, action, previous, wb, 1))
    lw_c = float(np.mean(action.lw_setpoint_k)) - K0
    assert f["tower_approach_setpoint"].value == pytest.approx(lw_c - (wb - K0), abs=1e-3)
    assert f["tower_approach_setpoint"].value > 0  # G36 keeps the leaving water above the wet bulb
    dt = out["return_temp_k"][1] - out["supply_temp_k"][1]
    assert f["secondary_heat_flow"].value == pytest.approx(out["secondary_flow_kg_s"][1] * 4186.0 * dt / 1e3, rel=1e-4)
    # the twin conserves energy: m c_p dT on the secondary side is within a few % of the blade heat (storage aside)
    assert abs(f["heat_balance_gap"].value) < 10.0
    assert f["cdu_heat"].value == pytest.approx(out["cdu_heat_w"][1] / 1e3, abs=1e-2)


def test_scores_follow_their_definitions(state):
    assert stability_score(np.array([30.0, 30.0, 30.0])) == 1.0
    assert stability_score(np.array([38.0, 30.0, 30.0])) == pytest.approx((0.4 + 1 + 1) / 3)
    assert stability_score(np.array([41.0, 19.0, 30.0])) == pytest.approx(1 / 3)
    assert efficiency_score(10.0) == 0.5 and efficiency_score(0.0) == 0.0
    assert efficiency_score(5.0) < efficiency_score(20.0) < 1.0
    system, out, action, previous, wb = state
    f = facts_by_name(cabinet_decision_facts(system, out, action, previous, wb, 0))
    assert f["stability_score"].value == pytest.approx(stability_score(out["branch_temp_k"][0] - K0), abs=1e-4)
    cop = f["cooling_cop"].value
    assert f["efficiency_score"].value == pytest.approx(cop / (cop + 10.0), abs=1e-4)
    assert 0.0 <= f["stability_score"].value <= 1.0 and 0.0 <= f["efficiency_score"].value <= 1.0


def test_tower_decision_facts(state):
    system, out, action, previous, wb = state
    for t in range(system.towers.count):
        f = facts_by_name(tower_decision_facts(system, out, action, previous, wb, t))
        assert f["tower"].value == t + 1
        assert f["tower_approach"].value == pytest.approx(out["approach_k"][t], abs=0.05)
        assert f["tower_fan_power"].value == pytest.approx(out["cell_fan_power_w"][t].sum() / 1e3, abs=1e-2)
        # the tower's water-side heat is the plate heat exchanger's heat, up to basin storage
        assert f["tower_heat_rejected"].value == pytest.approx(out["ehx_heat_w"][t] / 1e3, rel=0.1)
        assert 0.0 < f["efficiency_score"].value < 1.0


def test_bad_input_names_the_field(state):
    system, out, action, previous, wb = state
    with pytest.raises(ValueError, match="`cabinet` must be in 0..4"):
        cabinet_decision_facts(system, out, action, previous, wb, 5)
    with pytest.raises(ValueError, match="`tower` must be in 0..1"):
        tower_decision_facts(system, out, action, previous, wb, -1)
    broken = dict(out, branch_temp_k=out["branch_temp_k"].copy())
    broken["branch_temp_k"][3, 1] = np.nan
    with pytest.raises(ValueError, match="`branch_temp_k` of cabinet 3 must be finite"):
        cabinet_decision_facts(system, broken, action, previous, wb, 3)


def test_every_fact_text_is_grounded_in_the_facts(state):
    """Each fact's own sentence passes the evaluator against the facts alone."""
    system, out, action, previous, wb = state
    facts = cabinet_decision_facts(system, out, action, previous, wb, 4)
    text = ". ".join(f.text for f in facts) + "."
    record = {"id": "facts", "observation": {}, "action": {}, "explanation": text,
              "facts": [f.model_dump() for f in facts]}  # fmt: skip
    item = evaluate_record(record)
    assert item["numbers"]["checked"] > 40
    assert item["numeric_grounding"] == 1.0, item["flags"]
