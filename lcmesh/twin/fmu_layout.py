"""Variable layout of the generated FMU: every variable of a system, with its value reference.

Pure Python (no fmpy): the builder writes it into C and XML, the plant reads arrays by block name.
Value references are contiguous per block, so one numpy buffer reads or writes a whole block.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import prod

import numpy as np

from lcmesh.twin.system import PSI_TO_PA, PumpCurve, SystemDescription

RHO_WATER = 997.0


@dataclass(frozen=True)
class Block:
    """A named array of FMI reals with contiguous value references."""

    name: str  # FMI base name, e.g. "blade_temp_k"
    c_name: str  # macro stem in C, e.g. "OUT_BLADE_TEMP"
    shape: tuple[int, ...]
    causality: str  # parameter | input | output
    unit: str
    description: str
    start: tuple[float, ...] | None = None  # one value per element (parameters, inputs)
    offset: int = 0

    @property
    def size(self) -> int:
        return prod(self.shape)

    def vrs(self) -> np.ndarray:
        return np.arange(self.offset, self.offset + self.size, dtype=np.uint32)

    def element_names(self) -> list[str]:
        if self.shape == ():
            return [self.name]
        if len(self.shape) == 1:
            return [f"{self.name}[{i + 1}]" for i in range(self.shape[0])]
        rows, cols = self.shape
        return [f"{self.name}[{i + 1},{j + 1}]" for i in range(rows) for j in range(cols)]


@dataclass(frozen=True)
class Layout:
    blocks: tuple[Block, ...]

    @property
    def n_reals(self) -> int:
        last = self.blocks[-1]
        return last.offset + last.size

    def __getitem__(self, name: str) -> Block:
        for block in self.blocks:
            if block.name == name:
                return block
        raise KeyError(f"no variable block named {name!r}")

    def by_causality(self, causality: str) -> list[Block]:
        return [b for b in self.blocks if b.causality == causality]


def fit_pump_curve(curve: PumpCurve) -> tuple[float, float]:
    """Least-squares fit head_m = a - b*q^2 (q in m^3/s per pump) at nominal speed."""
    q2 = np.asarray(curve.flow_m3_s, dtype=float) ** 2
    head = np.asarray(curve.head_m, dtype=float)
    design = np.column_stack([np.ones_like(q2), -q2])
    (a, b), *_ = np.linalg.lstsq(design, head, rcond=None)
    return float(a), float(max(b, 0.0))


def parameter_values(system: SystemDescription) -> list[tuple[str, str, float, str, str]]:
    """(fmi name, C macro, value, unit, description) for every model parameter."""
    cab, cdu, bg = system.cabinets, system.cabinets.cdu, system.cabinets.blade_group
    tw, cell, htw = system.towers, system.towers.cell, system.htw
    per_group = cab.blade_groups_per_branch
    cdu_a, cdu_b = fit_pump_curve(cdu.pump)
    hru = system.heat_recovery
    rows = [
        ("bg_heat_capacity", "P_BG_HEAT_CAPACITY", bg.branch_heat_capacity_j_per_k / per_group, "J/K",
         "heat capacity of one blade group"),
        ("bg_conductance", "P_BG_CONDUCTANCE", bg.branch_conductance_w_per_k / per_group, "W/K",
         "blade-to-coolant conductance of one blade group at nominal flow"),
        ("bg_flow_nominal", "P_BG_FLOW_NOMINAL", bg.nominal_branch_flow_kg_s / per_group, "kg/s",
         "nominal coolant flow through one blade group"),
        ("bg_flow_exponent", "P_BG_FLOW_EXPONENT", bg.conductance_flow_exponent, "1",
         "conductance ~ flow^exponent"),
        ("heat_nonlinearity", "P_HEAT_NONLINEARITY", bg.heat_nonlinearity, "1",
         "quadratic heat term: q = P*(1 + a*P/unit)"),
        ("heat_unit", "P_HEAT_UNIT", bg.heat_unit_w / per_group, "W", "scaled heat unit of one blade group"),
        ("throttle_start", "P_THROTTLE_START", bg.throttle_start_k, "K", "blades start throttling"),
        ("shutdown_temp", "P_SHUTDOWN_TEMP", bg.shutdown_k, "K", "blades throttled to zero"),
        ("cabinet_volume_kg", "P_CABINET_VOLUME_KG", cab.coolant_volume_m3 * RHO_WATER, "kg",
         "coolant mass of the cabinet volume"),
        ("hx_volume_kg", "P_HX_VOLUME_KG", cdu.hx_secondary_volume_m3 * RHO_WATER, "kg",
         "coolant mass of the CDU secondary side"),
        ("hx_ua_sat", "P_HX_UA_SAT", cdu.hx_ua_sat_w_per_k, "W/K", "CDU HX UA at saturation flow"),
        ("hx_ua_correction", "P_HX_UA_CORRECTION", cdu.hx_ua_correction, "1", "CDU HX UA correction"),
        ("hx_flow_sat", "P_HX_FLOW_SAT", cdu.hx_flow_sat_m3_s, "m3/s", "volume flow where UA saturates"),
        ("r_hx_secondary", "P_R_HX_SECONDARY", cdu.r_hx_secondary_pa_per_kg_s, "Pa.s/kg",
         "CDU HX secondary flow resistance"),
        ("r_cabinet", "P_R_CABINET", cdu.r_cabinet_pa_per_kg_s, "Pa.s/kg", "cabinet flow resistance"),
        ("primary_flow_max", "P_PRIMARY_FLOW_MAX", cdu.primary_flow_max_kg_s, "kg/s",
         "primary flow at a fully open valve"),
        ("valve_min", "P_VALVE_MIN", cdu.valve_opening_min, "1", "minimum primary valve opening"),
        ("cdu_pump_a", "P_CDU_PUMP_A", cdu_a, "m", "pump head at zero flow (fit)"),
        ("cdu_pump_b", "P_CDU_PUMP_B", cdu_b, "s2/m5", "pump head curvature (fit)"),
        ("cdu_pump_n", "P_CDU_PUMP_N", float(cdu.pump.n_parallel), "1", "CDU pumps in parallel"),
        ("cdu_pump_eta", "P_CDU_PUMP_ETA", cdu.pump.efficiency, "1", "CDU pump efficiency"),
        ("cdu_speed_min", "P_CDU_SPEED_MIN", cdu.pump.speed_min, "1", "minimum CDU pump speed"),
        ("cdu_speed_max", "P_CDU_SPEED_MAX", cdu.pump.speed_max, "1", "maximum CDU pump speed"),
        ("pump_tau", "P_PUMP_TAU", cdu.pump_time_constant_s, "s", "pump drive lag"),
        ("valve_tau", "P_VALVE_TAU", cdu.valve_time_constant_s, "s", "primary valve lag"),
        ("dp_k", "P_DP_K", cdu.dp_pid.k, "1/psi", "dp PID gain"),
        ("dp_ti", "P_DP_TI", cdu.dp_pid.ti_s, "s", "dp PID integral time"),
        ("dp_td", "P_DP_TD", cdu.dp_pid.td_s, "s", "dp PID derivative time"),
        ("temp_k", "P_TEMP_K", cdu.temp_pid.k, "1/K", "supply temperature PID gain"),
        ("temp_ti", "P_TEMP_TI", cdu.temp_pid.ti_s, "s", "supply temperature PID integral time"),
        ("temp_td", "P_TEMP_TD", cdu.temp_pid.td_s, "s", "supply temperature PID derivative time"),
        ("temp_deadband", "P_TEMP_DEADBAND", cdu.temp_deadband_k, "K", "supply temperature deadband"),
        ("htw_supply_kg", "P_HTW_SUPPLY_KG", htw.supply_volume_m3 * RHO_WATER, "kg", "HTW supply mass"),
        ("htw_return_kg", "P_HTW_RETURN_KG", htw.return_volume_m3 * RHO_WATER, "kg", "HTW return mass"),
        ("htw_bypass", "P_HTW_BYPASS", htw.bypass_fraction, "1", "HTW flow margin over CDU demand"),
        ("htw_flow_min", "P_HTW_FLOW_MIN", htw.flow_min_kg_s, "kg/s", "minimum HTW flow"),
        ("htw_r_header", "P_HTW_R_HEADER", htw.r_header_pa_per_kg_s, "Pa.s/kg", "HTW header resistance"),
        ("htw_cdu_dp", "P_HTW_CDU_DP", htw.cdu_branch_dp_pa, "Pa", "dp across a CDU primary branch"),
        ("htw_pump_eta", "P_HTW_PUMP_ETA", htw.pump.efficiency, "1", "HTW pump efficiency"),
        ("hru_ua", "P_HRU_UA", hru.ua_w_per_k if hru else 0.0, "W/K", "heat-recovery HX UA"),
        ("hru_flow", "P_HRU_FLOW", hru.district_flow_kg_s if hru else 1.0, "kg/s", "district loop flow"),
        ("hru_temp", "P_HRU_TEMP", hru.district_supply_temp_k if hru else 293.15, "K", "district supply"),
        ("ct_cell_flow", "P_CT_CELL_FLOW", cell.water_flow_kg_s, "kg/s", "water flow per active cell"),
        ("ct_fan_nominal", "P_CT_FAN_NOMINAL", cell.fan_power_nominal_w, "W", "fan power at full speed"),
        ("ct_design_heat", "P_CT_DESIGN_HEAT", cell.design_heat_w, "W", "cell heat at adj = 1"),
        ("ct_free_convection", "P_CT_FREE_CONVECTION", cell.free_convection_air_ratio, "1",
         "air ratio with the fan off"),
        ("ct_wb_max_f", "P_CT_WB_MAX_F", cell.york_wet_bulb_max_f, "degF", "clamp of the fit's wet bulb"),
        ("ct_approach_min", "P_CT_APPROACH_MIN", cell.approach_min_k, "K", "smallest approach"),
        ("fan_k", "P_FAN_K", cell.fan_pi.k, "1/K", "fan PI gain"),
        ("fan_ti", "P_FAN_TI", cell.fan_pi.ti_s, "s", "fan PI integral time"),
        ("fan_tau", "P_FAN_TAU", cell.fan_time_constant_s, "s", "fan drive lag"),
        ("ct_pump_head", "P_CT_PUMP_HEAD", cell.pump_head_m, "m", "tower pump head"),
        ("ct_pump_eta", "P_CT_PUMP_ETA", cell.pump_efficiency, "1", "tower pump efficiency"),
        ("ehx_ua", "P_EHX_UA", tw.ehx_ua_w_per_k, "W/K", "plate HX UA per train"),
        ("basin_kg", "P_BASIN_KG", tw.basin_volume_m3 * RHO_WATER, "kg", "tower loop water mass per tower"),
        ("stage_up_speed", "P_STAGE_UP_SPEED", tw.stage_up_speed, "1", "fan speed that stages a cell on"),
        ("stage_down_speed", "P_STAGE_DOWN_SPEED", tw.stage_down_speed, "1", "fan speed that stages off"),
        ("stage_delay", "P_STAGE_DELAY", tw.stage_delay_s, "s", "staging delay"),
        ("init_supply_setpoint", "P_INIT_SUPPLY_SETPOINT", cdu.supply_temp_setpoint_k, "K",
         "initial and fallback supply setpoint"),
        ("init_dp_setpoint", "P_INIT_DP_SETPOINT", cdu.dp_setpoint_pa, "Pa", "initial and fallback dp setpoint"),
        ("init_lw_setpoint", "P_INIT_LW_SETPOINT", tw.lw_setpoint_k, "K", "initial leaving-water setpoint"),
    ]
    return rows


def build_layout(system: SystemDescription) -> Layout:
    """All FMU variables of `system`, value references assigned in order."""
    C, B = system.cabinets.count, system.cabinets.branches
    nbg, N, m = system.n_blade_groups, system.towers.count, system.towers.cells
    cdu = system.cabinets.cdu
    blocks: list[Block] = [
        Block(name, macro, (), "parameter", unit, desc, (value,))
        for name, macro, value, unit, desc in parameter_values(system)
    ]

    def inp(name, c_name, shape, unit, desc, start):
        size = prod(shape)
        blocks.append(Block(name, c_name, shape, "input", unit, desc, (float(start),) * size))

    def out(name, c_name, shape, unit, desc):
        blocks.append(Block(name, c_name, shape, "output", unit, desc))

    inp("blade_power_w", "IN_BLADE_POWER", (nbg,), "W", "IT power of each blade group", 0.0)
    inp("wet_bulb_k", "IN_WET_BULB", (), "K", "outside-air wet bulb", 288.15)
    inp("supply_temp_setpoint_k", "IN_SUPPLY_TEMP_SETPOINT", (C,), "K", "CDU coolant supply setpoint",
        cdu.supply_temp_setpoint_k)
    inp("dp_setpoint_pa", "IN_DP_SETPOINT", (C,), "Pa", "CDU cabinet differential-pressure setpoint",
        cdu.dp_setpoint_pa)
    inp("valve_fraction", "IN_VALVE_FRACTION", (C, B), "1", "branch valve split (normalized to sum 1)", 1.0 / B)
    inp("lw_setpoint_k", "IN_LW_SETPOINT", (N,), "K", "tower leaving-water setpoint", system.towers.lw_setpoint_k)
    inp("fault_pump_degradation", "IN_FAULT_PUMP_DEGRADATION", (C,), "1", "fault: CDU pump head loss 0..0.95", 0)
    inp("fault_valve_stuck", "IN_FAULT_VALVE_STUCK", (C,), "1", "fault: primary valve stuck when > 0.5", 0)
    inp("fault_cell_out", "IN_FAULT_CELL_OUT", (N, m), "1", "fault: tower cell out of service when > 0.5", 0)
    inp("fault_sensor_bias_k", "IN_FAULT_SENSOR_BIAS", (C,), "K", "fault: supply temperature sensor bias", 0)
    inp("hru_enable", "IN_HRU_ENABLE", (), "1", "heat-recovery unit on when > 0.5",
        1.0 if system.heat_recovery else 0.0)
    # the plant as built differs from its description (calibration, fouling): factors, 1 = as described
    inp("deviation_hx_ua_factor", "IN_DEVIATION_HX_UA", (C,), "1", "plant deviation: CDU HX UA x this", 1)
    inp("deviation_pump_head_factor", "IN_DEVIATION_PUMP_HEAD", (C,), "1",
        "plant deviation: CDU pump curve head x this", 1)
    inp("deviation_ct_approach_factor", "IN_DEVIATION_CT_APPROACH", (N,), "1",
        "plant deviation: tower approach correlation x this", 1)

    out("blade_temp_k", "OUT_BLADE_TEMP", (nbg,), "K", "blade group temperature")
    out("branch_temp_k", "OUT_BRANCH_TEMP", (C, B), "K", "mean blade temperature of the branch")
    out("branch_max_temp_k", "OUT_BRANCH_MAX_TEMP", (C, B), "K", "hottest blade group of the branch")
    out("branch_power_w", "OUT_BRANCH_POWER", (C, B), "W", "IT power of the branch")
    out("branch_flow_kg_s", "OUT_BRANCH_FLOW", (C, B), "kg/s", "coolant flow of the branch")
    out("applied_valve_fraction", "OUT_APPLIED_VALVE_FRACTION", (C, B), "1", "valve split as applied")
    for name, c_name, unit, desc in [
        ("supply_temp_k", "OUT_SUPPLY_TEMP", "K", "coolant supply temperature"),
        ("supply_temp_measured_k", "OUT_SUPPLY_TEMP_MEASURED", "K", "supply temperature as the sensor reads it"),
        ("return_temp_k", "OUT_RETURN_TEMP", "K", "coolant return temperature"),
        ("secondary_flow_kg_s", "OUT_SECONDARY_FLOW", "kg/s", "secondary coolant flow"),
        ("cabinet_dp_pa", "OUT_CABINET_DP", "Pa", "cabinet differential pressure"),
        ("pump_speed", "OUT_PUMP_SPEED", "1", "CDU pump speed (fraction of nominal)"),
        ("cdu_pump_power_w", "OUT_CDU_PUMP_POWER", "W", "CDU pump power (step mean)"),
        ("primary_valve", "OUT_PRIMARY_VALVE", "1", "primary valve opening"),
        ("primary_flow_kg_s", "OUT_PRIMARY_FLOW", "kg/s", "primary (HTW) flow through the CDU"),
        ("primary_return_temp_k", "OUT_PRIMARY_RETURN_TEMP", "K", "primary leaving temperature (step mean)"),
        ("cdu_heat_w", "OUT_CDU_HEAT", "W", "heat moved by the CDU HX (step mean)"),
        ("applied_supply_setpoint_k", "OUT_APPLIED_SUPPLY_SETPOINT", "K", "supply setpoint as applied"),
        ("applied_dp_setpoint_pa", "OUT_APPLIED_DP_SETPOINT", "Pa", "dp setpoint as applied"),
    ]:
        out(name, c_name, (C,), unit, desc)
    out("htw_supply_temp_k", "OUT_HTW_SUPPLY_TEMP", (), "K", "HTW supply header temperature")
    out("htw_return_temp_k", "OUT_HTW_RETURN_TEMP", (), "K", "HTW return header temperature")
    out("htw_flow_kg_s", "OUT_HTW_FLOW", (), "kg/s", "HTW loop flow (step mean)")
    out("htw_pump_power_w", "OUT_HTW_PUMP_POWER", (), "W", "HTW pump power (step mean)")
    for name, c_name, unit, desc in [
        ("ehx_heat_w", "OUT_EHX_HEAT", "W", "plate HX heat to the tower loop (step mean)"),
        ("ct_water_flow_kg_s", "OUT_CT_WATER_FLOW", "kg/s", "tower water flow"),
        ("ct_entering_temp_k", "OUT_CT_ENTERING_TEMP", "K", "water entering the cells (step mean)"),
        ("ct_leaving_temp_k", "OUT_CT_LEAVING_TEMP", "K", "water leaving the cells"),
        ("ct_basin_temp_k", "OUT_CT_BASIN_TEMP", "K", "tower loop (basin) temperature"),
        ("fan_speed", "OUT_FAN_SPEED", "1", "fan speed of the active cells"),
        ("cells_active", "OUT_CELLS_ACTIVE", "1", "cells staged on"),
        ("ct_pump_power_w", "OUT_CT_PUMP_POWER", "W", "tower pump power (step mean)"),
        ("approach_k", "OUT_APPROACH", "K", "leaving water minus wet bulb (step mean)"),
        ("applied_lw_setpoint_k", "OUT_APPLIED_LW_SETPOINT", "K", "leaving-water setpoint as applied"),
    ]:
        out(name, c_name, (N,), unit, desc)
    out("cell_fan_power_w", "OUT_CELL_FAN_POWER", (N, m), "W", "fan power of each cell (step mean)")
    out("cell_heat_w", "OUT_CELL_HEAT", (N, m), "W", "heat rejected by each cell (step mean)")
    for name, c_name, unit, desc in [
        ("heat_in_w", "OUT_HEAT_IN", "W", "heat into the blade groups incl. the non-linear term (step mean)"),
        ("heat_rejected_w", "OUT_HEAT_REJECTED", "W", "heat rejected by the towers (step mean)"),
        ("heat_recovered_w", "OUT_HEAT_RECOVERED", "W", "heat recovered to the district loop (step mean)"),
        ("district_return_temp_k", "OUT_DISTRICT_RETURN_TEMP", "K", "district loop leaving temperature"),
        ("stored_energy_rate_w", "OUT_STORED_ENERGY_RATE", "W", "rate of stored thermal energy (step mean)"),
        ("stored_energy_j", "OUT_STORED_ENERGY", "J", "stored thermal energy (reference 0 K)"),
        ("stored_energy_change_j", "OUT_STORED_ENERGY_CHANGE", "J", "stored energy minus its initial value"),
        ("energy_in_j", "OUT_ENERGY_IN", "J", "heat in since initialization"),
        ("energy_rejected_j", "OUT_ENERGY_REJECTED", "J", "heat rejected since initialization"),
        ("energy_recovered_j", "OUT_ENERGY_RECOVERED", "J", "heat recovered since initialization"),
        ("ct_fan_power_w", "OUT_CT_FAN_POWER_TOTAL", "W", "total tower fan power (step mean)"),
        ("pump_power_w", "OUT_PUMP_POWER_TOTAL", "W", "CDU + HTW + tower pump power (step mean)"),
        ("it_cooling_w", "OUT_IT_COOLING", "W", "heat removed at the CDUs (step mean)"),
        ("it_power_w", "OUT_IT_POWER", "W", "IT power demanded by all blade groups"),
        ("throttled_power_w", "OUT_THROTTLED_POWER", "W", "IT power lost to thermal throttling"),
    ]:
        out(name, c_name, (), unit, desc)

    offset = 0
    placed = []
    for block in blocks:
        placed.append(Block(**{**block.__dict__, "offset": offset}))
        offset += block.size
    return Layout(tuple(placed))


__all__ = ["Block", "Layout", "build_layout", "fit_pump_curve", "parameter_values", "PSI_TO_PA"]
