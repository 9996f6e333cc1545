"""The typed reading of an operator question: what is asked, about what, where, over which window.

A question is read once into a ``Query`` (by the local LLM under ``query_schema()``, or by the rules
as the fallback); every later stage works on it. A ``Query`` holds up to ``MAX_ASKS`` ``Ask``s (a
multi-part question), the question's language, and whether it continues the previous turn ("and
cabinet 2?", "why?", "since when?"): a follow-up's asks carry only what changes, and
``resolve_follow_up`` fills the rest from the previous turn's query. No ask is a refusal: nothing
the assistant has answers the question.

Field meanings (the same words the tool specs use, ``lcmesh/assistant/tools.py``):

- ``ask``: value (a quantity now), overview (the plant at a glance), trend (a quantity over a window:
  mean, max, min or change), top (entities ranked), compare (named entities side by side), count
  (blade groups outside a temperature band now), energy (the power balance now), energy_used (energy
  over a window), gap (measured minus setpoint), peak (when and where a quantity was highest or lowest
  over a window), weather (the wet bulb's effect on the towers), why (a controller decision and its
  reasons), alerts, agents, controller (the list of each), command (a change the operator wants: a
  proposal, never applied), whatif (a setpoint change simulated), whatif_controller (another controller
  simulated).
- ``quantity``: one of the plant's quantities (``plant_data.QUANTITIES``).
- ``level``: what entities are meant: branch (a blade group), cabinet (its CDU), tower, plant.
- ``cabinets``, ``branches``, ``towers``: entity numbers as a person reads them, from 1.
- ``stat``: mean, max, min, change (over ``minutes``); ``order``: highest or lowest; ``top``: how many.
- ``low_c``, ``high_c``: a temperature band; ``minutes``: the window, back from now.
- ``setpoint``, ``value``, ``change``, ``unit``: a setpoint change (command, whatif).
- ``controller``, ``mode``: a controller or mode to switch to, or to simulate.
- ``action``, ``direction``, ``decision_id``: the decision a "why" is about.
- ``energy``: what energy is asked (cooling, pumps, tower_fans, it, heat_rejected).
- ``include_cleared``: alerts of any state, not only the active ones.
"""

from __future__ import annotations

import json
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from lcmesh.mesh.tools.operations import EnergyWhat
from lcmesh.mesh.tools.plant_data import QuantityKey, Setpoint, SetpointUnit

MAX_ASKS = 4  # a question asks a few things at most
AskKind = Literal["value", "overview", "trend", "top", "compare", "count", "energy", "energy_used", "gap", "peak",
                  "weather", "why", "alerts", "agents", "controller", "command", "whatif", "whatif_controller"]
Language = Literal["en", "es", "de", "fr"]
Entity = Field(None, min_length=1, max_length=50)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Ask(_Model):
    """One thing asked; fields that do not apply stay unset (None)."""

    ask: AskKind | None = Field(None, description="what is asked; unset only in a follow-up that keeps the kind")
    quantity: QuantityKey | None = None
    level: Literal["branch", "cabinet", "tower", "plant"] | None = None
    cabinets: list[int] | None = Field(None, min_length=1, max_length=50)
    branches: list[int] | None = Field(None, min_length=1, max_length=8)
    towers: list[int] | None = Field(None, min_length=1, max_length=50)
    stat: Literal["mean", "max", "min", "change"] | None = None
    order: Literal["highest", "lowest"] | None = None
    top: int | None = Field(None, ge=1, le=100)
    minutes: float | None = Field(None, gt=0, le=7 * 24 * 60)
    low_c: float | None = Field(None, ge=-20, le=120)
    high_c: float | None = Field(None, ge=-20, le=120)
    setpoint: Setpoint | None = None
    value: float | None = None
    change: float | None = None
    unit: SetpointUnit | None = None
    controller: str | None = Field(None, min_length=1, max_length=80)
    mode: Literal["auto", "manual"] | None = None
    action: Literal["valve", "supply", "dp", "lw"] | None = None
    direction: Literal["up", "down"] | None = None
    decision_id: str | None = Field(None, max_length=80)
    energy: EnergyWhat | None = None
    include_cleared: bool | None = Field(None, description="alerts: cleared ones too, not only the active")

    def fields(self) -> dict:
        """The fields that are set, in declaration order."""
        return self.model_dump(exclude_none=True)


class Query(_Model):
    """A question's whole reading: its asks (none: refuse), its language, whether it continues the last turn."""

    asks: list[Ask] = Field(default_factory=list, max_length=MAX_ASKS)
    lang: Language = "en"
    follow_up: bool = Field(False, description="refers to the previous turn; its asks carry only what changes")

    @property
    def refuse(self) -> bool:
        return not self.asks

    def text(self) -> str:
        """The compact JSON the local model writes (unset fields left out, whole floats as ints)."""
        return query_text(self)


def _compact(value):
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, list):
        return [_compact(v) for v in value]
    return value


def query_text(query: Query) -> str:
    doc: dict = {"asks": [{k: _compact(v) for k, v in a.fields().items()} for a in query.asks]}
    if query.lang != "en":
        doc["lang"] = query.lang
    if query.follow_up:
        doc["follow_up"] = True
    return json.dumps(doc, separators=(",", ":"), ensure_ascii=False)


def parse_query(text: str) -> Query:
    """A Query from the model's JSON (``ValueError`` with the reason when it is not one)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON: {exc.msg} at character {exc.pos}") from None
    return Query.model_validate(data)


def resolve_follow_up(query: Query, previous: Query | None) -> Query:
    """A follow-up's asks completed from the previous turn's (still marked ``follow_up``: it was read as one).

    Each of its fields replaces the previous ask's; entities of one kind replace all entities ("and tower 2?"
    after a cabinet question asks about tower 2); another kind of ask keeps only the quantity, entities and
    window. A follow-up with no previous turn, or a query that is not one, is returned as it is."""
    if not query.follow_up or previous is None or not previous.asks:
        return query
    base = previous.asks[0]
    if not query.asks:  # "and?" / "why?" with nothing of its own: the previous question again
        return Query(asks=list(previous.asks), lang=query.lang, follow_up=True)
    out = []
    for ask in query.asks:
        new = ask.fields()
        keep = base.fields()
        if {"cabinets", "towers", "branches"} & set(new):
            for key in ("cabinets", "towers", "branches"):
                keep.pop(key, None)
        if new.get("ask") not in (None, keep.get("ask")):  # another kind of ask: keep only what it can reuse
            keep = {k: v for k, v in keep.items() if k in ("quantity", "cabinets", "branches", "towers", "minutes")}
        out.append(Ask.model_validate({**keep, **new}))
    return Query(asks=out, lang=query.lang, follow_up=True)


def query_schema() -> dict:
    """The JSON schema the local model's reading is decoded under (llama.cpp's grammar)."""
    from lcmesh.assistant.plan import _grammar_node  # noqa: PLC0415

    from lcmesh.twin.controllers import REGISTRY

    full = Query.model_json_schema()
    schema = _grammar_node(full, full.get("$defs", {}))
    # a controller is one the registry names (the mesh refuses any other): the model picks among them, it does
    # not spell one ("switch to manual" is a mode, not a controller called "manual")
    schema["properties"]["asks"]["items"]["properties"]["controller"] = {"enum": sorted(REGISTRY)}
    return schema
