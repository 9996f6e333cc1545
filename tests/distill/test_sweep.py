"""``lcmesh train sweep``: seeds x grid points as engine units, each in its own folder; a re-run trains only what is
new or gone; bad settings are refused before anything trains."""

from __future__ import annotations

import shutil

import pytest
from typer.testing import CliRunner

from lcmesh.bench.engine import EngineSettings
from lcmesh.cli import app
from lcmesh.distill.ppo_config import PpoConfig
from lcmesh.distill.sweep import parse_grid, run_sweep, sweep_configs

TINY = ["total_env_steps=100", "n_envs=2", "episode_steps=50", "eval_every=1", "eval_hours=0.25",
        "eval_trace=synthetic:1002", "system=lcopt-5"]  # fmt: skip


def test_a_grid_is_typed_as_the_settings_and_names_the_folders(tmp_path):
    grid = parse_grid(["reward=lcopt,energy", "ent_coef=0.01", "guardrails=true"])
    assert grid == {"reward": ["lcopt", "energy"], "ent_coef": [0.01], "guardrails": [True]}
    configs = sweep_configs(PpoConfig(case=6, out=str(tmp_path)), [0, 1], grid)
    assert [c.out.rsplit("/", 1)[1] for c in configs] == [
        "reward=lcopt-seed0", "reward=lcopt-seed1", "reward=energy-seed0", "reward=energy-seed1"]
    assert {c.ent_coef for c in configs} == {0.01} and {c.case for c in configs} == {6}


@pytest.mark.parametrize("item, says", [("seed=1,2", "not a PPO setting"), ("nope=1", "not a PPO setting"),
                                        ("ent_coef=lots", "not a float"), ("reward", "name=v1,v2")])  # fmt: skip
def test_bad_grid_items_are_refused(item, says):
    with pytest.raises(ValueError, match=says):
        parse_grid([item])


def test_a_rerun_trains_only_what_is_new_or_gone(tmp_path):
    settings = EngineSettings(engine="serial", cache=tmp_path / "units.sqlite")
    configs = sweep_configs(PpoConfig(case=6, out=str(tmp_path / "runs")), [0, 1], parse_grid(TINY))
    first = run_sweep(configs, settings)
    assert [o.error for o in first] == [None, None] and not any(o.cached for o in first)
    again = run_sweep(configs, settings)
    assert [o.cached for o in again] == [True, True]
    assert [o.result for o in again] == [o.result for o in first]
    shutil.rmtree(tmp_path / "runs" / "case6-seed1")  # a run folder removed: that run trains again
    third = run_sweep(configs, settings)
    assert [o.cached for o in third] == [True, False]
    assert (tmp_path / "runs" / "case6-seed1" / "best.json").exists()


def test_the_cli_refuses_a_bad_setting_before_training(tmp_path):
    result = CliRunner().invoke(app, ["train", "sweep", "--grid", "n_envs=0", "--out", str(tmp_path), "--engine",
                                      "serial"])  # fmt: skip
    assert result.exit_code == 2 and "n_envs" in result.output
    assert not any(tmp_path.iterdir())
