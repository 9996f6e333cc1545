"""The chat's planner: an operator question becomes a plan of operator-tool calls (``[]``: none answers it).

Three planners share one output, a ``Plan`` of validated ``ToolCall``s:

- ``LlmPlanner``: the local SmolLM2-135M-Instruct with the planner adapter
  (``lcmesh/artifacts/llm-planner``, trained by ``lcmesh distill planner``), greedy, prompted with
  ``lcmesh/prompts/chat_plan.md``; it writes a compact JSON list ``[{"tool": .., "args": {..}}]``.
- ``OpenAiPlanner``: any OpenAI-compatible endpoint with function calling (vLLM, Ollama,
  llama.cpp): the tools go out as ``tools=[{"type": "function", ...}]`` and ``tool_calls`` come back.
- ``RulePlanner``: the regular-expression classifier (``intents.classify``) mapped to calls.

Every call an LLM writes is validated against its request model (``PLANNER_TOOLS``, the same
pydantic models the tools serve); an answer that is not JSON, names an unknown tool, has bad
arguments, or does not arrive in time makes the LLM planners fall back to ``RulePlanner``, and they
say so in the plan (``by="rules"``, ``note="llm output invalid: ..."``) and count it
(``fallbacks``, ``fallback_reasons``). A plan proposes at most; nothing here acts on the plant.
"""

from __future__ import annotations

import re

import functools
import json
import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from string import Template
from typing import Any, Literal, Protocol

from pydantic import BaseModel, ValidationError

from lcmesh.llm.budget import Clock
from lcmesh.llm.io_format import load_template
from lcmesh.assistant.intents import Intent, classify, find_change, normalize
from lcmesh.mesh.tools.plant_data import (
    AgentsRequest, AlertsRequest, BandRequest, CompareRequest, ControllerRequest, DecisionRequest, EnergyRequest,
    HistoryRequest, OverviewRequest, ProposeRequest, RankRequest, StateRequest, WhatIfSetpointRequest,
)  # fmt: skip
from lcmesh.mesh.tools.operations import (
    EnergyUsedRequest, PeakRequest, TrackingGapRequest, WeatherRequest, WhatIfControllerRequest,
)  # fmt: skip
from lcmesh.twin.system import PSI_TO_PA

PLANNER_TOOLS: dict[str, type[BaseModel]] = {
    "plant_state": StateRequest, "overview": OverviewRequest, "history_stat": HistoryRequest, "rank": RankRequest,
    "compare": CompareRequest, "band_count": BandRequest, "energy_balance": EnergyRequest, "alerts": AlertsRequest,
    "decision": DecisionRequest, "controller": ControllerRequest, "agents": AgentsRequest,
    "propose_change": ProposeRequest, "whatif_setpoint": WhatIfSetpointRequest,
    "energy_used": EnergyUsedRequest, "tracking_gap": TrackingGapRequest, "peak": PeakRequest,
    "weather_effect": WeatherRequest, "whatif_controller": WhatIfControllerRequest,
}  # fmt: skip
PLANNER_ADAPTER = Path(__file__).resolve().parents[1] / "artifacts" / "llm-planner"
MAX_CALLS = 4  # a question asks a few things at most; more is a runaway answer
PLAN_STOP = ("}]", "[]")  # a plan's JSON list ends with one of these (no argument is an empty list)
log = logging.getLogger("lcmesh.assistant")
MAX_NEW_TOKENS = 96  # two calls with arguments take about 60
TIME_BUDGET_S = 2.4  # the plan's share of the 3 s answer (the mesh's agents share the cores); then the rules plan


@dataclass(frozen=True)
class ToolCall:
    """One tool call: a name from ``PLANNER_TOOLS`` and arguments its request model accepts."""

    tool: str
    args: dict[str, Any] = field(default_factory=dict)

    def request(self) -> BaseModel:
        """The validated request (raises ``PlanError``)."""
        return validate_call(self.tool, self.args)


@dataclass
class Plan:
    """The calls that answer a question, who planned them, and why a fallback happened (``note``)."""

    calls: list[ToolCall]
    by: str  # "llm" | "openai" | "rules"
    note: str | None = None
    raw: str | None = None  # the LLM's own output, when there was one
    seconds: float = 0.0
    query: Any = None  # the typed reading the calls follow from (lcmesh.assistant.query.Query), when there is one


class Planner(Protocol):
    def plan(self, question: str) -> Plan: ...


class PlanError(ValueError):
    """An LLM plan that cannot be used: ``reason`` is a short kind (not_json, schema, unknown_tool, args)."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason, self.detail = reason, detail


# --- validation and the JSON form -------------------------------------------------------------------------
def validate_call(tool: str, args: Any) -> BaseModel:
    """The request model instance for ``tool(args)``; PlanError names the tool and the bad field."""
    model = PLANNER_TOOLS.get(tool) if isinstance(tool, str) else None
    if model is None:
        import difflib

        close = difflib.get_close_matches(str(tool), PLANNER_TOOLS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise PlanError("unknown_tool", f"no tool {tool!r}{hint}")
    if not isinstance(args, dict):
        raise PlanError("args", f"{tool}: `args` must be an object, got {type(args).__name__}")
    try:
        return model.model_validate(args)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "args"
        raise PlanError("args", f"{tool}.{where}: {first['msg']}") from None


def validate_plan(calls: list[dict] | list[ToolCall]) -> list[BaseModel]:
    """Every call's validated request, in order (``{"tool", "args"}`` dicts or ToolCalls)."""
    out = []
    for c in calls:
        tool, args = (c.tool, c.args) if isinstance(c, ToolCall) else (c.get("tool"), c.get("args", {}))
        out.append(validate_call(tool, args))
    return out


def repair_args(tool: str, args: dict) -> tuple[dict, list[str]]:
    """A model's arguments with what can be read unambiguously put right, and a note per change: a key the tool
    does not take dropped, a misspelt choice replaced by the one valid choice it is close to ("supply_temperature"
    -> "supply_temp"). A wrong number is not guessed at: the call stays invalid and the plan falls back."""
    import difflib

    model = PLANNER_TOOLS.get(tool)
    if model is None or not isinstance(args, dict):
        return args, []
    fixed, notes = {}, []
    for key, value in args.items():
        field = model.model_fields.get(key)
        if field is None:
            notes.append(f"dropped `{key}` ({tool} takes no such argument)")
            continue
        choices = _literal_choices(field.annotation)
        if isinstance(value, str) and choices and value not in choices:
            close = difflib.get_close_matches(value, choices, n=2, cutoff=0.75)
            if len(close) == 1 or (close and difflib.SequenceMatcher(None, value, close[0]).ratio() >= 0.9):
                notes.append(f"`{key}` {value!r} read as {close[0]!r}")
                value = close[0]
        fixed[key] = value
    return fixed, notes


def _literal_choices(annotation: Any) -> list[str]:
    """The strings a Literal (or an optional Literal) annotation allows."""
    import typing

    out = []
    for arg in typing.get_args(annotation):
        out += [arg] if isinstance(arg, str) else _literal_choices(arg)
    return out


def parse_plan(text: str, notes: list[str] | None = None) -> list[ToolCall]:
    """A plan from an LLM's text: exactly one JSON list of ``{"tool", "args"}`` objects, each valid (after
    ``repair_args``; what it changed is appended to `notes`)."""
    text = text.strip()
    if not text:
        raise PlanError("empty", "no output")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PlanError("not_json", f"{exc.msg} at character {exc.pos} of {text[:80]!r}") from None
    if not isinstance(data, list):
        raise PlanError("schema", f"a JSON list of calls was expected, got {type(data).__name__}")
    if len(data) > MAX_CALLS:
        raise PlanError("schema", f"at most {MAX_CALLS} calls, got {len(data)}")
    calls = []
    for i, item in enumerate(data):
        if not isinstance(item, dict) or set(item) - {"tool", "args"} or "tool" not in item:
            raise PlanError("schema", f"call {i + 1} must be {{\"tool\": .., \"args\": {{..}}}}, got {item!r}"[:160])
        call = ToolCall(item["tool"], item.get("args") or {})
        try:
            call.request()
        except PlanError:
            args, changed = repair_args(call.tool, call.args)
            if not changed:
                raise
            call = ToolCall(call.tool, args)
            call.request()  # still invalid: the first error is as good as this one
            if notes is not None:
                notes += [f"{call.tool}: {c}" for c in changed]
        calls.append(call)
    return calls


def plan_text(calls: list[dict] | list[ToolCall]) -> str:
    """The compact JSON a planner writes: ``[{"tool":"rank","args":{}}]``."""
    items = [{"tool": c.tool, "args": c.args} if isinstance(c, ToolCall) else {"tool": c["tool"],
                                                                             "args": c.get("args", {})}
             for c in calls]  # fmt: skip
    return json.dumps(items, separators=(",", ":"), ensure_ascii=False)


def same_plan(a: list[ToolCall], b: list[ToolCall]) -> bool:
    """Whether two plans make the same calls in the same order (arguments compared after validation)."""
    if [c.tool for c in a] != [c.tool for c in b]:
        return False
    try:
        return all(x.request() == y.request() for x, y in zip(a, b))
    except PlanError:
        return False


@functools.cache
def plan_schema() -> dict:
    """The JSON schema a local plan is decoded under (llama.cpp's grammar): a list of at most ``MAX_CALLS`` calls,
    each ``{"tool": <a planner tool>, "args": <that tool's arguments>}``. The arguments follow the tool's request
    model (names, types, choices, no stray key), so an argument the model cannot take can not be written; every
    one is optional here and in the order the model learned (the request model still checks what is required).
    A number's range is left to the request model, but for small whole-number fields (cabinet, branch, tower,
    limits) whose values are listed."""
    items = []
    for name in sorted(PLANNER_TOOLS):
        full = PLANNER_TOOLS[name].model_json_schema()
        args = _grammar_node(full, full.get("$defs", {}))
        items.append({"type": "object", "properties": {"tool": {"const": name}, "args": args},
                      "required": ["tool", "args"], "additionalProperties": False})  # fmt: skip
    return {"type": "array", "maxItems": MAX_CALLS, "items": {"anyOf": items}}


_LISTED_INTS = 100  # a bounded whole-number field lists at most this many values (1-100 for an entity number)


def _grammar_node(node: dict, defs: dict) -> dict:
    """A request model's JSON schema cut to what llama.cpp's schema grammar honours (see ``plan_schema``)."""
    if "$ref" in node:
        node = defs[node["$ref"].rsplit("/", 1)[-1]]
    if "anyOf" in node:
        alts = [_grammar_node(a, defs) for a in node["anyOf"] if a.get("type") != "null"]
        return alts[0] if len(alts) == 1 else {"anyOf": alts}
    if "enum" in node or "const" in node:
        return {k: node[k] for k in ("enum", "const") if k in node}
    kind = node.get("type")
    if kind == "integer" and node.get("minimum", -1) >= 0 and "maximum" in node:
        lo = int(node["minimum"])
        return {"enum": list(range(lo, min(int(node["maximum"]), lo + _LISTED_INTS - 1) + 1))}
    if kind == "array":
        out = {"type": "array", "items": _grammar_node(node.get("items", {}), defs)}
        return out | {k: node[k] for k in ("minItems", "maxItems") if k in node}
    if kind == "object":
        props = {k: _grammar_node(v, defs) for k, v in node.get("properties", {}).items()}
        return {"type": "object", "properties": props, "additionalProperties": False}
    if kind == "string":
        return {"type": "string"} | {k: node[k] for k in ("maxLength",) if k in node}
    return {"type": kind} if kind else {}


def plan_messages(question: str) -> list[dict[str, str]]:
    """The chat messages the local planner reads (``chat_plan.md``)."""
    system, user = load_template("chat_plan")
    return [{"role": "system", "content": system},
            {"role": "user", "content": Template(user).safe_substitute(question=" ".join(question.split()))}]


# --- the rules ----------------------------------------------------------------------------------------------
# the classifier's quantity names that differ from the tools'
_QUANTITY = {"it_cooling": "cdu_heat"}
_PER = {"blade_temp": "branch", "blade_temp_mean": "branch", "flow": "branch", "valve": "branch", "it_power": "branch",
        "leaving_water": "tower", "lw_setpoint": "tower", "approach": "tower", "tower_power": "tower",
        "fan_speed": "tower"}  # fmt: skip
_PLANT_WIDE = {"pump_power", "cooling_power", "heat_rejected", "wet_bulb", "in_band", "pue", "htw_supply_temp",
               "htw_return_temp"}  # fmt: skip
_SETPOINT = {"supply_setpoint": "supply", "supply_temp": "supply", "dp": "dp", "dp_setpoint": "dp", "lw_setpoint": "lw",
             "leaving_water": "lw"}  # fmt: skip


def _quantity(intent: Intent, default: str = "blade_temp") -> str:
    return _QUANTITY.get(intent.quantity or default, intent.quantity or default)


def _entity_args(q: str, intent: Intent) -> dict:
    """The cabinet, branch or tower a quantity can be read for."""
    per = _PER.get(q, "plant" if q in _PLANT_WIDE else "cabinet")
    if per == "tower":
        return {"tower": intent.tower} if intent.tower else {}
    if per == "plant":
        return {}
    args = {"cabinet": intent.cabinet} if intent.cabinet else {}
    if per == "branch" and intent.branch and intent.cabinet:
        args["branch"] = intent.branch
    return args


def _change_args(intent: Intent) -> dict | None:
    """ProposeRequest / WhatIfSetpointRequest arguments of the intent's setpoint change (dp in psi)."""
    ch = intent.change
    if ch is None:
        return None
    setpoint = _SETPOINT.get(ch.quantity)
    if setpoint is None:
        return None
    amount, unit = (round(ch.amount / PSI_TO_PA, 4), "psi") if setpoint == "dp" else (ch.amount, "K")
    if ch.absolute:
        return {"setpoint": setpoint, "value": amount, "unit": "degC" if unit == "K" else unit}
    return {"setpoint": setpoint, "change": amount, "unit": unit}


def _decision_args(intent: Intent) -> dict:
    action = {"valve": "valve", **_SETPOINT}.get(intent.quantity or "")
    args = {"cabinet": intent.cabinet, "branch": intent.branch if action == "valve" else None, "action": action,
            "direction": intent.direction if action else None}  # fmt: skip
    return {k: v for k, v in args.items() if v is not None}


def intent_calls(intent: Intent) -> list[ToolCall]:
    """The tool calls that answer a classified question ([] for help and what the rules cannot map)."""
    kind, q = intent.kind, _quantity(intent)
    if kind == "state":
        if intent.quantity is None:
            return [ToolCall("overview", {})] if intent.cabinet is None and intent.tower is None else \
                [ToolCall("plant_state", {"quantity": "blade_temp", **_entity_args("blade_temp", intent)})]
        if q == "pump_power" and intent.cabinet is not None:
            q = "cdu_pump_power"  # a cabinet's pump power: its CDU pump
        return [ToolCall("plant_state", {"quantity": q, **_entity_args(q, intent)})]
    if kind == "band":
        low, high = intent.band_c or (None, None)
        return [ToolCall("band_count", {k: v for k, v in (("low_c", low), ("high_c", high)) if v is not None})]
    if kind == "energy":
        return [ToolCall("energy_balance", {})]
    if kind == "rank":
        if q == "pump_power" and intent.cabinet is None:
            q = "cdu_pump_power"  # ranking cabinets by pump power: their CDU pumps
        top = {"top": intent.top} if intent.top else {}
        level = {"level": "branch"} if intent.level == "branch" and q in ("blade_temp", "blade_temp_mean", "flow",
                                                                          "valve", "it_power") else {}  # fmt: skip
        return [ToolCall("rank", {"quantity": q, "order": "lowest" if intent.low else "highest", **top, **level})]
    if kind == "entities":
        which = {"cabinets": list(intent.cabinets)} if intent.cabinets else {"towers": list(intent.towers)}
        return [ToolCall("compare", {"quantity": q, **which})]
    if kind in ("history", "compare"):
        minutes = round(intent.window_s / 60.0, 4) if intent.window_s else 60.0
        return [ToolCall("history_stat", {"quantity": q, "minutes": minutes, "stat": intent.stat or "change"})]
    if kind in ("alerts", "agents", "controller"):
        return [ToolCall(kind, {})]
    if kind == "why":
        if intent.decision_id:
            return [ToolCall("decision", {"decision_id": intent.decision_id})]
        return [ToolCall("decision", _decision_args(intent))]
    if kind == "whatif":
        args = _change_args(intent)
        if args is None or "value" in args:
            return []  # a what-if needs a change by an amount
        minutes = {"minutes": round(intent.window_s / 60.0, 4)} if intent.window_s and intent.window_s != 60.0 else {}
        return [ToolCall("whatif_setpoint", {**args, **({"cabinet": intent.cabinet} if intent.cabinet else {}),
                                             **minutes})]  # fmt: skip
    if kind == "command":
        return _command_calls(intent)
    return _ops_calls(intent)


def _ops_calls(intent: Intent) -> list[ToolCall]:
    """The operator tools' calls (energy, gap, peak, weather, another controller); defaults left out."""
    minutes = {"minutes": round(intent.window_s / 60.0, 4)} if intent.window_s and intent.window_s != 3600.0 else {}
    if intent.kind == "energy_used":
        return [ToolCall("energy_used", {**({"what": intent.what} if intent.what != "cooling" else {}), **minutes})]
    if intent.kind == "gap":
        args = {"level": "tower"} if intent.level == "tower" else {}
        args.update({k: v for k, v in (("cabinet", intent.cabinet), ("tower", intent.tower)) if v is not None})
        return [ToolCall("tracking_gap", args)]
    if intent.kind == "peak":
        q = _quantity(intent)
        args = {"quantity": q} if q != "blade_temp" else {}
        return [ToolCall("peak", {**args, **minutes, **({"extreme": "min"} if intent.low else {})})]
    if intent.kind == "weather":
        return [ToolCall("weather_effect", minutes)]
    if intent.kind == "whatif_controller":
        return [ToolCall("whatif_controller", {"controller": intent.controller, **minutes})]
    return []


def _command_calls(intent: Intent) -> list[ToolCall]:
    if intent.controller:
        return [ToolCall("propose_change", {"controller": intent.controller, **({"mode": intent.mode} if intent.mode
                                                                                 else {})})]  # fmt: skip
    if intent.mode:
        return [ToolCall("propose_change", {"mode": intent.mode})]
    args = _change_args(intent)
    if args is None:
        return []
    if intent.cabinet and args["setpoint"] != "lw":
        args["cabinet"] = intent.cabinet
    return [ToolCall("propose_change", args)]


def _checked(calls: list[ToolCall]) -> list[ToolCall]:
    """Calls whose arguments validate (a rule that reads a question oddly drops the call, it never crashes)."""
    kept = []
    for c in calls:
        try:
            c.request()
        except PlanError:
            continue
        kept.append(c)
    return kept


class RulePlanner:
    """Deterministic plans from the regular-expression classifier (the fallback of the LLM planners)."""

    by = "rules"

    def plan(self, question: str) -> Plan:
        calls = _checked(intent_calls(classify(question)))
        parts = split_parts(question)
        if len(parts) > 1:  # a multi-part question: each part's calls, kept when they cover more of the question
            from lcmesh.assistant.engine import uncovered

            combined: list[ToolCall] = []
            previous = None
            for part in parts:  # a part without a quantity or entity of its own ("and propose raising it") borrows them
                intent = classify(part)
                if previous is not None:
                    borrowed = {k: getattr(previous, k) for k in ("quantity", "cabinet", "tower")
                                if getattr(intent, k) is None and getattr(previous, k) is not None}
                    if intent.kind == "command" and "quantity" in borrowed and intent.change is None:
                        intent = replace(intent, change=find_change(normalize(part), borrowed["quantity"]))
                    intent = replace(intent, **borrowed)
                previous = intent
                combined += [c for c in _checked(intent_calls(intent)) if c not in combined]
            missing, whole = len(uncovered(question, combined[:MAX_CALLS])), len(uncovered(question, calls))
            if combined and (missing < whole or (missing == whole and len(combined) > len(calls))):
                calls = combined[:MAX_CALLS]
        return Plan(calls, by=self.by)


_PARTS = re.compile(r"\s*(?:[?;]|,?\s+(?:and|also|plus|then|y|e|und|sowie|et|puis)\s+(?=(?:what|which|how|is|are|"
                    r"the|why|when|where|list|show|give|compare|cu[aá]l|qu[eé]|c[oó]mo|d[oó]nde|por qu[eé]|wie|was|"
                    r"welche|warum|wo|wann|quel|quelle|comment|pourquoi|o[uù]|combien|la|le|les|el|los|las|die|der|"
                    r"das)\b)|,\s+(?=(?:what|which|how|why|where|when)\b))", re.IGNORECASE)  # fmt: skip


def split_parts(question: str) -> list[str]:
    """A question's parts at "?", ";" and a conjunction that starts a new question ("... and what is ..."), in the
    four languages; one part when there is nothing to split."""
    return [p.strip() for p in _PARTS.split(question) if p and p.strip() and len(p.strip()) > 2]


# --- the local LLM ------------------------------------------------------------------------------------------
class _Fallbacks:
    """The rules planner standing in for an LLM planner, and the count of how often it did."""

    def __init__(self, fallback: Planner | None):
        self.fallback = fallback or RulePlanner()
        self.plans = 0
        self.fallbacks = 0
        self.repairs = 0  # plans whose arguments repair_args put right (still the model's plans)
        self.fallback_reasons: Counter = Counter()

    def _fall_back(self, question: str, reason: str, detail: str, raw: str | None, t0: float) -> Plan:
        self.fallbacks += 1
        self.fallback_reasons[reason] += 1
        plan = self._fallback_plan(question)
        plan.note, plan.raw = f"llm output invalid: {reason}: {detail}"[:300], raw
        plan.seconds = self.clock() - t0
        return plan

    def _fallback_plan(self, question: str) -> Plan:
        """The fallback's plan of `question` (a reader's fallback also reads the session's previous question)."""
        return self.fallback.plan(question)

    def stats_snapshot(self) -> dict:
        return {"plans": self.plans, "fallbacks": self.fallbacks, "fallback_reasons": dict(self.fallback_reasons),
                "repairs": self.repairs,
                "fallback_rate": self.fallbacks / max(self.plans, 1)}  # fmt: skip


class LlmPlanner(_Fallbacks):
    """Plans from the local model with the planner adapter; rules when its output is unusable or late.

    The backend loads on the first plan (or is given: tests pass one with a test clock), once, under
    a lock; planning is serialized on the same lock (one model, two cores).
    """

    def __init__(self, *, backend=None, adapter: str | Path | None = None, fallback: Planner | None = None,
                 max_new_tokens: int = MAX_NEW_TOKENS, time_budget_s: float | None = TIME_BUDGET_S,
                 threads: int = 0, clock: Clock | None = None):  # fmt: skip
        super().__init__(fallback)
        self._backend, self._lock = backend, threading.Lock()
        self._ready, self._warming = threading.Event(), False
        self.adapter = Path(adapter) if adapter is not None else PLANNER_ADAPTER
        self.max_new_tokens, self.time_budget_s, self.threads = max_new_tokens, time_budget_s, threads
        self._clock = clock

    @property
    def clock(self) -> Clock:
        return self._clock or getattr(self._backend, "clock", time.monotonic)

    @property
    def backend(self):
        """The local backend with the planner adapter merged (loaded on first use)."""
        with self._lock:
            if self._backend is None:
                from lcmesh.llm.gguf_lora import runtime_files
                from lcmesh.llm.hf.backend import HfBackend
                from lcmesh.llm.llama_backend import LlamaCppBackend, llama_available
                from lcmesh.llm.model_cache import resolve_model

                if not (self.adapter / "adapter_config.json").is_file():
                    raise FileNotFoundError(f"no planner adapter in {self.adapter} (train: lcmesh distill planner)")
                if llama_available():  # the CPU runtime: the shipped GGUF with the adapter as a GGUF LoRA
                    gguf, lora, adapter_id = runtime_files(str(self.adapter), "planner")
                    self._backend = LlamaCppBackend(gguf, lora=lora, threads=self.threads, adapter_id=adapter_id)
                else:
                    self._backend = HfBackend(resolve_model("smollm2-135m-instruct"), adapter=self.adapter,
                                              threads=self.threads)  # fmt: skip
            self._ready.set()
            return self._backend

    def warm(self) -> threading.Thread:
        """Load the model in the background; until it is in, questions get the rules' plan (counted, not waited)."""
        self._warming = True

        def load() -> None:
            try:
                self.backend
            except Exception as exc:  # the rules keep answering; every plan says why
                log.warning("the planner model did not load (%s: %s); planning with the rules", type(exc).__name__, exc)
            finally:
                self._ready.set()  # loaded or failed: plans stop waiting (a failure is re-reported per plan)

        thread = threading.Thread(target=load, name="planner-load", daemon=True)
        thread.start()
        return thread

    # what a subclass reading another output changes: the prompt, the schema it is decoded under, the parser
    stop: tuple[str, ...] = PLAN_STOP

    def messages(self, question: str) -> list[dict[str, str]]:
        return plan_messages(question)

    def schema(self) -> dict:
        return plan_schema()

    def parse(self, text: str, repaired: list[str], question: str) -> Plan:
        """The plan in the model's text (PlanError when it holds none)."""
        return Plan(parse_plan(text, repaired), by="llm")

    def plan(self, question: str) -> Plan:
        t0 = self.clock()
        self.plans += 1
        if self._warming and not self._ready.is_set():
            return self._fall_back(question, "backend", "the planner model is still loading", None, t0)
        try:
            backend = self.backend
            with self._lock:
                grammar = {"json_schema": self.schema()} if getattr(backend, "runtime", "") == "llama.cpp" else {}
                gen = backend.chat([self.messages(question)], max_new_tokens=self.max_new_tokens,
                                   stop=list(self.stop), time_budget_s=self.time_budget_s, **grammar)[0]  # fmt: skip
        except Exception as exc:  # a missing adapter or a failing backend: the rules answer
            return self._fall_back(question, "backend", f"{type(exc).__name__}: {exc}", None, t0)
        if gen.failure and not gen.text.rstrip().endswith(self.stop):
            return self._fall_back(question, gen.failure if gen.failure == "timeout" else "backend",
                                   gen.failure, gen.text, t0)  # fmt: skip
        repaired: list[str] = []
        try:
            plan = self.parse(gen.text, repaired, question)
        except PlanError as exc:
            if gen.finish_reason == "length":
                return self._fall_back(question, "length", f"no complete plan in {gen.new_tokens} tokens", gen.text, t0)
            return self._fall_back(question, exc.reason, exc.detail, gen.text, t0)
        if repaired:  # said, and counted: the model planned, its arguments were put right
            self.repairs += 1
        note = f"llm arguments repaired: {'; '.join(repaired)}"[:300] if repaired else None
        plan.note, plan.raw, plan.seconds = note, gen.text, self.clock() - t0
        return plan


# --- any OpenAI-compatible endpoint with function calling ----------------------------------------------
OPENAI_SYSTEM = (
    "You are the planner of a liquid-cooling plant's operator assistant. Call the tools that answer the "
    "operator's question (several if it asks several things), and none if no tool can answer it. Cabinets, "
    "branches and towers are numbered from 1. A request to change the plant becomes propose_change: you never "
    "change the plant yourself, whatever the message says."
)


def openai_tools() -> list[dict]:
    """The operator tools in the OpenAI ``tools`` format (descriptions from the request models)."""
    return [{"type": "function", "function": {"name": name, "description": " ".join((model.__doc__ or name).split()),
                                              "parameters": model.model_json_schema()}}
            for name, model in PLANNER_TOOLS.items()]  # fmt: skip


def parse_tool_calls(message: dict) -> list[ToolCall]:
    """Validated calls from an OpenAI chat ``message`` (its ``tool_calls``; arguments are a JSON string)."""
    calls = []
    for item in (message.get("tool_calls") or [])[: MAX_CALLS + 1]:
        fn = item.get("function") or {}
        raw = fn.get("arguments") or "{}"
        try:
            args = json.loads(raw) if isinstance(raw, str) else raw
        except json.JSONDecodeError as exc:
            raise PlanError("not_json", f"{fn.get('name')}: arguments {exc.msg}") from None
        call = ToolCall(fn.get("name"), args if args is not None else {})
        call.request()
        calls.append(call)
    if len(calls) > MAX_CALLS:
        raise PlanError("schema", f"at most {MAX_CALLS} calls")
    return calls


class OpenAiPlanner(_Fallbacks):
    """Plans by function calling on an OpenAI-compatible endpoint (``LCMESH_LLM_BASE_URL``, ``_MODEL``, ``_API_KEY``).

    No tool call in the answer is the endpoint's refusal (an empty plan); an HTTP error, a timeout or
    a call that does not validate falls back to the rules and is counted.
    """

    def __init__(self, settings=None, *, fallback: Planner | None = None, transport=None,
                 time_budget_s: float | None = None, clock: Clock = time.monotonic):  # fmt: skip
        import httpx

        from lcmesh.llm.base import LlmBackendSettings

        super().__init__(fallback)
        self.settings = settings or LlmBackendSettings(backend="openai")
        self.base_url = self.settings.base_url.rstrip("/")
        self.clock, self.time_budget_s = clock, time_budget_s
        headers = {"Authorization": f"Bearer {self.settings.api_key}"} if self.settings.api_key else {}
        self._client = httpx.Client(timeout=self.settings.timeout_s, headers=headers, transport=transport)
        self._tools = openai_tools()

    def close(self) -> None:
        self._client.close()

    def request_body(self, question: str) -> dict:
        return {"model": self.settings.model, "temperature": 0.0, "tools": self._tools, "tool_choice": "auto",
                "messages": [{"role": "system", "content": OPENAI_SYSTEM}, {"role": "user", "content": question}]}

    def plan(self, question: str) -> Plan:
        import httpx

        t0 = self.clock()
        self.plans += 1
        timeout = self.settings.timeout_s if self.time_budget_s is None else min(self.settings.timeout_s,
                                                                                 self.time_budget_s)  # fmt: skip
        try:
            response = self._client.post(f"{self.base_url}/chat/completions", json=self.request_body(question),
                                         timeout=timeout)  # fmt: skip
            response.raise_for_status()
            message = response.json()["choices"][0]["message"]
        except httpx.TimeoutException as exc:
            return self._fall_back(question, "timeout", str(exc) or "no answer in time", None, t0)
        except (httpx.HTTPError, ValueError, KeyError, IndexError, TypeError) as exc:
            return self._fall_back(question, "backend", f"{type(exc).__name__}: {exc}", None, t0)
        raw = json.dumps(message.get("tool_calls") or message.get("content"))[:2000]
        try:
            calls = parse_tool_calls(message)
        except PlanError as exc:
            return self._fall_back(question, exc.reason, exc.detail, raw, t0)
        note = None if calls else "no tool call: the endpoint found no tool for this question"
        return Plan(calls, by="openai", note=note, raw=raw, seconds=self.clock() - t0)


def make_planner(kind: Literal["llm", "openai", "rules"] = "llm", **kwargs) -> Planner:
    """The planner the UI settings name; ``kwargs`` go to its constructor (``settings=`` for openai)."""
    from lcmesh.assistant.understand import LlmReader, RuleReader, reads_queries

    planners = {"llm": LlmPlanner, "openai": OpenAiPlanner, "rules": RuleReader}
    if kind == "llm" and reads_queries(kwargs.get("adapter") or PLANNER_ADAPTER):
        planners["llm"] = LlmReader  # an adapter trained on tool-call lists (its manifest says so) still plans
    if kind not in planners:
        import difflib

        close = difflib.get_close_matches(str(kind), planners, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"`kind` must be one of {', '.join(planners)}, got {kind!r}{hint}")
    return planners[kind](**kwargs)
