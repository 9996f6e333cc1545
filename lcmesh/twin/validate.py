"""Physics checks of a twin (``lcmesh twin validate``); the tests assert the same checks.

Each check returns ``{"name", "passed", "criterion", ...measured values}``; the checks against published
Frontier figures also carry ``"source"``. Steady states come from holding inputs constant for `settle_h`
simulated hours from a saved state. Sources and why each range is what it is: docs/twin.md, "Validation".
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.controllers.static import StaticController
from lcmesh.twin.plant import Plant, PlantAction
from lcmesh.twin.run import plot_run, run_twin
from lcmesh.twin.system import PSI_TO_PA, SystemDescription
from lcmesh.twin.traces import FRONTIER_DAY, FRONTIER_MEAN_CDU_LOAD_W, load_trace

_K = 273.15
WET_BULB_K = 288.15  # 15 C: a mild day, so setpoint changes are reachable
GPM_PER_KG_S = 15.850 / 0.997  # US gallons per minute of water at 997 kg/m^3
FRONTIER_CDUS = 25

# Published Frontier figures the twin is checked against (docs/twin.md, "Validation", has the sources).
PUE_RANGE = (1.03, 1.06)  # ORNL/OLCF, as quoted: 1.03 and "1.05-1.06 annualized"
RAPS_CDU_PUMP_W = 8473.47  # ExaDigiT RAPS config/frontier.yaml, power_cdu
CDU_PUMP_RATIO_RANGE = (2 / 3, 1.5)
FACILITY_FLOW_GPM = 6000.0  # Bloomberg, 2023-01-05: "about 6,000 gallons per minute"
FACILITY_FLOW_RATIO_RANGE = (0.5, 2.0)
SUPPLY_RANGE_C = (27.0, 32.0)  # launch coverage: "about 85 F" (29.4 C); 32 C in secondary notes
RETURN_RANGE_C = (30.0, 38.0)  # Sun et al., Scientific Data 11:1077 (2024): waste heat at 30-38 C
IN_BAND_MIN_PCT = 99.0
# The tower fans' share of the cooling power (docs/twin.md, "Fan and pump split", has the source and the limit).
CITED_FAN_SHARE_PCT = 73.0  # Jadhav and Liu, arXiv 2603.01198, as summarized by arxivlens.com: one figure, no range
# The source gives no uncertainty, so the twin is held to its qualitative claim only: fans carry most of the cooling
# power. Our reading of the 73 %, not a published bound.
FAN_SHARE_RANGE_PCT = (50.0, 100.0)
FAN_SPLIT_DOC = "docs/twin.md, 'Fan and pump split'"
SPLIT_TOLERANCE_PCT = 0.1  # the groups must add up to the run's cooling power (float sums of the same outputs)
SPLIT_GROUPS = ("fans_kw", "cdu_pumps_kw", "htw_pumps_kw", "tower_pumps_kw")


def validate_twin(system: SystemDescription, *, plot_dir: Path | None = None, settle_h: float = 3.0) -> dict:
    """Run every check on `system`; returns the report written by ``--json``."""
    checks: list[Callable[..., dict]] = [
        check_energy_balance, check_blade_band, check_setpoint_step,
        check_flow_monotonic, check_setpoint_monotonic, check_tower_fan,
    ]  # fmt: skip
    results = []
    with Plant(system) as plant:
        for check in checks:
            results.append(check(plant, settle_h=settle_h, plot_dir=plot_dir))
        if _real_scale(system):
            real_day = _day_under_g36(plant, "frontier")
            design_day = _day_under_g36(plant, "design-day")
            results += published_checks(system, real_day, design_day)
        else:
            results.append({"name": "published_figures", "passed": True, "skipped": True,
                            "criterion": "only for systems with the traces' real CDU loads (design_heat_w 650 kW)"})  # fmt: skip
    return {"system": system.name, "passed": all(r["passed"] for r in results), "checks": results}


def _real_scale(system: SystemDescription) -> bool:
    return abs(system.cabinets.design_heat_w - FRONTIER_MEAN_CDU_LOAD_W) < 1.0


def _day_under_g36(plant: Plant, scenario: str) -> dict:
    """Day means of what the published figures describe, G36 controlling the Frontier day under `scenario`."""
    trace = load_trace(FRONTIER_DAY, plant.system, scenario=scenario)
    sums = dict.fromkeys(("htw_flow", "htw_supply", "htw_return", *SPLIT_GROUPS), 0.0)
    fan_peak = 0.0

    def record(_: int) -> None:
        nonlocal fan_peak
        out = plant.out
        sums["htw_flow"] += float(out["htw_flow_kg_s"])
        sums["htw_supply"] += float(out["htw_supply_temp_k"]) - _K
        sums["htw_return"] += float(out["htw_return_temp_k"]) - _K
        fan_peak = max(fan_peak, float(out["ct_fan_power_w"]))
        sums["fans_kw"] += float(out["ct_fan_power_w"]) / 1e3
        sums["cdu_pumps_kw"] += float(out["cdu_pump_power_w"].sum()) / 1e3
        sums["htw_pumps_kw"] += float(out["htw_pump_power_w"]) / 1e3
        sums["tower_pumps_kw"] += float(out["ct_pump_power_w"].sum()) / 1e3

    result = run_twin(plant, trace, G36Controller(plant.system), record_every=40, on_step=record)
    n = result.kpi["steps"]
    means = {k: v / n for k, v in sums.items()}
    installed_fan_w = plant.system.n_cells * plant.system.towers.cell.fan_power_nominal_w
    return {
        "scenario": scenario,
        "d_blade_pct": result.kpi["d_blade_pct"],
        "cooling_pue": result.kpi["pue_cooling"],
        "it_mw": result.kpi["it_power_kw_avg"] / 1e3,
        "cdu_pump_kw_per_cdu": means["cdu_pumps_kw"] / plant.system.n_cabinets,
        "facility_flow_gpm_at_25_cdus": means["htw_flow"] * GPM_PER_KG_S * FRONTIER_CDUS / plant.system.n_cabinets,
        "htw_supply_c": means["htw_supply"],
        "htw_return_c": means["htw_return"],
        "fan_peak_pct_of_installed": 100.0 * fan_peak / installed_fan_w,
        "cooling_split": {
            **{k: means[k] for k in SPLIT_GROUPS},
            "cooling_kw": result.kpi["cooling_power_kw_avg"],
            "installed_fans_kw": installed_fan_w / 1e3,
        },
    }


def _within(value: float, bounds: tuple[float, float]) -> bool:
    return bounds[0] <= value <= bounds[1]


def published_checks(system: SystemDescription, real_day: dict, design_day: dict) -> list[dict]:
    """The twin against published Frontier figures: G36 on the Frontier day, as recorded and on a design day."""
    pump_ratio = real_day["cdu_pump_kw_per_cdu"] * 1e3 / RAPS_CDU_PUMP_W
    flow_ratio = real_day["facility_flow_gpm_at_25_cdus"] / FACILITY_FLOW_GPM
    return [
        {"name": "cooling_pue", "source": "ORNL/OLCF via HPCwire and launch coverage (docs/twin.md)",
         "criterion": f"G36 on the Frontier day: (IT + pumps + tower fans) / IT within {PUE_RANGE[0]}-{PUE_RANGE[1]}",
         "measured": real_day["cooling_pue"], "passed": _within(real_day["cooling_pue"], PUE_RANGE)},
        {"name": "cdu_pump_power", "source": "ExaDigiT RAPS config/frontier.yaml, power_cdu = 8,473.47 W",
         "criterion": "G36 on the Frontier day: mean CDU pump power per CDU within 2/3-1.5x of 8.47 kW",
         "measured_kw": real_day["cdu_pump_kw_per_cdu"], "ratio": pump_ratio,
         "passed": _within(pump_ratio, CDU_PUMP_RATIO_RANGE)},
        {"name": "facility_flow", "source": "Bloomberg, 2023-01-05 (about 6,000 gpm; the loop is not named)",
         "criterion": "G36 on the Frontier day: mean hot-water flow, scaled to 25 CDUs, within 0.5-2x of 6,000 gpm",
         "measured_gpm": real_day["facility_flow_gpm_at_25_cdus"], "ratio": flow_ratio,
         "passed": _within(flow_ratio, FACILITY_FLOW_RATIO_RANGE)},
        {"name": "facility_temperatures", "source": "launch coverage (about 85 F supply); Sun et al. 2024 (30-38 C)",
         "criterion": f"G36 on the design day: mean HTW supply within {SUPPLY_RANGE_C[0]}-{SUPPLY_RANGE_C[1]} C "
                      f"and return within {RETURN_RANGE_C[0]}-{RETURN_RANGE_C[1]} C",
         "supply_c": design_day["htw_supply_c"], "return_c": design_day["htw_return_c"],
         "passed": _within(design_day["htw_supply_c"], SUPPLY_RANGE_C)
         and _within(design_day["htw_return_c"], RETURN_RANGE_C)},
        {"name": "g36_in_band", "source": "issue target; the design day: ASHRAE climatic design conditions",
         "criterion": f"G36 keeps >= {IN_BAND_MIN_PCT} % of blade-group steps in 20-40 C on the Frontier day and "
                      "on the 0.4 % design day, with tower fans below their installed power",
         "real_day_pct": real_day["d_blade_pct"], "design_day_pct": design_day["d_blade_pct"],
         "design_day_fan_peak_pct": design_day["fan_peak_pct_of_installed"],
         "passed": real_day["d_blade_pct"] >= IN_BAND_MIN_PCT and design_day["d_blade_pct"] >= IN_BAND_MIN_PCT
         and design_day["fan_peak_pct_of_installed"] < 100.0},
        fan_pump_split([real_day, design_day]),
        {"name": "day_figures", "passed": True, "criterion": "reported, not checked",
         "real_day": real_day, "design_day": design_day},
    ]  # fmt: skip


def split_row(scenario: str, split: dict) -> dict:
    """One scenario's cooling-power split: each group's day mean, the fans' share and where it stands."""
    pumps_kw = split["cdu_pumps_kw"] + split["htw_pumps_kw"] + split["tower_pumps_kw"]
    parts_kw = split["fans_kw"] + pumps_kw
    share = 100.0 * split["fans_kw"] / parts_kw if parts_kw > 0 else 0.0
    inside = _within(share, FAN_SHARE_RANGE_PCT)
    return {
        "scenario": scenario,
        **{k: split[k] for k in SPLIT_GROUPS},
        "cooling_kw": split["cooling_kw"],
        "unaccounted_pct": 100.0 * abs(split["cooling_kw"] - parts_kw) / max(split["cooling_kw"], 1e-9),
        "fan_share_pct": share,
        # the cited plant's denominator is not known to us: without the CDU pumps, which sit in the CDUs
        "fan_share_without_cdu_pumps_pct": 100.0 * split["fans_kw"] / max(parts_kw - split["cdu_pumps_kw"], 1e-9),
        # every installed fan at full speed against the same day's pumps: the most this plant's fans could weigh
        "fan_share_at_full_speed_pct": 100.0 * split["installed_fans_kw"] / (split["installed_fans_kw"] + pumps_kw),
        "cited_fan_share_pct": CITED_FAN_SHARE_PCT,
        "status": "inside the cited range" if inside else f"outside: documented limit ({FAN_SPLIT_DOC})",
    }


def fan_pump_split(days: list[dict]) -> dict:
    """Tower fans against each pump group per scenario (G36 day means), beside the cited 73 % fan share.

    Passes when the four groups add up to the run's cooling power (the split misses no consumer); the fans'
    share is reported with its status, inside the cited range or outside as the documented limit.
    """
    rows = [split_row(day["scenario"], day["cooling_split"]) for day in days]
    return {
        "name": "fan_pump_split",
        "source": "Jadhav and Liu, arXiv 2603.01198 (fans 73 % of cooling power, as summarized by arxivlens.com); "
                  f"the limit: {FAN_SPLIT_DOC}",
        "criterion": f"G36 per scenario: fans + CDU + HTW + tower pumps = the cooling power within "
                     f"{SPLIT_TOLERANCE_PCT:g} %; fans' share reported against {CITED_FAN_SHARE_PCT:g} % "
                     f"(inside: {FAN_SHARE_RANGE_PCT[0]:g}-{FAN_SHARE_RANGE_PCT[1]:g} %, else the documented limit)",
        "rows": rows,
        "passed": all(r["unaccounted_pct"] <= SPLIT_TOLERANCE_PCT and min(r[k] for k in SPLIT_GROUPS) >= 0.0
                      for r in rows),
    }  # fmt: skip


def _uniform_branch_load(plant: Plant, branch_w: float) -> np.ndarray:
    groups = plant.system.cabinets.blade_groups_per_branch
    return np.full(plant.system.n_blade_groups, branch_w / groups)


def _settle(plant: Plant, power: np.ndarray, action: PlantAction, hours: float, wet_bulb_k: float = WET_BULB_K):
    for _ in range(int(hours * 3600 / plant.step_s)):
        out = plant.step(power, wet_bulb_k, action)
    return out


def _static_action(plant: Plant, wet_bulb_k: float = WET_BULB_K) -> PlantAction:
    action = plant.default_action()
    action.lw_setpoint_k[:] = wet_bulb_k + 10.0 / 1.8
    return action


def check_energy_balance(plant: Plant, *, plot_dir: Path | None = None, **_) -> dict:
    """Heat in = rejected + recovered + stored change, within 0.5 % over the Frontier day."""
    trace = load_trace(FRONTIER_DAY, plant.system)
    result = run_twin(plant, trace, StaticController(plant.system), record_every=4)
    if plot_dir is not None:
        plot_run(result, Path(plot_dir) / f"validate-day-{plant.system.name}.png")
    error = result.kpi["energy_balance_error_pct"]
    return {
        "name": "energy_balance",
        "criterion": "|heat in - rejected - recovered - stored change| / heat in <= 0.5 % over 24 h",
        "energy_balance_error_pct": error,
        "d_blade_pct_static": result.kpi["d_blade_pct"],
        "passed": error is not None and abs(error) <= 0.5,
    }


def check_blade_band(plant: Plant, *, settle_h: float, **_) -> dict:
    """At the design dp and supply setpoint, blades stay in the 20-40 C band over the real range of branch loads.

    The range: 0.1 to 1.65 times the design branch load (a third of `design_heat_w`: 217 kW on the
    reference systems), covering the Frontier day's 1st-99th percentile CDU loads. With no load at all
    nothing heats the coolant, so an idle branch settles at the coolant supply: checked separately.
    """
    start = plant.save_state()
    action = _static_action(plant)
    design_branch_w = plant.system.cabinets.design_heat_w / plant.system.cabinets.branches
    rows = []
    for fraction in (0.0, 0.05, 0.1, 0.3, 0.6, 1.0, 1.3, 1.65):
        plant.restore_state(start)
        out = _settle(plant, _uniform_branch_load(plant, fraction * design_branch_w), action, settle_h)
        rows.append({"branch_kw": fraction * design_branch_w / 1e3, "min_c": float(out["blade_temp_k"].min() - _K),
                     "max_c": float(out["blade_temp_k"].max() - _K),
                     "supply_c": float(out["supply_temp_k"].mean() - _K),
                     "flow_kg_s": float(out["secondary_flow_kg_s"].mean())})  # fmt: skip
    plant.restore_state(start)
    plant.free_state(start)
    held = [r for r in rows if r["branch_kw"] >= 0.1 * design_branch_w / 1e3 - 1e-9]
    light = [r for r in rows if r["branch_kw"] < 0.1 * design_branch_w / 1e3 - 1e-9]
    lo, hi = min(r["min_c"] for r in held), max(r["max_c"] for r in held)
    return {
        "name": "blade_band",
        "criterion": (
            "0.1-1.65x the design branch load at the design dp and supply setpoint: blades within 20-40 C; "
            "below that the supply may fall under its setpoint: blades no colder than their coolant and < 40 C"
        ),
        "rows": rows,
        "passed": 20.0 < lo and hi < 40.0 and all(r["supply_c"] - 0.01 <= r["min_c"] < 40.0 for r in light),
    }


def check_setpoint_step(plant: Plant, *, settle_h: float, plot_dir: Path | None = None, **_) -> dict:
    """A -2 K supply-setpoint step on cabinet 1 settles within minutes (63 % within 0.1-30 min)."""
    power = _uniform_branch_load(plant, plant.system.cabinets.design_heat_w / plant.system.cabinets.branches)
    action = _static_action(plant)
    start = plant.save_state()
    out = _settle(plant, power, action, settle_h)
    before = float(out["return_temp_k"][0])
    others_before = out["return_temp_k"][1:].copy()
    action.supply_temp_setpoint_k[0] -= 2.0
    n = int(2 * 3600 / plant.step_s)
    trace = np.zeros(n)
    supply = np.zeros(n)
    for k in range(n):
        out = plant.step(power, WET_BULB_K, action)
        trace[k] = out["return_temp_k"][0]
        supply[k] = out["supply_temp_k"][0]
    coupling = float(np.abs(out["return_temp_k"][1:] - others_before).max()) if len(others_before) else 0.0
    plant.restore_state(start)
    plant.free_state(start)
    change = trace[-1] - before
    reached = np.nonzero(np.abs(trace - before) >= 0.63 * abs(change))[0]
    t63_min = float((reached[0] + 1) * plant.step_s / 60.0) if len(reached) else None
    inside = np.abs(trace - trace[-1]) <= 0.1 * abs(change)
    outside = np.nonzero(~inside)[0]
    settle_min = float((outside[-1] + 2) * plant.step_s / 60.0) if len(outside) else plant.step_s / 60.0
    if plot_dir is not None:
        _plot_step(np.arange(1, n + 1) * plant.step_s / 60.0, trace, supply, before, Path(plot_dir))
    return {
        "name": "setpoint_step",
        "criterion": "return temperature: 63 % of the change within 0.1-30 min, gain 0.5-1.5 K/K",
        "return_change_k": float(change),
        "gain_k_per_k": float(-change / 2.0),
        "t63_min": t63_min,
        "settle_10pct_min": settle_min,
        "coupling_other_cdus_k": coupling,
        "passed": t63_min is not None and 0.1 <= t63_min <= 30.0 and 0.5 <= -change / 2.0 <= 1.5,
    }


def _steady_blades(plant: Plant, action: PlantAction, power: np.ndarray, settle_h: float, start) -> np.ndarray:
    plant.restore_state(start)
    return _settle(plant, power, action, settle_h)["blade_temp_k"].copy()


def check_flow_monotonic(plant: Plant, *, settle_h: float, **_) -> dict:
    """More flow (a higher dp setpoint) never heats a blade group at steady state."""
    return _monotonic(plant, settle_h, "dp_setpoint_pa", [p * PSI_TO_PA for p in (25, 28, 31, 34, 38)],
                      "flow_monotonic", "dp setpoint 25 -> 38 psi")  # fmt: skip


def check_setpoint_monotonic(plant: Plant, *, settle_h: float, **_) -> dict:
    """A lower supply setpoint never heats a blade group at steady state."""
    return _monotonic(plant, settle_h, "supply_temp_setpoint_k", [_K + c for c in (36, 32, 28, 24, 20)],
                      "setpoint_monotonic", "supply setpoint 36 -> 20 C")  # fmt: skip


def _monotonic(plant: Plant, settle_h: float, field: str, values: list[float], name: str, sweep: str) -> dict:
    start = plant.save_state()
    worst = -np.inf
    rows = []
    # half to 1.5x the design branch load: lighter loads hold the primary valve at its minimum opening, where
    # more secondary flow through the out-cooling exchanger warms the supply (physical, and not the point here)
    design_branch_kw = plant.system.cabinets.design_heat_w / plant.system.cabinets.branches / 1e3
    for branch_kw in (0.5 * design_branch_kw, design_branch_kw, 1.5 * design_branch_kw):
        power = _uniform_branch_load(plant, branch_kw * 1e3)
        previous = None
        for value in values:
            action = _static_action(plant)
            getattr(action, field)[:] = value
            temps = _steady_blades(plant, action, power, settle_h, start)
            if previous is not None:
                worst = max(worst, float((temps - previous).max()))
            rows.append({"branch_kw": branch_kw, field: value, "blade_max_c": float(temps.max() - _K)})
            previous = temps
    plant.restore_state(start)
    plant.free_state(start)
    # the supply loop rests anywhere within +-deadband of its setpoint, so two steady states may differ by the
    # band's full width
    tolerance_k = 2.0 * plant.system.cabinets.cdu.temp_deadband_k
    return {
        "name": name,
        "criterion": f"{sweep}: no blade group warmer at steady state (tolerance {tolerance_k:g} K: the width of "
        "the supply loop's deadband, where the supply may rest)",
        "largest_rise_k": worst,
        "rows": rows,
        "passed": worst <= tolerance_k,
    }


def check_tower_fan(plant: Plant, *, settle_h: float, **_) -> dict:
    """Tower fan power rises as the leaving-water setpoint approaches the wet bulb."""
    start = plant.save_state()
    rows, passed = [], True
    for branch_kw in (50.0, 150.0):
        power = _uniform_branch_load(plant, branch_kw * 1e3)
        fans = []
        for approach in (8.0, 6.0, 5.0, 4.0, 3.5, 3.0, 2.5):
            plant.restore_state(start)
            action = _static_action(plant)
            action.lw_setpoint_k[:] = WET_BULB_K + approach
            fan = [float(plant.step(power, WET_BULB_K, action)["ct_fan_power_w"])
                   for _ in range(int(settle_h * 3600 / plant.step_s))]  # fmt: skip
            fans.append(float(np.mean(fan[-240:]) / 1e3))
            rows.append({"branch_kw": branch_kw, "approach_setpoint_k": approach, "fan_kw": fans[-1],
                         "cells_active": float(plant.out["cells_active"].sum())})  # fmt: skip
        tolerance_kw = 0.5 * plant.system.n_cells
        passed &= all(b >= a - tolerance_kw for a, b in zip(fans, fans[1:])) and fans[-1] > fans[0] + 1.0
    plant.restore_state(start)
    plant.free_state(start)
    return {
        "name": "tower_fan",
        "criterion": (
            "steady fan power rises as the setpoint goes 8 -> 2.5 K above wet bulb (each step non-decreasing "
            "within 0.5 kW per cell, the dip when more cells are staged on) and ends > 1 kW higher"
        ),
        "rows": rows,
        "passed": passed,
    }


def _plot_step(t_min, ret, supply, before, plot_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(t_min, ret - _K, label="return (cabinet 1)")
    ax.plot(t_min, supply - _K, label="supply (cabinet 1)")
    ax.axhline(before - _K, color="gray", ls=":", lw=0.8)
    ax.set_xlabel("minutes after a -2 K supply-setpoint step")
    ax.set_ylabel("C")
    ax.legend()
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot_dir / "validate-setpoint-step.png", dpi=90)
    plt.close(fig)
