"""lcmesh/bench/mesh.py: the figures of a speed level, the BENCHMARKS.md section, and a short real run."""

from __future__ import annotations

import pytest

from lcmesh.bench.mesh import _level_figures, _Recorder, measure_latency, render_mesh
from lcmesh.mesh.messages import ActionModel, AppliedAction
from tests.mesh.conftest import free_port


def _applied(step, fallback=False, late_ms=0.0, latency=2.0):
    return AppliedAction(source="s", run_id="r", step=step, time_s=15.0 * step, source_controller="g36",
                         source_version="1", action=ActionModel(supply_temp_setpoint_k=[300.0], dp_setpoint_pa=[1e5],
                                                                valve_fractions=[[1.0]], lw_setpoint_k=[295.0]),
                         fallback=fallback, late_ms=late_ms, latency_ms=None if fallback else latency)  # fmt: skip


def test_a_level_counts_missing_proposals_and_late_periods():
    rec = _Recorder()
    for step in range(10):
        rec.applied[step] = _applied(step, fallback=step == 3, late_ms=20.0 if step == 7 else 0.0)
        rec.period_s[step] = 15.0 / 960
    figures = _level_figures(rec, 960, 0, 10)
    assert figures["missed"] == 2 and figures["no_proposal"] == 1 and figures["late"] == 1
    assert figures["steps"] == 10 and figures["period_ms"] == pytest.approx(15.625)


def test_render_names_every_figure_and_target():
    lat = {"system": "lcopt-5", "speed_factor": 300.0, "steps": 10, "controllers_used": ["g36"], "fallback_steps": 0,
           "p50_ms": 1.0, "p99_ms": 2.0, "max_ms": 3.0, "target_p99_ms": 10.0}  # fmt: skip
    result = {"machine": {"cpu": "cpu", "logical_cpus": 2, "python": "3.11", "commit": "abc", "date": "today"},
              "controller": {"requested": "tree", "notes": {"frontier-full": "tree missing", "lcopt-5": None}},
              "latency": {"lcopt-5": lat, "frontier-full": {**lat, "system": "frontier-full", "target_p99_ms": 50.0}},
              "speed": {"roles": ["sensor"], "max_sustained_speed_factor": 480,
                        "levels": [{"speed_factor": 480, "period_ms": 31.25, "missed": 0, "steps": 64}]},
              "encoding": [{"system": "lcopt-5", "state_bytes": 2564, "encode_ms": 0.1, "decode_ms": 0.2}]}  # fmt: skip
    text = render_mesh(result)
    assert "p99 <= 10 ms" in text and "p99 <= 50 ms" in text and "| 480x |" in text
    assert "Note (frontier-full): tree missing" in text and "Note (lcopt-5)" not in text


@pytest.mark.slow
def test_a_short_real_latency_run():
    r = measure_latency("lcopt-5", "g36", 300.0, 30, free_port(), print)
    assert r["steps"] == 30 and r["p50_ms"] is not None and r["p50_ms"] > 0  # its size is a benchmark figure
    assert r["controllers_used"] == ["g36"]
