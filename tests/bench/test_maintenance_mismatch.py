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
from lcmesh.mesh.tools.thermo import (
    GRAVITY_M_S2,
    RHO_WATER_KG_M3,
    CduPumpModel,
    cdu_hx_ua_w_k,
    counterflow_heat_w,
)
from lcmesh.twin.plant import Plant
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import load_trace


def test_deviation_inputs_change_the_plant_by_the_expected_amounts(plant):
    s = plant.system
    cab = s.cabinets
    # 0.8 of the design load: valves mid-stroke and the tower fans running (at a third of it they stand still)
    action, power = plant.default_action(), np.full(s.n_blade_groups, 0.8 * cab.design_heat_w / cab.branches)
    for _ in range(120):
        plant.step(power, 290.0, action)
    nominal = {k: v.copy() for k, v in plant.out.items()}
    state = plant.save_state()
    head_factor = np.array([1, 0.85, 1.15, 1, 1])
    plant.set_deviations(pump_head_factor=head_factor, hx_ua_factor=[1, 1, 1, 0.85, 1],
                         ct_approach_factor=[1.2, 1.0])  # fmt: skip
    for _ in range(120):
        out = plant.step(power, 290.0, action)
    assert out["secondary_flow_kg_s"] == pytest.approx(nominal["secondary_flow_kg_s"], rel=1e-3)  # dp loop holds it
    # a curve f x the described one (H = f (c - k m^2), c = rho g a s^2) delivering the same flow against the same
    # loop: the model sees the missing head (1 - f)(1 - k m^2 / (rho g a s^2)) (1 - f at zero flow) ...
    pump = CduPumpModel.from_system(s)
    speed, flow = out["pump_speed"], out["secondary_flow_kg_s"]
    loss = pump.head_loss(speed, flow)
    k_head = GRAVITY_M_S2 * pump.b_s2_m5 / (RHO_WATER_KG_M3 * pump.n_parallel**2) * flow**2
    rho_g_a = RHO_WATER_KG_M3 * GRAVITY_M_S2 * pump.a_m
    np.testing.assert_allclose(loss, (1 - head_factor) * (1 - k_head / (rho_g_a * speed**2)), atol=1e-6)
    assert loss[1] > 0.1 and loss[2] < -0.1  # lcopt-5 at this load: 0.118 / -0.110
    # ... and a weaker pump runs faster for it, a stronger one slower: s'^2 = s^2 / f + (k m^2 / (rho g a))(1 - 1/f)
    expected_speed = np.sqrt(nominal["pump_speed"] ** 2 / head_factor + k_head / rho_g_a * (1 - 1 / head_factor))
    np.testing.assert_allclose(speed, expected_speed, atol=1e-6)
    # lcopt-5 at this load: 0.758 / 0.676 against 0.712 (the flow's k m^2 share of the head damps the change)
    assert speed[1] > nominal["pump_speed"][1] + 0.04 and speed[2] < nominal["pump_speed"][2] - 0.03
    # a weaker HX: the twin's heat is the toolbox's counter-flow heat at 0.85 of the described UA, and the valve
    # opens further for it (measured 0.500 against 0.485)
    for c, factor in ((0, 1.0), (3, 0.85)):
        m_p, m_s = out["primary_flow_kg_s"][c], out["secondary_flow_kg_s"][c]
        q_w = counterflow_heat_w(factor * cdu_hx_ua_w_k(s, m_p, m_s), m_s, out["return_temp_k"][c], m_p,
                                 float(out["htw_supply_temp_k"]))  # fmt: skip
        assert q_w == pytest.approx(out["cdu_heat_w"][c], rel=1e-5)
    assert out["primary_valve"][3] > nominal["primary_valve"][3] + 0.01
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
        ("pump_degradation", "cabinet_1"), ("pump_degradation", "cabinet_2")}  # locations count from 1


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
