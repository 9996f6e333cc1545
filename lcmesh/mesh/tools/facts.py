"""Grounded decision facts: the numbers an explanation of a control step may cite.

The toolbox computes these before any text is written; the deterministic renderer
(``lcmesh.mesh.tools.explain``) and the LLM prompts (``lcmesh/prompts/explain_*.md``) cite only
them, and ``lcmesh explain-eval`` checks every number of an explanation against them.

Facts carry display units (deg C for absolute temperatures, K for temperature differences, kW,
kg/s, psi, fractions); SI stays inside the twin. Branches, cabinets and towers are numbered from 1
in fact names and texts (``branch_2_temp`` is the second branch), as operators count them.

Definitions (also in docs/explanations.md):

- power share of branch j: ``P_j / sum_k P_k`` (branch IT power, the trace's load).
- valve-power rank agreement: Spearman's rho between the valve fractions and the power shares
  (average ranks for ties; 0 when either vector is constant, e.g. an equal split).
- valve-power L1 distance: ``sum_j |v_j - s_j|`` (0 = valves exactly proportional to load, at most 2).
- stability score: the mean over branches of ``clip(margin_j / 5 K, 0, 1)`` with
  ``margin_j = min(T_j - 20 degC, 40 degC - T_j)``: 1 when every branch sits at least 5 K inside the
  20-40 degC compliance band, falling linearly to 0 at the band edge, 0 outside it.
- cabinet cooling power: the CDU pump plus the cabinet's share (by CDU heat) of the tower fans, tower
  pumps and the hot-water pump.
- cooling COP: CDU heat removed / cabinet cooling power.
- efficiency score: ``COP / (COP + 10)``: 0.5 at COP 10 (a cooling-only pPUE of 1.10), towards 1 for
  a better plant, towards 0 for a worse one. The tower version uses heat rejected / fan power.
- CDU heat balance: secondary ``m_dot c_p (T_return - T_supply)`` against the blade heat
  ``sum_j P_j (1 + a P_j / P_u)`` (the twin's non-linear heat term); the gap is storage in blades and
  coolant during load changes.
- direction of a setpoint change: "raised" / "lowered" beyond a dead band (0.05 K, 0.05 psi,
  0.005 valve fraction), else "held"; "set" when no previous action is known.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from lcmesh.mesh.tools.thermo import branch_heat_w, heat_flow_w
from lcmesh.twin.system import PSI_TO_PA, SystemDescription

if TYPE_CHECKING:  # PlantAction's module loads the FMU runner; facts only read its arrays
    from lcmesh.twin.plant import PlantAction

K0 = 273.15
BAND_LOW_C, BAND_HIGH_C = 20.0, 40.0  # blade compliance band (LC-Opt Section 6)
STABILITY_FULL_MARGIN_K = 5.0
COP_REFERENCE = 10.0
DEAD_BAND = {"K": 0.05, "psi": 0.05, "fraction": 0.005}

Unit = Literal["degC", "K", "kW", "W", "kg/s", "psi", "Pa", "fraction", "%", "J/(kg K)", ""]
Kind = Literal["observation", "action", "change", "derived", "score", "index", "label", "constant"]
_SUFFIX = {"degC": " °C", "K": " K", "kW": " kW", "W": " W", "kg/s": " kg/s", "psi": " psi", "Pa": " Pa", "%": " %",
           "J/(kg K)": " J/(kg K)"}  # fmt: skip
_DECIMALS = {"degC": 1, "K": 1, "kW": 1, "W": 0, "kg/s": 2, "psi": 1, "Pa": 0, "fraction": 2, "%": 1, "J/(kg K)": 0}


class Fact(BaseModel):
    """One grounded number (or label) an explanation may cite."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    value: float | str
    unit: Unit = ""
    text: str
    kind: Kind = "derived"

    @property
    def display(self) -> str:
        """The value as explanations should write it, e.g. ``36.4 °C`` or ``0.33``."""
        return format_value(self.value, self.unit)


def format_value(value: float | str, unit: str) -> str:
    """Format a fact value to the precision explanations cite (and the evaluator accepts)."""
    if isinstance(value, str):
        return value
    if unit == "" and float(value).is_integer():
        return str(int(value))
    return f"{value:.{_DECIMALS.get(unit, 2)}f}{_SUFFIX.get(unit, '')}"


def _fact(name: str, value: float | str, unit: str = "", text: str = "", kind: str = "derived") -> Fact:
    return Fact(name=name, value=value, unit=unit, text=text, kind=kind)


def percent_text(fraction: float) -> str:
    """A fraction as a whole percent, halves rounded up (0.025 -> '3 %', as its display 0.03 reads)."""
    return f"{math.floor(fraction * 100.0 + 0.5 + 1e-9):.0f} %"


def direction_word(change: float | None, unit: str) -> str:
    """``raised`` / ``lowered`` / ``held`` for a change beyond the unit's dead band; ``set`` if unknown."""
    if change is None:
        return "set"
    band = DEAD_BAND.get(unit, 0.0)
    return "raised" if change > band else "lowered" if change < -band else "held"


def spearman_rho(a, b) -> float:
    """Spearman rank correlation with average ranks for ties; 0 when either side is constant."""
    ra, rb = _ranks(list(a)), _ranks(list(b))
    ma, mb = sum(ra) / len(ra), sum(rb) / len(rb)
    da, db = [x - ma for x in ra], [x - mb for x in rb]
    denom = (sum(x * x for x in da) * sum(x * x for x in db)) ** 0.5
    return sum(x * y for x, y in zip(da, db)) / denom if denom > 1e-12 else 0.0


def stability_score(branch_temp_c: np.ndarray) -> float:
    """Mean over branches of clip(margin to the 20-40 degC band / 5 K, 0, 1)."""
    margin = np.minimum(branch_temp_c - BAND_LOW_C, BAND_HIGH_C - branch_temp_c)
    return float(np.clip(margin / STABILITY_FULL_MARGIN_K, 0.0, 1.0).mean())


def efficiency_score(cop: float) -> float:
    """COP / (COP + 10): 0.5 at the reference COP of 10."""
    return float(cop / (cop + COP_REFERENCE)) if cop > 0 else 0.0


def cabinet_decision_facts(
    system: SystemDescription,
    out: Mapping[str, np.ndarray],
    action: PlantAction,
    previous_action: PlantAction | None,
    wet_bulb_k: float,
    cabinet: int,
) -> list[Fact]:
    """Facts behind one cabinet's decision: its branches, valves, CDU setpoints and the tower action.

    ``out`` is shaped like ``Plant.out``; ``cabinet`` is 0-based (texts say ``cabinet {cabinet + 1}``).
    Raises ValueError naming the field when the cabinet index or the observation is unusable.
    """
    n_cab = system.cabinets.count
    if not 0 <= cabinet < n_cab:
        raise ValueError(f"`cabinet` must be in 0..{n_cab - 1} (0-based), got {cabinet}")
    temp_c = np.asarray(out["branch_temp_k"][cabinet], dtype=float) - K0
    power_w = np.asarray(out["branch_power_w"][cabinet], dtype=float)
    valves = np.asarray(action.valve_fractions[cabinet], dtype=float)
    for name, arr in (("branch_temp_k", temp_c), ("branch_power_w", power_w), ("valve_fractions", valves)):
        if not np.isfinite(arr).all():
            raise ValueError(f"`{name}` of cabinet {cabinet} must be finite, got {arr.tolist()}")
    facts: list[Fact] = [_fact(name="cabinet", value=cabinet + 1, text=f"cabinet {cabinet + 1}", kind="index")]
    facts += _branch_facts(temp_c, power_w, valves, previous_action, cabinet)
    facts += _cdu_facts(system, out, action, previous_action, cabinet, temp_c, power_w)
    facts += tower_action_facts(out, action, previous_action, wet_bulb_k)
    return facts


def _branch_facts(temp_c, power_w, valves, previous_action, cabinet) -> list[Fact]:
    # plain Python on B values: numpy's per-call overhead dominates arrays this small
    temps, powers, vals = temp_c.tolist(), power_w.tolist(), valves.tolist()
    n = len(temps)
    total_w = sum(powers)
    shares = [p / total_w for p in powers] if total_w > 0 else [1.0 / n] * n
    prev = None if previous_action is None else np.asarray(previous_action.valve_fractions[cabinet], float).tolist()
    facts = []
    for j in range(n):
        b = j + 1
        t, p, s, v = temps[j], powers[j] / 1e3, shares[j], vals[j]
        facts += [
            _fact(f"branch_{b}_temp", round(t, 3), "degC", f"branch {b} runs at {format_value(t, 'degC')}",
                  "observation"),
            _fact(f"branch_{b}_power", round(p, 3), "kW", f"branch {b} draws {format_value(p, 'kW')}", "observation"),
            _fact(f"branch_{b}_power_share", round(s, 4), "fraction",
                  f"branch {b} carries {percent_text(round(s, 4))} of the cabinet load"),
            _fact(f"branch_{b}_valve_fraction", round(v, 4), "fraction",
                  f"branch {b} valve fraction {format_value(v, 'fraction')}", "action"),
        ]  # fmt: skip
        if prev is not None:
            dv = v - prev[j]
            facts.append(_fact(f"branch_{b}_valve_change", round(dv, 4), "fraction",
                               _change_text(f"branch {b} valve fraction", dv, "fraction"), "change"))  # fmt: skip
    first = list(range(n))
    hot, cold = max(first, key=temps.__getitem__), min(first, key=temps.__getitem__)
    big, small = max(first, key=powers.__getitem__), min(first, key=powers.__getitem__)
    wide = max(first, key=vals.__getitem__)
    rho = spearman_rho(vals, shares)
    l1 = sum(abs(v - s) for v, s in zip(vals, shares))
    equal = max(vals) - min(vals) < 0.01
    if equal:
        split = "equal"
    else:
        split = "follows load" if rho >= 0.99 else "partly follows load" if rho > 0 else "against load"
    spread = temps[hot] - temps[cold]
    facts += [
        _fact("hottest_branch", hot + 1, "", f"branch {hot + 1} is the hottest", "index"),
        _fact("hottest_branch_temp", round(temps[hot], 3), "degC",
              f"the hottest branch runs at {format_value(temps[hot], 'degC')}", "observation"),
        _fact("coolest_branch", cold + 1, "", f"branch {cold + 1} is the coolest", "index"),
        _fact("coolest_branch_temp", round(temps[cold], 3), "degC",
              f"the coolest branch runs at {format_value(temps[cold], 'degC')}", "observation"),
        _fact("branch_temp_spread", round(spread, 3), "K", f"the branches span {format_value(spread, 'K')}"),
        _fact("most_loaded_branch", big + 1, "", f"branch {big + 1} carries the most load", "index"),
        _fact("most_loaded_branch_power", round(powers[big] / 1e3, 3), "kW",
              f"the most loaded branch draws {format_value(powers[big] / 1e3, 'kW')}", "observation"),
        _fact("least_loaded_branch", small + 1, "", f"branch {small + 1} carries the least load", "index"),
        _fact("cabinet_power", round(total_w / 1e3, 3), "kW",
              f"the cabinet's branches draw {format_value(total_w / 1e3, 'kW')} in total", "observation"),
        _fact("most_opened_branch", wide + 1, "",
              "the valves are split equally" if equal else f"branch {wide + 1} has the largest valve fraction",
              "index"),
        _fact("valve_split", split, "", f"the valve split is {split}", "label"),
        _fact("valve_power_spearman", round(rho, 4), "", f"valve-to-power rank agreement (Spearman) {rho:.2f}"),
        _fact("valve_power_l1", round(l1, 4), "fraction",
              f"valve split differs from the power shares by {l1:.2f} (L1)"),
    ]  # fmt: skip
    margins = [min(t - BAND_LOW_C, BAND_HIGH_C - t) for t in temps]
    worst = min(margins)
    in_band = sum(1 for m in margins if m > 0)
    score = sum(min(max(m / STABILITY_FULL_MARGIN_K, 0.0), 1.0) for m in margins) / n  # = stability_score(temp_c)
    facts += [
        _fact("branches_in_band", in_band, "", f"{in_band} of {n} branches inside the 20-40 °C band"),
        _fact("band_margin_min", round(worst, 3), "K",
              f"the tightest branch is {format_value(worst, 'K')} inside the band" if worst > 0
              else f"a branch is {format_value(-worst, 'K')} outside the band"),
        _fact("stability_score", round(score, 4), "",
              f"stability score {score:.2f} (mean of band margin / 5 K, clipped to 0..1)", "score"),
    ]  # fmt: skip
    return facts


def _cdu_facts(system, out, action, previous_action, cabinet, temp_c, power_w) -> list[Fact]:
    c = cabinet
    sp_c = float(action.supply_temp_setpoint_k[c]) - K0
    dp_psi = float(action.dp_setpoint_pa[c]) / PSI_TO_PA
    facts = [_fact(name="supply_setpoint", value=round(sp_c, 3), unit="degC", kind="action",
                  text=f"CDU supply setpoint {format_value(sp_c, 'degC')}")]  # fmt: skip
    sp_change = dp_change = None
    if previous_action is not None:
        prev_c = float(previous_action.supply_temp_setpoint_k[c]) - K0
        sp_change = sp_c - prev_c
        prev_psi = float(previous_action.dp_setpoint_pa[c]) / PSI_TO_PA
        dp_change = dp_psi - prev_psi
        facts += [
            _fact(name="supply_setpoint_previous", value=round(prev_c, 3), unit="degC", kind="action",
                 text=f"previous supply setpoint {format_value(prev_c, 'degC')}"),
            _fact(name="supply_setpoint_change", value=round(sp_change, 3), unit="K", kind="change",
                 text=_change_text("supply setpoint", sp_change, "K")),
            _fact(name="dp_setpoint_previous", value=round(prev_psi, 3), unit="psi", kind="action",
                 text=f"previous dp setpoint {format_value(prev_psi, 'psi')}"),
            _fact(name="dp_setpoint_change", value=round(dp_change, 3), unit="psi", kind="change",
                 text=_change_text("dp setpoint", dp_change, "psi")),
        ]  # fmt: skip
    facts += [
        _fact(name="supply_setpoint_direction", value=direction_word(sp_change, "K"), kind="label",
             text=f"supply setpoint {direction_word(sp_change, 'K')}"),
        _fact(name="dp_setpoint", value=round(dp_psi, 3), unit="psi", kind="action",
             text=f"secondary differential-pressure setpoint {format_value(dp_psi, 'psi')}"),
        _fact(name="dp_setpoint_direction", value=direction_word(dp_change, "psi"), kind="label",
             text=f"dp setpoint {direction_word(dp_change, 'psi')}"),
    ]  # fmt: skip
    facts += _measured_cdu_facts(system, out, c, sp_c, power_w)
    return facts


def _measured_cdu_facts(system, out, c, sp_c, power_w) -> list[Fact]:
    facts = []
    supply = _get(out, "supply_temp_k", c)
    ret = _get(out, "return_temp_k", c)
    flow = _get(out, "secondary_flow_kg_s", c)
    dp = _get(out, "cabinet_dp_pa", c)
    if supply is not None:
        s_c = supply - K0
        err = s_c - sp_c
        facts += [
            _fact(name="supply_temp", value=round(s_c, 3), unit="degC", kind="observation",
                 text=f"measured CDU supply {format_value(s_c, 'degC')}"),
            _fact(name="supply_tracking_error", value=round(err, 3), unit="K", kind="derived",
                 text=f"supply runs {format_value(abs(err), 'K')} {'above' if err >= 0 else 'below'} its setpoint"),
        ]  # fmt: skip
    if flow is not None:
        facts.append(_fact(name="secondary_flow", value=round(flow, 3), unit="kg/s", kind="observation",
                          text=f"secondary flow {format_value(flow, 'kg/s')}"))  # fmt: skip
    if dp is not None:
        facts.append(_fact(name="cabinet_dp", value=round(dp / PSI_TO_PA, 3), unit="psi", kind="observation",
                          text=f"measured cabinet dp {format_value(dp / PSI_TO_PA, 'psi')}"))  # fmt: skip
    blade_heat_w = float(np.sum(branch_heat_w(system, power_w)))  # q = P (1 + a P / P_u), the twin's heat term
    if supply is not None and ret is not None and flow is not None:
        dt = ret - supply
        q_w = float(heat_flow_w(flow, dt))
        gap = 100.0 * (q_w - blade_heat_w) / blade_heat_w if blade_heat_w > 0 else 0.0
        facts += [
            _fact(name="return_temp", value=round(ret - K0, 3), unit="degC", kind="observation",
                 text=f"CDU return {format_value(ret - K0, 'degC')}"),
            _fact(name="coolant_delta_t", value=round(dt, 3), unit="K", kind="derived",
                 text=f"coolant warms by {format_value(dt, 'K')} across the cabinet"),
            _fact(name="secondary_heat_flow", value=round(q_w / 1e3, 3), unit="kW", kind="derived",
                 text=f"m_dot c_p dT = {format_value(q_w / 1e3, 'kW')} on the secondary side"),
            _fact(name="blade_heat", value=round(blade_heat_w / 1e3, 3), unit="kW", kind="derived",
                 text=f"blade heat input {format_value(blade_heat_w / 1e3, 'kW')}"),
            _fact(name="heat_balance_gap", value=round(gap, 3), unit="%", kind="derived",
                 text=f"secondary heat flow and blade heat differ by {format_value(abs(gap), '%')}"),
        ]  # fmt: skip
    facts += _efficiency_facts(out, c)
    return facts


def _efficiency_facts(out, c) -> list[Fact]:
    heat = out.get("cdu_heat_w")
    pump = out.get("cdu_pump_power_w")
    if heat is None or pump is None:
        return []
    heat_all = float(np.sum(heat))
    share = float(heat[c]) / heat_all if heat_all > 0 else 0.0
    shared_w = sum(float(np.sum(out[k])) for k in ("ct_fan_power_w", "ct_pump_power_w", "htw_pump_power_w") if k in out)
    cooling_w = float(pump[c]) + share * shared_w
    cop = float(heat[c]) / cooling_w if cooling_w > 0 else 0.0
    score = efficiency_score(cop)
    return [
        _fact(name="cdu_heat", value=round(float(heat[c]) / 1e3, 3), unit="kW", kind="observation",
             text=f"CDU removes {format_value(float(heat[c]) / 1e3, 'kW')}"),
        _fact(name="cdu_pump_power", value=round(float(pump[c]) / 1e3, 3), unit="kW", kind="observation",
             text=f"CDU pump draws {format_value(float(pump[c]) / 1e3, 'kW')}"),
        _fact(name="cabinet_cooling_power", value=round(cooling_w / 1e3, 3), unit="kW", kind="derived",
             text=f"the cabinet's pump and fan power share is {format_value(cooling_w / 1e3, 'kW')}"),
        _fact(name="cooling_cop", value=round(cop, 4), kind="derived", text=f"cooling COP {cop:.2f}"),
        _fact(name="efficiency_score", value=round(score, 4), kind="score",
             text=f"efficiency score {score:.2f} (COP / (COP + 10))"),
    ]  # fmt: skip


def tower_action_facts(
    out: Mapping[str, np.ndarray], action: PlantAction, previous_action: PlantAction | None, wet_bulb_k: float
) -> list[Fact]:
    """Plant-wide tower facts (mean over towers): leaving-water setpoint, its change, approach, fans."""
    lw_c = float(np.mean(action.lw_setpoint_k)) - K0
    wb_c = wet_bulb_k - K0
    approach = lw_c - wb_c
    change = None if previous_action is None else lw_c - (float(np.mean(previous_action.lw_setpoint_k)) - K0)
    direction = direction_word(change, "K")
    facts = [
        _fact(name="tower_lw_setpoint", value=round(lw_c, 3), unit="degC", kind="action",
             text=f"tower leaving-water setpoint {format_value(lw_c, 'degC')}"),
        _fact(name="tower_lw_direction", value=direction, kind="label",
              text=f"tower leaving-water setpoint {direction}"),
        _fact(name="wet_bulb", value=round(wb_c, 3), unit="degC", kind="observation",
             text=f"outside wet bulb {format_value(wb_c, 'degC')}"),
        _fact(name="tower_approach_setpoint", value=round(approach, 3), unit="K", kind="derived",
             text=f"leaving-water setpoint sits {format_value(approach, 'K')} above the wet bulb"),
    ]  # fmt: skip
    if change is not None:
        prev = lw_c - change
        facts += [
            _fact(name="tower_lw_setpoint_previous", value=round(prev, 3), unit="degC", kind="action",
                 text=f"previous leaving-water setpoint {format_value(prev, 'degC')}"),
            _fact(name="tower_lw_change", value=round(change, 3), unit="K", kind="change",
                 text=_change_text("leaving-water setpoint", change, "K")),
        ]  # fmt: skip
    leaving = out.get("ct_leaving_temp_k")
    if leaving is not None:
        lv = float(np.mean(leaving)) - K0
        facts.append(_fact(name="tower_leaving_temp", value=round(lv, 3), unit="degC", kind="observation",
                          text=f"towers deliver water at {format_value(lv, 'degC')}"))  # fmt: skip
    fans = out.get("cell_fan_power_w")
    if fans is not None:
        fan_kw = float(np.sum(fans)) / 1e3
        facts.append(_fact(name="tower_fan_power", value=round(fan_kw, 3), unit="kW", kind="observation",
                          text=f"tower fans draw {format_value(fan_kw, 'kW')}"))  # fmt: skip
    return facts


def tower_decision_facts(
    system: SystemDescription,
    out: Mapping[str, np.ndarray],
    action: PlantAction,
    previous_action: PlantAction | None,
    wet_bulb_k: float,
    tower: int,
) -> list[Fact]:
    """Facts behind one cooling tower's leaving-water decision (``tower`` 0-based)."""
    n = system.towers.count
    if not 0 <= tower < n:
        raise ValueError(f"`tower` must be in 0..{n - 1} (0-based), got {tower}")
    t = tower
    lw_c = float(action.lw_setpoint_k[t]) - K0
    wb_c = wet_bulb_k - K0
    change = None if previous_action is None else lw_c - (float(previous_action.lw_setpoint_k[t]) - K0)
    direction = direction_word(change, "K")
    facts = [
        _fact(name="tower", value=t + 1, text=f"tower {t + 1}", kind="index"),
        _fact(name="tower_lw_setpoint", value=round(lw_c, 3), unit="degC", kind="action",
             text=f"tower {t + 1} leaving-water setpoint {format_value(lw_c, 'degC')}"),
        _fact(name="tower_lw_direction", value=direction, kind="label", text=f"leaving-water setpoint {direction}"),
        _fact(name="wet_bulb", value=round(wb_c, 3), unit="degC", kind="observation",
             text=f"outside wet bulb {format_value(wb_c, 'degC')}"),
        _fact(name="tower_approach_setpoint", value=round(lw_c - wb_c, 3), unit="K", kind="derived",
             text=f"setpoint sits {format_value(lw_c - wb_c, 'K')} above the wet bulb"),
    ]  # fmt: skip
    if change is not None:
        facts.append(_fact(name="tower_lw_change", value=round(change, 3), unit="K", kind="change",
                          text=_change_text("leaving-water setpoint", change, "K")))  # fmt: skip
    leaving = _get(out, "ct_leaving_temp_k", t)
    entering = _get(out, "ct_entering_temp_k", t)
    flow = _get(out, "ct_water_flow_kg_s", t)
    fan_w = float(np.sum(out["cell_fan_power_w"][t])) if "cell_fan_power_w" in out else None
    if leaving is not None:
        facts += [
            _fact(name="tower_leaving_temp", value=round(leaving - K0, 3), unit="degC", kind="observation",
                 text=f"tower {t + 1} delivers water at {format_value(leaving - K0, 'degC')}"),
            _fact(name="tower_approach", value=round(leaving - wet_bulb_k, 3), unit="K", kind="derived",
                 text=f"measured approach {format_value(leaving - wet_bulb_k, 'K')}"),
        ]  # fmt: skip
    if fan_w is not None:
        facts.append(_fact(name="tower_fan_power", value=round(fan_w / 1e3, 3), unit="kW", kind="observation",
                          text=f"tower {t + 1} fans draw {format_value(fan_w / 1e3, 'kW')}"))  # fmt: skip
    cells = _get(out, "cells_active", t)
    if cells is not None:
        facts.append(_fact(name="cells_active", value=int(round(cells)), kind="observation",
                          text=f"{int(round(cells))} of {system.towers.cells} cells running"))  # fmt: skip
    if leaving is not None and entering is not None and flow is not None:
        q_w = float(heat_flow_w(flow, entering - leaving))
        facts.append(_fact(name="tower_heat_rejected", value=round(q_w / 1e3, 3), unit="kW", kind="derived",
                          text=f"tower {t + 1} rejects {format_value(q_w / 1e3, 'kW')}"))  # fmt: skip
        if fan_w is not None and fan_w > 0:
            ratio = q_w / fan_w
            score = efficiency_score(ratio)
            facts += [
                _fact(name="tower_heat_per_fan_power", value=round(ratio, 4), kind="derived",
                     text=f"{ratio:.2f} kW rejected per kW of fan power"),
                _fact(name="efficiency_score", value=round(score, 4), kind="score",
                     text=f"tower efficiency score {score:.2f} (ratio / (ratio + 10))"),
            ]  # fmt: skip
    return facts


def _change_text(what: str, change: float, unit: str) -> str:
    word = direction_word(change, unit)
    return f"{what} {word}" if word == "held" else f"{what} {word} by {format_value(abs(change), unit)}"


def facts_by_name(facts: list[Fact]) -> dict[str, Fact]:
    """Index facts by name (later facts win)."""
    return {f.name: f for f in facts}


def _get(out: Mapping[str, np.ndarray], name: str, index: int) -> float | None:
    arr = out.get(name)
    if arr is None:
        return None
    value = float(np.asarray(arr).reshape(-1)[index]) if np.ndim(arr) else float(arr)
    return value if np.isfinite(value) else None


def _ranks(x: list[float]) -> list[float]:
    order = sorted(range(len(x)), key=x.__getitem__)
    ranks = [0.0] * len(x)
    i = 0
    while i < len(order):  # equal values share their average rank
        j = i
        while j + 1 < len(order) and x[order[j + 1]] == x[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2.0
        i = j + 1
    return ranks


# --- what the template does not say: what-ifs, the trade-off in kW, the input furthest from normal ----------------
WHATIF_FACTS = ("hottest_branch_expected", "hottest_branch_if_held", "pump_power_expected", "pump_power_if_dp_held",
                "dp_tradeoff_pump_power", "top_input", "top_input_value")  # fmt: skip
# The learned policies' own input scaling (lcmesh.distill.features): (value - centre) / scale.
_INPUT_SCALES = {"hottest branch temperature": (35.0, 5.0), "cabinet load": (1.0, 1.0),  # load per design
                 "wet bulb": (20.0, 10.0)}  # fmt: skip


def decision_whatif_facts(
    system: SystemDescription,
    out: Mapping[str, np.ndarray],
    action: PlantAction,
    previous_action: PlantAction | None,
    wet_bulb_k: float,
    cabinet: int,
) -> list[Fact]:
    """Toolbox estimates beside a cabinet decision that the renderer does not state (LLM explanations may cite them).

    - ``hottest_branch_expected`` / ``hottest_branch_if_held``: the hottest branch once the supply reaches the new
      setpoint, and had the previous setpoint been held; the branch keeps its present rise over the supply (same
      flow and heat), so it moves with the supply one to one.
    - ``pump_power_expected`` / ``pump_power_if_dp_held`` and their difference ``dp_tradeoff_pump_power``: the CDU
      pump at the new and at the previous dp setpoint by the affinity laws on a fixed system curve (dp ~ n^2,
      power ~ n^3, so power ~ dp^1.5) from the measured dp and pump power.
    - ``top_input``: of the hottest branch, the cabinet load and the wet bulb, the one furthest from its normal
      value in the learned policies' input scaling (load per design load), with ``top_input_value`` in its unit.
    """
    from lcmesh.mesh.tools.thermo import pump_affinity

    c = cabinet
    hottest_c = float(np.max(out["branch_max_temp_k"][c] if "branch_max_temp_k" in out else out["branch_temp_k"][c])) - K0
    supply = _get(out, "supply_temp_k", c)
    facts: list[Fact] = []
    if supply is not None:
        rise = hottest_c - (supply - K0)
        new_c = float(action.supply_temp_setpoint_k[c]) - K0 + rise
        facts.append(_fact(name="hottest_branch_expected", value=round(new_c, 3), unit="degC", kind="derived",
                           text=f"at the new supply setpoint the hottest branch settles near {format_value(new_c, 'degC')}"))
        if previous_action is not None:
            held_c = float(previous_action.supply_temp_setpoint_k[c]) - K0 + rise
            facts.append(_fact(name="hottest_branch_if_held", value=round(held_c, 3), unit="degC", kind="derived",
                               text=f"holding the previous supply setpoint would leave it near "
                                    f"{format_value(held_c, 'degC')}"))  # fmt: skip
    dp = _get(out, "cabinet_dp_pa", c)
    pump = out.get("cdu_pump_power_w")
    if dp is not None and dp > 0 and pump is not None:
        pump_w = float(np.asarray(pump).reshape(-1)[c])

        def at(dp_to: float) -> float:
            return pump_affinity(1.0, math.sqrt(max(dp_to, 0.0) / dp), 1.0, dp, pump_w).power_w / 1e3

        new_kw = at(float(action.dp_setpoint_pa[c]))
        facts.append(_fact(name="pump_power_expected", value=round(new_kw, 3), unit="kW", kind="derived",
                           text=f"at the new dp setpoint the CDU pump would draw {format_value(new_kw, 'kW')}"))
        if previous_action is not None:
            held_kw = at(float(previous_action.dp_setpoint_pa[c]))
            facts += [
                _fact(name="pump_power_if_dp_held", value=round(held_kw, 3), unit="kW", kind="derived",
                      text=f"holding the previous dp setpoint, {format_value(held_kw, 'kW')}"),
                _fact(name="dp_tradeoff_pump_power", value=round(new_kw - held_kw, 3), unit="kW", kind="change",
                      text=f"the dp decision costs {format_value(new_kw - held_kw, 'kW')} of pump power"),
            ]  # fmt: skip
    load_kw = float(np.sum(out["branch_power_w"][c])) / 1e3
    inputs = {"hottest branch temperature": (hottest_c, "degC"), "cabinet load": (load_kw, "kW"),
              "wet bulb": (wet_bulb_k - K0, "degC")}  # fmt: skip
    scaled = {"hottest branch temperature": hottest_c, "cabinet load": load_kw * 1e3 / system.cabinets.design_heat_w,
              "wet bulb": wet_bulb_k - K0}  # fmt: skip
    z = {name: abs(scaled[name] - _INPUT_SCALES[name][0]) / _INPUT_SCALES[name][1] for name in inputs}
    top = max(z, key=z.get)
    value, unit = inputs[top]
    facts += [
        _fact(name="top_input", value=top, kind="label", text=f"the input furthest from normal is the {top}"),
        _fact(name="top_input_value", value=round(value, 3), unit=unit, kind="observation",
              text=f"{top} {format_value(value, unit)}"),
    ]
    return facts
