"""Understand: an operator question becomes one typed ``Query``, once; its tool calls follow through the specs.

- ``LlmReader``: the local model with the reader adapter (``lcmesh/artifacts/llm-planner``, trained by
  ``lcmesh distill planner`` on many authors' (question, Query) pairs) writes the Query as JSON under its JSON
  schema (llama.cpp's grammar), prompted with ``lcmesh/prompts/chat_query.md``. A reading that is not a valid
  Query, whose asks do not make valid calls, or that comes late falls back to the rules, said and counted.
- ``RuleReader``: the regular-expression rules (``plan.RulePlanner``) read back into a Query through the specs,
  and a follow-up ("and cabinet 2?", "why?") read by a few patterns in the four languages.

Both return a ``plan.Plan`` whose ``query`` is the reading (follow-ups resolved against the previous turn's
Query) and whose ``calls`` are ``tools.call_for`` of its asks.
"""

from __future__ import annotations

import re
import threading
from string import Template

from pydantic import ValidationError

from lcmesh.assistant.language import detect_language
from lcmesh.assistant.plan import LlmPlanner, Plan, PlanError, RulePlanner, ToolCall
from lcmesh.assistant.query import Ask, Query, parse_query, query_schema, resolve_follow_up
from lcmesh.assistant.tools import PLANNER_TOOLS, ask_for, call_for
from lcmesh.llm.io_format import load_template

MAX_NEW_TOKENS = 120  # a two-ask reading with entities and a window takes about 70


def calls_of(query: Query) -> list[ToolCall]:
    """The tool calls a (resolved) Query asks for, each validated (PlanError names the ask and the field)."""
    calls = []
    for i, ask in enumerate(query.asks):
        try:
            tool, args = call_for(ask)
            PLANNER_TOOLS[tool].model_validate(args)
        except (ValueError, ValidationError) as exc:
            raise PlanError("args", f"ask {i + 1}: {str(exc).splitlines()[0][:160]}") from None
        calls.append(ToolCall(tool, args))
    return calls


def query_of(calls: list[ToolCall], question: str) -> Query:
    """The Query a list of calls answers (the rules' and an endpoint's plans, read back through the specs)."""
    return Query(asks=[ask_for(c.tool, c.args) for c in calls], lang=detect_language(question))


def read_messages(question: str) -> list[dict[str, str]]:
    system, user = load_template("chat_query")
    return [{"role": "system", "content": system},
            {"role": "user", "content": Template(user).safe_substitute(question=" ".join(question.split()))}]


# --- the rules ---------------------------------------------------------------------------------------------
_LEAD = r"(?:and|what about|how about|same for|y|y el|y la|y en|¿y|und|und f[üu]r|et|et pour|e)"
_FOLLOW_ENTITY = re.compile(rf"^\s*(?:{_LEAD})\b[\s,]*(?:(?:the|el|la|der|die|das|le)\s+|l')?"
                            r"(?P<kind>cabinet|cab|cdu|rack|gabinete|armario|schrank|armoire|tower|ct|torre|turm|tour)"
                            r"\s*#?\s*(?P<n>\d{1,3})\s*[?!.]*\s*$", re.IGNORECASE)  # fmt: skip
_FOLLOW_WHY = re.compile(r"^\s*(?:and\s+)?(?:why|how come|¿?\s*por\s*qu[eé]|warum|wieso|pourquoi)\s*[?¿!.]*\s*$",
                         re.IGNORECASE)  # fmt: skip
_TOWER_WORDS = ("tower", "ct", "torre", "turm", "tour")


def rules_follow_up(question: str) -> Query | None:
    """A follow-up the patterns read ("and cabinet 2?", "y la torre 1?", "why?"), or None."""
    lang = detect_language(question)
    if _FOLLOW_WHY.match(question):
        return Query(asks=[Ask(ask="why")], lang=lang, follow_up=True)
    m = _FOLLOW_ENTITY.match(question)
    if m:
        n = int(m["n"])
        if n < 1:
            return None
        which = "towers" if m["kind"].lower() in _TOWER_WORDS else "cabinets"
        return Query(asks=[Ask.model_validate({which: [n]})], lang=lang, follow_up=True)
    return None


class RuleReader:
    """The rules' reading: the regex planner's calls read back into a Query, and follow-ups by pattern."""

    by = "rules"

    def __init__(self):
        self._rules = RulePlanner()

    def plan(self, question: str, previous: Query | None = None) -> Plan:
        follow = rules_follow_up(question) if previous is not None else None
        if follow is not None:
            query = resolve_follow_up(follow, previous)
            try:
                return Plan(calls_of(query), by=self.by, query=query)
            except PlanError:
                pass  # the previous question's kind does not take this entity: read the question alone
        calls = self._rules.plan(question).calls
        return Plan(calls, by=self.by, query=query_of(calls, question))


# --- the local model ---------------------------------------------------------------------------------------
class LlmReader(LlmPlanner):
    """The local model reads the question into a Query; the rules' reading when it cannot (said and counted)."""

    stop = ()

    def __init__(self, **kwargs):
        kwargs.setdefault("max_new_tokens", MAX_NEW_TOKENS)
        kwargs.setdefault("fallback", RuleReader())
        super().__init__(**kwargs)
        self._turn = threading.local()

    def messages(self, question: str) -> list[dict[str, str]]:
        return read_messages(question)

    def schema(self) -> dict:
        return query_schema()

    def parse(self, text: str, repaired: list[str], question: str) -> Plan:
        try:
            query = parse_query(text)
        except ValidationError as exc:
            first = exc.errors()[0]
            raise PlanError("schema", f"{'.'.join(map(str, first['loc']))}: {first['msg']}") from None
        except ValueError as exc:
            raise PlanError("not_json", str(exc)) from None
        previous = getattr(self._turn, "previous", None)
        if query.follow_up and previous is None:
            query = query.model_copy(update={"follow_up": False})  # nothing to continue: read it as it stands
            if any(a.ask is None for a in query.asks):
                raise PlanError("follow_up", "a follow-up with no previous question in this session")
        resolved = resolve_follow_up(query, previous)
        return Plan(calls_of(resolved), by="llm", query=resolved)

    def plan(self, question: str, previous: Query | None = None) -> Plan:  # type: ignore[override]
        self._turn.previous = previous
        try:
            return super().plan(question)
        finally:
            self._turn.previous = None

    def _fallback_plan(self, question: str) -> Plan:
        return self.fallback.plan(question, getattr(self._turn, "previous", None))


def reads_queries(adapter) -> bool:
    """Whether an adapter folder was trained to write Queries (its manifest's ``output``), not tool-call lists."""
    import json
    from pathlib import Path

    manifest = Path(adapter) / "manifest.json"
    try:
        return json.loads(manifest.read_text()).get("output") == "query"
    except (OSError, ValueError):
        return False


__all__ = ["LlmReader", "RuleReader", "calls_of", "query_of", "read_messages", "reads_queries"]
