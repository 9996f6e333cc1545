"""Chat facts: the retrieved numbers an answer may cite, and the check that it cites nothing else.

Every number in a chat answer comes from a ``ChatFact``: a value with its unit, the display
string the answer prints, a short sentence, where it came from (``source``) and a reference
(``ref``) precise enough to look the value up again (a plant state's output block and index at a
step, a history column, an applied action, a toolbox reply, an alert, the question itself).
Answers are written with ``render(template, facts)``: templates hold no digits, placeholders
name facts, so the text can only print fact displays.
"""

from __future__ import annotations

import re
import string
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

Source = Literal["state", "history", "decision", "whatif", "alert", "config", "agents", "question", "system", "tool"]
DECIMALS = {"degC": 1, "K": 1, "kW": 1, "kWh": 1, "W": 0, "psi": 1, "kg/s": 2, "fraction": 2, "%": 1, "min": 0, "h": 1, "s": 0,
            "pue": 3}
SUFFIX = {"degC": " °C", "K": " K", "kW": " kW", "kWh": " kWh", "W": " W", "psi": " psi", "kg/s": " kg/s", "%": " %", "min": " min",
          "h": " h", "s": " s"}  # fmt: skip
NUMBER = re.compile(r"\d+(?:\.\d+)?")


def format_value(value: float | int | str, unit: str = "") -> str:
    """The display of a value: fixed decimals per unit, integers without decimals when unitless."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "yes" if value else "no"
    decimals = DECIMALS.get(unit)
    if decimals is None:
        decimals = 0 if float(value).is_integer() else 2
    text = f"{abs(float(value)):.{decimals}f}"
    if float(text) == 0.0:  # no "-0.0"
        return text + SUFFIX.get(unit, "")
    return ("-" if value < 0 else "") + text + SUFFIX.get(unit, "")


class ChatFact(BaseModel):
    """One grounded value a chat answer may cite."""

    model_config = ConfigDict(extra="forbid")

    name: str
    value: float | int | str
    unit: str = ""
    display: str
    text: str
    source: Source
    ref: dict[str, Any] = {}
    entity: str | None = None  # what the value belongs to ("cabinet 3", "tower 1", "plant"), for the semantic check
    quantity: str | None = None  # which quantity it is (a plant_data.QUANTITIES key or a tool field)


def fact(name: str, value: float | int | str, unit: str, text: str, source: Source, *, entity: str | None = None,
         quantity: str | None = None, **ref: Any) -> ChatFact:
    """A fact whose display follows `unit` (magnitudes print without sign when the text says the direction)."""
    if isinstance(value, float) and unit == "" and value.is_integer():
        value = int(value)
    return ChatFact(name=name, value=value, unit=unit, display=format_value(value, unit), text=text, source=source,
                    ref=ref, entity=entity, quantity=quantity)  # fmt: skip


def magnitude(f: ChatFact) -> ChatFact:
    """The same fact displayed without its sign (for 'up 1.2 K' / 'down 1.2 K')."""
    if isinstance(f.value, str):
        return f
    return f.model_copy(update={"display": format_value(abs(f.value), f.unit)})


class FactBook:
    """Facts of one answer, by name; `say` renders a digit-free template against them."""

    def __init__(self):
        self.facts: dict[str, ChatFact] = {}
        self._shown: dict[str, str] = {}
        self._cited: dict[str, None] = {}  # insertion-ordered set

    def add(self, f: ChatFact, *, unsigned: bool = False) -> ChatFact:
        self.facts[f.name] = f
        self._shown[f.name] = magnitude(f).display if unsigned else f.display
        return f

    def __contains__(self, name: str) -> bool:
        return name in self.facts

    def __getitem__(self, name: str) -> ChatFact:
        return self.facts[name]

    def say(self, template: str) -> str:
        """`template` with ``{name}`` placeholders replaced by fact displays; a digit in the template is a bug."""
        parts = list(string.Formatter().parse(template))
        if NUMBER.search("".join(part[0] for part in parts)):
            raise ValueError(f"chat templates must not contain digits (numbers come from facts): {template!r}")
        text = template.format_map(self._shown)
        for _literal, name, _spec, _conv in parts:
            if name:
                self._cited[name] = None
        return text

    def listed(self) -> list[ChatFact]:
        """The facts the answer cites, in the order it first cites them."""
        return [self.facts[name] for name in self._cited]


def numbers_in(text: str) -> list[str]:
    """Every number written in `text` (digits, optionally with a decimal part; signs are words here)."""
    return NUMBER.findall(text)


def grounded_numbers(facts: list[ChatFact]) -> set[str]:
    """Number strings an answer may contain: those in the facts' displays and string values."""
    allowed: set[str] = set()
    for f in facts:
        allowed.update(numbers_in(f.display))
        if isinstance(f.value, str):
            allowed.update(numbers_in(f.value))
    return allowed


def ungrounded_numbers(answer: str, facts: list[ChatFact]) -> list[str]:
    """Numbers in `answer` that no fact carries (empty when the answer is grounded)."""
    allowed = grounded_numbers(facts)
    return [n for n in numbers_in(answer) if n not in allowed]
