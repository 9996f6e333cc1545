"""The operator views' own arithmetic and words: cooling PUE, the wet bulb's label, what a decision changed."""

from __future__ import annotations

import pytest

from lcmesh.mesh.agents.ui.views import MAX_CHANGES, action_changes, clamp_view, cooling_pue, wet_bulb_note


def _action(supply=(30.0, 30.0, 30.0), dp=(27.5, 27.5, 27.5), lw=(25.0, 25.0), valves=None) -> dict:
    """An action view (°C, psi, fractions) of a 3-cabinet, 3-branch, 2-tower plant."""
    return {"supply_temp_setpoint_c": list(supply), "dp_setpoint_psi": list(dp), "lw_setpoint_c": list(lw),
            "valve_fractions": [list(r) for r in (valves or [[0.31, 0.33, 0.36]] * 3)]}  # fmt: skip


def test_cooling_pue_is_it_plus_fans_plus_pumps_over_it():
    assert cooling_pue(1_000_000.0, 20_000.0, 30_000.0) == pytest.approx(1.05)
    assert cooling_pue(0.0, 20_000.0, 30_000.0) is None  # no IT load: no ratio


def test_the_wet_bulb_is_labelled_exactly_when_it_is_not_the_recorded_one():
    assert wet_bulb_note("frontier", 0.0) is None
    assert wet_bulb_note("lcopt", 15.0) == "recorded + 15 K, scenario lcopt"
    assert wet_bulb_note("frontier", -5.0) == "recorded − 5 K, scenario frontier"  # LCMESH_WET_BULB_OFFSET_K alone
    assert wet_bulb_note("design-day", 0.0) == "design day knoxville-0.4, scenario design-day"


def test_a_decision_says_what_changed_numbered_from_one():
    before = _action()
    after = _action(supply=(30.5, 30.5, 30.5), lw=(25.0, 26.0),
                    valves=[[0.31, 0.33, 0.36], [0.31, 0.33, 0.36], [0.26, 0.33, 0.41]])  # fmt: skip
    assert action_changes(before, after) == [
        "supply setpoint 30.0 → 30.5 °C (all cabinets)",  # alike on every cabinet: said once
        "tower 2 leaving-water setpoint 25.0 → 26.0 °C",
        "cabinet 3 branch 1 valve 0.31 → 0.26",
        "cabinet 3 branch 3 valve 0.36 → 0.41",
    ]
    one = action_changes(before, _action(supply=(30.0, 30.0, 29.5), dp=(27.5, 28.0, 27.5)))
    assert one == ["cabinet 3 supply setpoint 30.0 → 29.5 °C", "cabinet 2 dp setpoint 27.5 → 28.0 psi"]


def test_changes_below_the_pages_resolution_are_no_change():
    """What the page would print the same is not a change: such steps collapse into one row of the feed."""
    wiggle = _action(supply=(30.01, 30.0, 29.99), valves=[[0.311, 0.329, 0.36]] * 3)
    assert action_changes(_action(), wiggle) == []


def test_a_long_list_of_changes_is_cut_and_counted():
    after = _action(valves=[[0.2, 0.3, 0.5]] * 3)  # 9 valve moves
    items = action_changes(_action(), after)
    assert len(items) == MAX_CHANGES + 1 and items[-1] == f"{9 - MAX_CHANGES} more"


def test_clamp_indices_count_from_one_at_the_api():
    clamp = {"field": "valve_fractions", "index": [0, 2], "proposed": 0.0, "applied": 0.05, "reason": "below v_min"}
    assert clamp_view(clamp)["index"] == [1, 3] and clamp["index"] == [0, 2]  # the bus's clamp is left as it was
