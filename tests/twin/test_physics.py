"""Physics of the twin: the validate checks, faults, heat recovery, stability at the bounds."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.twin.plant import Plant
from lcmesh.twin.system import PSI_TO_PA, load_system
from lcmesh.twin.validate import validate_twin

K = 273.15


def test_lcopt5_passes_every_validation_check(lcopt5, tmp_path):
    report = validate_twin(lcopt5, plot_dir=tmp_path)
    failed = [c["name"] for c in report["checks"] if not c["passed"]]
    assert report["passed"], f"failed checks: {failed}"
    checks = {c["name"]: c for c in report["checks"]}
    assert abs(checks["energy_balance"]["energy_balance_error_pct"]) < 0.5
    # a 2 K setpoint step settles within minutes, not hours (LC-Opt's twin: 6-9 min; ours is faster, docs/twin.md)
    assert 0.5 <= checks["setpoint_step"]["t63_min"] <= 30
    published = [c for c in report["checks"] if "source" in c]
    assert len(published) >= 5 and all(c["passed"] for c in published)
    # the fan/pump split: every pump group runs, and the fans stay a small share, the limit docs/twin.md states
    # ("Fan and pump split": 0.7-8 % on lcopt-5 against the cited 73 %); a share near the source needs new docs
    split = checks["fan_pump_split"]["rows"]
    assert [r["scenario"] for r in split] == ["frontier", "design-day"]
    for row in split:
        assert min(row["cdu_pumps_kw"], row["htw_pumps_kw"], row["tower_pumps_kw"]) > 0
        assert row["fan_share_pct"] < 20.0 and row["status"].startswith("outside: documented limit")
    assert (tmp_path / "validate-setpoint-step.png").stat().st_size > 10_000


# A check a reference system fails, and why (docs/twin.md, Validation): kept failing, not widened.
KNOWN_SHORTFALLS = {"lcopt-10": {"facility_flow"}}  # 2.02x the 6,000 gpm press figure; the check allows 2x


@pytest.mark.slow
@pytest.mark.parametrize("name", ["lcopt-10", "lcopt-25", "lcopt-5-hru", "lcopt-5-paper"])
def test_other_reference_systems_pass_every_validation_check(name):
    report = validate_twin(load_system(name))
    failed = {c["name"] for c in report["checks"] if not c["passed"]}
    assert failed == KNOWN_SHORTFALLS.get(name, set())


@pytest.mark.slow
def test_frontier_full_passes_every_validation_check():
    report = validate_twin(load_system("frontier-full"))
    assert report["passed"], [c["name"] for c in report["checks"] if not c["passed"]]


def _settle(plant: Plant, hours: float, branch_w: float = 150e3, wet_bulb_k: float = 288.15, action=None):
    action = action or plant.default_action()
    action.lw_setpoint_k[:] = wet_bulb_k + 5.0
    power = np.full(plant.system.n_blade_groups, branch_w / plant.system.cabinets.blade_groups_per_branch)
    for _ in range(int(hours * 240)):
        out = plant.step(power, wet_bulb_k, action)
    return out


def test_pump_degradation_cuts_flow_and_warms_blades(plant):
    base = _settle(plant, 1.0)
    flow0, hot0 = base["secondary_flow_kg_s"][0], base["blade_temp_k"][:3].max()
    # the pumps run near 70 % speed at the design dp, so a 50 % head loss is made up by speeding up: take 70 %
    plant.set_faults(pump_degradation=[0.7, 0, 0, 0, 0])
    out = _settle(plant, 1.0)
    assert out["secondary_flow_kg_s"][0] < 0.9 * flow0
    assert out["blade_temp_k"][:3].max() > hot0 + 0.5
    assert out["secondary_flow_kg_s"][1] == pytest.approx(flow0, rel=1e-3)  # other CDUs unaffected


def test_stuck_valve_freezes_the_primary_valve(plant):
    _settle(plant, 1.0, branch_w=60e3)
    plant.set_faults(valve_stuck=[1, 0, 0, 0, 0])
    stuck_at = plant.out["primary_valve"][0]
    out = _settle(plant, 1.0, branch_w=250e3)  # the load more than quadruples
    assert out["primary_valve"][0] == pytest.approx(stuck_at, abs=1e-3)
    assert out["primary_valve"][1] > stuck_at + 0.1  # a healthy CDU opens its valve
    assert out["supply_temp_k"][0] > out["supply_temp_k"][1] + 1.0


def test_tower_cell_out_leaves_the_others_working(plant):
    _settle(plant, 1.0)
    plant.set_faults(cell_out=[[1, 0], [0, 0]])
    out = _settle(plant, 1.0)
    assert out["cell_fan_power_w"][0, 0] == 0 and out["cell_heat_w"][0, 0] == 0
    assert out["cells_active"][0] <= 1
    assert out["heat_rejected_w"] > 0.9 * out["heat_in_w"]


def test_sensor_bias_shifts_the_true_supply_temperature(plant):
    supply0 = float(_settle(plant, 1.0, branch_w=60e3)["supply_temp_k"][0])  # the valve has room to act
    plant.set_faults(sensor_bias_k=[2.0, 0, 0, 0, 0])
    out = _settle(plant, 1.0, branch_w=60e3)
    # the loop holds the biased reading at its setpoint, so the true supply runs ~2 K cold
    assert out["supply_temp_k"][0] < supply0 - 1.5
    assert out["supply_temp_measured_k"][0] - out["supply_temp_k"][0] == pytest.approx(2.0)


def test_heat_recovery_takes_load_off_the_towers():
    with Plant(load_system("lcopt-5-hru")) as hru, Plant(load_system("lcopt-5")) as plain:
        with_hru, without = _settle(hru, 3.0), _settle(plain, 3.0)
        assert with_hru["heat_recovered_w"] > 50e3
        assert with_hru["heat_rejected_w"] < without["heat_rejected_w"] - 50e3
        balance = (float(with_hru["energy_in_j"]) - float(with_hru["energy_rejected_j"])
                   - float(with_hru["energy_recovered_j"]) - float(with_hru["stored_energy_change_j"]))  # fmt: skip
        assert abs(balance) < 1e-6 * float(with_hru["energy_in_j"])


@pytest.mark.parametrize("case", ["cold_max_flow", "hot_min_flow", "one_branch", "overload_hot_day"])
def test_stable_at_the_action_bounds(plant, case):
    """Every action within bounds and every trace value in range keeps the state finite and physical."""
    action = plant.default_action()
    branch_w, wet_bulb = 150e3, 288.15
    if case == "cold_max_flow":
        action.supply_temp_setpoint_k[:], action.dp_setpoint_pa[:] = K + 20, 38 * PSI_TO_PA
        wet_bulb = K + 2.9
    elif case == "hot_min_flow":
        action.supply_temp_setpoint_k[:], action.dp_setpoint_pa[:] = K + 40, 25 * PSI_TO_PA
    elif case == "one_branch":
        action.valve_fractions[:] = [1.0, 0.0, 0.0]
    else:
        branch_w, wet_bulb = 330e3, K + 28.2  # 2x the mean load on the hottest hardened day
    for hours in (0.5, 1.5):
        out = _settle(plant, hours, branch_w=branch_w, wet_bulb_k=wet_bulb, action=action)
        temps = out["blade_temp_k"]
        # blades above 85 C throttle and shut down at 105 C, so nothing runs away
        assert np.isfinite(temps).all() and (temps > K).all() and (temps < K + 106).all()
        assert np.isfinite(out["stored_energy_j"])
    if case == "one_branch":  # a branch with no coolant heats up to shutdown, the others stay cool
        assert temps[1] > K + 100 and temps[0] < K + 45
        assert out["throttled_power_w"] > 0.5 * 10 * 150e3


def test_non_finite_inputs_fall_back_instead_of_poisoning_the_state(plant):
    action = plant.default_action()
    action.supply_temp_setpoint_k[0] = np.nan
    action.valve_fractions[1] = [np.nan, np.inf, -3.0]
    power = np.full(15, 50e3)
    power[4] = np.nan
    for _ in range(40):
        out = plant.step(power, np.nan, action)
    assert np.isfinite(plant.out["blade_temp_k"]).all()
    assert out["applied_supply_setpoint_k"][0] == pytest.approx(plant.system.cabinets.cdu.supply_temp_setpoint_k)
    np.testing.assert_allclose(out["applied_valve_fraction"][1], [1 / 3, 1 / 3, 1 / 3])


def test_a_run_does_not_depend_on_what_the_plant_ran_before(lcopt5):
    from lcmesh.twin.controllers import make_controller
    from lcmesh.twin.run import run_twin
    from lcmesh.twin.traces import FRONTIER_DAY, load_trace

    trace = load_trace(FRONTIER_DAY, lcopt5, hours=1)
    with Plant(lcopt5) as fresh, Plant(lcopt5) as used:
        hot = load_trace(FRONTIER_DAY, lcopt5, scenario="design-day", hours=2)
        run_twin(used, hot, make_controller("static", lcopt5))
        used.set_faults(pump_degradation=[0.7, 0, 0, 0, 0])
        fresh.set_faults(pump_degradation=[0.7, 0, 0, 0, 0])
        a = run_twin(fresh, trace, make_controller("g36", lcopt5)).kpi
        b = run_twin(used, trace, make_controller("g36", lcopt5)).kpi
        assert a == b
        assert used.faults.pump_degradation[0] == 0.7  # the faults set survive the restart
