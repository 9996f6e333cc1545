"""Issue 12: every action reaches its setpoint where the plant allows, and moves the KPIs (lcmesh/bench/actions.py)."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from lcmesh.bench.actions import HELD, HeldSetpoints, render_actions, run_bench_actions, tracking
from lcmesh.bench.control import render_control
from lcmesh.cli import app

SHARES = ("supply_tracked", "dp_tracked", "tower_tracked")


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """Two hours of the Frontier day under the real loads and under LC-Opt's hardening."""
    return run_bench_actions(scenarios=("frontier", "lcopt"), hours=2.0, plot_dir=tmp_path_factory.mktemp("img"))


def _point(bench: dict, scenario: str, action: str, value) -> dict:
    points = bench["systems"]["lcopt-5"][scenario]["sweep"]["actions"][action]["points"]
    return next(p for p in points if p["value"] == value)


def test_the_static_rule_tracks_the_supply_setpoint_on_the_frontier_day():
    # the target: >= 80 % of (cabinet, step) within 0.5 K under a rule controller, default scenario
    row = tracking("lcopt-5", "frontier", "static", hours=2.0)
    assert row["controller"] == "static"
    assert all(0.0 <= row[k] <= 1.0 for k in SHARES)
    assert row["supply_tracked"] >= 0.8
    assert row["pue_cooling"] > 1.0 and row["fan_kwh"] >= 0.0 and row["pump_kwh"] > 0.0


def test_an_unreachable_supply_setpoint_is_reported_as_not_tracked(lcopt5):
    # +15 K wet bulb: the tower's water is far above 20 C, so no CDU can supply 20 C
    held = HeldSetpoints(lcopt5, **{**HELD, "supply_c": 20.0})
    row = tracking("lcopt-5", "lcopt", held, hours=1.0)
    assert row["supply_tracked"] < 0.5 and row["supply_median_miss_k"] > 0.5


def test_every_run_reports_shares_and_every_sweep_point_its_tracked_setpoint(bench):
    for scenario in bench["systems"]["lcopt-5"].values():
        for row in scenario["tracking"].values():
            assert all(0.0 <= row[k] <= 1.0 for k in SHARES)
        for action, a in scenario["sweep"]["actions"].items():
            assert isinstance(a["matters"], bool)
            for p in a["points"]:
                assert (p["tracked_share"] is None) == (action == "valves")


def test_the_inverse_valve_split_starves_the_hot_branches_under_the_25_to_1_skew(bench):
    proportional = _point(bench, "lcopt", "valves", "proportional")
    inverse = _point(bench, "lcopt", "valves", "inverse")
    assert inverse["d_blade_pct"] < proportional["d_blade_pct"] - 5.0
    assert inverse["blade_max_c"] > proportional["blade_max_c"] + 5.0
    assert bench["systems"]["lcopt-5"]["lcopt"]["sweep"]["actions"]["valves"]["matters"]


def test_the_dp_setpoint_moves_the_pump_energy(bench):
    low, high = _point(bench, "frontier", "dp_psi", 25.0), _point(bench, "frontier", "dp_psi", 38.0)
    assert high["pump_kwh"] > 1.1 * low["pump_kwh"] and high["dp_tracked"] >= 0.8


def test_the_rendered_section_holds_the_tables_verdicts_and_plot(bench):
    text = render_actions(bench)
    assert text.startswith("## Plant and scenarios: setpoint tracking and each action's effect (issue 12)")
    assert "### Setpoint tracking (lcopt-5)" in text and "| frontier | static |" in text
    assert "### Each action's effect: lcopt (lcopt-5)" in text and "| branch valve split | inverse |" in text
    assert text.count("- branch valve split: ") == 3 and "### Each action's effect: lcopt (lcopt-5-paper)" in text
    assert f"![actions]({bench['plot']})" in text
    control = {"machine": bench["machine"], "trace": "t", "hours": 2.0, "ablation": {}, "actions": bench}
    heading = "\n### Plant and scenarios: setpoint tracking and each action's effect (issue 12)\n"
    assert heading in render_control(control)


def test_cli_bench_actions_writes_json_and_its_benchmarks_section(tmp_path):
    runner = CliRunner()
    assert runner.invoke(app, ["bench", "actions", "--help"]).exit_code == 0
    out, md = tmp_path / "actions.json", tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\nkept text\n")
    args = ["bench", "actions", "--hours", "0.25", "--json", str(out), "--markdown", str(md), "--plots", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data["systems"]["lcopt-5"]) == {"frontier", "design-day", "lcopt"}
    text = md.read_text()
    assert "kept text" in text and text.count("<!-- bench:actions:start -->") == 1
    assert (tmp_path / "actions.png").is_file()
