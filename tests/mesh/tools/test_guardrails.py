from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from lcmesh.mesh.tools.guardrails import GuardrailLimits, apply_guardrails, check_action, project_valve_split
from lcmesh.twin.plant import PlantAction


def _action(lcopt5, supply=300.0, dp=190e3, valves=None, lw=295.0):
    C, B, N = lcopt5.cabinets.count, lcopt5.cabinets.branches, lcopt5.towers.count
    return PlantAction(np.full(C, supply), np.full(C, dp), np.full((C, B), 1 / B) if valves is None else valves,
                       np.full(N, lw))  # fmt: skip


def test_an_action_inside_every_limit_passes_unchanged(lcopt5):
    a = _action(lcopt5)
    r = apply_guardrails(a, a.copy(), 285.0, GuardrailLimits(), lcopt5)
    assert r.rejected is None and r.clamps == []
    for x, y in zip(a.astuple(), r.action.astuple()):
        np.testing.assert_allclose(x, y)


def test_range_and_rate_clamps_are_reported_with_field_index_and_reason(lcopt5):
    limits = GuardrailLimits()
    previous = _action(lcopt5)
    proposed = _action(lcopt5)
    proposed.supply_temp_setpoint_k[1] = 400.0  # outside the range
    proposed.supply_temp_setpoint_k[2] = 300.0 + 10.0  # inside the range, too fast
    r = apply_guardrails(proposed, previous, 285.0, limits, lcopt5)
    by_index = {c.index[0]: c for c in r.clamps if c.field == "supply_temp_setpoint_k"}
    assert set(by_index) == {1, 2}
    assert "outside" in by_index[1].reason and by_index[1].proposed == 400.0
    assert by_index[1].applied == pytest.approx(300.0 + limits.supply_temp_rate_k)
    assert "rate limit" in by_index[2].reason
    assert r.action.supply_temp_setpoint_k[2] == pytest.approx(300.0 + limits.supply_temp_rate_k)


def test_tower_approach_wins_over_the_rate_limit(lcopt5):
    limits = GuardrailLimits(min_approach_k=3.0)
    previous = _action(lcopt5, lw=290.0)
    r = apply_guardrails(_action(lcopt5, lw=290.0), previous, 295.0, limits, lcopt5)
    assert np.all(r.action.lw_setpoint_k >= 298.0 - 1e-9)
    assert any("minimum approach" in c.reason for c in r.clamps)


def test_valves_end_up_at_least_v_min_and_summing_to_one(lcopt5):
    valves = np.tile([0.0, 0.2, 0.9], (lcopt5.cabinets.count, 1))
    previous = _action(lcopt5, valves=np.tile([0.1, 0.2, 0.7], (lcopt5.cabinets.count, 1)))
    r = apply_guardrails(_action(lcopt5, valves=valves), previous, 285.0, GuardrailLimits(), lcopt5)
    v = r.action.valve_fractions
    np.testing.assert_allclose(v.sum(axis=1), 1.0)
    assert v.min() >= 0.05 - 1e-12
    assert any(c.field == "valve_fractions" and "v_min" in c.reason for c in r.clamps)


@pytest.mark.parametrize("row", [[0.0, 0.0, 1.0], [3.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.33, 0.33, 0.33]])
def test_valve_projection(row):
    out = project_valve_split(np.array(row), 0.05)
    assert out.sum() == pytest.approx(1.0)
    assert out.min() >= 0.05 - 1e-12


def test_malformed_actions_are_rejected_not_clamped(lcopt5):
    bad = _action(lcopt5)
    bad.supply_temp_setpoint_k[0] = np.nan
    r = apply_guardrails(bad, _action(lcopt5), 285.0, GuardrailLimits(), lcopt5)
    assert r.action is None and "non-finite" in r.rejected and "supply_temp_setpoint_k" in r.rejected
    wrong = _action(lcopt5, valves=np.full((5, 2), 0.5))
    assert "`valve_fractions` must have shape (5, 3)" in check_action(wrong, lcopt5)


def test_limits_validate_themselves_and_against_the_plant(lcopt5):
    with pytest.raises(ValidationError, match="`dp_min_pa`"):
        GuardrailLimits(dp_min_pa=300e3)
    with pytest.raises(ValueError, match="valve_fraction_min"):
        GuardrailLimits(valve_fraction_min=0.4).check_system(lcopt5)


def test_the_vectorized_split_is_the_row_by_row_split():
    from lcmesh.mesh.tools.guardrails import project_valve_splits

    rng = np.random.default_rng(7)
    for _ in range(200):
        rows = rng.normal(0.3, 0.4, (int(rng.integers(1, 8)), 3))
        rows[0] = 0.0 if rng.random() < 0.2 else rows[0]
        v_min = float(rng.choice([0.0, 0.02, 0.05, 0.2]))
        expected = np.array([project_valve_split(row, v_min) for row in rows])
        np.testing.assert_allclose(project_valve_splits(rows, v_min), expected, atol=1e-12)
