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


def test_bench_llm_keeps_validation_days_out_of_benchmarks_md(tmp_path):
    result = runner.invoke(app, ["bench", "llm", "--sections", "loop", "--days", "val-hot-1993",
                                 "--markdown", str(tmp_path / "B.md")])  # fmt: skip
    assert result.exit_code != 0 and "validation days are for choosing settings" in " ".join(result.output.split())
    assert not (tmp_path / "B.md").exists()
    result = runner.invoke(app, ["bench", "llm", "--sections", "loop", "--days", "val-hot-199"])
    assert result.exit_code != 0 and "did you mean 'val-hot-1993'" in " ".join(result.output.split())
