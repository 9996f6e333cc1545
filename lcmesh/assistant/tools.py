"""One spec per operator tool: the ask it answers, its request model, how a typed ask becomes its call and back,
whether it needs the live plant (a what-if) or an operator's confirmation (a proposal).

``call_for(ask)`` is the only place an ``Ask`` turns into a tool call, and ``ask_for(call)`` its inverse (the
rules' and an endpoint's calls read back into a Query, and the hand-labelled question sets compared as
Queries). ``PLANNER_TOOLS`` (name -> request model) is derived from ``SPECS``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from lcmesh.assistant.query import Ask
from lcmesh.mesh.tools import operations as ops
from lcmesh.mesh.tools import plant_data as pd


def _first(values: list[int] | None) -> int | None:
    return values[0] if values else None


def _one(values: int | None) -> list[int] | None:
    return [values] if values is not None else None


def _drop_none(args: dict) -> dict:
    return {k: v for k, v in args.items() if v is not None}


@dataclass(frozen=True)
class AssistantTool:
    """A tool as the assistant uses it."""

    name: str
    ask: str  # the Ask kind it answers
    request: type[BaseModel]
    to_args: Callable[[Ask], dict]
    from_args: Callable[[dict], dict]  # request fields (validated, defaults filled) -> Ask fields
    live: bool = False  # runs the live twin (a what-if)
    confirm: bool = False  # its result is a proposal an operator must confirm with the API token
    covers: str = ""  # what it answers, for people and the OpenAI tool description


def _state_args(a: Ask) -> dict:
    return {"quantity": a.quantity, "cabinet": _first(a.cabinets), "branch": _first(a.branches),
            "tower": _first(a.towers)}  # fmt: skip


def _entities(r: dict) -> dict:
    return {"cabinets": _one(r.get("cabinet")), "branches": _one(r.get("branch")), "towers": _one(r.get("tower"))}


def _decision_args(a: Ask) -> dict:
    return {"decision_id": a.decision_id, "cabinet": _first(a.cabinets), "branch": _first(a.branches),
            "action": a.action, "direction": a.direction}  # fmt: skip


SPECS: dict[str, AssistantTool] = {t.name: t for t in (
    AssistantTool("plant_state", "value", pd.StateRequest, _state_args,
                  lambda r: {"quantity": r["quantity"], **_entities(r)}, covers="a quantity now, per entity"),
    AssistantTool("overview", "overview", pd.OverviewRequest, lambda a: {}, lambda r: {},
                  covers="the plant at a glance"),
    AssistantTool("history_stat", "trend", pd.HistoryRequest,
                  lambda a: {"quantity": a.quantity, "minutes": a.minutes, "stat": a.stat},
                  lambda r: {"quantity": r["quantity"], "minutes": r["minutes"], "stat": r["stat"]},
                  covers="a plant-wide quantity over a window: mean, max, min, change"),
    AssistantTool("rank", "top", pd.RankRequest,
                  lambda a: {"quantity": a.quantity, "order": a.order, "top": a.top,
                             "level": a.level if a.level != "plant" else None},
                  lambda r: {"quantity": r["quantity"], "order": r["order"], "top": r["top"], "level": r["level"]},
                  covers="entities ranked by a quantity now"),
    AssistantTool("compare", "compare", pd.CompareRequest,
                  lambda a: {"quantity": a.quantity, "cabinets": a.cabinets, "towers": a.towers},
                  lambda r: {"quantity": r["quantity"], "cabinets": r["cabinets"], "towers": r["towers"]},
                  covers="named cabinets or towers side by side"),
    AssistantTool("band_count", "count", pd.BandRequest, lambda a: {"low_c": a.low_c, "high_c": a.high_c},
                  lambda r: {"low_c": r["low_c"], "high_c": r["high_c"]},
                  covers="blade groups inside, above and below a temperature band now"),
    AssistantTool("energy_balance", "energy", pd.EnergyRequest, lambda a: {}, lambda r: {},
                  covers="power and heat balance now, cooling PUE"),
    AssistantTool("energy_used", "energy_used", ops.EnergyUsedRequest,
                  lambda a: {"what": a.energy, "minutes": a.minutes},
                  lambda r: {"energy": r["what"], "minutes": r["minutes"]}, covers="energy over a window, kWh"),
    AssistantTool("tracking_gap", "gap", ops.TrackingGapRequest,
                  lambda a: {"level": a.level if a.level in ("cabinet", "tower") else None,
                             "cabinet": _first(a.cabinets), "tower": _first(a.towers)},
                  lambda r: {"level": r["level"], "cabinets": _one(r.get("cabinet")), "towers": _one(r.get("tower"))},
                  covers="measured minus setpoint, per CDU or tower"),
    AssistantTool("peak", "peak", ops.PeakRequest,
                  lambda a: {"quantity": a.quantity, "minutes": a.minutes,
                             "extreme": {"highest": "max", "lowest": "min"}.get(a.order or "")},
                  lambda r: {"quantity": r["quantity"], "minutes": r["minutes"],
                             "order": {"max": "highest", "min": "lowest"}[r["extreme"]]},
                  covers="when and where a quantity was highest or lowest over a window"),
    AssistantTool("weather_effect", "weather", ops.WeatherRequest, lambda a: {"minutes": a.minutes},
                  lambda r: {"minutes": r["minutes"]}, covers="the wet bulb's effect on the towers over a window"),
    AssistantTool("decision", "why", pd.DecisionRequest, _decision_args,
                  lambda r: {"decision_id": r["decision_id"], **_entities(r), "action": r["action"],
                             "direction": r["direction"]},
                  covers="a controller decision and its reasons"),
    AssistantTool("alerts", "alerts", pd.AlertsRequest,
                  lambda a: {"limit": a.top, "active_only": False if a.include_cleared else None},
                  lambda r: {"top": r["limit"], "include_cleared": True if not r["active_only"] else None},
                  covers="maintenance alerts"),
    AssistantTool("controller", "controller", pd.ControllerRequest, lambda a: {"limit": a.top},
                  lambda r: {"top": r["limit"]}, covers="the controller, since when, recent configuration changes"),
    AssistantTool("agents", "agents", pd.AgentsRequest, lambda a: {}, lambda r: {},
                  covers="the mesh's agents, alive or gone"),
    AssistantTool("propose_change", "command", pd.ProposeRequest,
                  lambda a: {"setpoint": a.setpoint, "value": a.value, "change": a.change, "unit": a.unit,
                             "cabinet": _first(a.cabinets), "controller": a.controller, "mode": a.mode},
                  lambda r: {"setpoint": r["setpoint"], "value": r["value"], "change": r["change"], "unit": r["unit"],
                             "cabinets": _one(r.get("cabinet")), "controller": r["controller"], "mode": r["mode"]},
                  confirm=True, covers="a change proposed for an operator to confirm (never applied)"),
    AssistantTool("whatif_setpoint", "whatif", pd.WhatIfSetpointRequest,
                  lambda a: {"setpoint": a.setpoint, "change": a.change, "unit": a.unit,
                             "cabinet": _first(a.cabinets), "minutes": a.minutes},
                  lambda r: {"setpoint": r["setpoint"], "change": r["change"], "unit": r["unit"],
                             "cabinets": _one(r.get("cabinet")), "minutes": r["minutes"]},
                  live=True, covers="a setpoint change simulated on the live twin"),
    AssistantTool("whatif_controller", "whatif_controller", ops.WhatIfControllerRequest,
                  lambda a: {"controller": a.controller, "minutes": a.minutes},
                  lambda r: {"controller": r["controller"], "minutes": r["minutes"]},
                  live=True, covers="another controller simulated on the live twin"),
)}  # fmt: skip
BY_ASK: dict[str, AssistantTool] = {t.ask: t for t in SPECS.values()}
PLANNER_TOOLS: dict[str, type[BaseModel]] = {name: t.request for name, t in SPECS.items()}


def call_for(ask: Ask) -> tuple[str, dict[str, Any]]:
    """The tool call that answers one ask: (tool name, arguments; unset ones left to the request's defaults).

    A value asked of two or more cabinets (or towers) is a comparison. Raises ValueError for an ask with no kind.
    """
    kind = ask.ask
    if kind is None:
        raise ValueError("an ask needs a kind (`ask`) once follow-ups are resolved")
    if kind == "value" and ask.quantity is None and not (ask.cabinets or ask.towers):
        kind = "overview"
    elif kind == "value" and (len(ask.cabinets or ()) > 1 or len(ask.towers or ()) > 1):
        kind = "compare"
    if kind == "value" and ask.quantity is None:
        ask = ask.model_copy(update={"quantity": "blade_temp"})
    spec = BY_ASK[kind]
    return spec.name, _drop_none(spec.to_args(ask))


def ask_for(tool: str, args: dict) -> Ask:
    """The ask a tool call answers (arguments validated; the request's defaults left out)."""
    spec = SPECS[tool]
    request = spec.request.model_validate(args)
    full = request.model_dump(mode="json")
    defaults = _defaults(spec.request)
    fields = {k: v for k, v in spec.from_args(full).items() if v is not None}
    for key, value in list(fields.items()):  # a request default is not something the question said
        arg = _ARG_OF.get((tool, key), key)
        if arg in defaults and defaults[arg] == full.get(arg) and arg not in args:
            fields.pop(key)
    return Ask.model_validate({"ask": spec.ask, **fields})


_ARG_OF = {("energy_used", "energy"): "what", ("alerts", "top"): "limit", ("controller", "top"): "limit",
           ("peak", "order"): "extreme"}  # fmt: skip


@functools.cache
def _defaults(model: type[BaseModel]) -> dict:
    """A request model's arguments as it fills them with none given ({} when it needs some)."""
    try:
        return model().model_dump(mode="json")
    except ValueError:  # pydantic's ValidationError: a required argument
        return {}
