"""Issue 13: the held-out suite of days, declared once, and every controller's figures on it (lcmesh/bench/suite.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lcmesh.bench import suite
from lcmesh.bench.suite import (
    FIGURES, REGRET, TEST_DAYS, TRAVEL, VALIDATION_DAYS, Day, assert_disjoint, days_named, load_day, plot_pareto,
    render_suite, run_suite,
)  # fmt: skip
from lcmesh.cli import app
from lcmesh.distill.tree_config import TreeDistillConfig
from lcmesh.twin.traces import EVAL_SEEDS, FRONTIER_DAY, TRAIN_SEEDS

DAY_KEYS = {*FIGURES, "it_kwh", "travel", "heat_recovered_kwh", "guardrails"}
LABELS = ("frontier", "mild-1010", "hot-1003")  # one Frontier, one mild and one hot day


@pytest.fixture(scope="module")
def result():
    """Half an hour of three days under static and G36 (the reference), and a name that builds nothing."""
    return run_suite(["static", "g36", "no-such-controller"], days=days_named(LABELS), hours=0.5, reference="g36")


class FailsMidRun:
    """A controller that builds but raises on its first action (named "tests.twin.test_suite:FailsMidRun")."""

    name, version = "fails-mid-run", "1"

    def __init__(self, system):
        pass

    def reset(self) -> None:
        pass

    def act(self, obs):
        raise RuntimeError("no setpoints today")


def _seed(day: Day) -> int | None:
    return int(day.trace.removeprefix("synthetic:")) if day.trace.startswith("synthetic:") else None


def test_the_declared_days_are_held_out_and_span_frontier_mild_and_hot_days():
    assert_disjoint()
    assert len(TEST_DAYS) >= 10 and len(VALIDATION_DAYS) >= 4
    assert any(d.trace == FRONTIER_DAY for d in TEST_DAYS)
    synthetic = [d for d in TEST_DAYS if _seed(d) is not None]
    assert sum(d.scenario == "frontier" for d in synthetic) >= 6  # mild: the trace's own weather
    assert sum(d.scenario == "design-day" for d in synthetic) >= 4  # hot: Knoxville's design wet bulb
    held_out = [_seed(d) for d in TEST_DAYS + VALIDATION_DAYS if _seed(d) is not None]
    assert all(s in EVAL_SEEDS and s not in TRAIN_SEEDS for s in held_out)
    assert not {d.trace for d in TEST_DAYS} & {d.trace for d in VALIDATION_DAYS}


@pytest.mark.parametrize("leak", ["validation", "training", "tree distiller"])
def test_assert_disjoint_catches_a_test_day_that_leaks(monkeypatch, leak):
    if leak == "validation":
        monkeypatch.setattr(suite, "VALIDATION_DAYS", (*VALIDATION_DAYS, Day("synthetic:1010", "frontier", "v")))
    elif leak == "training":
        monkeypatch.setattr(suite, "TEST_DAYS", (*TEST_DAYS, Day("synthetic:7", "frontier", "leak-7")))
    else:  # a test day on one of the distiller's reward traces
        monkeypatch.setattr(suite, "TEST_DAYS", (*TEST_DAYS, Day("synthetic:1105", "design-day", "leak-1105")))
    with pytest.raises(AssertionError, match=leak):
        suite.assert_disjoint()


def test_the_tree_distillers_seeds_run_no_held_out_day():
    seeds = TreeDistillConfig().trace_seeds()
    assert set(seeds) == {"train_seeds", "heldout_seed", "reward_seeds"}
    for field, values in seeds.items():
        assert suite.held_out_days_in(f"synthetic:{s}" for s in values) == [], field
    evaluation = seeds["heldout_seed"] + seeds["reward_seeds"]
    assert all(s in EVAL_SEEDS for s in evaluation) and not set(evaluation) & set(seeds["train_seeds"])
    assert len(seeds["reward_seeds"]) == 10  # Tables 12 and 14: 10 episodes
    # the seeds the shipped trees were distilled with ran four test days' traces (two of them as the very day)
    with pytest.raises(ValueError, match=r"`reward_seeds` must not run on the bench suite's test or validation "
                       r"days, got mild-1010 \(synthetic:1010\), mild-1019 .*hot-1016 .*hot-1011"):  # fmt: skip
        TreeDistillConfig(reward_seeds="1010-1019")
    with pytest.raises(ValueError, match=r"`heldout_seed` .* got hot-1003 \(synthetic:1003\)"):
        TreeDistillConfig(heldout_seed=1003)


def test_an_unknown_day_label_names_the_closest_one():
    with pytest.raises(ValueError, match="did you mean 'mild-1019'"):
        days_named(["mild-101"])


def test_a_day_loads_under_its_own_scenario(lcopt5):
    hot = load_day(days_named(["frontier-hot"])[0], lcopt5, hours=1.0)
    mild = load_day(days_named(["frontier"])[0], lcopt5, hours=1.0)
    assert hot.scenario == "design-day" and mild.scenario == "frontier"
    assert (hot.cabinet_load_w == mild.cabinet_load_w).all()  # the same loads ...
    assert hot.wet_bulb_k.mean() > mild.wet_bulb_k.mean() + 10.0  # ... under the design day's wet bulb


def test_every_day_and_the_mean_and_std_carry_the_figures(result):
    assert [d["label"] for d in result["days"]] == list(LABELS)
    for name in ("static", "g36"):
        entry = result["controllers"][name]
        assert entry["error"] is None and list(entry["days"]) == list(LABELS)
        for day in entry["days"].values():
            assert set(day) == DAY_KEYS and set(day["travel"]) == set(TRAVEL)
            assert day["cooling_kwh"] == pytest.approx(day["tower_fan_kwh"] + day["pump_kwh"])
            assert day["pue_cooling"] == pytest.approx(1.0 + day["cooling_kwh"] / day["it_kwh"])
            assert 0.0 <= day["d_blade_pct"] <= 100.0 and day["pump_kwh"] > 0.0
        for stat in ("mean", "std"):
            assert set(entry[stat]) == {*FIGURES, "travel"} and set(entry[stat]["travel"]) == set(TRAVEL)
        cooling = [d["cooling_kwh"] for d in entry["days"].values()]
        assert entry["mean"]["cooling_kwh"] == pytest.approx(sum(cooling) / len(cooling))
        assert entry["std"]["cooling_kwh"] > 0.0  # three different days
    # G36 moves the CDU supply setpoint with the load; the static rule holds it
    assert result["controllers"]["g36"]["mean"]["travel"]["supply_temp_setpoint_k"] > 0.0
    assert result["controllers"]["static"]["mean"]["travel"]["supply_temp_setpoint_k"] == 0.0


def test_regret_is_zero_for_the_reference_and_the_difference_for_the_others(result):
    assert result["reference"] == "g36" and result["regret_note"] is None
    ref, static = result["controllers"]["g36"], result["controllers"]["static"]
    assert all(ref["regret"]["mean"][k] == 0.0 and ref["regret"]["std"][k] == 0.0 for k in REGRET)
    for label in LABELS:
        regret, mine, theirs = static["regret"]["days"][label], static["days"][label], ref["days"][label]
        assert regret["cooling_kwh"] == pytest.approx(mine["cooling_kwh"] - theirs["cooling_kwh"])
        assert regret["d_blade_pts"] == pytest.approx(theirs["d_blade_pct"] - mine["d_blade_pct"])


def test_a_controller_that_fails_to_build_is_reported_not_raised(result):
    failed = result["controllers"]["no-such-controller"]
    assert failed["error"].startswith("build failed") and "unknown controller" in failed["error"]
    assert failed["days"] == {} and "mean" not in failed and "regret" not in failed
    json.dumps(result)  # the whole result, errors included, is plain JSON


def test_a_controller_that_fails_mid_run_is_reported_with_the_day():
    r = run_suite(["tests.twin.test_suite:FailsMidRun"], days=days_named(["mild-1010"]), hours=0.25, reference="static")
    failed = r["controllers"]["tests.twin.test_suite:FailsMidRun"]
    assert failed["error"] == "run on mild-1010 failed: RuntimeError: no setpoints today" and failed["days"] == {}


def test_regret_is_skipped_with_a_note_when_the_reference_is_missing_or_broken():
    days = days_named(["frontier"])
    absent = run_suite(["static"], days=days, hours=0.25, reference="g36")
    assert "not among the controllers" in absent["regret_note"] and "regret" not in absent["controllers"]["static"]
    broken = run_suite(["static", "no-such-controller"], days=days, hours=0.25, reference="no-such-controller")
    assert "failed" in broken["regret_note"] and "regret" not in broken["controllers"]["static"]
    assert "Regret: no regret" in render_suite(broken)


def test_run_suite_refuses_an_empty_controller_list():
    with pytest.raises(ValueError, match="at least one controller"):
        run_suite([], days=days_named(["frontier"]), hours=0.25)


def test_the_rendered_section_holds_the_tables_the_days_and_the_machine(result):
    text = render_suite(result)
    g36 = result["controllers"]["g36"]
    assert suite.SUITE_HEADER in text
    assert f"| g36 | {g36['mean']['d_blade_pct']:.2f} ± {g36['std']['d_blade_pct']:.2f} | " in text
    assert "### Per day: D_blade % / cooling kWh" in text and "| day | static | g36 |" in text
    for label in LABELS:
        assert f"| {label} | " in text
    assert "no-such-controller | not run: build failed" in text
    assert result["machine"]["cpu"] in text and "commit" in text


def test_the_pareto_plot_is_written(result, tmp_path):
    path = plot_pareto(result, tmp_path / "img" / "suite_pareto.png")
    assert path.is_file() and path.stat().st_size > 10_000


def test_the_cli_writes_json_markdown_and_plot_and_answers_bad_input(tmp_path):
    runner = CliRunner()
    md, out = tmp_path / "BENCHMARKS.md", tmp_path / "suite.json"
    args = ["bench", "suite", "--controllers", "static", "--days", "frontier", "--hours", "0.25", "--reference", "static",
            "--json", str(out), "--markdown", str(md), "--plots", str(tmp_path / "img")]  # fmt: skip
    ran = runner.invoke(app, args)
    assert ran.exit_code == 0, ran.output
    written = json.loads(out.read_text())
    assert written["controllers"]["static"]["error"] is None and written["plot"].endswith("suite_pareto.png")
    assert "<!-- bench:suite:start -->" in md.read_text() and "](" + written["plot"] + ")" in md.read_text()
    assert written["plot_days"].endswith("suite_days.png") and Path(written["plot_days"]).stat().st_size > 10_000
    assert "](" + written["plot_days"] + ")" in md.read_text()
    assert "Units (lcmesh/bench/engine.py): 1 unit computed at commit" in md.read_text()
    bad_day = runner.invoke(app, ["bench", "suite", "--controllers", "static", "--days", "mild-101"])
    assert bad_day.exit_code == 2 and "did you mean 'mild-1019'" in bad_day.output
    no_controller = runner.invoke(app, ["bench", "suite", "--controllers", ","])
    assert no_controller.exit_code == 2 and "at least one controller" in no_controller.output


def test_a_warmup_runs_unscored_and_the_kpis_cover_the_window(lcopt5):
    from lcmesh.twin.controllers import make_controller
    from lcmesh.twin.plant import Plant
    from lcmesh.twin.run import run_twin

    trace = suite.load_day(suite.days_named(["hot-1033"])[0], lcopt5, hours=0.5)  # 120 steps
    with Plant(lcopt5) as plant:
        whole = run_twin(plant, trace, make_controller("g36", lcopt5))
        warmup = run_twin(plant, trace, make_controller("g36", lcopt5), n_steps=80)
        window = run_twin(plant, trace, make_controller("g36", lcopt5), score_from=80)
        with pytest.raises(ValueError, match="score_from"):
            run_twin(plant, trace, make_controller("g36", lcopt5), score_from=120)
    assert window.sim_seconds == 40 * trace.step_s and whole.sim_seconds == 120 * trace.step_s
    for key in ("pump_power_kw_avg", "ct_power_kw_avg"):  # the same deterministic run, split at step 80
        assert 80 * warmup.kpi[key] + 40 * window.kpi[key] == pytest.approx(120 * whole.kpi[key], rel=1e-6)


def test_the_busiest_window_is_picked_from_the_load_alone(lcopt5):
    import numpy as np

    from lcmesh.bench.llm import busiest_window

    trace = suite.load_day(suite.days_named(["frontier"])[0], lcopt5)
    start = busiest_window(trace, 240)
    load = trace.cabinet_load_w.sum(axis=1)
    means = np.convolve(load, np.ones(240) / 240, mode="valid")
    assert means[start] == pytest.approx(means.max())
    assert busiest_window(trace.slice(0, 100), 240) == 0  # a window longer than the trace starts at its first step
