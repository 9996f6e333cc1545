"""The operator assistant's engine: read the question, plan its calls, run them, write the answer, check it.

``ChatEngine.ask(message, session=None)`` returns ``{"answer", "facts", "intent", "proposed_command",
"phrased_by", "grounded", "elapsed_ms", "plan", "planned_by", "refused", "problems", "lang", "query",
"follow_up", "session", "detail"}``, answered in the question's language (English, Spanish, German or French:
``language.detect_language``):

1. a reader (``understand.py``: the local LLM under the Query's JSON schema, the rules as the counted
   fallback) turns the question into one typed ``Query``; a follow-up in a chat session is completed from
   the session's previous Query; the calls follow from its asks through the tool specs (``tools.py``); an
   OpenAI-compatible endpoint's function calls are read back into a Query (``plan.py``);
2. the tools compute: the data tools here, on the UI's live state and history; the what-if on the
   live twin, through the Sensor's queryable;
3. ``write.py`` writes the answer from the results only, every number a fact;
4. the semantic guard (``lcmesh.mesh.tools.semantic``) checks every number is bound to the right
   entity and quantity and every ranking and direction agrees with the results. An answer that
   fails is not sent as grounded: a rephrasing falls back to the written draft, a draft that fails
   is a bug and is reported; then the answer is checked against what was asked (``check``: the
   question's words, ``uncovered``, by default; or the Query's fields, ``check.unanswered``).

A question no tool answers gets an honest "I can't tell that from here" and is never grounded. A
request to change the plant comes back as a proposed command: chat never actuates.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import Counter, OrderedDict
from typing import Any

from lcmesh.assistant import write as writer
from lcmesh.assistant.sources import ChatSources, NotReady
from lcmesh.assistant.facts import ChatFact, FactBook, fact, numbers_in, ungrounded_numbers
from lcmesh.mesh.agents.ui.gateway import MeshRefused, MeshUnavailable
from lcmesh.assistant.language import detect_language, phrase
from lcmesh.assistant.phrasing import Phraser, TemplatePhraser
from lcmesh.assistant.plan import Plan, RulePlanner, ToolCall
from lcmesh.assistant.check import unanswered
from lcmesh.assistant.query import Query
from lcmesh.assistant.understand import LlmReader, RuleReader, query_of
from lcmesh.mesh.ratelimit import RateLimited
from lcmesh.mesh.tools import registry, semantic
from lcmesh.mesh.tools.claims import Claim, Fact
from lcmesh.mesh.tools.vocab import (
    ASKED_STATS, DOWN_ASKED, HIGH_WORD, LOW_WORD, MEASURED_WORD, MISSING_WORDS, PAIRED_CONCEPTS, QUESTION_CONCEPTS,
    SETPOINT_WORD, TRACKING_ERROR, UP_ASKED,
)  # fmt: skip
from lcmesh.mesh.tools.plant_data import PLANT_TOOLS

log = logging.getLogger("lcmesh.assistant")
MAX_CALLS = 4  # a multi-part question; more is a planner gone astray
CAN_DO = phrase("en", "can_do")  # every language's wording: ui/language.py
REFUSAL = writer.refusal("en")
_QUOTED = re.compile(r"“[^”]*”")


class ToolRunner:
    """Runs registry tools: data tools on the UI's sources, plant tools on the Sensor through the bus."""

    def __init__(self, sources: ChatSources, plant: Any = None):
        self.sources = sources
        self.context = registry.ToolContext(system=sources.system, data=sources, plant=plant)

    def __call__(self, call: ToolCall) -> registry.ToolResult:
        if call.tool == "whatif_controller" and call.args.get("current") is None:  # the Sensor does not know it
            current = self._controller_now()
            call = ToolCall(call.tool, {**call.args, "current": current}) if current else call
        if call.tool in PLANT_TOOLS and self.context.plant is None:
            return self._remote(call)  # MeshBusy (over a rate limit or the what-if budget) goes up: HTTP 429
        result = registry.invoke(call.tool, call.args, self.context)
        if result.retry_after_s is not None:
            raise RateLimited(f"the {call.tool} tool: {result.error}", result.retry_after_s)
        return result

    def _controller_now(self) -> str | None:
        """The configured controller (else the one of the last applied action), for a controller what-if."""
        try:
            doc = self.sources.config()
            applied = self.sources.applied()
        except Exception:  # no configuration yet: the tool says what is missing
            return None
        if doc is not None:
            return doc.config.controller
        return getattr(applied, "source_controller", None)

    def _remote(self, call: ToolCall) -> registry.ToolResult:
        gateway = self.sources.gateway
        if gateway is None:
            return registry.ToolResult(ok=False, tool=call.tool, error="no bus to reach the live twin", not_ready=True)
        try:
            return registry.ToolResult(ok=True, tool=call.tool, result=gateway.tool(call.tool, call.args))
        except MeshRefused as exc:
            return registry.ToolResult(ok=False, tool=call.tool, error=str(exc))
        except MeshUnavailable as exc:
            return registry.ToolResult(ok=False, tool=call.tool, error=str(exc), not_ready=True)


def guard_data(facts: list[ChatFact]) -> tuple[list[Fact], list[Fact]]:
    """The values and rankings an answer may state, from the facts its tool results produced."""
    values, rankings = [], []
    for f in facts:
        if isinstance(f.value, str) or f.quantity == "number":
            continue
        signed = float(f.value) if f.ref.get("stat") == "change" else None
        for shown in numbers_in(f.display)[:1]:
            values.append(semantic.value_fact(shown, f.entity, f.quantity, signed))
        if f.ref.get("rank") == 1:
            rankings.append(semantic.rank_fact(f.quantity, f.ref["order"], f.entity))
        if f.ref.get("extreme"):
            rankings.append(semantic.rank_fact(f.quantity, f.ref["extreme"], f.entity))
    return values, rankings


def check_answer(text: str, facts: list[ChatFact]) -> list[Claim]:
    """The semantic guard on an answer: quoted text (alerts, explanations) is cited verbatim and skipped."""
    values, rankings = guard_data(facts)
    plain = _QUOTED.sub("“”", text)
    for f in facts:  # a text value (a time, a name, an alert) is cited whole, not read as numbers
        if isinstance(f.value, str) and f.value:
            plain = plain.replace(f.value, "“”")
    problems = semantic.check(plain, values, rankings)
    return problems + [Claim("equals", n, extra={"reason": "no_value"}).fails("ungrounded_number",
                                                                            "no fact holds this number")
                       for n in ungrounded_numbers(text, facts) if not problems]  # fmt: skip


# --- does the plan cover the question? ------------------------------------------------------------------------
TOOL_COVERS: dict[str, frozenset[str]] = {k: frozenset(v) for k, v in {
    "energy_balance": {"pue", "it_power", "heat_rejected", "cdu_heat", "cooling_power", "tower_power", "pump_power",
                       "pumps", "fans"},
    "overview": {"pue", "blade_temp", "in_band", "it_power", "tower_power", "pump_power", "wet_bulb", "controller",
                 "ranking", "pumps", "fans"},
    "band_count": {"in_band", "blade_temp"}, "alerts": {"alerts", "pumps"}, "agents": {"agents"},
    "controller": {"controller", "history", "mode"},
    "decision": {"controller", "history"},  # the setpoint it is about comes from its `action` argument
    "rank": {"ranking"}, "compare": {"ranking", "lowest"},
    "history_stat": {"history"},
    "whatif_setpoint": {"whatif", "blade_temp", "in_band", "tower_power", "pump_power", "cooling_power", "pumps",
                        "fans"},
    "propose_change": {"controller"},
    "energy_used": {"energy", "history", "pump_power", "tower_power", "cooling_power", "it_power", "heat_rejected"},
    "tracking_gap": {"gap", "supply", "supply_temp", "supply_setpoint", "leaving_water", "lw_setpoint", "lw",
                     "where", "ranking", "tower"},
    "peak": {"history", "where", "when", "ranking", "lowest"},
    "weather_effect": {"weather", "wet_bulb", "approach", "leaving_water", "fan_speed", "tower_power", "tower",
                       "history", "fans"},
    "whatif_controller": {"whatif", "controller", "energy", "cooling_power", "blade_temp", "in_band", "pumps", "fans"},
}.items()}  # fmt: skip
# Concepts a tool covers only with some of its arguments, or that every listing of entities covers.
ENERGY_WHAT = {"cooling": {"pumps", "fans"}, "pumps": {"pumps"}, "tower_fans": {"fans"}, "it": set(),
               "heat_rejected": set()}  # fmt: skip
WHERE_TOOLS = {"rank", "compare", "band_count", "overview", "plant_state", "alerts", "decision"}
WHEN_TOOLS = {"decision", "controller", "alerts"}
COUNT_TOOLS = {"band_count", "agents", "alerts", "rank"}
_SETPOINT_CONCEPTS = {"supply": {"supply", "supply_setpoint", "supply_temp"}, "dp": {"dp", "dp_setpoint"},
                      "lw": {"lw", "lw_setpoint", "leaving_water"}}  # fmt: skip


# Things no tool knows: a plan for such a question answers something else, so the question is refused.
OUT_OF_SCOPE = re.compile(
    r"\b(price|prices|(?:cost|costs|cuesta|cuestan|kostet|kosten|co[uû]te?)(?!\s+(?:\w+\s+){0,2}(?:in|en|an)\s+"
    r"(?:fan\s+|pump\s+)?(?:power|energy|kw|potencia|leistung|puissance|[ée]nergie|energ[ií]a|ventil|l[uü]fter))"
    r"|bill|tariff|precio|preis|prix|jobs?|users?"
    r"|trabajos?|usuarios?|benutzer|utilisateurs?|forecast|pron[oó]stico|vorhersage|pr[ée]vision|tomorrow|ma[nñ]ana"
    r"|morgen|demain|next week|joke|chiste|witz|blague|married|are you single|love|weather in|other sites?|password"
    r"|contrase[nñ]a|passwort|mot de passe"
    r"|conductivity|turbidity|viscosity|corrosion|glycol|humidity|leitf[aä]higkeit|conductividad|conductivit[ée]"
    r"|vibrations?|vibraci[oó]n|vibration|schwingung|noise|haiku|poem|poema|gedicht|po[eè]me|from now"
    r"|at the \w+ site)\b",
    re.IGNORECASE)  # fmt: skip
# An order, not a question: only a proposal answers it (chat never acts; the operator confirms).
COMMAND = re.compile(
    r"(^|\b(and|und|y|et|then|dann|luego|puis)\s+|^(please|bitte|por favor|s'il (te|vous) pla[iî]t)\s+)"
    r"(set|switch|change|raise|lower|increase|decrease|put(?!\s.*\b(next to|beside|side by side|against)\b)|turn"
    r"|apply|pon|pone|cambia|sube|baja|pasa|establece"
    r"|ajusta|setze|setz|stelle|stell|schalte|schalt|erh[oö]he|senke|wechsle|passe|mets|r[eè]gle|augmente|baisse)\b",
    re.IGNORECASE)  # fmt: skip
_UNITS = [(re.compile(p, re.IGNORECASE), unit) for p, unit in (
    (r"\d\s*(°\s*f\b|f\b|fahrenheit)", "degF"), (r"\d\s*bar\b", "bar"), (r"\d\s*kpa\b", "kPa"),
)]  # fmt: skip
_HOURS = re.compile(r"(\d+(?:[.,]\d+)?)\s*(?:(?:last|past|derni[eè]res|[uú]ltimas|letzten)\s+)?"
                    r"(h|hrs?|hours?|horas?|stunden?|heures?)\b", re.IGNORECASE)  # fmt: skip


def _arg_numbers(calls: list[ToolCall], *, time: bool | None = None) -> set[float]:
    """Every number in the plan's arguments, with the request models' defaults filled in; `time` True: only the
    time windows (`minutes`), False: only the others, None: all."""
    out: set[float] = set()

    def walk(value: Any, key: str = "") -> None:
        if isinstance(value, bool):
            return
        if isinstance(value, str) and value.isdigit() and time is not True:  # a decision id "1187"
            out.add(round(float(value), 6))
        if isinstance(value, (int, float)):
            if time is None or time == (key == "minutes"):
                out.add(round(abs(float(value)), 6))
        elif isinstance(value, (list, tuple)):
            for v in value:
                walk(v, key)
        elif isinstance(value, dict):
            for k, v in value.items():
                walk(v, k)

    for call in calls:
        spec = registry.TOOLS.get(call.tool)
        try:
            walk(spec.request_model.model_validate(call.args).model_dump() if spec else call.args)
        except ValueError:
            walk(call.args)
    return out


_LAST_HOUR = re.compile(r"\b(last|past|previous) hour\b|[uú]ltima hora|letzten stunde|derni[eè]re heure", re.IGNORECASE)
_MINUTES = re.compile(r"(\d+(?:\.\d+)?)\s*(min|mins|minutes?|minutos?|minuten?)\b", re.IGNORECASE)


def _question_numbers(question: str) -> list[tuple[str, set[float], bool | None]]:
    """Numbers the question states (not entity numbers), each with the values a plan may carry for it and whether
    it is a time window (True: it must be a `minutes` argument; None: any argument)."""
    entity_spans = [m.span() for m in semantic.ENTITY.finditer(question)]
    hours = {m.start(1): float(m.group(1).replace(",", ".")) * 60.0 for m in _HOURS.finditer(question)}
    minutes = {m.start(1) for m in _MINUTES.finditer(question)}
    out = []  # "0,5 psi": a decimal comma (not "1,000", a thousands separator)
    for m in re.finditer(r"(?<![\w.:,])\d+(?:\.\d+|,\d{1,2}(?!\d))?(?!\s*(?:am|pm|a\.m\.|p\.m\.)\b|:\d)", question):
        if any(a <= m.start() < b for a, b in entity_spans):
            continue
        value = float(m.group(0).replace(",", "."))
        ok = {round(value, 6)} | ({round(hours[m.start()], 6)} if m.start() in hours else set())
        out.append((m.group(0), ok, True if m.start() in minutes or m.start() in hours else None))
    if _LAST_HOUR.search(question):  # "the last hour" is 60 minutes, said without a digit
        out.append(("the last hour", {60.0}, True))
    return out


def _covered(calls: list[ToolCall]) -> tuple[set[str], set[str]]:
    """(concepts, entities) a plan's calls address."""
    concepts, entities = set(), set()
    for call in calls:
        args = call.args
        concepts |= TOOL_COVERS.get(call.tool, frozenset())
        if args.get("quantity"):
            concepts.add(args["quantity"])
            concepts |= {"supply"} if args["quantity"].startswith("htw_supply") else set()
        if call.tool == "history_stat" and args.get("stat") in ("min", "max"):
            concepts |= {"ranking", "lowest"} if args["stat"] == "min" else {"ranking"}
        if args.get("setpoint"):
            concepts |= _SETPOINT_CONCEPTS.get(args["setpoint"], set())
        if args.get("action"):
            concepts |= _SETPOINT_CONCEPTS.get(args["action"], {args["action"]})
        if args.get("order") == "lowest":
            concepts.add("lowest")
        if args.get("mode"):
            concepts.add("mode")
        if call.tool == "energy_used":
            concepts |= ENERGY_WHAT.get(call.args.get("what", "cooling"), set())
        if call.tool in WHERE_TOOLS:
            concepts.add("where")
        if call.tool in WHEN_TOOLS:
            concepts.add("when")
        if call.tool in COUNT_TOOLS:
            concepts.add("count")
        if call.tool == "rank" and args.get("level") == "branch" or call.tool in ("band_count", "peak"):
            concepts.add("branch_level")
        for key in ("cabinet", "tower", "branch"):
            if args.get(key) is not None:
                entities.add(f"{key} {args[key]}")
        for key in ("cabinets", "towers"):
            entities |= {f"{key[:-1]} {n}" for n in args.get(key) or ()}
    return concepts, entities


def uncovered(question: str, calls: list[ToolCall], facts: list[ChatFact] = ()) -> list[str]:
    """What the question names that the plan does not address: entities ("cabinet 3") and concepts ("pue").

    With the answer's `facts`, an entity is addressed too when a fact gives its own value (a listing of every
    cabinet answers "cabinet 2's supply")."""
    concepts, entities = _covered(calls)
    for f in facts:
        if f.entity and f.entity != "plant" and f.quantity not in (None, "number"):
            entities.add(f.entity)
    missing = []
    for m in semantic.ENTITY.finditer(question):
        name = semantic.canonical_entity(*m.groups())
        parts = name.split(" of ")
        if not any(p in entities for p in parts) and not (len(parts) == 2 and parts[1] in entities):
            missing.append(name)
    for pattern, wanted in QUESTION_CONCEPTS:
        if pattern.search(question) and not wanted & concepts:
            missing.append(sorted(wanted)[0])
    if SETPOINT_WORD.search(question):  # a setpoint, and with "measured" both: values of the setpoints themselves
        setpoints = {"supply_setpoint", "dp_setpoint", "lw_setpoint"} & concepts
        acts = {"decision", "propose_change", "whatif_setpoint", "tracking_gap", "controller"} & {c.tool for c in calls}
        if not setpoints and not acts:
            missing.append("setpoint")
        elif MEASURED_WORD.search(question) and not acts and not concepts & {"supply_temp", "dp", "leaving_water"}:
            missing.append("measured")
    stats = {c.args.get("stat", "mean") for c in calls if c.tool == "history_stat"}
    if stats:  # the aggregate asked over a window must be the one computed
        missing += [word for word, pattern in ASKED_STATS.items() if pattern.search(question) and word not in stats
                    and not ({"max", "min"} & {word} and any(c.tool == "peak" for c in calls))]  # fmt: skip
    if TRACKING_ERROR.search(question) and not any(c.tool == "tracking_gap" for c in calls):
        missing.append("gap")
    changes = [c.args["change"] for c in calls if c.tool in ("whatif_setpoint", "propose_change")
               and isinstance(c.args.get("change"), (int, float))]  # fmt: skip
    down, up = DOWN_ASKED.search(question), UP_ASKED.search(question)
    if changes and down and not up and any(x > 0 for x in changes) or changes and up and not down and any(
            x < 0 for x in changes):  # fmt: skip
        missing.append("the direction asked")
    orders = {c.args.get("order", "highest") for c in calls if c.tool == "rank"}
    if orders == {"lowest"} and HIGH_WORD.search(question) and not LOW_WORD.search(question):
        missing.append("highest")
    for first, second, wanted in PAIRED_CONCEPTS:
        if first.search(question) and second.search(question) and not wanted & concepts:
            missing.append(sorted(wanted)[0])
    if calls and OUT_OF_SCOPE.search(question):
        missing.append(f"“{OUT_OF_SCOPE.search(question).group(0)}” (no tool knows it)")
    if COMMAND.search(question) and not any(c.tool == "propose_change" for c in calls):
        missing.append("the change asked for")
    numbers, windows = _arg_numbers(calls), _arg_numbers(calls, time=True)
    missing += [text for text, ok, is_time in _question_numbers(question)
                if not ok & (windows if is_time and windows else numbers)]  # fmt: skip
    units = {c.args.get("unit") for c in calls}
    missing += [unit for pattern, unit in _UNITS if pattern.search(question) and unit not in units]
    return missing


def reading_of(calls: list[ToolCall], message: str) -> Query | None:
    """The Query of a plan written as calls (an endpoint's, the rules'), or None when a call is to a tool the
    assistant's specs do not hold (a physics tool an endpoint may know) or does not validate."""
    try:
        return query_of(calls, message)
    except (KeyError, ValueError):
        return None


SESSION_S = 900.0  # a chat session's previous question is forgotten after this long without a question
MAX_SESSIONS = 512  # the oldest session is dropped beyond this many


class Sessions:
    """The previous Query of each chat session: bounded (least recently asked dropped first) and expiring."""

    def __init__(self, ttl_s: float = SESSION_S, max_sessions: int = MAX_SESSIONS, clock: Any = time.monotonic):
        self.ttl_s, self.max_sessions, self.clock = ttl_s, max_sessions, clock
        self._items: OrderedDict[str, tuple[float, Query]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, session: str) -> Query | None:
        with self._lock:
            item = self._items.get(session)
            if item is None:
                return None
            if self.clock() - item[0] > self.ttl_s:
                del self._items[session]
                return None
            return item[1]

    def put(self, session: str, query: Query) -> None:
        with self._lock:
            self._items.pop(session, None)
            self._items[session] = (self.clock(), query)
            while len(self._items) > self.max_sessions:
                self._items.popitem(last=False)

    def __len__(self) -> int:
        return len(self._items)


class ChatEngine:
    """Answers operator questions through tools; counts plans, fallbacks, refusals, guard failures, latency."""

    def __init__(self, sources: ChatSources, phraser: Phraser | None = None, planner: Any = None,
                 runner: ToolRunner | None = None, session_s: float = SESSION_S,
                 clock: Any = time.monotonic, check: str = "words"):  # fmt: skip
        """``check``: "words" (the default, chosen on the dev parts: BENCHMARKS.md, issue 34): every plan is also
        checked against the question's words and may be replaced by the rules' (``uncovered``, ``second_opinion``);
        "query": a plan the local model read is checked against its Query's fields only (``check.unanswered``),
        with no second reading of the question. Plans of the rules and of an endpoint get the word check either
        way."""
        if check not in ("query", "words"):
            raise ValueError(f"`check` must be 'query' or 'words', got {check!r}")
        self.check = check
        self.sources = sources
        self.phraser = phraser or TemplatePhraser()
        self.planner = planner or RuleReader()
        self.runner = runner or ToolRunner(sources)
        self.intents: Counter = Counter()  # tool calls by name ("refuse" for none)
        self.planned_by: Counter = Counter()
        self.ungrounded = 0  # drafts the guard refused: a writer bug
        self.rejected_phrasings = 0
        self.uncovered = 0  # answers whose plan missed something the question names (sent, not grounded)
        self.second_opinions = 0  # model plans replaced by the rules' because the rules covered more
        self._rules = RulePlanner()
        self.not_ready = 0
        self.latency_s: list[float] = []
        self.sessions = Sessions(session_s, clock=clock)

    def ask(self, message: str, session: str | None = None) -> dict[str, Any]:
        """The answer to `message`; NotReady (HTTP 503) when the data it needs is not there yet.

        With a `session`, a follow-up ("and cabinet 2?", "why?") reads the session's previous question's Query.
        """
        t0 = time.perf_counter()
        previous = self.sessions.get(session) if session else None
        plan = self.read(message, previous)
        read_once = self.check == "query" and plan.by == "llm"
        if not (plan.query is not None and plan.query.follow_up) and not read_once:
            plan = self.second_opinion(message, plan)
            if plan.query is None:  # the rules' plan stood in: its reading
                plan.query = reading_of(plan.calls, message)
        reply = self.answer(message, plan)
        if session and plan.query is not None and plan.query.asks:
            self.sessions.put(session, plan.query)
        elapsed = time.perf_counter() - t0
        self.latency_s.append(elapsed)
        del self.latency_s[:-1000]
        return {**reply, "elapsed_ms": round(elapsed * 1e3, 2), "session": session}

    def read(self, message: str, previous: Query | None) -> Plan:
        """The planner's reading of `message` (a follow-up of `previous` where the planner reads Queries), its Query
        filled in from its calls where the planner wrote calls only."""
        if isinstance(self.planner, (LlmReader, RuleReader)):
            plan = self.planner.plan(message, previous)
        else:
            plan = self.planner.plan(message)
        if plan.query is None:
            plan.query = reading_of(plan.calls, message)
        return plan

    def second_opinion(self, message: str, plan: Plan) -> Plan:
        """The rules' plan instead of a model's that leaves out something the question names and the rules cover.

        A counted fallback (``planned_by`` "rules", the note says what the model's plan missed); the model's
        plan stands whenever the rules cover no more.
        """
        if plan.calls and OUT_OF_SCOPE.search(message):
            self.second_opinions += 1
            return Plan([], plan.by, f"“{OUT_OF_SCOPE.search(message).group(0)}” is nothing the tools know")
        if plan.by == "rules" or isinstance(self.planner, (RulePlanner, RuleReader)):
            return plan
        if not plan.calls:  # the model found nothing to call: the rules' plan, if they have one, is worth a try
            alternative = self._rules.plan(message)
            if alternative.calls and not uncovered(message, alternative.calls):
                self.second_opinions += 1
                return Plan(alternative.calls, "rules", f"the {plan.by} plan was empty")
            return plan
        missing = uncovered(message, plan.calls)
        if not missing:
            return plan
        alternative = self._rules.plan(message)
        if alternative.calls and len(uncovered(message, alternative.calls)) < len(missing):
            self.second_opinions += 1
            return Plan(alternative.calls, "rules", f"the {plan.by} plan left out {', '.join(missing)}")
        return plan

    def answer(self, message: str, plan: Plan) -> dict[str, Any]:
        """Run `plan`'s calls and write, check and phrase the answer (no timing)."""
        self.planned_by[plan.by.split(":")[0]] += 1
        calls = plan.calls[:MAX_CALLS]
        lang = detect_language(message)
        if not calls:
            self.intents["refuse"] += 1
            return self._reply(writer.refusal(lang), [], plan, refused=True, grounded=False, lang=lang)
        book = FactBook()
        parts, proposed, failed, details = [], None, False, []
        for k, call in enumerate(calls):
            self.intents[call.tool] += 1
            result = self.runner(call)
            if result.not_ready:
                self.not_ready += 1
                raise NotReady(result.error or f"the {call.tool} tool has no data yet")
            if not result.ok:
                failed = True
                parts.append(_tool_error(book, call, result.error or "failed", k, lang))
                continue
            try:
                parts.append(writer.write(call.tool, result.result, call.args, book, k, lang))
            except Exception as exc:  # a writer bug must cost one part of one answer, not the request
                log.exception("chat writer for %s failed on %r", call.tool, message)
                self.ungrounded += 1
                failed = True
                parts.append(_tool_error(book, call, f"could not write the {call.tool} result ({type(exc).__name__})",
                                         k, lang))
                continue
            if call.tool == "decision" and result.result.get("reasons"):  # the whole reasoning, one click away
                details.append({"title": result.result.get("what") or "decision", "text": result.result["reasons"]})
            if call.tool == "propose_change":
                proposed = _proposal(result.result) or proposed
            elif call.tool == "whatif_setpoint" and proposed is None:  # the change it tried, ready to confirm
                proposed = self._whatif_proposal(call.args)
        draft = " ".join(parts)
        facts = book.listed()
        problems = check_answer(draft, facts)
        if self.check == "query" and plan.by == "llm" and plan.query is not None:
            missing = unanswered(plan.query, facts, errors=failed)  # the model's reading is the one reading
        else:
            missing = uncovered(message, calls, facts)
        if missing:  # a true answer to another question is not an answer: say so, and offer what was found
            self.uncovered += 1
            plan = Plan(plan.calls, plan.by, "; ".join(x for x in (plan.note, "the plan may not answer what the "
                        f"question names: {', '.join(missing)}") if x), plan.raw)  # fmt: skip
            if problems:
                self.ungrounded += 1
                log.error("chat draft for %r fails the semantic guard: %s", message, problems)
            return self._reply(decline(lang, missing, draft), facts, plan, proposed=proposed, grounded=False,
                               problems=problems, lang=lang, declined=missing, details=details)  # fmt: skip
        if problems:
            self.ungrounded += 1
            log.error("chat draft for %r fails the semantic guard: %s", message, problems)
        phrased = self.phraser.phrase(message, calls[0].tool, draft, facts)
        text, by, note = phrased.text, phrased.by, phrased.note
        if text != draft:
            rephrased_problems = check_answer(text, facts)
            if rephrased_problems:
                self.rejected_phrasings += 1
                text, by, note = draft, "template", f"rephrasing refused: {rephrased_problems[0].flag.detail}"
        return self._reply(text, facts, plan, proposed=proposed, grounded=not (problems or failed),
                           phrased_by=by, note=note, problems=problems, lang=lang, details=details)  # fmt: skip

    def _whatif_proposal(self, args: dict) -> dict | None:
        """The proposed command that would apply a what-if's change (None when it is outside the limits)."""
        keys = ("setpoint", "change", "unit", "cabinet")
        request = {k: args[k] for k in keys if args.get(k) is not None}
        result = self.runner(ToolCall("propose_change", request))
        return _proposal(result.result) if result.ok else None

    def _reply(self, text: str, facts: list[ChatFact], plan: Plan, *, refused: bool = False, grounded: bool,
               proposed: dict | None = None, phrased_by: str = "template", note: str | None = None,
               problems: list | None = None, lang: str = "en", declined: list[str] | None = None,
               details: list[dict] | None = None) -> dict[str, Any]:  # fmt: skip
        return {
            "answer": text,
            "facts": [f.model_dump() for f in facts],
            "intent": plan.calls[0].tool if plan.calls else "refuse",
            "proposed_command": proposed,
            "phrased_by": phrased_by,
            "phrasing_note": note,
            "grounded": grounded,
            "plan": [{"tool": c.tool, "args": c.args} for c in plan.calls],
            "planned_by": plan.by,
            "plan_note": plan.note,
            "refused": refused,
            "declined": bool(declined),  # the question asks for something this answer does not give
            "missing": list(declined or []),
            "problems": [{"kind": p.flag.kind, "span": p.text, "detail": p.flag.detail} for p in problems or []
                         if p.flag is not None],
            "lang": lang,
            "query": plan.query.model_dump(exclude_none=True) if plan.query is not None else None,
            "follow_up": bool(plan.query is not None and plan.query.follow_up),
            "detail": list(details or []),
        }


def decline(lang: str, missing: list[str], draft: str) -> str:
    """The reply when the results do not answer what was asked: what is missing, then what can be given instead."""
    words = ", ".join(MISSING_WORDS.get(m, {}).get(lang, m.replace("_", " ")) for m in missing)
    return phrase(lang, "decline", missing=words) + " " + phrase(lang, "decline.instead", draft=draft)


def _proposal(result: dict) -> dict | None:
    """The command an operator may confirm, from a propose_change result; None if the change breaks a limit."""
    if result.get("problem"):
        return None
    return {key: result[key] for key in ("method", "path", "body", "summary")}


def _tool_error(book: FactBook, call: ToolCall, error: str, index: int, lang: str = "en") -> str:
    """A tool's refusal, quoted: "there is no cabinet 9: this plant has cabinets 1 to 5"."""
    name = f"{call.tool}{index}_error"
    book.add(fact(name, error, "", f"the {call.tool} tool's answer", "tool", quantity="error", tool=call.tool))
    return book.say(phrase(lang, "tool_error", error="{" + name + "}"))
