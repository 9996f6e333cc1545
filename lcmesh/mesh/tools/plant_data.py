"""The operator's tools: plant state, history, rankings, the band, energy, alerts, decisions, the controller.

These are the tools the chat assistant plans with (docs/ui.md "The assistant"). They live in the
same registry as the physics tools (``registry.TOOLS``) and are served on ``tools/{name}`` by the
agent that holds the data (the UI agent: live state, the history file, the configuration). They
compute and return numbers; they write no prose. Cabinets, branches and towers are numbered from 1
in every request and response, as operators count them.

A tool reads its data through ``ToolContext.data``, any object with the ``PlantData`` shape: the
UI's ``ChatSources``, or the recorded site the chat benchmark replays.
"""

from __future__ import annotations

import logging
import re

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from lcmesh.twin.system import PSI_TO_PA, SystemDescription

K0 = 273.15
log = logging.getLogger("lcmesh.mesh.tools")
BAND_C = (20.0, 40.0)  # the blade compliance band (LC-Opt, docs/twin.md)


class NotReady(RuntimeError):
    """The data a tool needs is not there yet (no plant state, no history file, no configuration)."""


class PlantData(Protocol):
    """Where the data tools read: the UI's ChatSources has this shape."""

    system: SystemDescription

    def latest_state(self) -> Any: ...  # PlantState; raises NotReady when none has arrived
    def history(self) -> Any: ...  # HistoryReader
    def config(self) -> Any: ...  # ConfigDoc | None
    def applied(self) -> Any: ...  # AppliedAction | None
    def agents(self) -> list[dict]: ...


# --- quantities ---------------------------------------------------------------------------------------
Per = Literal["plant", "cabinet", "branch", "tower"]


@dataclass(frozen=True)
class Quantity:
    """Something an operator asks about: how to read it per entity from a plant state and from history.

    Definitions (docs/ui.md): approach = tower leaving water minus wet bulb; cooling power = tower
    fans + CDU, hot-water and tower pumps; cooling PUE = (IT + cooling power) / IT; in band = share
    of blade groups strictly inside 20-40 degC.

    `block` is the output block (None for derived quantities); `per` the finest entity it has;
    `history` the summary column of plant_states that tracks it plant-wide (or None); `plant` how
    the plant-wide value folds the entities ("mean", "sum", "max").
    """

    key: str
    label: str
    unit: str  # display unit: degC, K, kW, psi, kg/s, fraction, %, pue (a ratio)
    per: Per
    block: str | None
    plant: str = "mean"
    history: str | None = None


QUANTITIES: dict[str, Quantity] = {q.key: q for q in (
    Quantity("blade_temp", "blade temperature", "degC", "branch", "branch_max_temp_k", "max", "blade_temp_max_k"),
    Quantity("blade_temp_mean", "mean blade temperature", "degC", "branch", "branch_temp_k", "mean",
             "blade_temp_mean_k"),
    Quantity("supply_temp", "measured CDU supply temperature", "degC", "cabinet", "supply_temp_measured_k", "mean",
             "supply_temp_mean_k"),
    Quantity("supply_setpoint", "CDU supply setpoint", "degC", "cabinet", "applied_supply_setpoint_k"),
    Quantity("return_temp", "CDU return temperature", "degC", "cabinet", "return_temp_k"),
    Quantity("dp", "secondary differential pressure", "psi", "cabinet", "cabinet_dp_pa"),
    Quantity("dp_setpoint", "dp setpoint", "psi", "cabinet", "applied_dp_setpoint_pa"),
    Quantity("flow", "secondary coolant flow", "kg/s", "branch", "branch_flow_kg_s", "sum"),
    Quantity("valve", "valve fraction", "fraction", "branch", "applied_valve_fraction"),
    Quantity("pump_speed", "CDU pump speed", "%", "cabinet", "pump_speed"),
    Quantity("cdu_pump_power", "CDU pump power", "kW", "cabinet", "cdu_pump_power_w", "sum"),
    Quantity("it_power", "IT power", "kW", "branch", "branch_power_w", "sum", "it_power_w"),
    Quantity("cdu_heat", "heat removed at the CDUs", "kW", "cabinet", "cdu_heat_w", "sum", "it_cooling_w"),
    Quantity("leaving_water", "tower leaving-water temperature", "degC", "tower", "ct_leaving_temp_k", "mean",
             "ct_leaving_temp_mean_k"),
    Quantity("lw_setpoint", "tower leaving-water setpoint", "degC", "tower", "applied_lw_setpoint_k"),
    Quantity("approach", "tower approach", "K", "tower", "approach_k"),
    Quantity("fan_speed", "tower fan speed", "%", "tower", "fan_speed"),
    Quantity("tower_power", "tower fan power", "kW", "tower", "cell_fan_power_w", "sum", "ct_fan_power_w"),
    Quantity("pump_power", "total pump power", "kW", "plant", "pump_power_w", "sum",
             "pump_power_w"),
    Quantity("cooling_power", "cooling power", "kW", "plant", None, "sum"),
    Quantity("heat_rejected", "heat rejected by the towers", "kW", "plant", "heat_rejected_w", "sum",
             "heat_rejected_w"),
    Quantity("wet_bulb", "outside wet-bulb temperature", "degC", "plant", None, "mean", "wet_bulb_k"),
    Quantity("htw_supply_temp", "hot-water supply temperature", "degC", "plant", "htw_supply_temp_k"),
    Quantity("htw_return_temp", "hot-water return temperature", "degC", "plant", "htw_return_temp_k"),
    Quantity("in_band", "share of blade groups in band", "%", "plant", None, "mean",
             "blade_in_band_pct"),
    Quantity("pue", "cooling PUE", "pue", "plant", None),
)}  # fmt: skip
QuantityKey = Literal[
    "blade_temp", "blade_temp_mean", "supply_temp", "supply_setpoint", "return_temp", "dp", "dp_setpoint", "flow",
    "valve", "pump_speed", "cdu_pump_power", "it_power", "cdu_heat", "leaving_water", "lw_setpoint", "approach",
    "fan_speed", "tower_power", "pump_power", "cooling_power", "heat_rejected", "wet_bulb", "htw_supply_temp",
    "htw_return_temp", "in_band", "pue",
]  # fmt: skip
assert set(QuantityKey.__args__) == set(QUANTITIES)


def convert(unit: str, raw: np.ndarray | float) -> np.ndarray:
    """SI output values in a quantity's display unit."""
    raw = np.asarray(raw, dtype=float)
    if unit == "degC":
        return raw - K0
    if unit == "kW":
        return raw / 1e3
    if unit == "psi":
        return raw / PSI_TO_PA
    if unit == "%":
        return raw * 100.0
    return raw


# --- requests and responses -------------------------------------------------------------------------------
class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Number = Field(None, ge=1, le=10_000, description="numbered from 1")


class EntityValue(_Model):
    """One entity's value: ``entity`` is what a person reads ("cabinet 3", "branch 2 of cabinet 3", "tower 1")."""

    entity: str
    kind: Per
    cabinet: int | None = None
    branch: int | None = None
    tower: int | None = None
    value: float


class StateRequest(_Model):
    """A quantity now, for one entity or for all of its kind."""

    quantity: QuantityKey
    cabinet: int | None = Number
    branch: int | None = Number
    tower: int | None = Number


class StateResponse(_Model):
    quantity: str
    label: str
    unit: str
    step: int
    time_s: float
    per: Per
    values: list[EntityValue] = Field(description="the entities asked for (all of the quantity's kind if none)")
    selected: float | None = Field(None, description="the entities asked for, folded as the plant value is")
    plant: float | None = Field(None, description="the plant-wide value (mean, total or max over entities)")
    plant_reduce: str = "mean"


class OverviewRequest(_Model):
    """The plant at a glance."""


class OverviewResponse(_Model):
    step: int
    time_s: float
    hottest: EntityValue = Field(description="the hottest blade group's branch and its temperature, degC")
    in_band_pct: float
    it_power_kw: float
    tower_power_kw: float
    pump_power_kw: float
    wet_bulb_c: float
    pue: float | None
    controller: str | None = None


class HistoryRequest(_Model):
    """A plant-wide quantity over the last `minutes` of history: mean, max, min and the change."""

    quantity: QuantityKey
    minutes: float = Field(60.0, gt=0, le=7 * 24 * 60)
    stat: Literal["mean", "max", "min", "change"] = "mean"


class HistoryResponse(_Model):
    quantity: str
    label: str
    unit: str
    stat: str
    minutes_asked: float
    minutes_covered: float = Field(description="plant time between the first and last sample found")
    samples: int
    from_step: int
    to_step: int
    mean: float
    max: float
    min: float
    first: float
    last: float
    change: float = Field(description="last minus first")


class RankRequest(_Model):
    """Entities ordered by a quantity: cabinets for cabinet and branch quantities, towers for tower ones."""

    quantity: QuantityKey = "blade_temp"
    order: Literal["highest", "lowest"] = "highest"
    top: int = Field(3, ge=1, le=100)
    level: Literal["branch", "cabinet", "tower"] | None = Field(
        None, description="what to rank: branches (blade groups), cabinets or towers; default cabinets for cabinet "
                          "and branch quantities, towers for tower ones")  # fmt: skip


class RankResponse(_Model):
    quantity: str
    label: str
    unit: str
    order: str
    step: int
    ranked: list[EntityValue]
    count: int = Field(description="how many entities were ranked")
    plant: float | None = None
    plant_reduce: str = "mean"


class CompareRequest(_Model):
    """A quantity for two or more cabinets (or towers) side by side."""

    quantity: QuantityKey = "blade_temp"
    cabinets: list[int] | None = Field(None, min_length=2, max_length=50)
    towers: list[int] | None = Field(None, min_length=2, max_length=50)

    @model_validator(mode="after")
    def _one_kind(self) -> "CompareRequest":
        if (self.cabinets is None) == (self.towers is None):
            raise ValueError("give either `cabinets` or `towers` (two or more, numbered from 1)")
        return self


class CompareResponse(_Model):
    quantity: str
    label: str
    unit: str
    step: int
    values: list[EntityValue]
    highest: str
    lowest: str
    difference: float = Field(description="highest minus lowest, in the quantity's unit (K for temperatures)")


class BandRequest(_Model):
    """How many blade groups are inside, above and below the compliance band now."""

    low_c: float = Field(BAND_C[0], ge=-20, le=120)
    high_c: float = Field(BAND_C[1], ge=-20, le=120)


class BandResponse(_Model):
    step: int
    low_c: float
    high_c: float
    total: int
    inside: int
    above: int
    below: int
    in_band_pct: float
    outside: list[EntityValue] = Field(description="the blade groups outside, hottest first (up to 10), degC")


class EnergyRequest(_Model):
    """Heat and power balance now: IT load, heat moved and rejected, cooling power, cooling PUE."""


class EnergyResponse(_Model):
    step: int
    it_power_kw: float
    cdu_heat_kw: float
    heat_rejected_kw: float
    tower_power_kw: float
    pump_power_kw: float
    cooling_power_kw: float
    pue: float | None = Field(description="(IT + tower fans + pumps) / IT; None with no IT load")
    rejected_over_it_pct: float | None


class AlertsRequest(_Model):
    """Maintenance alerts: the active ones (raised and not cleared) or the latest of any state."""

    active_only: bool = True
    limit: int = Field(10, ge=1, le=100)


class AlertItem(_Model):
    alert_id: str
    severity: str
    kind: str
    location: str
    message: str
    prescription: str = ""
    state: str
    step: int | None = None


class AlertsResponse(_Model):
    active_only: bool
    count: int
    alerts: list[AlertItem]


Action = Literal["valve", "supply", "dp", "lw"]


class DecisionRequest(_Model):
    """A decision and its explanation: by id, or the newest that changed `action` (for a cabinet, a branch)."""

    decision_id: str | None = Field(None, max_length=80)
    cabinet: int | None = Number
    branch: int | None = Number
    action: Action | None = None
    direction: Literal["up", "down"] | None = None


class Change(_Model):
    what: str = Field(description="e.g. 'supply setpoint of cabinet 3', 'valve of branch 2 of cabinet 3'")
    action: Action
    before: float
    after: float
    unit: str


class DecisionResponse(_Model):
    found: bool
    decision_id: str | None = None
    step: int | None = None
    controller: str | None = None
    fallback: bool = False
    changes: list[Change] = []
    explanation: str | None = Field(None, description="the published explanation text, verbatim")
    searched_decisions: int = 0
    reasons: str | None = Field(None, description="the decision's reasons for the cabinet asked about (or the one "
                                "that changed), as plain sentences for a chat: no markdown")  # fmt: skip
    reasons_for: str | None = Field(None, description="the cabinet the reasons are about")
    reasons_source: Literal["published", "rendered"] | None = Field(
        None, description="published: the explanation the mesh published is about that cabinet; rendered: it is about "
                          "another cabinet, so the toolbox's renderer wrote this cabinet's from the decision's state")


class ControllerRequest(_Model):
    """The controller now, since when, and the recent configuration changes."""

    limit: int = Field(5, ge=1, le=50)


class ConfigEvent(_Model):
    version: int
    at: str
    by: str
    reason: str
    changes: dict[str, Any]


class ControllerResponse(_Model):
    configured: str | None
    mode: str | None
    version: int | None
    since: str | None = Field(None, description="when the configured controller was set (UTC, ISO 8601)")
    since_version: int | None = None
    acting: str | None = Field(None, description="the controller of the last applied action")
    acting_step: int | None = None
    fallback: bool = False
    fallback_reason: str | None = None
    history: list[ConfigEvent] = []


class AgentsRequest(_Model):
    """The mesh's agents: alive or gone, and the Agent Monitor's advice."""


class AgentsResponse(_Model):
    known: int
    alive: int
    down: list[str]
    advice: list[str]


Setpoint = Literal["supply", "dp", "lw"]
SetpointUnit = Literal["K", "degC", "degF", "psi", "kPa", "bar"]


class ProposeRequest(_Model):
    """A change the operator asks for, turned into the exact authenticated request that would apply it.

    Nothing is applied: the response is a proposal for an operator holding the API token.
    """

    setpoint: Setpoint | None = None
    value: float | None = Field(None, description="the new setpoint, in `unit`")
    change: float | None = Field(None, description="a change of the setpoint, in `unit` (K for temperatures)")
    unit: SetpointUnit | None = None
    cabinet: int | None = Number
    controller: str | None = Field(None, max_length=80)
    mode: Literal["auto", "manual"] | None = None

    @model_validator(mode="after")
    def _something(self) -> "ProposeRequest":
        if self.setpoint is None and self.controller is None and self.mode is None:
            raise ValueError("name a `setpoint` (with `value` or `change`), a `controller` or a `mode`")
        if self.setpoint is not None and (self.value is None) == (self.change is None):
            raise ValueError("a setpoint change needs exactly one of `value` and `change`")
        return self


class ProposeResponse(_Model):
    applied: bool = Field(False, description="always false: chat never actuates")
    method: str
    path: str
    body: dict[str, Any]
    summary: str
    current: float | None = None
    proposed: float | None = None
    unit: str = ""
    problem: str | None = Field(None, description="why this cannot be proposed as asked (out of limits, unknown)")


class WhatIfSetpointRequest(_Model):
    """What a setpoint change would do over the next minutes, on the live twin (restored afterwards)."""

    setpoint: Setpoint
    change: float = Field(description="the change, in `unit` (K for temperatures; degC means a change too)")
    unit: SetpointUnit = "K"
    cabinet: int | None = Field(None, ge=1, le=10_000, description="one cabinet (numbered from 1); all if none")
    minutes: float = Field(1.0, gt=0, le=60)


class Outcome(_Model):
    hottest_blade_c: float
    in_band_pct: float
    supply_temp_c: float
    tower_power_kw: float
    pump_power_kw: float
    cooling_power_kw: float


class WhatIfSetpointResponse(_Model):
    setpoint: str
    change_si: float = Field(description="the change applied: K, or Pa for dp")
    cabinets: list[int]
    minutes: float
    baseline: Outcome = Field(description="holding the current setpoints")
    predicted: Outcome = Field(description="with the change")


# --- reading a plant state ----------------------------------------------------------------------------------
class ToolInputError(ValueError):
    """A well-formed request this plant cannot answer (no cabinet 9, a quantity without history ...)."""


_FOLD: dict[str, Callable[[np.ndarray], float]] = {"mean": np.mean, "sum": np.sum, "max": np.max, "min": np.min}


def _data(ctx: Any) -> PlantData:
    if getattr(ctx, "data", None) is None:
        raise ToolInputError("this host holds no plant data (state, history); ask the UI agent's tools")
    return ctx.data


def check_number(what: str, number: int | None, count: int) -> None:
    """A clear error for a cabinet / branch / tower that does not exist (numbered from 1)."""
    if number is not None and not 1 <= number <= count:
        plural = "branches" if what == "branch" else f"{what}s"
        raise ToolInputError(f"there is no {what} {number}: this plant has {plural} 1 to {count}")


def _outputs(state: Any, name: str) -> np.ndarray:
    if name not in state.outputs:
        raise ToolInputError(f"the plant state has no {name!r} output")
    return np.asarray(state.outputs[name], dtype=float)


def plant_scalars(state: Any) -> dict[str, float]:
    """Plant-wide SI values of a state: IT, CDU heat, rejected heat, tower fans, pumps (W) and the wet bulb (K)."""
    out = {name: float(np.sum(_outputs(state, name))) for name in
           ("it_power_w", "cdu_heat_w", "heat_rejected_w", "ct_fan_power_w", "pump_power_w")}  # fmt: skip
    out["wet_bulb_k"] = float(state.wet_bulb_k)
    return out


def cooling_pue(it_w: float, fan_w: float, pump_w: float) -> float | None:
    """(IT + tower fans + pumps) / IT; None with no IT load (the ratio means nothing then)."""
    return (it_w + fan_w + pump_w) / it_w if it_w > 0 else None


def _pue(scalars: dict[str, float]) -> float | None:
    return cooling_pue(scalars["it_power_w"], scalars["ct_fan_power_w"], scalars["pump_power_w"])


def in_band_pct(state: Any, low_c: float = BAND_C[0], high_c: float = BAND_C[1]) -> float:
    temps = _outputs(state, "blade_temp_k") - K0
    return float(np.mean((temps > low_c) & (temps < high_c)) * 100.0)


def _plant_value(q: Quantity, state: Any) -> float | None:
    """The plant-wide value of `q` now, in its display unit."""
    s = plant_scalars(state)
    if q.key == "wet_bulb":
        return float(convert("degC", s["wet_bulb_k"]))
    if q.key == "in_band":
        return in_band_pct(state)
    if q.key == "pue":
        return _pue(s)
    if q.key == "cooling_power":
        return (s["ct_fan_power_w"] + s["pump_power_w"]) / 1e3
    raw = _outputs(state, q.block)
    return float(_FOLD[q.plant](convert(q.unit, raw)))


def entity_values(q: Quantity, state: Any, system: SystemDescription) -> list[EntityValue]:
    """Every entity of `q`'s kind with its value now (display unit); a plant quantity gives one 'plant' value."""
    C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
    if q.per == "plant":
        return [EntityValue(entity="plant", kind="plant", value=_plant_value(q, state))]
    raw = _outputs(state, q.block)
    if q.per == "tower":
        values = convert(q.unit, raw.reshape(N, -1).sum(axis=1) if raw.size != N else raw)
        return [EntityValue(entity=f"tower {t + 1}", kind="tower", tower=t + 1, value=float(values[t])) for t in range(N)]
    if q.per == "cabinet":
        values = convert(q.unit, raw)
        return [EntityValue(entity=f"cabinet {c + 1}", kind="cabinet", cabinet=c + 1, value=float(values[c]))
                for c in range(C)]  # fmt: skip
    values = convert(q.unit, raw.reshape(C, B))
    return [EntityValue(entity=f"branch {b + 1} of cabinet {c + 1}", kind="branch", cabinet=c + 1, branch=b + 1,
                        value=float(values[c, b])) for c in range(C) for b in range(B)]  # fmt: skip


def cabinet_values(q: Quantity, state: Any, system: SystemDescription) -> list[EntityValue]:
    """Per-cabinet values: branch quantities folded per cabinet the way the plant value folds them."""
    values = entity_values(q, state, system)
    if q.per != "branch":
        return values
    out = []
    for c in range(1, system.cabinets.count + 1):
        mine = np.asarray([v.value for v in values if v.cabinet == c])
        out.append(EntityValue(entity=f"cabinet {c}", kind="cabinet", cabinet=c, value=float(_FOLD[q.plant](mine))))
    return out


def _fold(q: Quantity, values: list[EntityValue]) -> float | None:
    if not values:
        return None
    return float(_FOLD[q.plant](np.asarray([v.value for v in values])))


# --- the tools ---------------------------------------------------------------------------------------------
def plant_state(req: StateRequest, ctx: Any) -> StateResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    q = QUANTITIES[req.quantity]
    check_number("cabinet", req.cabinet, system.cabinets.count)
    check_number("branch", req.branch, system.cabinets.branches)
    check_number("tower", req.tower, system.towers.count)
    if q.per in ("cabinet", "branch") and req.tower is not None:
        raise ToolInputError(f"the {q.label} is per {q.per}, not per tower; ask for a cabinet")
    if q.per == "tower" and (req.cabinet is not None or req.branch is not None):
        raise ToolInputError(f"the {q.label} is per tower, not per cabinet; ask for a tower")
    values = entity_values(q, state, system)
    if q.per == "plant":  # one value for the plant: a cabinet or tower named with it does not narrow it
        return StateResponse(quantity=q.key, label=q.label, unit=q.unit, step=state.step, time_s=state.time_s,
                             per=q.per, values=values, plant=values[0].value, plant_reduce=q.plant)  # fmt: skip
    picked = [v for v in values
              if (req.cabinet is None or v.cabinet == req.cabinet)
              and (req.branch is None or q.per != "branch" or v.branch == req.branch)
              and (req.tower is None or v.tower == req.tower)]  # fmt: skip
    plant = _plant_value(q, state)
    return StateResponse(quantity=q.key, label=q.label, unit=q.unit, step=state.step, time_s=state.time_s, per=q.per,
                         values=picked, selected=_fold(q, picked) if len(picked) > 1 else None, plant=plant,
                         plant_reduce=q.plant)  # fmt: skip


def overview(req: OverviewRequest, ctx: Any) -> OverviewResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    hottest = max(entity_values(QUANTITIES["blade_temp"], state, system), key=lambda v: v.value)
    s = plant_scalars(state)
    applied = data.applied()
    return OverviewResponse(step=state.step, time_s=state.time_s, hottest=hottest, in_band_pct=in_band_pct(state),
                            it_power_kw=s["it_power_w"] / 1e3, tower_power_kw=s["ct_fan_power_w"] / 1e3,
                            pump_power_kw=s["pump_power_w"] / 1e3, wet_bulb_c=s["wet_bulb_k"] - K0,
                            pue=_pue(s), controller=applied.source_controller if applied else None)  # fmt: skip


def history_stat(req: HistoryRequest, ctx: Any) -> HistoryResponse:
    data = _data(ctx)
    q = QUANTITIES[req.quantity]
    if q.history is None:
        kept = ", ".join(k for k, x in QUANTITIES.items() if x.history)
        raise ToolInputError(f"history keeps plant-wide series only for: {kept}; not the {q.label}")
    state = data.latest_state()
    back = max(1, int(round(req.minutes * 60.0 / data.system.step_s)))
    rows = data.history().states(start_step=max(0, state.step - back), end_step=state.step, fields=(q.history,),
                                 run_id=state.run_id, limit=back + 2)  # fmt: skip
    rows = [r for r in rows if r[q.history] is not None]
    if len(rows) < 2:
        raise NotReady("history holds fewer than two plant states of this run yet")
    unit = "degC" if q.history.endswith("_k") else "kW" if q.history.endswith("_w") else "%"
    values = convert(unit, np.asarray([r[q.history] for r in rows], dtype=float))
    return HistoryResponse(quantity=q.key, label=q.label, unit=unit, stat=req.stat, minutes_asked=req.minutes,
                           minutes_covered=(rows[-1]["time_s"] - rows[0]["time_s"]) / 60.0, samples=len(rows),
                           from_step=rows[0]["step"], to_step=rows[-1]["step"], mean=float(values.mean()),
                           max=float(values.max()), min=float(values.min()), first=float(values[0]),
                           last=float(values[-1]), change=float(values[-1] - values[0]))  # fmt: skip


def rank(req: RankRequest, ctx: Any) -> RankResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    q = QUANTITIES[req.quantity]
    if q.per == "plant":
        raise ToolInputError(f"the {q.label} is one plant-wide value; there is nothing to rank")
    level = req.level or ("tower" if q.per == "tower" else "cabinet")
    if (level == "tower") != (q.per == "tower") or (level == "branch" and q.per != "branch"):
        raise ToolInputError(f"the {q.label} is per {q.per}; it cannot be ranked by {level}")
    values = entity_values(q, state, system) if level == "branch" else cabinet_values(q, state, system)
    ordered = sorted(values, key=lambda v: v.value, reverse=req.order == "highest")
    return RankResponse(quantity=q.key, label=q.label, unit=q.unit, order=req.order, step=state.step,
                        ranked=ordered[: req.top], count=len(values), plant=_fold(q, values),
                        plant_reduce=q.plant)  # fmt: skip


def compare(req: CompareRequest, ctx: Any) -> CompareResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    q = QUANTITIES[req.quantity]
    kind, numbers = ("cabinet", req.cabinets) if req.cabinets is not None else ("tower", req.towers)
    for n in numbers:
        check_number(kind, n, system.cabinets.count if kind == "cabinet" else system.towers.count)
    if q.per == "plant" or (kind == "tower") != (q.per == "tower"):
        raise ToolInputError(f"the {q.label} is {'plant-wide' if q.per == 'plant' else 'per ' + q.per}; "
                             f"it cannot be compared between {kind}s")  # fmt: skip
    by_number = {(v.cabinet if kind == "cabinet" else v.tower): v for v in cabinet_values(q, state, system)}
    values = [by_number[n] for n in dict.fromkeys(numbers)]
    if len(values) < 2:
        raise ToolInputError(f"name two different {kind}s to compare")
    hi, lo = max(values, key=lambda v: v.value), min(values, key=lambda v: v.value)
    return CompareResponse(quantity=q.key, label=q.label, unit=q.unit, step=state.step, values=values,
                           highest=hi.entity, lowest=lo.entity, difference=hi.value - lo.value)  # fmt: skip


def band_count(req: BandRequest, ctx: Any) -> BandResponse:
    data = _data(ctx)
    system, state = data.system, data.latest_state()
    if req.low_c >= req.high_c:
        raise ToolInputError(f"the band's low edge ({req.low_c}) must be below its high edge ({req.high_c})")
    temps = _outputs(state, "blade_temp_k") - K0
    C, B = system.cabinets.count, system.cabinets.branches
    per_branch = temps.size // (C * B)
    outside = []
    for i in np.argsort(-temps):
        t = float(temps[i])
        if req.low_c < t < req.high_c:
            continue
        c, rest = divmod(int(i), B * per_branch)
        b, g = divmod(rest, per_branch)
        name = f"branch {b + 1} of cabinet {c + 1}" if per_branch == 1 else \
            f"blade group {g + 1} of branch {b + 1} of cabinet {c + 1}"
        outside.append(EntityValue(entity=name, kind="branch", cabinet=c + 1, branch=b + 1, value=t))
    above, below = int(np.sum(temps >= req.high_c)), int(np.sum(temps <= req.low_c))
    return BandResponse(step=state.step, low_c=req.low_c, high_c=req.high_c, total=int(temps.size),
                        inside=int(temps.size) - above - below, above=above, below=below,
                        in_band_pct=in_band_pct(state, req.low_c, req.high_c), outside=outside[:10])  # fmt: skip


def energy_balance(req: EnergyRequest, ctx: Any) -> EnergyResponse:
    data = _data(ctx)
    state = data.latest_state()
    s = plant_scalars(state)
    it = s["it_power_w"]
    return EnergyResponse(step=state.step, it_power_kw=it / 1e3, cdu_heat_kw=s["cdu_heat_w"] / 1e3,
                          heat_rejected_kw=s["heat_rejected_w"] / 1e3, tower_power_kw=s["ct_fan_power_w"] / 1e3,
                          pump_power_kw=s["pump_power_w"] / 1e3,
                          cooling_power_kw=(s["ct_fan_power_w"] + s["pump_power_w"]) / 1e3, pue=_pue(s),
                          rejected_over_it_pct=s["heat_rejected_w"] / it * 100.0 if it > 0 else None)  # fmt: skip


def alerts(req: AlertsRequest, ctx: Any) -> AlertsResponse:
    rows = _data(ctx).history().alerts(active_only=req.active_only, limit=req.limit)
    items = [AlertItem(alert_id=r["alert_id"], severity=r["severity"], kind=r["kind"], location=r["location"] or "",
                       message=r["message"] or "", prescription=r.get("prescription") or "", state=r["state"],
                       step=r.get("step")) for r in rows]  # fmt: skip
    return AlertsResponse(active_only=req.active_only, count=len(items), alerts=items)


# --- decisions, the controller, agents ------------------------------------------------------------------------
DEAD_BAND = {"valve": 0.005, "supply": 0.05, "dp": 0.05, "lw": 0.05}  # fraction, K, psi, K: smaller is no change
DECISIONS_SEARCHED = 240  # one hour of 15 s steps
_ACTION_FIELDS = {"supply": ("supply_temp_setpoint_k", "degC", "supply setpoint"),
                  "dp": ("dp_setpoint_pa", "psi", "dp setpoint"),
                  "lw": ("lw_setpoint_k", "degC", "leaving-water setpoint"),
                  "valve": ("valve_fractions", "fraction", "valve")}  # fmt: skip


def action_changes(now: dict, prev: dict) -> list[Change]:
    """Every setpoint and valve that moved beyond its dead band between two applied actions, largest first."""
    changes = []
    for kind, (name, unit, label) in _ACTION_FIELDS.items():
        a, b = convert(unit, np.asarray(now[name], dtype=float)), convert(unit, np.asarray(prev[name], dtype=float))
        for index in zip(*np.nonzero(np.abs(a - b) > DEAD_BAND[kind])):
            if kind == "valve":
                what = f"valve of branch {index[1] + 1} of cabinet {index[0] + 1}"
            elif kind == "lw":
                what = f"{label} of tower {index[0] + 1}"
            else:
                what = f"{label} of cabinet {index[0] + 1}"
            changes.append(Change(what=what, action=kind, before=float(b[index]), after=float(a[index]), unit=unit))
    return sorted(changes, key=lambda c: -abs(c.after - c.before) / DEAD_BAND[c.action])


def _matches(change: Change, req: DecisionRequest) -> bool:
    if req.action is not None and change.action != req.action:
        return False
    if req.direction is not None and (change.after > change.before) != (req.direction == "up"):
        return False
    if req.cabinet is not None and f"cabinet {req.cabinet}" not in change.what.split(" of ", 1)[-1]:
        return False
    return req.branch is None or f"branch {req.branch} of" in change.what


def decision(req: DecisionRequest, ctx: Any) -> DecisionResponse:
    data = _data(ctx)
    system = data.system
    check_number("cabinet", req.cabinet, system.cabinets.count)
    check_number("branch", req.branch, system.cabinets.branches)
    state = data.latest_state()
    rows = data.history().decisions(limit=DECISIONS_SEARCHED + 1, run_id=state.run_id)
    if len(rows) < 2:
        raise NotReady("history holds fewer than two applied actions of this run yet")
    filtered = any(x is not None for x in (req.cabinet, req.branch, req.action, req.direction))
    for k, (row, prev) in enumerate(zip(rows, rows[1:])):
        if req.decision_id is not None and row["decision_id"] != req.decision_id:
            continue
        changes = action_changes(row["action"], prev["action"])
        picked = [c for c in changes if _matches(c, req)]
        if req.decision_id is None and filtered and not picked:
            continue
        shown = (picked or changes)[:6]
        cabinet = req.cabinet or next((_cabinet_of(c.what) for c in shown if _cabinet_of(c.what)), None)
        reasons, source, about = decision_reasons(data, row, prev, cabinet)
        return DecisionResponse(found=True, decision_id=row["decision_id"], step=row["step"],
                                controller=row["source_controller"], fallback=row["fallback"], changes=shown,
                                explanation=row.get("explanation"), searched_decisions=k + 1, reasons=reasons,
                                reasons_for=f"cabinet {about}" if reasons and about else None,
                                reasons_source=source)  # fmt: skip
    return DecisionResponse(found=False, searched_decisions=len(rows) - 1)


_CABINET_IN = re.compile(r"\bcabinet (\d+)\b", re.IGNORECASE)
_MARKDOWN_HEADING = re.compile(r"^\s*#{1,6}\s*([^\n]*)$", re.MULTILINE)


def _cabinet_of(what: str) -> int | None:
    """The cabinet a change is of ("valve of branch 2 of cabinet 3" -> 3); None for a tower's."""
    m = _CABINET_IN.search(what)
    return int(m.group(1)) if m else None


def readable(text: str) -> str:
    """An explanation as plain sentences for a chat: the short level's EXPLANATION and its overall temperature line,
    without markdown headings, emphasis or bullets."""
    parts = [p.strip() for p in _MARKDOWN_HEADING.split(text)]
    sections = dict(zip(parts[1::2], parts[2::2])) if len(parts) > 1 else {"": text}
    kept = [sections.get("EXPLANATION", "") or next(iter(sections.values()), "")]
    impact = sections.get("TEMPERATURE IMPACT", "")
    kept += [line.removeprefix("Overall:").strip() for line in impact.split("\n\n") if line.startswith("Overall:")]
    plain = " ".join(" ".join(k.split()) for k in kept if k)
    return re.sub(r"[*_`]{1,2}(\S[^*_`]*?)[*_`]{1,2}", r"\1", plain).replace("\n- ", " ").strip()


def decision_reasons(data: PlantData, row: dict, prev: dict,
                     cabinet: int | None) -> tuple[str | None, str | None, int | None]:  # fmt: skip
    """(reasons, source, cabinet) of a decision: the published explanation when it is about `cabinet` (or no cabinet
    is asked), else the toolbox renderer's for `cabinet` (the hottest when none is asked and nothing is published
    yet) from the decision's stored state."""
    published = row.get("explanation")
    about = _CABINET_IN.search(published or "")
    if published and (cabinet is None or (about and int(about.group(1)) == cabinet)):
        return readable(published), "published", int(about.group(1)) if about else cabinet
    from lcmesh.mesh.messages import ActionModel, plant_state_to_observation
    from lcmesh.mesh.tools.explain import render_explanation
    from lcmesh.mesh.tools.facts import cabinet_decision_facts

    state = data.history().state_at(row["step"], row.get("run_id"))
    if state is None:  # this step was stored without its full state: the published text is all there is
        return (readable(published), "published", cabinet) if published else (None, None, None)

    def action(a: dict):
        return ActionModel.model_validate(a).to_action()

    try:
        out = plant_state_to_observation(state, data.system).out
        if cabinet is None:  # nothing published yet and no cabinet asked: the hottest one, as the Control agent picks
            cabinet = int(np.argmax(np.asarray(out["branch_temp_k"]).max(axis=1))) + 1
        facts = cabinet_decision_facts(data.system, out, action(row["action"]), action(prev["action"]),
                                       float(state.wet_bulb_k), cabinet - 1)  # fmt: skip
        return readable(render_explanation(facts, "short")), "rendered", cabinet
    except (ValueError, KeyError) as exc:  # a state or action the renderer cannot read: say why, not crash
        log.warning("no reasons for cabinet %s of decision %s: %s", cabinet, row.get("decision_id"), exc)
        return (readable(published), "published", cabinet) if published else (None, None, None)


def controller(req: ControllerRequest, ctx: Any) -> ControllerResponse:
    data = _data(ctx)
    doc, applied = data.config(), data.applied()
    try:
        rows = data.history().config_changes(limit=200)
    except FileNotFoundError:
        rows = []
    configured = doc.config.controller if doc is not None else (rows[0]["config"]["controller"] if rows else None)
    since = since_version = None
    for row in rows:  # newest first: the oldest version of the current run of this controller
        if row["config"].get("controller") != configured:
            break
        since, since_version = row["created_at"], row["version"]
    history = [ConfigEvent(version=r["version"], at=r["created_at"], by=r["changed_by"], reason=r["reason"],
                           changes=r["changes"]) for r in rows[: req.limit]]  # fmt: skip
    if doc is None and applied is None and not rows:
        raise NotReady("neither the configuration nor an applied action is known yet")
    return ControllerResponse(configured=configured, mode=doc.config.mode if doc else None,
                              version=doc.version if doc else (rows[0]["version"] if rows else None), since=since,
                              since_version=since_version, acting=applied.source_controller if applied else None,
                              acting_step=applied.step if applied else None,
                              fallback=bool(applied.fallback) if applied else False,
                              fallback_reason=applied.fallback_reason if applied else None, history=history)  # fmt: skip


def agents(req: AgentsRequest, ctx: Any) -> AgentsResponse:
    rows = _data(ctx).agents()
    return AgentsResponse(known=len(rows), alive=sum(1 for a in rows if a["alive"]),
                          down=[a["agent_id"] for a in rows if not a["alive"]],
                          advice=[x for a in rows for x in a.get("advice", [])][:5])  # fmt: skip


# --- proposals and what-ifs -------------------------------------------------------------------------------------
_SETPOINT = {"supply": ("supply_temp_setpoint_k", "supply_temp_setpoint_c", "CDU supply setpoint"),
             "dp": ("dp_setpoint_pa", "dp_setpoint_psi", "dp setpoint"),
             "lw": ("lw_setpoint_k", "lw_setpoint_c", "tower leaving-water setpoint")}  # fmt: skip


def setpoint_si(setpoint: str, amount: float, unit: str | None, *, absolute: bool) -> float:
    """`amount` in SI (K for temperatures, Pa for dp); an absolute temperature becomes kelvin, a change stays K."""
    if setpoint == "dp":
        unit = unit or "psi"
        if unit not in ("psi", "kPa", "bar"):
            raise ToolInputError(f"a dp setpoint is in psi, kPa or bar, not {unit}")
        return amount * {"psi": PSI_TO_PA, "kPa": 1e3, "bar": 1e5}[unit]
    unit = unit or ("degC" if absolute else "K")
    if unit not in ("K", "degC", "degF"):
        raise ToolInputError(f"a temperature setpoint is in degC, degF or K, not {unit}")
    scale = 5.0 / 9.0 if unit == "degF" else 1.0
    if not absolute:
        return amount * scale
    if unit == "K":
        return amount
    return (amount - 32.0) * scale + K0 if unit == "degF" else amount + K0


def _limits(data: PlantData, setpoint: str) -> tuple[float, float]:
    from lcmesh.mesh.tools.guardrails import GuardrailLimits

    doc = data.config()
    g = doc.config.guardrails if doc is not None else GuardrailLimits()
    return {"supply": (g.supply_temp_min_k, g.supply_temp_max_k), "dp": (g.dp_min_pa, g.dp_max_pa),
            "lw": (g.lw_min_k, g.lw_max_k)}[setpoint]  # fmt: skip


def propose_change(req: ProposeRequest, ctx: Any) -> ProposeResponse:
    """The request an operator would send to apply the change; nothing here touches the plant."""
    data = _data(ctx)
    if req.setpoint is None:
        body = {k: v for k, v in (("controller", req.controller), ("mode", req.mode)) if v is not None}
        words = " and ".join(f"{k} {v}" for k, v in body.items())
        return ProposeResponse(method="POST", path="/api/control/mode", body=body, summary=f"switch to {words}")
    system = data.system
    check_number("cabinet", req.cabinet, system.cabinets.count)
    applied = data.applied()
    if applied is None:
        raise NotReady("no applied action yet: the current setpoints are not known")
    field, body_key, label = _SETPOINT[req.setpoint]
    display = "psi" if req.setpoint == "dp" else "degC"
    current = np.asarray(getattr(applied.action, field), dtype=float)
    selected = list(range(current.size)) if req.cabinet is None or req.setpoint == "lw" else [req.cabinet - 1]
    target = current.copy()
    if req.value is not None:
        target[selected] = setpoint_si(req.setpoint, req.value, req.unit, absolute=True)
    else:
        target[selected] += setpoint_si(req.setpoint, req.change, req.unit, absolute=False)
    low, high = _limits(data, req.setpoint)
    now, new = (float(convert(display, current[selected]).mean()), float(convert(display, target[selected]).mean()))
    problem = None
    if np.any(target[selected] < low - 1e-9) or np.any(target[selected] > high + 1e-9):
        lo, hi = float(convert(display, low)), float(convert(display, high))
        problem = f"the {label} must stay within {lo:.1f} to {hi:.1f} {'psi' if display == 'psi' else '°C'}"
    values = [round(float(v), 3) for v in convert(display, target)]
    where = f" of cabinet {req.cabinet}" if req.cabinet is not None and req.setpoint != "lw" else ""
    return ProposeResponse(method="POST", path="/api/control/setpoints",
                           body={body_key: values, "reason": "chat proposal, confirmed by an operator"},
                           summary=f"set the {label}{where} from {now:.1f} to {new:.1f}", current=now, proposed=new,
                           unit=display, problem=problem)  # fmt: skip


def _outcome(outputs: dict, cabinets: list[int]) -> Outcome:
    def arr(name: str) -> np.ndarray:
        return np.asarray(outputs[name], dtype=float).ravel()

    temps = arr("blade_temp_k") - K0
    fans, pumps = float(arr("ct_fan_power_w").sum()) / 1e3, float(arr("pump_power_w").sum()) / 1e3
    return Outcome(hottest_blade_c=float(temps.max()), in_band_pct=float(np.mean((temps > 20) & (temps < 40)) * 100),
                   supply_temp_c=float(arr("supply_temp_k")[cabinets].mean() - K0), tower_power_kw=fans,
                   pump_power_kw=pumps, cooling_power_kw=fans + pumps)  # fmt: skip


def whatif_setpoint(req: WhatIfSetpointRequest, ctx: Any) -> WhatIfSetpointResponse:
    """A look-ahead on the live twin: the change against holding the setpoints, then the plant restored."""
    import contextlib

    from lcmesh.mesh.tools import whatif

    plant, system = getattr(ctx, "plant", None), ctx.system
    if plant is None:
        raise ToolInputError("this host has no live twin; the Sensor agent serves what-ifs")
    check_number("cabinet", req.cabinet, system.cabinets.count)
    delta = setpoint_si(req.setpoint, req.change, req.unit if req.unit != "degC" else "K", absolute=False)
    C = system.cabinets.count
    cabinets = list(range(C)) if req.cabinet is None or req.setpoint == "lw" else [req.cabinet - 1]
    mask = np.zeros(C)
    mask[cabinets] = 1.0
    key = {"supply": "supply_temp_setpoint_k", "dp": "dp_setpoint_pa", "lw": "lw_setpoint_k"}[req.setpoint]
    change = {key: delta if req.setpoint == "lw" else delta * mask}
    steps = int(min(whatif.MAX_WHATIF_STEPS, max(1, round(req.minutes * 60.0 / system.step_s))))
    outputs = ("blade_temp_k", "ct_fan_power_w", "pump_power_w", "supply_temp_k")
    with ctx.lock if getattr(ctx, "lock", None) is not None else contextlib.nullcontext():
        r = whatif.one_step_whatif(plant, change, steps=steps, outputs=outputs)
    return WhatIfSetpointResponse(setpoint=req.setpoint, change_si=delta, cabinets=[c + 1 for c in cabinets],
                                  minutes=r["horizon_s"] / 60.0, baseline=_outcome(r["baseline"], cabinets),
                                  predicted=_outcome(r["predicted"], cabinets))  # fmt: skip


# --- the tool table (registered in registry.TOOLS) ----------------------------------------------------------------
DATA_TOOLS: list[tuple[str, str, type[BaseModel], type[BaseModel], Callable]] = [
    ("plant_state", "A quantity now for a cabinet, branch or tower, or for all of them", StateRequest,
     StateResponse, plant_state),
    ("overview", "The plant at a glance: hottest blade group, band, powers, weather, PUE, controller",
     OverviewRequest, OverviewResponse, overview),
    ("history_stat", "A plant-wide quantity over the last minutes: mean, max, min, change", HistoryRequest,
     HistoryResponse, history_stat),
    ("rank", "Branches (blade groups), cabinets or towers ordered by a quantity (hottest, highest power ...)", RankRequest, RankResponse,
     rank),
    ("compare", "A quantity for two or more cabinets or towers side by side", CompareRequest, CompareResponse,
     compare),
    ("band_count", "Blade groups inside, above and below the compliance band now", BandRequest, BandResponse,
     band_count),
    ("energy_balance", "IT load, heat moved and rejected, cooling power and cooling PUE now", EnergyRequest,
     EnergyResponse, energy_balance),
    ("alerts", "Maintenance alerts, active or recent", AlertsRequest, AlertsResponse, alerts),
    ("decision", "A controller decision, its changes and its published explanation", DecisionRequest,
     DecisionResponse, decision),
    ("controller", "The controller now, since when, and the configuration history", ControllerRequest,
     ControllerResponse, controller),
    ("agents", "The mesh's agents: alive, down, and the monitor's advice", AgentsRequest, AgentsResponse, agents),
    ("propose_change", "The authenticated request that would apply a setpoint, controller or mode change; "
     "nothing is applied", ProposeRequest, ProposeResponse, propose_change),
    ("whatif_setpoint", "What a supply, dp or tower setpoint change would do over the next minutes, on the live "
     "twin", WhatIfSetpointRequest, WhatIfSetpointResponse, whatif_setpoint),
]  # fmt: skip
PLANT_TOOLS = ("whatif_setpoint", "whatif_controller")  # need the live twin (ToolContext.plant): the Sensor serves them
