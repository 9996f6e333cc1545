"""Plain-text messages and prescriptions of the fault detector's findings: numbers with units, deg C in text only.

Each function takes the detector, the location's 0-based slot index and the finding's evidence, and returns
(severity, message, prescription, predicted_failure_s). Texts are for people: cabinets (and their CDUs),
branches, towers and cells count from 1, as on the page, in the API and in the chat.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lcmesh.mesh.tools import thermo

if TYPE_CHECKING:
    from lcmesh.mesh.tools.maintenance import FaultDetector

_K = 273.15


def _c(t_k: float) -> str:
    return f"{t_k - _K:.1f} °C"


def _pump_text(det: FaultDetector, i: int, d: dict):
    cab = i + 1
    loss, limit = d["head_loss"], d["head_loss_limit"]
    critical = d.get("head_loss_vs_curve", loss) >= limit  # the limit is on the head the curve should give
    reference = "as commissioned" if d.get("baseline_learned") else "its curve"
    msg = (f"CDU pump of cabinet {cab} gives {loss:.0%} less head than {reference} at {d['pump_speed']:.0%} speed: "
           f"{d['flow_kg_s']:.1f} kg/s where a healthy pump gives {d['expected_flow_kg_s']:.1f} kg/s.")  # fmt: skip
    eta = d["time_to_limit_s"]
    if critical:
        msg += f" Even at full speed it cannot hold the dp setpoint (that needs head loss below {limit:.0%})."
        eta = 0.0
    elif np.isfinite(eta) and eta < det.config.pump_trend_horizon_s:
        msg += (f" Head loss rises {d['head_loss_slope_per_h']:.1%}/h and reaches the {limit:.0%} limit in about "
                f"{eta / 3600:.1f} h.")  # fmt: skip
    else:
        eta = None
    fix = (f"Inspect the cabinet {cab} CDU pumps (impeller wear, clogged strainer, air in the loop, a failed pump "
           f"of the parallel set) and schedule the repair; meanwhile watch cabinet {cab}'s flow and branch "
           "temperatures.")
    return ("critical" if critical else "warning"), msg, fix, eta


def _bias_text(det: FaultDetector, i: int, d: dict):
    cab = i + 1
    b = d["bias_estimate_k"]
    msg = (f"Supply temperature sensor of cabinet {cab} reads {b:+.2f} K off: it shows "
           f"{_c(d['measured_supply_k'])} while the CDU heat balance implies {_c(d['implied_supply_k'])}.")  # fmt: skip
    effect = "overcooling and wasting tower energy" if b > 0 else "leaving the blades less cooling margin"
    side = "below" if b > 0 else "above"
    fix = (f"Recalibrate or replace the supply sensor of CDU {cab}. Its valve loop follows the reading, so the real "
           f"supply sits {abs(b):.1f} K {side} its setpoint ({effect}); until it is fixed, offset that setpoint by "
           f"{b:+.1f} K.")
    return ("critical" if abs(b) >= 2.0 else "warning"), msg, fix, None


def _valve_text(det: FaultDetector, i: int, d: dict):
    cab = i + 1
    err = d["supply_error_k"]
    msg = (f"Primary valve of CDU {cab} stays at {d['valve_position']:.0%} open while its supply is {err:+.2f} K "
           f"from setpoint; its control loop should have moved it about {d['owed_travel']:.0%} of stroke by now.")
    fix = (f"Check the valve actuator and positioner of CDU {cab} (power or air supply, stem, linkage) and stroke "
           f"it by hand; until it moves, cabinet {cab}'s supply temperature is not controlled, so watch its blades.")
    return ("critical" if abs(err) > 2.0 else "warning"), msg, fix, None


def _cell_text(det: FaultDetector, i: int, d: dict):
    n, j = divmod(i, det.m)
    tower, cell = n + 1, j + 1
    on, out, m = int(d["cells_active"]), det.active_out_cells(n), det.m
    msg = (f"Cell {cell} of tower {tower} is out of service: {d['fan_power_w'] / 1e3:.1f} kW fan power and "
           f"{d['heat_w'] / 1e3:.0f} kW heat while the tower runs {on} cell(s) at {d['fan_speed']:.0%} fan speed.")
    if d["stage_up_demand_s"] >= det.system.towers.stage_delay_s:
        msg += f" The tower has asked for another cell for {d['stage_up_demand_s'] / 60:.0f} min."
    fix = f"Check the fan motor, drive and isolation valves of tower {tower}'s cell {cell} and return it to service."
    heat, approach, wet_bulb = d["tower_heat_w"], d.get("approach_k", np.nan), d.get("wet_bulb_k", np.nan)
    if on >= 1 and np.isfinite(approach) and np.isfinite(wet_bulb) and approach > 0:
        now = thermo.tower_fan_power_w(det.system, heat, approach, wet_bulb, on)
        full = thermo.tower_fan_power_w(det.system, heat, approach, wet_bulb, m)
        if now.reachable and full.reachable:
            fix += (f" Holding the {approach:.1f} K approach at {heat / 1e3:.0f} kW costs about "
                    f"{now.fan_power_w / 1e3:.0f} kW of fan on {on} cell(s) against {full.fan_power_w / 1e3:.0f} kW "
                    f"on all {m}.")  # fmt: skip
        else:
            fix += f" Tower {tower} cannot hold a {approach:.1f} K approach at {heat / 1e3:.0f} kW on {on} cell(s)."
    return ("critical" if out >= m else "warning"), msg, fix, None


def _overtemp_text(det: FaultDetector, i: int, d: dict):
    cab = i + 1
    b, t = int(d["branch"]), d["hottest_branch_temp_k"]
    msg = f"Branch {b} of cabinet {cab} is at {_c(t)}, above the {_c(d['limit_k'])} limit."
    fix = (f"Lower cabinet {cab}'s supply setpoint, raise its dp setpoint or shift its valve split toward "
           f"branch {b}; check cabinet {cab}'s CDU findings.")  # fmt: skip
    return ("critical" if t > det.config.overtemp_critical_k else "warning"), msg, fix, None


def _trend_text(det: FaultDetector, i: int, d: dict):
    cab = i + 1
    eta = d["time_to_limit_s"]
    msg = (f"The hottest branch of cabinet {cab} rises {d['slope_k_per_s'] * 60:.2f} K/min (95 % CI from "
           f"{d['slope_low_k_per_s'] * 60:.2f}); at {_c(d['hottest_branch_temp_k'])} now it reaches "
           f"{_c(d['limit_k'])} in about {eta / 60:.0f} min.")  # fmt: skip
    fix = f"Act before the limit: lower cabinet {cab}'s supply setpoint or raise its flow, and check its IT load."
    return ("warning" if eta < det.config.trend_horizon_s / 2 else "info"), msg, fix, float(eta)


DESCRIBE = {
    "pump_degradation": _pump_text, "sensor_bias": _bias_text, "valve_stuck": _valve_text,
    "cell_out": _cell_text, "overtemperature": _overtemp_text, "trend": _trend_text,
}  # fmt: skip
