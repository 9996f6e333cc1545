"""validate's fan/pump split of the cooling power (docs/twin.md, "Fan and pump split"), without running the twin."""

from __future__ import annotations

import pytest

from lcmesh.twin.validate import CITED_FAN_SHARE_PCT, FAN_SPLIT_DOC, fan_pump_split, split_row

# frontier-full, G36 on the Frontier day without guardrails (docs/twin.md, "Fan and pump split"), in kW
FRONTIER_FULL_DAY = {"fans_kw": 7.0, "cdu_pumps_kw": 312.1, "htw_pumps_kw": 112.6, "tower_pumps_kw": 274.0,
                     "cooling_kw": 705.7, "installed_fans_kw": 746.0}  # fmt: skip


def _day(scenario: str, **changes) -> dict:
    return {"scenario": scenario, "cooling_split": {**FRONTIER_FULL_DAY, **changes}}


def test_split_reports_each_group_and_the_fan_share():
    row = split_row("frontier", FRONTIER_FULL_DAY)
    assert row["fan_share_pct"] == pytest.approx(100 * 7.0 / 705.7, rel=1e-6)
    assert row["fan_share_without_cdu_pumps_pct"] == pytest.approx(100 * 7.0 / (705.7 - 312.1), rel=1e-6)
    # every installed fan at full speed against the same pumps: still short of the cited 73 %
    assert row["fan_share_at_full_speed_pct"] == pytest.approx(100 * 746.0 / (746.0 + 698.7), rel=1e-6)
    assert row["fan_share_at_full_speed_pct"] < CITED_FAN_SHARE_PCT
    assert row["cited_fan_share_pct"] == CITED_FAN_SHARE_PCT


def test_a_share_outside_the_cited_range_points_at_the_documented_limit():
    assert split_row("frontier", FRONTIER_FULL_DAY)["status"] == f"outside: documented limit ({FAN_SPLIT_DOC})"
    # fans at three quarters of the cooling power, as the cited plant: inside
    fans_like_source = {**FRONTIER_FULL_DAY, "fans_kw": 2000.0, "cooling_kw": 2698.7}
    assert split_row("frontier", fans_like_source)["status"] == "inside the cited range"


def test_split_passes_only_when_the_groups_add_up_to_the_cooling_power():
    check = fan_pump_split([_day("frontier"), _day("design-day", fans_kw=71.8, cooling_kw=770.5)])
    assert check["passed"], check["rows"]
    assert [r["scenario"] for r in check["rows"]] == ["frontier", "design-day"]
    # a consumer the four groups miss (cooling power 10 kW above their sum) fails the check
    assert not fan_pump_split([_day("frontier"), _day("design-day", cooling_kw=715.7)])["passed"]
    assert not fan_pump_split([_day("frontier", htw_pumps_kw=-1.0, cooling_kw=592.1)])["passed"]
