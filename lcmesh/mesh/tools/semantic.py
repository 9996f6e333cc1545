"""The chat's semantic check: every number bound to the right entity and quantity, rankings and directions right.

A text passes only if each number it states is a value the data holds *for the entity and the
quantity the sentence attaches it to*, each "hottest / lowest / highest" names the entity the data
ranks so, and each "raised / fell / opened" agrees with the sign of the change it describes. The
data is a list of ``claims.Fact`` values (as shown, with entity and quantity) and ranking facts (``order``);
the chat passes its tool results' facts, and the explanation judge can pass a decision's facts.

The words (entities, quantities, directions and superlatives in English, Spanish, German and French) and
the binding of a number to its entity and quantity are ``vocab.py``'s, which the explanation judge reads
too. Reading is deliberately local: a number belongs to the nearest entity named before it in the same
clause (or right after it: "36.4 °C in cabinet 3"), and to the nearest quantity word before it in the
same sentence. Clauses end at ".", ";" and ","; sentences at "." and ";".
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from lcmesh.mesh.tools.claims import Claim, Fact

from lcmesh.mesh.tools.vocab import (
    DOWN_WORDS,
    ENTITY,
    FROM_TO,
    HIGHEST,
    LOWEST,
    UP_WORDS,
    canonical_entity,
    entity_of,
    quantity_before,
)

NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?![\w.]*\d)")
_HIGH = re.compile("|".join(HIGHEST), re.IGNORECASE)
_SUPERLATIVE = re.compile(r"\b(" + "|".join(HIGHEST + LOWEST) + r")\b", re.IGNORECASE)
_DIRECTION = re.compile(r"\b(" + "|".join(UP_WORDS + DOWN_WORDS) + r")\b", re.IGNORECASE)
_UP = re.compile("|".join(UP_WORDS), re.IGNORECASE)


def value_fact(shown: str, entity: str | None = None, quantity: str | None = None, signed: float | None = None) -> Fact:
    """A value the data holds, as a text may write it ("36.4"); entity None: tied to no entity; ``signed``: for a
    change, its signed value, to check the direction words against."""
    return Fact(f"{entity or 'plant'} {quantity or 'value'}", quantity=quantity, entity=entity, shown=shown,
                signed=signed)


def rank_fact(quantity: str | None, order: str, entity: str) -> Fact:
    """The data's first entity for ``order`` ("highest" / "lowest") of a quantity."""
    return Fact(f"{order} {quantity or 'value'}", quantity=quantity, entity=entity, order=order)


def _fails(kind: str, span: str, detail: str, reason: str = "", relation: str = "equals") -> Claim:
    claim = Claim(relation, span, extra={"reason": reason} if reason else {})  # type: ignore[arg-type]
    return claim.fails(kind, detail)


@dataclass
class _Clause:
    text: str
    start: int
    entities: list[tuple[int, int, str]] = field(default_factory=list)  # (start, end, canonical name)


def _clauses(text: str) -> list[_Clause]:
    out, start = [], 0
    for match in re.finditer(r"[;,]|\.(?!\d)|$", text):
        piece = text[start:match.start()]
        clause = _Clause(piece, start)
        for m in ENTITY.finditer(piece):
            clause.entities.append((m.start(), m.end(), canonical_entity(*m.groups())))
        out.append(clause)
        start = match.end()
    return out


def _entity_for(clause: _Clause, offset: int, end: int) -> str | None:
    return entity_of(clause.text, clause.entities, offset, end)


def _is_entity_number(clause: _Clause, offset: int) -> bool:
    return any(s <= offset < e for s, e, _ in clause.entities)


def _same_entity(claimed: str, bound: str | None) -> bool:
    if bound is None or bound == "plant":
        return False
    return bound == claimed or bound.endswith(f"of {claimed}") or claimed.endswith(f"of {bound}")


def check_numbers(text: str, values: Sequence[Fact]) -> list[Claim]:
    """Each number stated must be a bound value of the entity and quantity the sentence attaches it to."""
    problems = []
    by_shown: dict[str, list[Fact]] = {}
    for v in values:
        by_shown.setdefault(_plain(v.shown), []).append(v)
    for clause in _clauses(text):
        for m in NUMBER.finditer(clause.text):
            if _is_entity_number(clause, m.start()):
                continue
            shown = _plain(m.group(0))
            candidates = by_shown.get(shown, [])
            span = clause.text.strip()
            if not candidates:
                problems.append(_fails("ungrounded_number", span, f"{m.group(0)} is not a value the data holds",
                                       "no_value"))
                continue
            entity = _entity_for(clause, m.start(), m.end())
            if entity is not None and not any(_same_entity(entity, c.entity) or c.entity is None for c in candidates):
                holders = sorted({c.entity or "the plant" for c in candidates})
                problems.append(_fails("ungrounded_number", span, f"{m.group(0)} belongs to {', '.join(holders)}, "
                                       f"not {entity}", "wrong_entity"))  # fmt: skip
                continue
            quantity = quantity_before(text, clause.start + m.start())
            if quantity and not any(c.quantity is None or c.quantity in quantity or c.quantity == "number"
                                    for c in candidates):  # fmt: skip
                held = sorted({c.quantity for c in candidates if c.quantity})
                problems.append(_fails("ungrounded_number", span, f"{m.group(0)} is the data's {', '.join(held)}, "
                                       f"not {quantity[0]}", "wrong_quantity"))  # fmt: skip
    return problems


def _plain(number: str) -> str:
    return number.lstrip("+").removeprefix("-") if number not in ("-0", "+0") else "0"


def check_rankings(text: str, rankings: Iterable[Fact]) -> list[Claim]:
    """Every superlative next to an entity must name the entity the data ranks first that way."""
    firsts = {(r.order, r.entity) for r in rankings if r.order}
    opposite = {"highest": "lowest", "lowest": "highest"}
    problems = []
    for clause in _clauses(text):
        for m in _SUPERLATIVE.finditer(clause.text):
            order = "highest" if _HIGH.fullmatch(m.group(1)) else "lowest"
            if not clause.entities:
                continue
            entity = min(clause.entities, key=lambda e: abs(e[0] - m.start()))[2]
            names = {entity, entity.split(" of ")[-1]}
            known = sorted(e for o, e in firsts if o == order)
            wrong = (known and not names & set(known)) or any((opposite[order], n) in firsts for n in names)
            if wrong:
                truth = f"the data's {order} is {', '.join(known)}" if known else \
                    f"the data ranks {entity} {opposite[order]}"
                problems.append(_fails("wrong_ranking", clause.text.strip(), f"{truth}, not {entity} {order}",
                                       relation="rank"))
    return problems


def check_directions(text: str, values: Sequence[Fact]) -> list[Claim]:
    """'from A to B' must go the way its verb says; 'up N' / 'down N' must match the change's sign."""
    problems = []
    signed = {_plain(v.shown): v.signed for v in values if v.signed is not None}
    for clause in _clauses(text):
        verbs = [m.group(1).lower() for m in _DIRECTION.finditer(clause.text)]
        if not verbs:
            continue
        up = bool(_UP.fullmatch(verbs[-1]))
        pair = FROM_TO.search(clause.text)
        if pair:
            a, b = float(pair.group(1)), float(pair.group(2))
            if a != b and (b > a) != up:
                problems.append(_fails("wrong_direction", clause.text.strip(),
                                       f"'{verbs[-1]}' but {pair.group(1)} -> {pair.group(2)}", relation="change"))
            continue
        for m in NUMBER.finditer(clause.text):
            value = signed.get(_plain(m.group(0)))
            if value is not None and value != 0 and (value > 0) != up:
                problems.append(_fails("wrong_direction", clause.text.strip(),
                                       f"'{verbs[-1]}' but the change is {value:+g}", relation="change"))
    return problems


def check(text: str, values: Sequence[Fact], rankings: Iterable[Fact] = ()) -> list[Claim]:
    """The claims of `text` that fail against the data (numbers, entities, quantities, rankings, directions), each with
    its flag (``claims.FLAG_KINDS``: ``ungrounded_number``, ``wrong_ranking``, ``wrong_direction``); a number given for
    the wrong entity or quantity is an ungrounded number whose ``extra["reason"]`` says which."""
    rankings = list(rankings)
    return check_numbers(text, values) + check_rankings(text, rankings) + check_directions(text, values)
