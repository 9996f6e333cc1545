"""The twin benchmark runs end to end (figures are judged in BENCHMARKS.md, not here)."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from lcmesh.cli import app


@pytest.mark.slow  # a benchmark run (19 s); `make test-slow` and `lcmesh bench twin`
def test_bench_twin_quick_writes_every_figure(tmp_path):
    out, md = tmp_path / "twin.json", tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\nkept text\n")
    result = CliRunner().invoke(app, ["bench", "twin", "--quick", "--json", str(out), "--markdown", str(md)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert {"cabinet", "tower", "parallel"} <= set(data["env_lcopt5"])
    assert data["frontier_full_day"]["steps"] == 5760 and data["frontier_full_day"]["blade_groups"] > 9000
    assert data["fmi2_raw_vs_list"]["raw_fmi2_steps_per_s"] > 0 and data["machine"]["cpu"]
    text = md.read_text()
    assert "kept text" in text and "frontier-full" in text and text.count("<!-- bench:twin:start -->") == 1
