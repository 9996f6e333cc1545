"""The maintenance benchmark's mismatch scenario: the plant really differs from the detector's model, the
detector never sees how, and a mismatched plant stays quiet until a fault."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import lcmesh.bench.maintenance as bench
import lcmesh.mesh.tools.maintenance as detector_module
from lcmesh.bench.maintenance import NOMINAL_DETECTOR, Injection, SensorNoise, run_day
from lcmesh.bench.mismatch import LoadStep, MismatchSpec, PlantMismatch
from lcmesh.mesh.tools.thermo import CduPumpModel
from lcmesh.twin.plant import Plant
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import load_trace


def test_deviation_inputs_change_the_plant_by_the_expected_amounts(plant):
    s = plant.system
    action, power = plant.default_action(), np.full(s.n_blade_groups, 60e3)
    for _ in range(120):
        plant.step(power, 290.0, action)
    nominal = {k: v.copy() for k, v in plant.out.items()}
    state = plant.save_state()
    plant.set_deviations(pump_head_factor=[1, 0.85, 1.15, 1, 1], hx_ua_factor=[1, 1, 1, 0.85, 1],
                         ct_approach_factor=[1.2, 1.0])  # fmt: skip
    for _ in range(120):
        out = plant.step(power, 290.0, action)
    # the described curve's model sees the missing head: 1 - f at zero flow, (1 - f)(1 - b q^2 / a s^2) here
    loss = CduPumpModel.from_system(s).head_loss(out["pump_speed"], out["secondary_flow_kg_s"])
    assert loss[0] == pytest.approx(0.0, abs=1e-9)
    assert 0.13 < loss[1] < 0.15 and -0.15 < loss[2] < -0.13  # measured 0.145 / -0.143
    assert out["secondary_flow_kg_s"] == pytest.approx(nominal["secondary_flow_kg_s"], rel=1e-3)  # dp loop holds it
    # a weaker pump runs faster for it, a stronger one slower (measured 0.824 / 0.712 against 0.761)
    speed, nominal_speed = out["pump_speed"], nominal["pump_speed"]
    assert speed[1] > nominal_speed[1] + 0.04 and speed[2] < nominal_speed[2] - 0.04
    assert out["primary_valve"][3] > nominal["primary_valve"][3] + 0.05  # a weaker HX: the valve opens further
    assert out["fan_speed"][0] > nominal["fan_speed"][0] + 0.02  # a worse tower fit: the fans work harder
    assert out["fan_speed"][1] == pytest.approx(nominal["fan_speed"][1], abs=0.005)
    plant.restore_state(state)  # deviations are inputs saved with the FMU state, like faults
    assert plant.deviations.pump_head_factor.tolist() == [1.0] * 5


def test_a_mismatch_draw_stays_in_its_documented_bands(lcopt5):
    spec = MismatchSpec()
    a = PlantMismatch.draw(lcopt5, 5760, np.random.default_rng(3))
    b = PlantMismatch.draw(lcopt5, 5760, np.random.default_rng(3))
    assert a.summary() == b.summary()  # seeded
    for factor in (a.hx_ua_factor, a.pump_head_factor, a.ct_approach_factor):
        assert np.all((np.abs(factor - 1) >= spec.parameter_error[0]) & (np.abs(factor - 1) <= spec.parameter_error[1]))
    assert np.all((a.fouling_per_day >= 0.02) & (a.fouling_per_day <= 0.05))
    assert np.all(a.ua_factor(5760) < a.hx_ua_factor) and np.all(a.ua_factor(5760) >= a.hx_ua_factor * 0.95)
    drift = np.abs(np.concatenate([a.supply_drift_k_per_day, a.return_drift_k_per_day]))
    assert np.all((drift >= 0.1) & (drift <= 0.3))
    assert np.all(np.abs(a.supply_sensor_error_k(0)) <= 0.2)
    assert 20 < len(a.load_steps) < 100  # ~0.5 per hour per cabinet over a day: ~60
    assert all(0.4 <= s.factor <= 0.7 or 1.3 <= s.factor <= 1.6 for s in a.load_steps)
    assert all(40 <= s.end_step - s.start_step <= 240 or s.end_step == 5760 for s in a.load_steps)


def _hard_plant(system) -> PlantMismatch:
    """The far edge of every documented band, with two load steps inside the short window."""
    C = system.cabinets.count
    return PlantMismatch(
        hx_ua_factor=np.array([0.8, 1.2, 0.8, 1.2, 0.8]), pump_head_factor=np.array([0.8, 0.8, 1.2, 1.2, 0.8]),
        ct_approach_factor=np.array([1.2, 0.8]), fouling_per_day=np.full(C, 0.05),
        supply_offset_k=np.array([0.2, -0.2, 0.2, -0.2, 0.2]), supply_drift_k_per_day=np.full(C, 0.3),
        return_offset_k=np.array([-0.2, 0.2, -0.2, 0.2, -0.2]), return_drift_k_per_day=np.full(C, -0.3),
        load_steps=(LoadStep(1, 300, 400, 1.6), LoadStep(2, 350, 500, 0.4)), step_s=system.step_s,
    )  # fmt: skip


def test_a_mismatched_plant_stays_quiet_and_a_pump_fault_on_it_is_found(lcopt5):
    trace = load_trace("synthetic:1000", lcopt5, hours=2.5)
    hard = _hard_plant(lcopt5)
    assert lcopt5.towers.count == 2 and len(hard.ct_approach_factor) == 2
    # cabinet 2's pump is 20 % stronger than described: a 20 % loss leaves it near the described curve
    pump = Injection("pump_degradation", 2, 0.2, 450)
    with Plant(lcopt5) as plant, Plant(lcopt5, instance_name="healthy") as healthy:
        initial = plant.save_state()
        quiet = run_day(plant, healthy, trace, None, SensorNoise(), seed=5, start=initial, mismatch=hard)
        fault = run_day(plant, healthy, trace, pump, SensorNoise(), seed=5, start=initial, mismatch=hard)
        nominal = run_day(plant, healthy, trace, None, SensorNoise(), seed=5, start=initial, mismatch=hard,
                          config=NOMINAL_DETECTOR)  # fmt: skip
    assert quiet["false_alarms"] == [] and quiet["steps_run"] == trace.n_steps
    assert fault["false_alarms"] == [] and fault["misattributed"] == []
    assert 450 <= fault["detected_step"] <= 450 + 8  # within 2 simulated minutes
    # the same plant through the model's own zero: the weak pumps look degraded from the first minutes
    assert {(kind, loc) for k, kind, loc in nominal["false_alarms"] if k < 20} >= {
        ("pump_degradation", "cabinet_0"), ("pump_degradation", "cabinet_1")}


def test_the_detector_never_sees_the_mismatch(lcopt5, monkeypatch):
    """It is built from the nominal description and reads only plant outputs; its module knows no deviations."""
    built, seen = [], []

    class Recording(detector_module.FaultDetector):
        def __init__(self, system, config=None):
            built.append(system)
            super().__init__(system, config)

        def update(self, time_s, out, wet_bulb_k, action=None):
            seen.append(set(out))
            return super().update(time_s, out, wet_bulb_k, action)

    monkeypatch.setattr(bench, "FaultDetector", Recording)
    trace = load_trace("synthetic:1000", lcopt5, hours=0.25)
    with Plant(lcopt5) as plant, Plant(lcopt5, instance_name="healthy") as healthy:
        run_day(plant, healthy, trace, None, SensorNoise(), seed=1, start=plant.save_state(),
                mismatch=_hard_plant(lcopt5))  # fmt: skip
    assert built == [load_system("lcopt-5")]
    assert seen and not any(name.startswith(("deviation", "fault")) for names in seen for name in names)
    source = inspect.getsource(detector_module)
    assert "deviation" not in source and "lcmesh.bench" not in source
