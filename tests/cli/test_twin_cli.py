"""The ``lcmesh twin`` commands as a user runs them."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from lcmesh.cli import app

runner = CliRunner()


def test_twin_run_writes_the_design_kpis_and_a_plot(tmp_path):
    out = tmp_path / "run.json"
    result = runner.invoke(app, ["twin", "run", "--system", "lcopt-5", "--trace", "frontier-2024-04-07",
                                 "--hours", "2", "--controller", "static", "--json", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert {"d_blade_pct", "ct_power_kw_avg", "it_cooling_kw_avg", "energy_balance_error_pct"} <= set(data["kpi"])
    assert data["sim_seconds"] == 7200 and data["wall_seconds"] > 0
    assert data["realtime_factor"] == data["sim_seconds"] / data["wall_seconds"]
    assert 0 <= data["kpi"]["d_blade_pct"] <= 100 and abs(data["kpi"]["energy_balance_error_pct"]) < 0.5
    assert (tmp_path / "run.png").stat().st_size > 20_000


def test_twin_run_on_a_synthetic_trace(tmp_path):
    result = runner.invoke(app, ["twin", "run", "--trace", "synthetic:1234", "--hours", "0.5",
                                 "--json", str(tmp_path / "s.json")])  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "s.json").read_text())
    assert data["trace"] == "synthetic:1234"
    assert data["guardrails"]["guardrails"] == "mesh" and data["guardrails"]["steps"] == 120  # the mesh's, by default
    assert "guardrails (the mesh's):" in result.output
    bare = runner.invoke(app, ["twin", "run", "--trace", "synthetic:1234", "--hours", "0.5", "--no-guardrails",
                               "--json", str(tmp_path / "bare.json")])  # fmt: skip
    assert bare.exit_code == 0, bare.output
    assert json.loads((tmp_path / "bare.json").read_text())["guardrails"] == {"guardrails": "off"}
    assert "guardrails off" in bare.output


def test_bad_input_is_a_clear_error_not_a_traceback(tmp_path):
    bad_system = runner.invoke(app, ["twin", "run", "--system", "lcopt-6"])
    assert bad_system.exit_code == 2 and "unknown system 'lcopt-6'" in bad_system.output
    bad_trace = runner.invoke(app, ["twin", "run", "--trace", "synthetic:x"])
    assert bad_trace.exit_code == 2 and "synthetic" in bad_trace.output
    bad_controller = runner.invoke(app, ["twin", "run", "--controller", "statik"])
    assert bad_controller.exit_code == 2 and "did you mean 'static'" in bad_controller.output
    bad_hours = runner.invoke(app, ["twin", "run", "--hours", "-1"])
    assert bad_hours.exit_code == 2 and "--hours" in bad_hours.output
    corrupt = tmp_path / "corrupt.json"
    corrupt.write_text('{"name": "x", "cabinets": {"count": 0, "branches": 3}, "towers": {"count": 1, "cells": 1}}')
    bad_desc = runner.invoke(app, ["twin", "run", "--system", str(corrupt)])
    assert bad_desc.exit_code == 2 and "cabinets.count" in bad_desc.output


def test_twin_build_validates_the_fmu(tmp_path):
    result = runner.invoke(app, ["twin", "build", "--system", "lcopt-5", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "lcopt-5.fmu").exists()


def test_twin_validate_json(tmp_path):
    out = tmp_path / "validate.json"
    result = runner.invoke(app, ["twin", "validate", "--system", "lcopt-5", "--json", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    names = {c["name"] for c in report["checks"]}
    physics = {"energy_balance", "blade_band", "setpoint_step", "flow_monotonic", "setpoint_monotonic", "tower_fan"}
    published = {"cooling_pue", "cdu_pump_power", "facility_flow", "facility_temperatures", "g36_in_band"}
    assert report["passed"] and physics | published <= names
    assert all("source" in c for c in report["checks"] if c["name"] in published)


def test_twin_run_with_the_g36_baseline(tmp_path):
    out = tmp_path / "g36.json"
    result = runner.invoke(app, ["twin", "run", "--controller", "g36", "--hours", "1", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["controller"] == "g36"
