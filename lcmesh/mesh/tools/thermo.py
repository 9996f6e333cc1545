"""Thermodynamics of the cooling plant as pure functions: the numbers explanations cite.

Every function states its equation; inputs and outputs are SI with units in the names. The
plant-specific helpers (CDU pump, CDU heat exchanger, tower cells) take the SystemDescription and
use the same equations and constants as the twin's C model (lcmesh/twin/c/lcmesh_model.c), so a
toolbox number agrees with what the twin does. Arrays broadcast wherever scalars are shown.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lcmesh.twin.fmu_layout import fit_pump_curve
from lcmesh.twin.system import SystemDescription

CP_WATER_J_KG_K = 4186.0  # lcmesh_model.c CP_WATER
RHO_WATER_KG_M3 = 997.0  # lcmesh_model.c RHO_WATER
GRAVITY_M_S2 = 9.80665

ArrayLike = float | np.ndarray


# --- heat balance -------------------------------------------------------------------------------
def heat_flow_w(mass_flow_kg_s: ArrayLike, delta_t_k: ArrayLike, cp_j_kg_k: float = CP_WATER_J_KG_K) -> ArrayLike:
    """Sensible heat carried by a liquid stream: Q = m_dot * c_p * dT."""
    return np.multiply(np.multiply(mass_flow_kg_s, cp_j_kg_k), delta_t_k)


def delta_t_k(heat_w: ArrayLike, mass_flow_kg_s: ArrayLike, cp_j_kg_k: float = CP_WATER_J_KG_K) -> ArrayLike:
    """Temperature change of a stream that takes up `heat_w`: dT = Q / (m_dot * c_p) (inf at zero flow)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.divide(heat_w, np.multiply(mass_flow_kg_s, cp_j_kg_k))


def capacity_rate_w_k(mass_flow_kg_s: ArrayLike, cp_j_kg_k: float = CP_WATER_J_KG_K) -> ArrayLike:
    """Heat capacity rate of a stream: C = m_dot * c_p."""
    return np.multiply(mass_flow_kg_s, cp_j_kg_k)


# --- heat exchangers ----------------------------------------------------------------------------
def effectiveness_from_temperatures_k(
    hot_in_k: ArrayLike, hot_out_k: ArrayLike, cold_in_k: ArrayLike, cold_out_k: ArrayLike
) -> ArrayLike:
    """Effectiveness from the four terminal temperatures: eps = max(dT_hot, dT_cold) / (T_hot,in - T_cold,in).

    The stream with the smaller capacity rate C_min sees the larger temperature change (Q = C dT on both
    sides), so no flows are needed. Returns nan where the inlets are equal.
    """
    span = np.subtract(hot_in_k, cold_in_k)
    change = np.maximum(np.subtract(hot_in_k, hot_out_k), np.subtract(cold_out_k, cold_in_k))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(span) > 1e-12, change / np.where(span == 0, 1.0, span), np.nan)


def ntu(ua_w_k: ArrayLike, c_min_w_k: ArrayLike) -> ArrayLike:
    """Number of transfer units: NTU = UA / C_min."""
    with np.errstate(divide="ignore"):
        return np.divide(ua_w_k, c_min_w_k)


def counterflow_effectiveness(ntu_value: ArrayLike, capacity_ratio: ArrayLike) -> ArrayLike:
    """Counter-flow epsilon-NTU: eps = (1 - e) / (1 - Cr e), e = exp(-NTU (1 - Cr)); eps = NTU / (1 + NTU) at Cr = 1.

    The same formula as ``counterflow_effectiveness`` in lcmesh_model.c (Incropera, Table 11.3).
    """
    n = np.asarray(ntu_value, dtype=float)
    cr = np.clip(np.asarray(capacity_ratio, dtype=float), 0.0, 1.0)
    balanced = cr > 1.0 - 1e-9
    e = np.exp(-n * (1.0 - cr))
    with np.errstate(divide="ignore", invalid="ignore"):
        eps = np.where(balanced, n / (1.0 + n), (1.0 - e) / (1.0 - np.where(balanced, 0.0, cr) * e))
    eps = np.where(n > 0.0, eps, 0.0)
    return eps.item() if eps.ndim == 0 else eps


def counterflow_heat_w(
    ua_w_k: ArrayLike,
    hot_flow_kg_s: ArrayLike,
    hot_in_k: ArrayLike,
    cold_flow_kg_s: ArrayLike,
    cold_in_k: ArrayLike,
    cp_j_kg_k: float = CP_WATER_J_KG_K,
) -> ArrayLike:
    """Heat from the hot to the cold stream of a counter-flow exchanger: Q = eps C_min (T_hot,in - T_cold,in)."""
    c_hot, c_cold = capacity_rate_w_k(hot_flow_kg_s, cp_j_kg_k), capacity_rate_w_k(cold_flow_kg_s, cp_j_kg_k)
    c_min, c_max = np.minimum(c_hot, c_cold), np.maximum(c_hot, c_cold)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(c_max > 0, c_min / np.where(c_max > 0, c_max, 1.0), 0.0)
        eps = counterflow_effectiveness(ntu(ua_w_k, c_min), ratio)
    q = np.where(c_min > 0, eps * c_min * np.subtract(hot_in_k, cold_in_k), 0.0)
    return q.item() if np.ndim(q) == 0 else q


def cdu_hx_ua_w_k(system: SystemDescription, primary_flow_kg_s: ArrayLike, secondary_flow_kg_s: ArrayLike) -> ArrayLike:
    """CDU heat-exchanger UA as the twin computes it (docs/twin.md): UA = k_c / (1/h_p + 1/h_s).

    Each side's film conductance is h = 2 UA_sat min(V / V_sat, 1)^0.8 with V the volume flow.
    """
    cdu = system.cabinets.cdu

    def film(m_kg_s):
        v_ratio = np.minimum(np.asarray(m_kg_s, dtype=float) / RHO_WATER_KG_M3 / cdu.hx_flow_sat_m3_s, 1.0)
        return 2.0 * cdu.hx_ua_sat_w_per_k * np.power(np.maximum(v_ratio, 0.0), 0.8)

    hp, hs = film(primary_flow_kg_s), film(secondary_flow_kg_s)
    both = (hp > 0) & (hs > 0)
    series = 1.0 / np.where(both, hp, 1.0) + 1.0 / np.where(both, hs, 1.0)
    ua = np.where(both, cdu.hx_ua_correction / series, 0.0)
    return ua.item() if ua.ndim == 0 else ua


# --- cooling towers -----------------------------------------------------------------------------
def approach_k(leaving_water_k: ArrayLike, wet_bulb_k: ArrayLike) -> ArrayLike:
    """Tower approach: leaving (cold) water minus the entering air's wet bulb, T_lw - T_wb."""
    return np.subtract(leaving_water_k, wet_bulb_k)


def range_k(entering_water_k: ArrayLike, leaving_water_k: ArrayLike) -> ArrayLike:
    """Tower range: entering (hot) water minus leaving (cold) water, T_in - T_lw."""
    return np.subtract(entering_water_k, leaving_water_k)


def york_coefficients_k(system: SystemDescription, wet_bulb_k: float) -> tuple[float, float]:
    """(alpha, beta) of the twin's York-type fit T_app = alpha + beta * adj at this wet bulb (lcmesh_model.c).

    T_app = 5/9 (c1 + (c2 - 1) T_wb[F]) with c1 = 25 - 0.6 (27 - 17 adj), c2 = 0.73 + 0.0067 (27 - 17 adj)
    gives alpha = 5/9 (8.8 - 0.0891 T_wb[F]), beta = 5/9 (10.2 - 0.1139 T_wb[F]); T_wb[F] is capped at
    the description's ``york_wet_bulb_max_f``.
    """
    twb_f = min((wet_bulb_k - 273.15) * 1.8 + 32.0, system.towers.cell.york_wet_bulb_max_f)
    return 5.0 / 9.0 * (8.8 - 0.0891 * twb_f), 5.0 / 9.0 * (10.2 - 0.1139 * twb_f)


def tower_approach_k(system: SystemDescription, wet_bulb_k: float, cell_heat_w: float, fan_speed: float) -> float:
    """Approach of one active cell rejecting `cell_heat_w` at `fan_speed`: alpha + beta * Q / (Q_design * air).

    air = max(fan_speed, free-convection ratio); the result is held at or above ``approach_min_k`` (twin).
    """
    cell = system.towers.cell
    alpha, beta = york_coefficients_k(system, wet_bulb_k)
    air = max(float(fan_speed), cell.free_convection_air_ratio)
    return max(alpha + beta * float(cell_heat_w) / (cell.design_heat_w * air), cell.approach_min_k)


def tower_leaving_temp_k(system: SystemDescription, wet_bulb_k: float, entering_k: float, fan_speed: float) -> float:
    """Leaving water of an active cell, the twin's closed form (lcmesh_model.c ``tower_leaving_temp``).

    With Q = m c_p (T_in - T_lw) and adj = Q / (Q_design air): T_lw = (T_wb + alpha + beta g T_in) / (1 + beta g),
    g = m c_p / (Q_design air); then held in [T_wb + approach_min, T_in].
    """
    cell = system.towers.cell
    alpha, beta = york_coefficients_k(system, wet_bulb_k)
    air = max(float(fan_speed), cell.free_convection_air_ratio)
    gamma = cell.water_flow_kg_s * CP_WATER_J_KG_K / (cell.design_heat_w * air)
    t_lw = (wet_bulb_k + alpha + beta * gamma * entering_k) / (1.0 + beta * gamma)
    return min(max(t_lw, wet_bulb_k + cell.approach_min_k), entering_k)


def tower_fan_power_from_speed_w(system: SystemDescription, fan_speed: ArrayLike, cells_active: ArrayLike) -> ArrayLike:
    """Fan power of a tower: cells_active * P_nominal * speed^3 (fan affinity law, as the twin)."""
    return np.multiply(cells_active, system.towers.cell.fan_power_nominal_w * np.power(fan_speed, 3))


@dataclass(frozen=True)
class TowerFanEstimate:
    """Fan speed and power a tower needs to hold an approach while rejecting a heat load."""

    fan_speed: float  # fraction of nominal; 1.0 when the approach is out of reach
    fan_power_w: float  # all active cells
    reachable: bool  # False: even full fan speed cannot reach the asked approach
    approach_at_full_speed_k: float  # the best approach at full fan speed, same heat and wet bulb
    heat_per_cell_w: float


def tower_fan_power_w(
    system: SystemDescription, heat_w: float, approach_k: float, wet_bulb_k: float, cells_active: int
) -> TowerFanEstimate:
    """Fan power a tower needs to reject `heat_w` over `cells_active` cells at `approach_k` (twin tower model).

    Inverting T_app = alpha + beta Q_cell / (Q_design air) gives air = beta Q_cell / (Q_design (T_app - alpha));
    fan speed = air (below the free-convection ratio no fan is needed), power = cells P_nom speed^3.
    """
    if cells_active < 1:
        raise ValueError(f"`cells_active` must be >= 1, got {cells_active}")
    cell = system.towers.cell
    alpha, beta = york_coefficients_k(system, wet_bulb_k)
    q_cell = max(float(heat_w), 0.0) / cells_active
    best = tower_approach_k(system, wet_bulb_k, q_cell, 1.0)
    margin = approach_k - alpha
    if approach_k < best - 1e-12 or margin <= 0.0:
        speed, reachable = 1.0, False
    else:
        air = beta * q_cell / (cell.design_heat_w * margin)
        speed, reachable = (0.0 if air <= cell.free_convection_air_ratio else min(air, 1.0)), True
    power = float(tower_fan_power_from_speed_w(system, speed, cells_active))
    return TowerFanEstimate(speed, power, reachable, best, q_cell)


# --- pumps and fans: affinity laws ---------------------------------------------------------------
@dataclass(frozen=True)
class AffinityPoint:
    """A pump or fan operating point scaled to a new speed."""

    speed_ratio: float
    flow: float  # same unit as given (kg/s, m^3/s, ...)
    head: float  # pump head (m or Pa) or fan static pressure (Pa), same unit as given
    power_w: float


def affinity_scale(
    speed_from: float, speed_to: float, flow: float, head: float, power_w: float
) -> AffinityPoint:
    """Affinity laws for a fixed impeller on a fixed system curve: Q ~ n, H ~ n^2, P ~ n^3."""
    if speed_from <= 0:
        raise ValueError(f"`speed_from` must be > 0, got {speed_from}")
    r = speed_to / speed_from
    return AffinityPoint(speed_to, flow * r, head * r * r, power_w * r**3)


def pump_affinity(speed_from: float, speed_to: float, flow: float, head: float, power_w: float) -> AffinityPoint:
    """Pump affinity laws: flow ~ speed, head ~ speed^2, shaft power ~ speed^3."""
    return affinity_scale(speed_from, speed_to, flow, head, power_w)


def fan_affinity(
    speed_from: float, speed_to: float, airflow: float, pressure_pa: float, power_w: float
) -> AffinityPoint:
    """Fan affinity laws: airflow ~ speed, pressure ~ speed^2, power ~ speed^3."""
    return affinity_scale(speed_from, speed_to, airflow, pressure_pa, power_w)


# --- the CDU pump of the twin ---------------------------------------------------------------------
@dataclass(frozen=True)
class CduPumpModel:
    """The CDU pump and secondary loop of a system, as the twin models them (docs/twin.md, CDU pump).

    Pump head in Pa: c - k m^2 with c = rho g a s^2 (1 - head_loss), k = g b / (rho n^2) (the fitted
    curve H = a - b q^2 of n parallel pumps); loop: dp = R m with R = R_hx + R_cabinet.
    """

    a_m: float
    b_s2_m5: float
    n_parallel: int
    r_loop_pa_s_kg: float
    r_cabinet_pa_s_kg: float
    efficiency: float
    speed_min: float
    speed_max: float

    @classmethod
    def from_system(cls, system: SystemDescription) -> "CduPumpModel":
        cdu = system.cabinets.cdu
        a, b = fit_pump_curve(cdu.pump)
        r_loop = cdu.r_hx_secondary_pa_per_kg_s + cdu.r_cabinet_pa_per_kg_s
        return cls(a, b, cdu.pump.n_parallel, r_loop, cdu.r_cabinet_pa_per_kg_s, cdu.pump.efficiency,
                   cdu.pump.speed_min, cdu.pump.speed_max)  # fmt: skip

    @property
    def _k(self) -> float:
        return GRAVITY_M_S2 * self.b_s2_m5 / (RHO_WATER_KG_M3 * self.n_parallel**2)

    def flow_kg_s(self, speed: ArrayLike, head_loss: ArrayLike = 0.0) -> ArrayLike:
        """Secondary flow where the curve meets the loop: m = 2c / (R + sqrt(R^2 + 4 k c))."""
        c = RHO_WATER_KG_M3 * GRAVITY_M_S2 * np.square(speed) * self.a_m * (1.0 - np.clip(head_loss, 0.0, 0.95))
        r = self.r_loop_pa_s_kg
        flow = np.where(c > 0, 2.0 * c / (r + np.sqrt(r * r + 4.0 * self._k * np.maximum(c, 0.0))), 0.0)
        return flow.item() if flow.ndim == 0 else flow

    def head_loss(self, speed: ArrayLike, flow_kg_s: ArrayLike) -> ArrayLike:
        """Fraction of curve head missing at a measured operating point: 1 - (R m + k m^2) / (rho g a s^2)."""
        head_pa = self.r_loop_pa_s_kg * np.asarray(flow_kg_s) + self._k * np.square(flow_kg_s)
        nominal_pa = RHO_WATER_KG_M3 * GRAVITY_M_S2 * self.a_m * np.square(speed)
        with np.errstate(divide="ignore", invalid="ignore"):
            loss = np.where(nominal_pa > 0, 1.0 - head_pa / np.where(nominal_pa > 0, nominal_pa, 1.0), np.nan)
        return loss.item() if loss.ndim == 0 else loss

    def head_loss_limit(self, dp_setpoint_pa: ArrayLike) -> ArrayLike:
        """Head loss above which even top speed cannot hold the cabinet dp setpoint (flow m = dp / R_cabinet)."""
        return self.head_loss(self.speed_max, np.asarray(dp_setpoint_pa) / self.r_cabinet_pa_s_kg)

    def power_w(self, flow_kg_s: ArrayLike) -> ArrayLike:
        """Hydraulic power over efficiency: P = dp m / (rho eta) with dp = R m."""
        m = np.asarray(flow_kg_s, dtype=float)
        p = self.r_loop_pa_s_kg * m * m / (RHO_WATER_KG_M3 * self.efficiency)
        return p.item() if p.ndim == 0 else p


# --- CDU heat balance from plant outputs -----------------------------------------------------------
@dataclass(frozen=True)
class CduHeatBalance:
    """Heat removed by one CDU against the heat its branches put in, from one step's plant outputs."""

    cabinet: int
    cdu_heat_w: float  # heat moved by the CDU heat exchanger (step mean)
    branch_heat_w: float  # IT heat into the coolant incl. the non-linear term, less blade storage
    stored_heat_w: float  # rate of heat going into blade and coolant storage (0 without `previous_out`)
    residual_w: float  # branch_heat - stored - cdu_heat; ~0 for a consistent plant
    residual_pct: float  # of the CDU heat
    implied_supply_temp_k: float  # T_return - Q_cdu / (m_s c_p): the supply the heat balance implies
    supply_residual_k: float  # measured supply - implied supply


def branch_heat_w(system: SystemDescription, branch_power_w: ArrayLike) -> ArrayLike:
    """Heat a branch puts into its blades: q = P (1 + a P / P_unit), the paper's non-linear term (twin)."""
    bg = system.cabinets.blade_group
    p = np.maximum(np.asarray(branch_power_w, dtype=float), 0.0)
    return p * (1.0 + bg.heat_nonlinearity * p / bg.heat_unit_w)


def cdu_heat_balance(
    out: Mapping[str, np.ndarray],
    cabinet: int,
    system: SystemDescription,
    previous_out: Mapping[str, np.ndarray] | None = None,
) -> CduHeatBalance:
    """Residual between CDU heat removed and branch heat in for `cabinet`, from plant outputs.

    Branch heat uses the twin's non-linear heat term (exact for one blade group per branch, a lower
    bound for unequal groups). With `previous_out` (the step before) the rate of heat stored in the
    blades (C dT/dt) and the two coolant volumes (M c_p dT/dt) is taken off, so the residual is small
    in transients too; without it the balance holds in steady state only.
    """
    C = system.cabinets.count
    if not 0 <= cabinet < C:
        raise ValueError(f"`cabinet` must be in [0, {C - 1}], got {cabinet}")
    cab, bg = system.cabinets, system.cabinets.blade_group
    q_in = float(branch_heat_w(system, out["branch_power_w"][cabinet]).sum())
    stored = 0.0
    if previous_out is not None:
        dt_s = system.step_s
        d_blade = np.asarray(out["branch_temp_k"][cabinet]) - np.asarray(previous_out["branch_temp_k"][cabinet])
        stored += float(bg.branch_heat_capacity_j_per_k * d_blade.sum()) / dt_s
        volumes_m3 = {"return_temp_k": cab.coolant_volume_m3, "supply_temp_k": cab.cdu.hx_secondary_volume_m3}
        for key, volume_m3 in volumes_m3.items():
            d_t = float(out[key][cabinet] - previous_out[key][cabinet])
            stored += volume_m3 * RHO_WATER_KG_M3 * CP_WATER_J_KG_K * d_t / dt_s
    q_cdu = float(out["cdu_heat_w"][cabinet])
    residual = q_in - stored - q_cdu
    flow = float(out["secondary_flow_kg_s"][cabinet])
    implied = float(out["return_temp_k"][cabinet]) - (q_cdu / (flow * CP_WATER_J_KG_K) if flow > 0 else 0.0)
    measured = float(out["supply_temp_measured_k"][cabinet]) if "supply_temp_measured_k" in out else implied
    return CduHeatBalance(
        cabinet=cabinet,
        cdu_heat_w=q_cdu,
        branch_heat_w=q_in,
        stored_heat_w=stored,
        residual_w=residual,
        residual_pct=100.0 * residual / q_cdu if abs(q_cdu) > 1e-9 else float("nan"),
        implied_supply_temp_k=implied,
        supply_residual_k=measured - implied,
    )
