"""The controllers' CLI: shipped policies run through `twin run`; bad options get clear errors."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from lcmesh.cli import app

runner = CliRunner()


def test_twin_run_with_the_shipped_ppo_and_tree_controllers(tmp_path):
    for controller in ("ppo", "tree"):
        out = tmp_path / f"{controller}.json"
        result = runner.invoke(app, ["twin", "run", "--controller", controller, "--hours", "1", "--json", str(out)])
        assert result.exit_code == 0, result.output
        data = json.loads(out.read_text())
        assert data["controller"] == controller
        assert 0.0 <= data["kpi"]["d_blade_pct"] <= 100.0 and data["kpi"]["steps"] == 240


def test_bad_options_are_clear_errors(tmp_path):
    result = runner.invoke(app, ["train", "ppo", "--case", "9"])
    assert result.exit_code == 2 and "`case` must be one of" in result.output
    result = runner.invoke(app, ["distill", "tree", "--train-seeds", "a-b"])
    assert result.exit_code == 2 and "`train_seeds` must look like" in result.output
    result = runner.invoke(app, ["distill", "tree", "--reward-seeds", "1010-1019"])
    assert result.exit_code == 2 and "the bench suite's test or validation days" in result.output
    result = runner.invoke(app, ["twin", "run", "--controller", "ppo", "--policy", str(tmp_path / "none"), "--hours", "1"])
    assert result.exit_code == 2 and "lcmesh train ppo" in result.output
