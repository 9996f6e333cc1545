"""What-if look-ahead on the FMU: exact restore, the effect of a change, validation."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.mesh.tools.whatif import apply_delta, current_action, one_step_whatif
from lcmesh.twin.plant import Plant

LOAD_FRACTION = 0.8  # of the design branch load: the primary valves modulate mid-stroke (not pinned at a stop)
WET_BULB_K = 290.0


def _branch_w(system) -> float:
    cab = system.cabinets
    return LOAD_FRACTION * cab.design_heat_w / (cab.branches * cab.blade_groups_per_branch)


def _settle(plant: Plant, steps: int = 400) -> tuple[np.ndarray, object]:
    power = np.full(plant.system.n_blade_groups, _branch_w(plant.system))
    action = plant.default_action()
    action.lw_setpoint_k[:] = WET_BULB_K + 4.0
    for _ in range(steps):
        plant.step(power, WET_BULB_K, action)
    return power, action


def test_whatif_leaves_the_plant_bit_identical(lcopt5):
    with Plant(lcopt5) as a, Plant(lcopt5, instance_name="twin-b") as b:
        power, action = _settle(a, 200)
        _settle(b, 200)
        inputs_before = {k: v.copy() for k, v in a.inp.items()}
        out_before = {k: v.copy() for k, v in a.out.items()}
        one_step_whatif(a, {"supply_temp_setpoint_k": 2.0, "lw_setpoint_k": -1.0}, steps=40)
        assert all(np.array_equal(a.out[k], out_before[k]) for k in out_before)
        assert all(np.array_equal(a.inp[k], inputs_before[k]) for k in inputs_before)
        assert a.n_steps_done == b.n_steps_done and a.runner.time == b.runner.time
        for _ in range(3):
            oa, ob = a.step(power, WET_BULB_K, action), b.step(power, WET_BULB_K, action)
            for name in oa:
                assert np.array_equal(oa[name], ob[name]), name


def test_raising_the_supply_setpoint_warms_the_supply_and_saves_fan_power(plant):
    _settle(plant)
    r = one_step_whatif(plant, {"supply_temp_setpoint_k": 2.0}, steps=20)
    assert r["horizon_steps"] == 20 and r["horizon_s"] == 300.0
    assert np.all(r["delta"]["supply_temp_k"] > 1.5)  # the CDU valves close: supply rises ~2 K in 5 min
    assert np.all(r["delta"]["primary_valve"] < 0)
    assert np.all(r["delta"]["blade_temp_k"] > 1.0)
    assert float(r["delta"]["ct_fan_power_w"]) <= 0.0
    raised_k = r["baseline_action"]["supply_temp_setpoint_k"] + 2.0
    np.testing.assert_allclose(r["action"]["supply_temp_setpoint_k"], raised_k)


def test_a_zero_change_predicts_the_baseline_exactly(plant):
    _settle(plant, 100)
    r = one_step_whatif(plant, {}, steps=4)
    assert all(np.all(d == 0.0) for d in r["delta"].values())
    full = one_step_whatif(plant, current_action(plant), steps=4)
    assert all(np.all(d == 0.0) for d in full["delta"].values())


def test_whatif_with_given_load_and_weather(plant):
    _settle(plant, 100)
    hot = one_step_whatif(plant, {}, blade_power_w=np.full(15, 2 * _branch_w(plant.system)), wet_bulb_k=300.0, steps=8)
    calm = one_step_whatif(plant, {}, steps=8)
    assert np.all(hot["baseline"]["blade_temp_k"] > calm["baseline"]["blade_temp_k"] + 1.0)


def test_whatif_rejects_bad_input_by_name(plant):
    with pytest.raises(ValueError, match="unknown action field.*supply_setpoint"):
        one_step_whatif(plant, {"supply_setpoint": 1.0})
    with pytest.raises(ValueError, match="`lw_setpoint_k` delta must broadcast to shape \\(2,\\)"):
        apply_delta(current_action(plant), {"lw_setpoint_k": [1.0, 2.0, 3.0]})
    with pytest.raises(ValueError, match="`steps` must be in"):
        one_step_whatif(plant, {}, steps=0)
    with pytest.raises(ValueError, match="unknown output"):
        one_step_whatif(plant, {}, outputs=("blade_temp",))
    with pytest.raises(ValueError, match="`wet_bulb_k` must be finite"):
        one_step_whatif(plant, {}, wet_bulb_k=float("nan"))
    bad = current_action(plant)
    bad.supply_temp_setpoint_k[0] = np.nan
    with pytest.raises(ValueError, match="`supply_temp_setpoint_k` must be finite"):
        one_step_whatif(plant, bad)
