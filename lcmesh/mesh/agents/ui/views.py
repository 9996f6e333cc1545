"""Plant states and decisions as operators read them: °C, kW, psi, cabinets, branches and towers numbered from 1.

SI stays on the bus; these views are the UI edge (DESIGN.md). Blade groups are laid out
cabinet-major (``blade_temp_k`` reshapes to (C, B x groups per branch)). Besides conversions, a
view says what a person would otherwise work out: the cooling PUE, where the wet bulb comes from
when a scenario shifts it, and what each decision changed from the one before.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lcmesh.mesh.tools import plant_data
from lcmesh.mesh.messages import ActionModel, AppliedAction, PlantState, plant_state_to_observation
from lcmesh.twin.system import PSI_TO_PA, SystemDescription
from lcmesh.twin.traces import SCENARIOS

K0 = 273.15
DECIMALS = 3


def c(kelvin: float) -> float:
    """Kelvin to °C, rounded for display."""
    return round(float(kelvin) - K0, DECIMALS)


def kw(watts: float) -> float:
    return round(float(watts) / 1e3, DECIMALS)


def psi(pascals: float) -> float:
    return round(float(pascals) / PSI_TO_PA, DECIMALS)


def _r(x: float) -> float:
    return round(float(x), DECIMALS)


def _list(values: np.ndarray, convert=_r) -> list[float]:
    return [convert(v) for v in np.asarray(values, dtype=float).ravel()]


def state_view(state: PlantState, system: SystemDescription, applied: AppliedAction | None = None) -> dict[str, Any]:
    """The UI view of a plant state (ValueError naming the block if the state does not fit `system`)."""
    out = plant_state_to_observation(state, system).out
    C, N = system.cabinets.count, system.towers.count
    blades = np.asarray(out["blade_temp_k"]).reshape(C, -1)
    cabinets = []
    for i in range(C):
        cabinets.append({
            "cabinet": i + 1,
            "blade_temps_c": _list(blades[i], c),
            "blade_temp_max_c": c(blades[i].max()),
            "branch_temps_c": _list(out["branch_temp_k"][i], c),
            "branch_power_kw": _list(out["branch_power_w"][i], kw),
            "valve_fractions": _list(out["applied_valve_fraction"][i]),
            "supply_temp_c": c(out["supply_temp_k"][i]),
            "supply_temp_measured_c": c(out["supply_temp_measured_k"][i]),
            "supply_setpoint_c": c(out["applied_supply_setpoint_k"][i]),
            "return_temp_c": c(out["return_temp_k"][i]),
            "secondary_flow_kg_s": _r(out["secondary_flow_kg_s"][i]),
            "dp_psi": psi(out["cabinet_dp_pa"][i]),
            "dp_setpoint_psi": psi(out["applied_dp_setpoint_pa"][i]),
            "pump_power_kw": kw(out["cdu_pump_power_w"][i]),
            "cdu_heat_kw": kw(out["cdu_heat_w"][i]),
        })  # fmt: skip
    towers = []
    for t in range(N):
        towers.append({
            "tower": t + 1,
            "leaving_temp_c": c(out["ct_leaving_temp_k"][t]),
            "leaving_setpoint_c": c(out["applied_lw_setpoint_k"][t]),
            "entering_temp_c": c(out["ct_entering_temp_k"][t]),
            "approach_k": _r(out["approach_k"][t]),
            "fan_speed": _r(out["fan_speed"][t]),
            "cells_active": _r(out["cells_active"][t]),
            "fan_power_kw": kw(np.sum(out["cell_fan_power_w"][t])),
            "pump_power_kw": kw(out["ct_pump_power_w"][t]),
        })  # fmt: skip
    temps = np.asarray(out["blade_temp_k"], dtype=float)
    in_band = float(np.mean((temps > K0 + 20.0) & (temps < K0 + 40.0)) * 100.0)
    it_w, fan_w, pump_w = float(out["it_power_w"]), float(out["ct_fan_power_w"]), float(out["pump_power_w"])
    view = {
        "system": state.system, "run_id": state.run_id, "step": state.step, "time_s": state.time_s,
        "sent_at": state.sent_at.isoformat(), "period_s": state.period_s, "faults_active": state.faults_active,
        "wet_bulb_c": c(state.wet_bulb_k), "scenario": state.scenario, "wet_bulb_offset_k": _r(state.wet_bulb_offset_k),
        "wet_bulb_note": wet_bulb_note(state.scenario, state.wet_bulb_offset_k),
        "totals": {
            "it_power_kw": kw(it_w), "it_cooling_kw": kw(out["it_cooling_w"]),
            "ct_fan_power_kw": kw(fan_w), "pump_power_kw": kw(pump_w), "cooling_power_kw": kw(fan_w + pump_w),
            "cooling_pue": cooling_pue(it_w, fan_w, pump_w),
            "heat_rejected_kw": kw(out["heat_rejected_w"]), "blade_temp_max_c": c(temps.max()),
            "blade_temp_mean_c": c(temps.mean()), "blade_in_band_pct": _r(in_band),
        },
        "cabinets": cabinets,
        "towers": towers,
        "controller": None,
    }  # fmt: skip
    if applied is not None:
        view["controller"] = applied_brief(applied)
    return view


def cooling_pue(it_w: float, fan_w: float, pump_w: float) -> float | None:
    """The assistant's cooling PUE (plant_data.cooling_pue) to 4 decimals; None with no IT load."""
    pue = plant_data.cooling_pue(it_w, fan_w, pump_w)
    return None if pue is None else round(pue, 4)


def wet_bulb_note(scenario: str, offset_k: float) -> str | None:
    """Where the wet bulb comes from when it is not the trace's recorded one, e.g. 'recorded + 15 K, scenario
    lcopt'; None when it is (so the page labels exactly the shifted or replaced ones)."""
    design_day = getattr(SCENARIOS.get(scenario), "design_day", None)
    if design_day is None and abs(offset_k) < 0.05:
        return None
    base = f"design day {design_day}" if design_day else "recorded"
    shift = f" {'+' if offset_k > 0 else '−'} {abs(offset_k):g} K" if abs(offset_k) >= 0.05 else ""
    return f"{base}{shift}, scenario {scenario}"


def applied_brief(a: AppliedAction) -> dict[str, Any]:
    """Who decided the last applied action and what the guardrails did to it."""
    return {"step": a.step, "source": a.source_controller, "version": a.source_version, "decision_id": a.decision_id,
            "fallback": a.fallback, "fallback_reason": a.fallback_reason, "clamps": len(a.clamps)}  # fmt: skip


def action_view(act: ActionModel) -> dict[str, Any]:
    """An action in UI units."""
    return {
        "supply_temp_setpoint_c": [c(v) for v in act.supply_temp_setpoint_k],
        "dp_setpoint_psi": [psi(v) for v in act.dp_setpoint_pa],
        "valve_fractions": [[_r(v) for v in row] for row in act.valve_fractions],
        "lw_setpoint_c": [c(v) for v in act.lw_setpoint_k],
    }


def clamp_view(clamp: dict[str, Any]) -> dict[str, Any]:
    """A guardrail clamp with its `index` counted from 1 ([cabinet], [cabinet, branch] or [tower]); SI values."""
    return {**clamp, "index": [i + 1 for i in clamp.get("index", [])]}


def decision_view(a: AppliedAction, explanation: Any | None, previous: AppliedAction | None = None) -> dict[str, Any]:
    """One entry of the decision feed (the same keys as /api/decisions rows); `explanation`: its Explanation message
    (or None); `previous`: the decision before it."""
    action = action_view(a.action)
    return {
        "step": a.step, "time_s": a.time_s, "decision_id": a.decision_id, "source_controller": a.source_controller,
        "source_version": a.source_version, "fallback": a.fallback, "fallback_reason": a.fallback_reason,
        "rejected_reason": a.rejected_reason, "clamps": [clamp_view(cl.model_dump()) for cl in a.clamps],
        "latency_ms": a.latency_ms, "applied_at": a.sent_at.isoformat(), "action": action,
        "changes": action_changes(action_view(previous.action), action) if previous is not None else None,
        "explanation": explanation.text if explanation is not None else None,
        "explanation_written_by": explanation.written_by if explanation is not None else None,
        "explanation_why_renderer": explanation.why_renderer if explanation is not None else None,
        "explanation_llm_part": explanation.llm_part if explanation is not None else None,
    }  # fmt: skip


# what a decision may change, as the page shows it: (action view key, what, unit, decimals, numbered entity)
CHANGE_FIELDS = (
    ("supply_temp_setpoint_c", "supply setpoint", " °C", 1, "cabinet"),
    ("dp_setpoint_psi", "dp setpoint", " psi", 1, "cabinet"),
    ("lw_setpoint_c", "leaving-water setpoint", " °C", 1, "tower"),
)
VALVE_DECIMALS = 2
MAX_CHANGES = 8


def action_changes(before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """What `after` changed from `before` (action views), at the page's resolution, e.g. 'supply setpoint
    21.0 → 21.5 °C (all cabinets)', 'cabinet 3 branch 2 valve 0.31 → 0.36'; [] when nothing visible moved.

    A setpoint that moved alike on every cabinet (tower) is said once; beyond MAX_CHANGES items the rest is
    counted, not listed.
    """
    items: list[str] = []
    for key, what, unit, decimals, entity in CHANGE_FIELDS:
        moves = _moves(before[key], after[key], decimals)
        if len(moves) == len(after[key]) > 1 and len({(old, new) for _, old, new in moves}) == 1:
            items.append(f"{what} {moves[0][1]} → {moves[0][2]}{unit} (all {entity}s)")
        else:
            items += [f"{entity} {n} {what} {old} → {new}{unit}" for n, old, new in moves]
    for cab, (row_before, row_after) in enumerate(zip(before["valve_fractions"], after["valve_fractions"]), 1):
        items += [f"cabinet {cab} branch {n} valve {old} → {new}"
                  for n, old, new in _moves(row_before, row_after, VALVE_DECIMALS)]  # fmt: skip
    if len(items) > MAX_CHANGES:
        items = [*items[:MAX_CHANGES], f"{len(items) - MAX_CHANGES} more"]
    return items


def _moves(before: list[float], after: list[float], decimals: int) -> list[tuple[int, str, str]]:
    """(1-based number, old, new) of each value whose display at `decimals` changed."""
    shown = [(f"{b:.{decimals}f}", f"{a:.{decimals}f}") for b, a in zip(before, after)]
    return [(n, old, new) for n, (old, new) in enumerate(shown, 1) if old != new]
