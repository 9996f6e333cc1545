"""``lcmesh distill llm`` and ``lcmesh bench llm`` as a user calls them (argument checks; the runs are benchmarks)."""

from __future__ import annotations

from typer.testing import CliRunner

from lcmesh.cli import app

runner = CliRunner()


def test_distill_llm_refuses_an_unknown_teacher_naming_the_choices():
    result = runner.invoke(app, ["distill", "llm", "--teacher", "sac", "--out", "/nonexistent"])
    assert result.exit_code == 2
    assert "teacher" in result.output and "ppo" in result.output


def test_distill_llm_help_lists_the_training_knobs():
    result = runner.invoke(app, ["distill", "llm", "--help"])
    assert result.exit_code == 0
    for option in ("--teacher", "--samples", "--epochs", "--quant", "--out", "--explain-samples"):
        assert option in result.output


def test_bench_llm_help_lists_its_options():
    result = runner.invoke(app, ["bench", "llm", "--help"])
    assert result.exit_code == 0
    for option in ("--json", "--markdown", "--quick", "--hours", "--period"):
        assert option in result.output
