"""The thermo toolbox: each function against hand-computed values, and against the twin it describes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lcmesh.mesh.tools import thermo
from lcmesh.twin.system import PSI_TO_PA


def test_heat_flow_and_its_inverse():
    # 10 kg/s x 4186 J/(kg K) x 5 K = 209,300 W
    assert thermo.heat_flow_w(10.0, 5.0) == pytest.approx(209_300.0)
    assert thermo.heat_flow_w(10.0, 5.0, cp_j_kg_k=4000.0) == pytest.approx(200_000.0)
    assert thermo.delta_t_k(209_300.0, 10.0) == pytest.approx(5.0)
    np.testing.assert_allclose(thermo.heat_flow_w(np.array([1.0, 2.0]), 1.0), [4186.0, 8372.0])


def test_effectiveness_from_temperatures():
    # hot 60 -> 40 C (dT 20), cold 20 -> 30 C (dT 10): the hot side is C_min, eps = 20 / (60 - 20) = 0.5
    k = 273.15
    assert thermo.effectiveness_from_temperatures_k(60 + k, 40 + k, 20 + k, 30 + k) == pytest.approx(0.5)
    # swapped roles: cold side changes more (dT 30 of a 40 K span) -> 0.75
    assert thermo.effectiveness_from_temperatures_k(60 + k, 50 + k, 20 + k, 50 + k) == pytest.approx(0.75)
    assert math.isnan(thermo.effectiveness_from_temperatures_k(300.0, 300.0, 300.0, 300.0))


def test_counterflow_effectiveness_ntu():
    assert thermo.counterflow_effectiveness(1.0, 0.0) == pytest.approx(1 - math.exp(-1))  # Cr = 0: 1 - e^-NTU
    assert thermo.counterflow_effectiveness(1.0, 1.0) == pytest.approx(0.5)  # Cr = 1: NTU / (1 + NTU)
    # NTU 2, Cr 0.5: e = exp(-1) = 0.367879; (1 - e) / (1 - 0.5 e) = 0.632121 / 0.816060 = 0.774600
    assert thermo.counterflow_effectiveness(2.0, 0.5) == pytest.approx(0.774600, abs=1e-6)
    assert thermo.counterflow_effectiveness(0.0, 0.5) == 0.0
    assert thermo.ntu(1000.0, 4186.0) == pytest.approx(0.238892, abs=1e-6)


def test_counterflow_heat():
    # UA 1 kW/K; hot 1 kg/s (C_min 4186 W/K) at 330 K, cold 2 kg/s at 290 K: NTU 0.238892, Cr 0.5,
    # e = exp(-0.119446) = 0.887413, eps = 0.112587 / 0.556294 = 0.202387; Q = eps x 4186 x 40 = 33,888 W
    assert thermo.counterflow_heat_w(1000.0, 1.0, 330.0, 2.0, 290.0) == pytest.approx(33_888.0, abs=1.0)
    assert thermo.counterflow_heat_w(1000.0, 0.0, 330.0, 2.0, 290.0) == 0.0


def test_cdu_hx_ua(lcopt5):
    cdu = lcopt5.cabinets.cdu
    sat_kg_s = cdu.hx_flow_sat_m3_s * 997.0
    # both sides at saturation: h = 2 UA_sat each, in series UA_sat, x the correction (lcopt-5: 250 kW/K x 1.6)
    full = cdu.hx_ua_sat_w_per_k * cdu.hx_ua_correction
    assert full == pytest.approx(400_000.0)
    assert thermo.cdu_hx_ua_w_k(lcopt5, sat_kg_s, sat_kg_s) == pytest.approx(full)
    # both at half: each h scales 0.5^0.8 = 0.574349 -> 400 kW/K x 0.574349 = 229.740 kW/K
    assert thermo.cdu_hx_ua_w_k(lcopt5, sat_kg_s / 2, sat_kg_s / 2) == pytest.approx(full * 0.574349, abs=1.0)
    assert thermo.cdu_hx_ua_w_k(lcopt5, 0.0, sat_kg_s) == 0.0


def test_approach_and_range():
    assert thermo.approach_k(300.0, 295.0) == pytest.approx(5.0)
    assert thermo.range_k(305.0, 300.0) == pytest.approx(5.0)


def test_york_fit_coefficients(lcopt5):
    # 10 C = 50 F: alpha = 5/9 (8.8 - 0.0891 x 50) = 2.413889, beta = 5/9 (10.2 - 0.1139 x 50) = 2.502778
    assert thermo.york_coefficients_k(lcopt5, 283.15) == pytest.approx((2.413889, 2.502778), abs=1e-6)
    # 25 C = 77 F is held at the fit's 70 F cap: alpha = 1.423889, beta = 1.237222
    assert thermo.york_coefficients_k(lcopt5, 298.15) == pytest.approx((1.423889, 1.237222), abs=1e-6)
    # design heat at full fan: approach = alpha + beta = 2.661 K
    design_w = lcopt5.towers.cell.design_heat_w
    assert thermo.tower_approach_k(lcopt5, 298.15, design_w, 1.0) == pytest.approx(2.661111, abs=1e-6)


def test_tower_fan_power_inverts_the_tower_model(lcopt5):
    # 2 cells at design heat (lcopt-5: 2 x 1.338 MW) at a 3 K approach (wet bulb 25 C):
    # air = 1.237222 / (3 - 1.423889) = 0.784984, power = 2 x 37.3 kW x 0.784984^3 = 36.085 kW
    cell = lcopt5.towers.cell
    assert (cell.design_heat_w, cell.fan_power_nominal_w) == (1.338e6, 37.3e3)
    est = thermo.tower_fan_power_w(lcopt5, 2 * cell.design_heat_w, 3.0, 298.15, 2)
    assert est.reachable and est.fan_speed == pytest.approx(0.784984, abs=1e-6)
    assert est.fan_power_w == pytest.approx(36_085.0, abs=2.0)
    assert thermo.tower_approach_k(lcopt5, 298.15, cell.design_heat_w, est.fan_speed) == pytest.approx(3.0)
    too_close = thermo.tower_fan_power_w(lcopt5, 2 * cell.design_heat_w, 2.0, 298.15, 2)
    assert not too_close.reachable and too_close.fan_speed == 1.0
    assert too_close.approach_at_full_speed_k == pytest.approx(2.661111, abs=1e-6)
    with pytest.raises(ValueError, match="cells_active"):
        thermo.tower_fan_power_w(lcopt5, 1e5, 3.0, 298.15, 0)


def test_affinity_laws():
    # speed 1.0 -> 0.8: flow x 0.8, head x 0.64, power x 0.512
    p = thermo.pump_affinity(1.0, 0.8, flow=10.0, head=40.0, power_w=5000.0)
    assert (p.flow, p.head, p.power_w) == pytest.approx((8.0, 25.6, 2560.0))
    f = thermo.fan_affinity(0.5, 1.0, airflow=100.0, pressure_pa=200.0, power_w=1000.0)
    assert (f.flow, f.head, f.power_w) == pytest.approx((200.0, 800.0, 8000.0))
    with pytest.raises(ValueError, match="speed_from"):
        thermo.pump_affinity(0.0, 1.0, 1.0, 1.0, 1.0)


def test_cdu_pump_model_closed_form(lcopt5):
    pump = thermo.CduPumpModel.from_system(lcopt5)
    m = pump.flow_kg_s(0.8)
    # the operating point satisfies the head balance: rho g a s^2 - k m^2 = R m
    k = thermo.GRAVITY_M_S2 * pump.b_s2_m5 / (thermo.RHO_WATER_KG_M3 * pump.n_parallel**2)
    head_pa = thermo.RHO_WATER_KG_M3 * thermo.GRAVITY_M_S2 * pump.a_m * 0.8**2
    assert head_pa - k * m * m == pytest.approx(pump.r_loop_pa_s_kg * m, rel=1e-9)
    assert pump.head_loss(0.8, m) == pytest.approx(0.0, abs=1e-12)
    assert pump.head_loss(0.8, pump.flow_kg_s(0.8, head_loss=0.3)) == pytest.approx(0.3, abs=1e-12)
    # at the head-loss limit, full speed gives exactly the flow of the dp setpoint (27.5 psi / R_cabinet)
    cdu = lcopt5.cabinets.cdu
    assert (cdu.r_cabinet_pa_per_kg_s, cdu.r_hx_secondary_pa_per_kg_s) == (4_700.0, 1_800.0)
    dp_pa = 27.5 * PSI_TO_PA
    limit = pump.head_loss_limit(dp_pa)
    assert 0.0 < limit < 0.95  # a real margin: the pump reaches the setpoint flow with some head to spare
    assert pump.flow_kg_s(pump.speed_max, head_loss=limit) == pytest.approx(dp_pa / 4_700.0, rel=1e-9)
    # P = R_loop m^2 / (rho eta), R_loop = 4,700 + 1,800 Pa s/kg
    assert pump.power_w(m) == pytest.approx(6_500 * m * m / (997.0 * 0.85))


def test_toolbox_agrees_with_the_twin(plant):
    """Steady state on the FMU: pump curve, tower leaving water, fan power and the fan-power inverse."""
    cab = plant.system.cabinets
    # 4/3 of the design branch load, fans near half speed: a fixed point. (At a third of this load the fans run
    # near their free-convection floor and settle into a 3-step speed cycle, which a steady-state check cannot use.)
    branch_design_w = cab.design_heat_w / (cab.branches * cab.blade_groups_per_branch)
    power = np.full(plant.system.n_blade_groups, 4 / 3 * branch_design_w)
    action = plant.default_action()
    action.lw_setpoint_k[:] = 293.15 + 4.0
    for _ in range(480):  # 2 h at constant inputs
        out = plant.step(power, 293.15, action)
    s = plant.system
    pump = thermo.CduPumpModel.from_system(s)
    np.testing.assert_allclose(pump.flow_kg_s(out["pump_speed"]), out["secondary_flow_kg_s"], rtol=1e-9)
    n = 0
    speed, cells = float(out["fan_speed"][n]), int(out["cells_active"][n])
    lw = thermo.tower_leaving_temp_k(s, 293.15, float(out["ct_entering_temp_k"][n]), speed)
    assert lw == pytest.approx(float(out["ct_leaving_temp_k"][n]), abs=0.02)
    fan_w = float(thermo.tower_fan_power_from_speed_w(s, speed, cells))
    assert fan_w == pytest.approx(float(out["cell_fan_power_w"][n].sum()), rel=1e-3, abs=1.0)
    est = thermo.tower_fan_power_w(s, float(out["cell_heat_w"][n].sum()), float(out["approach_k"][n]), 293.15, cells)
    assert est.fan_speed == pytest.approx(speed, abs=0.01)


def test_cdu_heat_balance_closes_on_the_twin(plant):
    s = plant.system
    branch_design_w = s.cabinets.design_heat_w / s.cabinets.branches  # one blade group per branch on lcopt-5
    power = np.linspace(0.5, 2.0, s.n_blade_groups) * branch_design_w
    action = plant.default_action()
    prev = {k: v.copy() for k, v in plant.out.items()}
    worst = 0.0
    for k in range(120):
        power *= 1.002 if k < 60 else 0.997  # a load ramp: storage terms matter
        out = plant.step(power, 290.0, action)
        if k > 0:
            bal = thermo.cdu_heat_balance(out, 2, s, previous_out=prev)
            worst = max(worst, abs(bal.residual_pct))
        prev = {key: v.copy() for key, v in out.items()}
    # with the storage terms the balance is exact to rounding (one blade group per branch)
    assert worst < 1e-6
    steady = thermo.cdu_heat_balance(out, 2, s)
    assert steady.branch_heat_w == pytest.approx(float(thermo.branch_heat_w(s, out["branch_power_w"][2]).sum()))
    assert abs(steady.supply_residual_k) < 0.5
    with pytest.raises(ValueError, match="cabinet"):
        thermo.cdu_heat_balance(out, 9, s)
