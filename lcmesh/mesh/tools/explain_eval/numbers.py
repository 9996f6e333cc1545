"""Numbers in explanation text: value, unit, and whether the number is a measurement at all.

Each number found gets a *role*: ``measure`` (checked against the data), ``index`` ("branch 2",
"B1", "3rd", "cabinet 3"), ``count`` ("3 branches", "2 of 3 branches"), ``time`` (durations,
clock times, dates), ``year`` (1900-2100 with no unit) or ``tolerance`` ("±0.5 K"); only
measurements are scored. A unit-less number in a range takes the unit of its partner
("20-40 °C", "between 20 and 40 °C").

Measurements are turned into *interpretations*: (quantity, canonical value, tolerance) pairs in SI
(K, W, kg/s, Pa, fraction); a temperature in deg C or deg F is read both as an absolute temperature
and as a difference, a percentage both as a fraction and as a percent figure, a bare number as any
of the data's display units (deg C, kW, psi, fractions ...), so "0.42" and "42 %" both match a
valve fraction of 0.42 and "36.4 °C" matches 309.55 K.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field

from lcmesh.mesh.tools import vocab
from lcmesh.mesh.tools.claims import Claim

K0 = 273.15
PSI_TO_PA = 6894.757

_NUM = re.compile(
    r"(?P<sign>[-−–+])?(?P<num>\d{1,3}(?:,\d{3})+(?:\.\d+)?(?![\d,])|\d+(?:\.\d+)?|\.\d+)(?P<exp>[eE][-+]?\d+)?"
)
_DATE = re.compile(r"\b\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2})?Z?)?\b")
_PERCENT_LIST_AFTER = re.compile(r"(?:\s*/\s*\d+(?:[.,]\d+)?)+\s*%")
_CLOCK = re.compile(r"\b\d{1,2}:\d{2}(?::\d{2})?\b")
# words an index follows ("branch 2", "rama 2", "Schrank 3", "step 4"): the plant's entities in the four languages
# (vocab.py), and English document words
_ENTITY_NOUNS = vocab.alternation(*(w for by_lang in vocab.ENTITY_WORDS.values() for lang in vocab.LANGUAGES
                                    for w in by_lang[lang]),
                                  *(w for lang in vocab.LANGUAGES for w in vocab.BRANCH_WORDS[lang]))  # fmt: skip
_INDEX_WORD = re.compile(_ENTITY_NOUNS + "|" + vocab.alternation(
    "cells?", "nodes?", "heads?", "rank", "category", "level", "step", "index", "number", "no", "pumps?", "loop",
    "paso", "schritt", "pas", "étape", "zeitschritt", "reihe", "fila", "rangée", "prüfpunkt", "punkt", "hallazgo",
    "finding", "constat", "point", "schr", "gab", "arm", "cab",
    "zone", "row", "option", "priority", "id", "phase", "stage", "agent", "cts?", "b", "c", "t", "item", "decision",
    "line", "section", "table", "figure", "fig", "appendix", "equation", "eq", "algorithm", "case", "scenario",
    "example", "version", "blades", "lames"), re.IGNORECASE)  # fmt: skip
_COUNT_NOUNS = re.compile(
    r"^[\s\u00a0]*(?:(?:of|de|von|sur)[\s\u00a0]+\d+[\s\u00a0]+)?(?:" + _ENTITY_NOUNS + "|"
    + vocab.alternation(*vocab.COUNTED_NOUNS) + r")\b",
    re.IGNORECASE,
)
_IDENT_BEFORE = re.compile(r"[A-Za-z_]$|[A-Za-z]-$|\d\.$")  # B1, Llama-3, 1.2.3
_HASH_BEFORE = re.compile(r"(?:#|\bno\.)[\s\u00a0]*$", re.IGNORECASE)
_PLUSMINUS_BEFORE = re.compile(r"(?:±|\+/-|\+-)[\s\u00a0]*$")
_WORD_BEFORE = re.compile(r"([^\W\d_]+)[\s\u00a0]*\(?$")
_RANGE_DASH_BEFORE = re.compile(r"\d[\s\u00a0]*$|[A-Za-z]$")
_ORDINAL = re.compile(r"^(?:st|nd|rd|th)\b")
_AND_OR = vocab.alternation(*vocab.function_words("and"), *vocab.function_words("or"))
_CHAIN = re.compile(r"^[\s\u00a0]*(?:,|" + _AND_OR + r"|&|/|,[\s\u00a0]*" + _AND_OR + r"|to|through|-|–)[\s\u00a0]*$")
_LIST_COMMA = re.compile(r"^,[\s\u00a0]*$")
_RANGE = re.compile(r"^[\s\u00a0]*(?:-|–|—|to|and|/|y|und|et|a|à|bis|hasta)[\s\u00a0]*$")


@dataclass
class NumberMention:
    """One number in the text."""

    start: int
    end: int
    text: str
    value: float  # as stated, signed
    unit: str  # normalized unit ("" when none)
    decimals: int
    role: str  # measure | index | count | time | year | tolerance
    unit_end: int = -1
    interpretations: list[tuple[str, float, float]] = field(default_factory=list)

    @property
    def half_ulp(self) -> float:
        """Half a unit in the last stated digit, in the stated unit."""
        return 0.5 * 10.0 ** (-self.decimals)


def read_numbers(text: str) -> list[Claim]:
    """The measurements of ``text`` as claims that each equals some value (not yet checked), with their readings."""
    return [Claim("equals", m.text, m.start, m.end, value=m.value, unit=m.unit, readings=tuple(m.interpretations))
            for m in extract_numbers(text) if m.role == "measure"]  # fmt: skip


def extract_numbers(text: str) -> list[NumberMention]:
    """Every number in ``text`` with its unit and role; measurements also get interpretations."""
    masked = _mask(text)
    mentions: list[NumberMention] = []
    for m in _NUM.finditer(masked):
        num = m.group("num")
        start, end = m.start("num"), m.end()
        sign = m.group("sign")
        negative = False
        if sign and sign in "-−–":
            before = masked[: m.start()]
            # a dash right after a number (with or without spaces) is a range, not a sign
            if not _RANGE_DASH_BEFORE.search(before):
                negative, start = True, m.start()
        raw = num.replace(",", "")
        try:
            value = float(raw + (m.group("exp") or ""))
        except ValueError:
            continue
        value = -value if negative else value
        decimals = len(raw.split(".")[1]) if "." in raw else 0
        mention = NumberMention(start, end, text[start:end], value, "", decimals, "measure")
        _classify(mention, text, masked, mentions[-1] if mentions else None)
        mentions.append(mention)
    _inherit_range_units(mentions, text)
    for mention in mentions:
        if mention.role == "measure":
            mention.interpretations = interpretations(mention)
    return mentions


def _mask(text: str) -> str:
    """Replace dates, clock times and shares written as a fraction ("valves 1/3 each": the split, which coverage
    reads) by letters so they are not read as numbers."""
    out = _DATE.sub(lambda m: "D" * len(m.group()), text)
    out = vocab.SHARE_FRACTION.sub(lambda m: "F" * len(m.group()), out)
    return _CLOCK.sub(lambda m: "T" * len(m.group()), out)


def _classify(m: NumberMention, text: str, masked: str, previous: NumberMention | None) -> None:
    before = masked[max(0, m.start - 30) : m.start]
    after = masked[m.end : m.end + 60]
    if _IDENT_BEFORE.search(before):
        m.role = "index"  # B1, CDU3, Llama-3.1, version 1.2.3
        return
    if _HASH_BEFORE.search(before) or _ORDINAL.match(after):
        m.role = "index"
        return
    if (u := vocab.unit_at(text, m.end)) is not None:
        m.unit, m.unit_end = u
    if _PLUSMINUS_BEFORE.search(before):
        m.role = "tolerance"
    elif m.unit == "time":
        m.role = "time"
    elif m.unit or m.decimals > 0:
        return
    elif _PERCENT_LIST_AFTER.match(masked, m.end):
        return  # "válvulas 33/33/33 %": shares, each a percentage
    elif (word := _WORD_BEFORE.search(before)) and _INDEX_WORD.fullmatch(word.group(1)):
        m.role = "index"
    elif previous is not None and previous.role == "index" and _CHAIN.match(masked[previous.end : m.start]):
        m.role = "index"  # "branches 1, 2 and 3"
    elif _COUNT_NOUNS.match(after):
        m.role = "count"
    elif 1900 <= m.value <= 2100:
        m.role = "year"


def _inherit_range_units(mentions: list[NumberMention], text: str) -> None:
    """A bare number before a range or list partner takes its unit ("20-40 °C", "304,3, 319,1 et 311,3 kW"), from the
    last item of the list back to the first."""
    for a, b in reversed(list(zip(mentions, mentions[1:]))):
        both_measures = a.role == b.role == "measure"
        if both_measures and not a.unit and b.unit and (_RANGE.match(text[a.end : b.start])
                                                       or _LIST_COMMA.match(text[a.end : b.start])):  # fmt: skip
            a.unit = b.unit


RHO_WATER = 997.0  # kg/m^3 at the loop's ~25 degC: volumetric flows (L/s, gpm) are read as mass flows
# each unit the text may use -> (quantity, pint unit, SI unit of the pool)
_PINT = {"W": ("power", "W", "W"), "kW": ("power", "kW", "W"), "MW": ("power", "MW", "W"),
         "Pa": ("pressure", "Pa", "Pa"), "kPa": ("pressure", "kPa", "Pa"), "MPa": ("pressure", "MPa", "Pa"),
         "psi": ("pressure", "psi", "Pa"), "bar": ("pressure", "bar", "Pa"),
         "kg/s": ("flow", "kg/s", "kg/s"), "L/s": ("flow", "L/s", "m^3/s"), "L/min": ("flow", "L/min", "m^3/s"),
         "gpm": ("flow", "gallon/minute", "m^3/s"), "m3/h": ("flow", "m^3/hour", "m^3/s"),
         "kg/min": ("flow", "kg/minute", "kg/s"), "kg/h": ("flow", "kg/hour", "kg/s"), "lb/s": ("flow", "lb/s", "kg/s"),
         "lb/min": ("flow", "lb/minute", "kg/s"), "mbar": ("pressure", "mbar", "Pa")}  # fmt: skip
_QUANTITY = {u: q for u, (q, _, _) in _PINT.items()}


@functools.cache
def _factors() -> tuple[dict[str, float], float, float]:
    """(SI factor per unit, degF->K slope, degF->K offset), from pint once (its registry takes ~0.5 s to build)."""
    import pint

    ureg = pint.UnitRegistry()
    scale = {u: float(ureg.Quantity(1.0, src).to(si).magnitude) * (RHO_WATER if si == "m^3/s" else 1.0)
             for u, (_, src, si) in _PINT.items()}  # fmt: skip
    f0, f1 = (float(ureg.Quantity(x, "degF").to("K").magnitude) for x in (0.0, 1.0))
    return scale, f1 - f0, f0


def interpretations(m: NumberMention) -> list[tuple[str, float, float]]:
    """(quantity, canonical value, rounding tolerance) readings of a measurement."""
    v, h, u = m.value, m.half_ulp, m.unit
    if u == "degC":
        return [("temp_abs", v + K0, h), ("temp_delta", abs(v), h)]
    if u == "degF":
        _, slope, offset = _factors()
        return [("temp_abs", v * slope + offset, h * slope), ("temp_delta", abs(v) * slope, h * slope)]
    if u == "K":
        return [("temp_abs", v, h), ("temp_delta", abs(v), h)]
    if u in _QUANTITY:
        f = _factors()[0][u]
        return [(_QUANTITY[u], abs(v) * f, h * f)]
    if u == "%":
        return [("fraction", abs(v) / 100.0, h / 100.0), ("percent", abs(v), h)]
    if u == "pp":
        return [("fraction", abs(v) / 100.0, h / 100.0)]
    if u == "J/(kg K)":
        return [("specific_heat", abs(v), h)]
    if u == "x":
        return [("unitless", abs(v), h)]
    if u == "energy":
        return [("energy", abs(v), h)]
    # a bare number: any of the data's display units
    a = abs(v)
    out = [("unitless", a, h), ("fraction", a, h), ("percent", a, h), ("temp_abs", v + K0, h), ("temp_delta", a, h),
           ("power", a * 1e3, h * 1e3), ("power", a, h), ("flow", a, h), ("pressure", a * PSI_TO_PA, h * PSI_TO_PA),
           ("pressure", a * 1e3, h * 1e3), ("temp_abs", v, h)]  # fmt: skip
    if 1 < a <= 100:  # "57" for 57 %
        out.append(("fraction", a / 100.0, h / 100.0))
    return out
