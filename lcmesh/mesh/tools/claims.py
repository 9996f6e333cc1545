r"""What a text says and what the data holds: one claim type, one fact type and one set of flag names.

Every check of a text against data reads the text into :class:`Claim`\\ s once and verifies each against
:class:`Fact`\\ s: the explanation judge (``explain_eval``: a decision's observation, action and facts), the
chat's answer guard (``semantic.py``: the facts its tool results produced) and the LLM explainer's own check
(``lcmesh/llm/explainer.py``: the what-if facts it was given). A claim that fails carries a :class:`Flag`
whose kind is one of :data:`FLAG_KINDS`, the same names everywhere.

A claim's ``relation`` says what it asserts:

- ``equals``: a number is a value of the data (its entity and quantity, at the precision it was written with);
- ``change``: a setting went up, down or was held (``sign`` +1 / -1 / 0);
- ``rank``: an entity is the highest or lowest of a quantity, or above or below another;
- ``cause``: moving a setting moves an effect (blade temperature, fan or pump power, energy) one way;
- ``bound``: a value given for a setting lies within the plant's limits;
- ``covers``: an action dimension is explained (its absence is the claim that fails).

Entities are written as a person reads them, counted from 1 ("branch 2", "cabinet 3", "tower 1").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Literal, NamedTuple

FLAG_KINDS = ("ungrounded_number", "missing_action_dimension", "wrong_direction", "wrong_ranking", "out_of_bounds",
              "physics", "missing_section", "invalid_record", "not_read")  # fmt: skip
"""Every flag a check raises. ``not_read``: the text is in a language or shape no reader covers, so nothing in
it was checked (never passed or flagged silently)."""

FlagKind = Literal["ungrounded_number", "missing_action_dimension", "wrong_direction", "wrong_ranking",
                   "out_of_bounds", "physics", "missing_section", "invalid_record", "not_read"]  # fmt: skip
Relation = Literal["equals", "change", "rank", "cause", "bound", "covers"]
Verdict = Literal["holds", "fails", "unchecked"]


class Flag(NamedTuple):
    """A failed claim (or a missing one: a dimension, a section) as a report shows it."""

    kind: str
    detail: str


@dataclass
class Fact:
    """A value the data holds, in SI for the judge (K, W, kg/s, Pa, fraction) or as displayed for the chat.

    ``entity`` is the person's name of what it belongs to ("branch 2", "cabinet 3", "plant"; None: nothing in
    particular); ``branch`` is the judge's 0-based position of that branch in the record's lists. ``shown`` is how a
    text may write it ("36.4"); ``signed`` the signed value of a change; ``order`` marks the entity the data ranks
    first as "highest" or "lowest" of ``quantity``; ``topic`` the setting or reading a text may name it by
    (``supply_setpoint``, ``lw_setpoint``, ``wet_bulb``); ``alias`` the branch whose value this fact repeats (the
    hottest branch's temperature)."""

    name: str
    value: float | None = None
    quantity: str | None = None
    unit: str = ""
    entity: str | None = None
    branch: int | None = None
    shown: str = ""
    signed: float | None = None
    order: str | None = None
    topic: str | None = None
    alias: int | None = None


@dataclass
class Claim:
    """One thing a text says, where it says it, and the verdict of checking it.

    ``readings`` are the number's interpretations in SI: (quantity, value, tolerance from its stated precision).
    ``fact`` names what the claim was checked against; ``flag`` is set when it fails."""

    relation: Relation
    text: str
    start: int = -1
    end: int = -1
    entity: str | None = None
    quantity: str | None = None
    value: float | None = None
    unit: str = ""
    sign: int | None = None
    readings: tuple[tuple[str, float, float], ...] = ()
    verdict: Verdict = "unchecked"
    fact: str = ""
    flag: Flag | None = None
    extra: dict = field(default_factory=dict)

    def holds(self, fact: str = "") -> Claim:
        self.verdict, self.fact = "holds", fact or self.fact
        return self

    def fails(self, kind: str, detail: str, fact: str = "") -> Claim:
        """Mark the claim failed with its flag."""
        self.verdict, self.fact, self.flag = "fails", fact or self.fact, Flag(kind, detail)
        return self

    def as_dict(self) -> dict:
        """The claim as the report shows it (JSON)."""
        out = {k: v for k, v in asdict(self).items() if k not in ("readings", "extra", "start", "end")}
        out["flag"] = self.flag.kind if self.flag else None
        out["detail"] = self.flag.detail if self.flag else ""
        return {k: v for k, v in out.items() if v not in (None, "")} | {"verdict": self.verdict}


def failed(claims: list[Claim]) -> list[Claim]:
    """The claims that fail, in text order."""
    return [c for c in claims if c.verdict == "fails"]


def states(claims: list[Claim], quantity: str, value: float, min_tol: float = 0.0) -> bool:
    """True when one of ``claims`` (numbers with a unit) reads as ``value`` of ``quantity`` (SI) within its stated
    precision or ``min_tol``, the larger."""
    return any(c.unit and any(q == quantity and abs(v - value) <= max(min_tol, tol) for q, v, tol in c.readings)
               for c in claims)  # fmt: skip
