"""Check: does the answer give what the reading asked? The answer's facts against the Query's fields.

Every call follows from an ask through its spec, so what can still go wrong is what the tools returned:
an entity asked for that no fact is about (the tool answered for the plant, or for other cabinets).
``unanswered`` lists those; the engine then declines with what it found, as it does for the word check of a
rules plan (``engine.uncovered``). A window of history shorter than the one asked is said by the writer.
"""

from __future__ import annotations

from lcmesh.assistant.facts import ChatFact
from lcmesh.assistant.query import Query


def _names(ask) -> list[str]:
    cabinets, branches, towers = ask.cabinets or [], ask.branches or [], ask.towers or []
    if branches and len(cabinets) == 1:
        return [f"branch {b} of cabinet {cabinets[0]}" for b in branches]
    return [f"cabinet {c}" for c in cabinets] + [f"tower {t}" for t in towers]


def unanswered(query: Query | None, facts: list[ChatFact], errors: bool = False) -> list[str]:
    """What the reading asks that the facts do not give ([] when the answer covers it, or a tool said why not)."""
    if query is None or errors:
        return []
    about = {f.entity for f in facts if f.entity}
    about |= {e.split(" of ", 1)[1] for e in about if " of " in e}  # a branch's facts are its cabinet's too
    missing = []
    for ask in query.asks:
        if ask.ask in ("command", "whatif", "why"):  # the proposal, the look-ahead, the decision name what they did
            continue
        for name in _names(ask):
            if name not in about and name.split(" of ")[-1] not in about:
                missing.append(name)
    return missing
