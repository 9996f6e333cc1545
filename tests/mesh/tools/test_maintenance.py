"""The fault detector on the real twin: each injected fault is flagged where it is, a healthy plant stays quiet."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from lcmesh.bench.maintenance import Injection, SensorNoise, render_maintenance, run_day, summarize
from lcmesh.mesh.tools.maintenance import FAULT_KINDS, DetectorConfig, FaultDetector, Finding
from lcmesh.twin.controllers import Observation, make_controller
from lcmesh.twin.plant import Plant
from lcmesh.twin.traces import FRONTIER_DAY, load_trace

STEP_S = 15.0


def _branch_w(system, fraction: float) -> float:
    """`fraction` of a blade group's share of the design cabinet load, W (lcopt-5: one group per branch)."""
    cab = system.cabinets
    return fraction * cab.design_heat_w / (cab.branches * cab.blade_groups_per_branch)


def _run_trace(plant, spec, hours, *, inject_at_h=None, faults=None, noise=1.0, seed=0):
    """G36 on `hours` of a trace (the default scenario: real loads and wet bulb) with optional faults at
    `inject_at_h`; returns (detector, raised after injection)."""
    s = plant.system
    trace = load_trace(spec, s, hours=hours)
    ctrl = make_controller("g36", s)
    det = FaultDetector(s)
    rng, noisy = np.random.default_rng(seed), SensorNoise().scaled(noise)
    power = np.zeros(s.n_blade_groups)
    plant.spin_up(trace.blade_power_w(0, out=power), float(trace.wet_bulb_k[0]), plant.default_action(), hours=1.0)
    out = plant.reset()
    k0 = None if inject_at_h is None else int(inject_at_h * 3600 / STEP_S)
    raised = []
    for k in range(trace.n_steps):
        if k == k0:
            plant.set_faults(**faults)
        wb = float(trace.wet_bulb_k[k])
        action = ctrl.act(Observation(out, wb, trace.blade_power_w(k, out=power), k * STEP_S))
        out = plant.step(power, wb, action)
        det.update((k + 1) * STEP_S, noisy.apply(out, rng) if noise else out, wb, action)
        raised += [(k - (k0 or 0), f) for f in det.last_raised if f.kind in FAULT_KINDS]
    return det, raised


def _first(raised, kind):
    hits = [(k, f) for k, f in raised if f.kind == kind]
    assert hits, f"no {kind} finding; raised: {[(k, f.kind, f.location) for k, f in raised]}"
    return hits[0]


def test_pump_degradation_is_flagged_at_its_cabinet_within_minutes(plant):
    det, raised = _run_trace(plant, FRONTIER_DAY, 1.5, inject_at_h=1.0,
                             faults=dict(pump_degradation=[0, 0, 0.2, 0, 0]))  # fmt: skip
    k, f = _first(raised, "pump_degradation")
    assert f.location == "cabinet_3" and 0 <= k <= 8  # <= 2 simulated minutes
    assert f.evidence["head_loss"] == pytest.approx(0.2, abs=0.04)
    assert "20%" in f.message or "19%" in f.message or "21%" in f.message
    assert {g.kind for _, g in raised} == {"pump_degradation"}
    assert f.severity == "warning" and "strainer" in f.prescription


def test_sensor_bias_is_flagged_with_its_size_and_sign(plant):
    bias = dict(sensor_bias_k=[0, 0, 0, -0.8, 0])
    det, raised = _run_trace(plant, "synthetic:1000", 1.5, inject_at_h=1.0, faults=bias)
    k, f = _first(raised, "sensor_bias")
    assert f.location == "cabinet_4" and 0 <= k <= 20  # <= 5 simulated minutes
    assert f.evidence["bias_estimate_k"] == pytest.approx(-0.8, abs=0.25)
    assert "above its setpoint" in f.prescription  # reads low -> the real supply runs warm
    assert {g.kind for _, g in raised} == {"sensor_bias"}


def test_cell_out_is_flagged_at_the_right_cell(plant):
    det, raised = _run_trace(plant, FRONTIER_DAY, 1.5, inject_at_h=1.0,
                             faults=dict(cell_out=[[0, 0], [1, 0]]))  # fmt: skip
    k, f = _first(raised, "cell_out")
    assert f.location == "tower_2/cell_1" and 0 <= k <= 40  # <= 10 simulated minutes
    assert f.evidence["fan_power_w"] < 1e3
    assert {g.location for _, g in raised} == {"tower_2/cell_1"}


def test_cell_out_is_flagged_while_the_fans_idle(plant):
    """A quarter load on a cool day: free convection carries the heat and the fans stand still. The shipped
    systems never stage a cell down (stage-down speed 0), so a cell that stops is out however slow the fans."""
    s = plant.system
    assert s.towers.stage_down_speed == 0.0
    det, action = FaultDetector(s), plant.default_action()
    power = np.full(s.n_blade_groups, _branch_w(s, 0.25))
    raised, k_out = [], 120
    for k in range(k_out + 40):
        if k == k_out:
            plant.set_faults(cell_out=[[0, 1], [0, 0]])
        out = plant.step(power, 285.0, action)
        if k == k_out - 1:
            assert out["fan_speed"].max() < 0.02 and out["cells_active"].tolist() == [2, 2]  # idle fans, both cells on
        det.update((k + 1) * STEP_S, out, 285.0, action)
        raised += [(k, f.kind, f.location) for f in det.last_raised]
    assert [(kind, loc) for _, kind, loc in raised] == [("cell_out", "tower_1/cell_2")]
    assert k_out <= raised[0][0] <= k_out + 4


def test_stuck_valve_is_flagged_when_the_load_moves(plant):
    """Valve modulating at a moderate load; stuck; then the load doubles and the supply runs warm."""
    s = plant.system
    det, rng, noise = FaultDetector(s), np.random.default_rng(4), SensorNoise()
    action = plant.default_action()
    action.lw_setpoint_k[:] = 294.0
    power = np.full(s.n_blade_groups, _branch_w(s, 0.8))
    raised, k_stuck, k_load = [], 240, 260
    for k in range(400):
        if k == k_stuck:
            plant.set_faults(valve_stuck=[0, 1, 0, 0, 0])
        if k == k_load:
            power[3:6] *= 2.0  # cabinet 2's branches (index 1)
        out = plant.step(power, 290.0, action)
        det.update((k + 1) * STEP_S, noise.apply(out, rng), 290.0, action)
        raised += [(k, f) for f in det.last_raised if f.kind in FAULT_KINDS]
    k, f = _first(raised, "valve_stuck")
    assert f.location == "cabinet_2" and k_load <= k <= k_load + 40
    assert [g.kind for _, g in raised] == ["valve_stuck"]
    assert f.evidence["supply_error_k"] > 0.45  # it had to be outside the deadband to be seen


def test_valve_exercise_finds_a_valve_stuck_where_it_would_stay_and_spares_healthy_ones(plant):
    """A constant load: the stuck valve would stand still anyway and shows nothing, until it is stroked."""
    from lcmesh.mesh.tools.maintenance import ValveExercise

    s = plant.system
    exercise = ValveExercise(s, period_s=600.0)
    det, rng, noise = FaultDetector(s), np.random.default_rng(4), SensorNoise()
    base = plant.default_action()
    base.lw_setpoint_k[:] = 294.0
    power = np.full(s.n_blade_groups, _branch_w(s, 0.8))
    raised, tested, k_stuck = [], set(), 120
    out = plant.out
    for k in range(k_stuck + 80):
        if k == k_stuck:
            plant.set_faults(valve_stuck=[0, 0, 0, 1, 0])
        action, cabinets = exercise.stroked(k, base, out)
        tested.update(cabinets)
        assert (action is base) == (not cabinets)  # a stroke works on a copy; the proposal stays as it was
        moved = np.abs(action.supply_temp_setpoint_k - base.supply_temp_setpoint_k)
        assert np.all((moved == 0) | (moved >= 1.5 - 1e-9)) and np.count_nonzero(moved) <= 1
        out = plant.step(power, 290.0, action)
        det.update((k + 1) * STEP_S, noise.apply(out, rng), 290.0, action)
        raised += [(k, f) for f in det.last_raised if f.kind in FAULT_KINDS]
    assert tested == set(range(s.cabinets.count))
    k, f = _first(raised, "valve_stuck")
    assert [(g.kind, g.location) for _, g in raised] == [("valve_stuck", "cabinet_4")]
    assert exercise.under_test(k - 3)[3]  # found during its stroke, not by chance
    with pytest.raises(ValueError, match="shorter than"):
        ValveExercise(s, period_s=30.0)
    same, none = ValveExercise(s, period_s=0).stroked(5, base, out)
    assert same is base and none == []


@pytest.mark.parametrize("spec,noise", [(FRONTIER_DAY, 1.0), ("synthetic:1001", 1.0), (FRONTIER_DAY, 3.0)])
def test_a_healthy_plant_raises_no_fault_findings(plant, spec, noise):
    """Hours of G36 operation with sensor noise. At 3x noise fixed thresholds raise a sensor_bias false alarm
    on this window; the detector's thresholds scale with the residual noise it measures."""
    det, raised = _run_trace(plant, spec, 4.0, noise=noise, seed=7)
    assert raised == []
    assert det.ignored_updates == 0


def test_a_slowly_degrading_pump_gets_a_failure_prediction(plant):
    s = plant.system
    det = FaultDetector(s)
    action = plant.default_action()
    power = np.full(s.n_blade_groups, _branch_w(s, 16 / 15))
    ramp_per_step = 0.35 / 720  # 0 -> 35 % head loss over 3 h
    finding = None
    for k in range(720):
        plant.set_faults(pump_degradation=[0, 0, 0, 0, ramp_per_step * k])
        out = plant.step(power, 290.0, action)
        findings = det.update((k + 1) * STEP_S, out, 290.0, action)
        finding = next((f for f in findings if f.kind == "pump_degradation"), finding)
    assert finding is not None and finding.location == "cabinet_5"
    limit = finding.evidence["head_loss_limit"]  # ~49 % at the 27.5 psi dp setpoint (test_thermo.py)
    true_eta_s = (limit - 0.35) / ramp_per_step * STEP_S
    assert finding.predicted_failure_s == pytest.approx(true_eta_s, rel=0.5)
    assert "reaches the" in finding.message


def test_overtemperature_and_trend(plant):
    s = plant.system
    det = FaultDetector(s)
    action = plant.default_action()
    action.supply_temp_setpoint_k[:] = 305.15
    power = np.full(s.n_blade_groups, _branch_w(s, 0.8))
    # start settled at the 32 C supply: the step there from the default setpoint warms every cabinet by ~2 K
    # within minutes, a rise the trend check would rightly extrapolate to the limit
    plant.spin_up(power, 290.0, action, hours=0.5)
    plant.reset()
    kinds_seen = {}
    for k in range(360):
        power[6:9] = _branch_w(s, 0.8 + k / 187.5)  # cabinet 3 (index 2) ramps to 2.7x its design load
        out = plant.step(power, 290.0, action)
        for f in det.update((k + 1) * STEP_S, out, 290.0, action):
            kinds_seen.setdefault(f.kind, (k, f))
    k_trend, trend = kinds_seen["trend"]
    k_hot, hot = kinds_seen["overtemperature"]
    assert trend.location == hot.location == "cabinet_3"
    assert k_trend < k_hot and trend.predicted_failure_s > 0  # the trend warns before the limit is crossed
    assert hot.evidence["hottest_branch_temp_k"] > 313.15 and "°C" in hot.message
    assert hot.message.startswith(f"Branch {int(hot.evidence['branch'])} of cabinet 3 ")  # numbered from 1


def _from_a_runs_start(plant, config: DetectorConfig, steps: int, ramp_from: int | None = None) -> list:
    """The Sensor's start: a 1 h spin-up at the Frontier day's first row under G36's first action, then G36 on
    the day. From step `ramp_from` cabinet 3's load rises steadily (x2 in 30 min), as in the trend test above.
    Returns the findings raised, as (step, kind, location)."""
    s = plant.system
    plant.restart()  # from the FMU's initial state, whatever ran before
    trace, ctrl, det = load_trace(FRONTIER_DAY, s, hours=2.0), make_controller("g36", s), FaultDetector(s, config)
    power = np.zeros(s.n_blade_groups)
    first = Observation(plant.out, float(trace.wet_bulb_k[0]), trace.blade_power_w(0, out=power), 0.0)
    plant.spin_up(power, first.wet_bulb_k, ctrl.act(first), hours=1.0)
    out, raised = plant.reset(), []
    ctrl.reset()
    for k in range(steps):
        wb = float(trace.wet_bulb_k[k])
        trace.blade_power_w(k, out=power)
        if ramp_from is not None and k >= ramp_from:
            power[6:9] *= 1.0 + (k - ramp_from) / 120.0
        action = ctrl.act(Observation(out, wb, power, k * STEP_S))
        out = plant.step(power, wb, action)
        det.update((k + 1) * STEP_S, out, wb, action)
        raised += [(k, f.kind, f.location) for f in det.last_raised]
    return raised


def test_no_trend_while_a_run_starts_up_and_a_real_rise_after_it_is_flagged(plant):
    warmup_steps = int(DetectorConfig().trend_warmup_s / STEP_S)
    # without the warm-up the start-up transient (G36 walking its setpoints, the hottest branches climbing
    # ~1 K) is extrapolated to 40 C on most cabinets within minutes: the false alerts the warm-up is for
    unguarded = _from_a_runs_start(plant, DetectorConfig(trend_warmup_s=0.0), warmup_steps)
    early = {loc for k, kind, loc in unguarded if kind == "trend" and k < 20}
    assert len(early) >= 4, unguarded

    raised = _from_a_runs_start(plant, DetectorConfig(), warmup_steps + 150, ramp_from=warmup_steps)
    assert [r for r in raised if r[0] < warmup_steps] == []  # nothing at all during the start-up
    trends = [(k, loc) for k, kind, loc in raised if kind == "trend"]
    hot = [k for k, kind, loc in raised if kind == "overtemperature" and loc == "cabinet_3"]
    assert trends and {loc for _, loc in trends} == {"cabinet_3"}, raised
    assert hot and trends[0][0] < hot[0]  # the trend warns before the limit is crossed


# one finding's evidence per kind, at the first slot (cabinet 1, or tower 1's cell 1); values only shape the text
FIRST_SLOT_EVIDENCE = {
    "pump_degradation": dict(head_loss=0.3, head_loss_limit=0.49, pump_speed=0.9, flow_kg_s=10.0,
                             expected_flow_kg_s=12.0, time_to_limit_s=np.inf, head_loss_slope_per_h=0.0),
    "sensor_bias": dict(bias_estimate_k=1.0, measured_supply_k=303.15, implied_supply_k=302.15),
    "valve_stuck": dict(supply_error_k=1.0, valve_position=0.5, owed_travel=0.2),
    "cell_out": dict(cells_active=1, fan_power_w=0.0, heat_w=0.0, fan_speed=0.5, stage_up_demand_s=0.0,
                     tower_heat_w=1e6),
    "overtemperature": dict(branch=1, hottest_branch_temp_k=315.0, limit_k=313.15),
    "trend": dict(time_to_limit_s=600.0, slope_k_per_s=1e-3, slope_low_k_per_s=5e-4, hottest_branch_temp_k=310.0,
                  limit_k=313.15),
}  # fmt: skip


@pytest.mark.parametrize("kind", sorted(FIRST_SLOT_EVIDENCE))
def test_alert_texts_and_locations_count_from_one(lcopt5, kind):
    """The detector's slot 0 is cabinet 1 (tower 1, cell 1) wherever a person reads it: never "cabinet 0"."""
    from lcmesh.mesh.tools.maintenance_text import DESCRIBE

    det = FaultDetector(lcopt5)
    _, message, prescription, _ = DESCRIBE[kind](det, 0, FIRST_SLOT_EVIDENCE[kind])
    text = f"{message} {prescription}"
    assert re.search(r"\b(cabinet|CDU|tower|cell|branch) 0\b", text, re.I) is None, text
    assert re.search(r"\b(cabinet|CDU|tower) 1\b", text), text
    assert det.location(kind, 0) == ("tower_1/cell_1" if kind == "cell_out" else "cabinet_1")
    assert det.location(kind, lcopt5.towers.cells) == ("tower_2/cell_1" if kind == "cell_out" else "cabinet_3")


def test_bad_input_is_named_and_nan_does_not_crash(plant):
    det = FaultDetector(plant.system)
    out = {k: v.copy() for k, v in plant.out.items()}
    with pytest.raises(ValueError, match="lacks 'pump_speed'"):
        det.update(15.0, {k: v for k, v in out.items() if k != "pump_speed"}, 290.0)
    with pytest.raises(ValueError, match=r"`out\['fan_speed'\]` must have shape \(2,\)"):
        det.update(15.0, {**out, "fan_speed": np.zeros(3)}, 290.0)
    with pytest.raises(ValueError, match="time_s"):
        det.update(float("nan"), out, 290.0)
    action, power = plant.default_action(), np.full(15, _branch_w(plant.system, 2 / 3))
    for k in range(40):
        out = {key: v.copy() for key, v in plant.step(power, 290.0, action).items()}
        if k % 3 == 0:
            for name in ("secondary_flow_kg_s", "supply_temp_measured_k", "primary_valve", "cell_heat_w"):
                out[name][...] = np.nan
        assert [f for f in det.update((k + 1) * STEP_S, out, 290.0, action) if f.kind in FAULT_KINDS] == []
    det.update(40 * STEP_S, out, 290.0, action)  # a repeated timestamp is ignored, not an error
    assert det.ignored_updates == 1
    det.update(STEP_S, out, 290.0, action)  # back to the start: a restarted plant, not a late message
    assert det.restarts == 1 and det.ignored_updates == 1 and det._last_time_s == STEP_S


def test_findings_serialize_and_config_validates(plant):
    plant.set_faults(pump_degradation=[0.6, 0, 0, 0, 0])
    det = FaultDetector(plant.system)
    for k in range(10):
        power = np.full(15, _branch_w(plant.system, 16 / 15))
        findings = det.update((k + 1) * STEP_S, plant.step(power, 290.0, plant.default_action()), 290.0)
    data = json.loads(findings[0].model_dump_json())
    assert data["kind"] == "pump_degradation" and data["severity"] == "critical"  # 60 % is past the ~49 % limit
    assert data["predicted_failure_s"] == 0.0
    assert Finding.model_validate(data) == findings[0]
    with pytest.raises(ValueError, match="persistence_steps"):
        DetectorConfig(persistence_steps=0)


def test_benchmark_harness_counts_detection_and_manifestation(lcopt5):
    trace = load_trace("synthetic:1002", lcopt5, hours=2.0)
    pump = Injection("pump_degradation", 1, 0.3, 300)
    with Plant(lcopt5) as plant, Plant(lcopt5, instance_name="healthy") as healthy:
        initial = plant.save_state()
        runs = [
            run_day(plant, healthy, trace, pump, SensorNoise(), seed=1, start=initial),
            run_day(plant, healthy, trace, None, SensorNoise(), seed=2, start=initial),
        ]
        again = run_day(plant, healthy, trace, pump, SensorNoise(), seed=1, start=initial)
    assert again == runs[0]  # each run starts from the same state: order does not matter
    assert runs[0]["manifest_step"] == 300 and 300 <= runs[0]["detected_step"] <= 308
    assert runs[0]["steps_run"] < trace.n_steps  # stops once found and shown
    summary = summarize(runs, lcopt5.step_s)
    assert summary["per_kind"]["pump_degradation"]["detection_rate"] == 1.0
    assert summary["false_alarms"]["fault_free_days"] == pytest.approx((300 + trace.n_steps) * 15 / 86400)
    result = {**summary, "machine": {"cpu": "x", "logical_cpus": 2, "python": "3", "commit": "c", "date": "d"},
              "system": "lcopt-5", "controller": "g36", "days": ["synthetic:1002"], "injections_per_day_and_kind": 1,
              "simulated_days": 0.2, "wall_s": 1.0, "targets": {"detection_rate": 0.9, "median_delay_min": 10,
                                                                 "false_alarms_per_day": 1}}  # fmt: skip
    table = render_maintenance(result)
    assert "| pump_degradation | matched | 1/1 | 100% |" in table and "0.00 per day" in table


@pytest.mark.slow
def test_bench_maintenance_cli_quick(tmp_path):
    """The whole benchmark command in its smoke size: JSON keys and the BENCHMARKS.md section."""
    from typer.testing import CliRunner

    from lcmesh.cli import app

    out, md = tmp_path / "m.json", tmp_path / "BENCHMARKS.md"
    result = CliRunner().invoke(app, ["bench", "maintenance", "--quick", "--json", str(out), "--markdown", str(md)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data["per_kind"]) == set(FAULT_KINDS)
    assert data["false_alarms"]["per_day"] <= 1.0
    assert data["per_kind"]["pump_degradation"]["detection_rate"] == 1.0
    assert set(data["mismatched"]["per_kind"]) == set(FAULT_KINDS)  # the same injections on mismatched plants
    assert data["mismatched"]["false_alarms"]["per_day"] <= 1.0
    assert "| pump_degradation | mismatched |" in md.read_text()
