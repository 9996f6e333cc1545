"""Numeric grounding: does every measurement in the text match a value of the record?

A number is *grounded* when one of its interpretations (numbers.py) lies within tolerance of a pool
value (record.py) of the same quantity. Tolerance is the larger of the stated precision (half a unit
in the last digit: "36 °C" covers 35.5-36.5 °C) and the configured one (``temp_tol_k``,
``fraction_tol``, ``rel_tol``). A number is *derived* (and counts as grounded) when its clause says
it is a difference or a sum ("4.2 K above branch 1", "together 230 kW") and it equals the difference
or sum of two pool values of one quantity. A grounded temperature, power or fraction written right
after "branch j" must be branch j's own value (or a value that belongs to no branch): "branch 1 at
40.6 °C" when 40.6 °C is branch 2's temperature is ungrounded. Valve shares given as percentages rounded
to sum to 100 % ("33 % / 33 % / 34 %" for three equal valves) are grounded as the split they round.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from lcmesh.mesh.tools import vocab
from lcmesh.mesh.tools.explain_eval.numbers import K0, NumberMention
from lcmesh.mesh.tools.claims import Claim, Fact
from lcmesh.mesh.tools.explain_eval.record import EvalConfig, Record

DIFF_CUE = re.compile(
    r"\b(?:above|below|than|warmer|hotter|cooler|colder|higher|lower|more|less|difference|differ\w*|spread|spans?"
    r"|gap|margin|apart|delta|approach|between|exceed\w*|short of|beyond|inside|outside|headroom|under|away|off"
    # es / de / fr
    r"|margen|marge|abstand|reserve|diferencia|differenz|unterschied|écart|sous|unter|über|debajo|encima|au-dessus"
    r"|en\s+dessous|por\s+debajo|por\s+encima|más\s+que|menos\s+que|plus\s+que|moins\s+que|hasta|bis|jusqu)\b|Δ",
    re.IGNORECASE,
)
SUM_CUE = re.compile(
    r"\b(?:total|together|combined|sum|plus|altogether|in all|overall|add\w*|jointly)\b", re.IGNORECASE
)
_BRANCH_QUANTITIES = ("temp_abs", "power", "fraction")


@dataclass
class GroundingResult:
    checked: int = 0
    grounded: int = 0
    derived: int = 0
    skipped: int = 0
    claims: list[Claim] = field(default_factory=list)  # one per measurement, with its verdict: the failed ones flag

    @property
    def score(self) -> float:
        return self.grounded / self.checked if self.checked else 1.0


class ValuePool:
    """Pool values per quantity as arrays, with lazily built pairwise differences and sums."""

    def __init__(self, entries: list[Fact]):
        self.entries: dict[str, list[Fact]] = {}
        for e in entries:
            self.entries.setdefault(e.quantity, []).append(e)
        self.values = {q: np.array([e.value for e in es]) for q, es in self.entries.items()}
        self._pairs: dict[tuple[str, str], np.ndarray] = {}

    def direct(self, quantity: str, value: float, tol: float) -> list[Fact]:
        arr = self.values.get(quantity)
        if arr is None:
            return []
        hits = np.flatnonzero(np.abs(arr - value) <= tol)
        return [self.entries[quantity][i] for i in hits]

    def derived(self, quantity: str, value: float, tol: float, how: str) -> bool:
        source = {"temp_delta": "temp_abs"}.get(quantity, quantity) if how == "diff" else quantity
        key = (source, how)
        if key not in self._pairs:
            v = self.values.get(source, np.zeros(0))
            i, j = np.triu_indices(v.size, k=1)
            self._pairs[key] = np.abs(v[i] - v[j]) if how == "diff" else v[i] + v[j]
        pairs = self._pairs[key]
        return bool(pairs.size and (np.abs(pairs - value) <= tol).any())


def tolerance(quantity: str, value: float, half_ulp: float, cfg: EvalConfig) -> float:
    """Accepted distance for a stated value: its precision or the configured tolerance, the larger."""
    if quantity in ("temp_abs", "temp_delta"):
        base = cfg.temp_tol_k
    elif quantity == "fraction":
        base = cfg.fraction_tol
    elif quantity == "percent":
        base = cfg.fraction_tol * 100.0
    else:
        base = cfg.rel_tol * abs(value)
    return max(base, half_ulp * 1.0001) + 1e-9


def check_grounding(
    rec: Record,
    mentions: list[NumberMention],
    pool: ValuePool,
    clause_at,
    branch_at,
    cfg: EvalConfig,
    base: int = 1,
    rounded_shares: frozenset[int] = frozenset(),
) -> GroundingResult:
    """Score the measurements; ``clause_at(pos)`` gives the clause text, ``branch_at(pos)`` the branch
    (0-based) whose span holds ``pos`` or None; ``rounded_shares`` holds the starts of percentages that give the
    valve split rounded to sum to 100 % (claims.rounded_shares), which are grounded."""
    res = GroundingResult()
    for m in mentions:
        if m.role != "measure":
            res.skipped += 1
            continue
        res.checked += 1
        claim = Claim("equals", _quote(rec.text, m).strip("'"), m.start, m.end, value=m.value, unit=m.unit,
                      readings=tuple(m.interpretations))  # fmt: skip
        res.claims.append(claim)
        if m.start in rounded_shares:
            res.grounded += 1
            claim.holds("the valve split, rounded to sum to 100 %")
            continue
        hits: list[Fact] = []
        fraction_only = _named_valve_fraction(rec.text, m)
        for q, x, h in m.interpretations:
            if not fraction_only or q == "fraction":
                hits += pool.direct(q, x, tolerance(q, x, h, cfg))
        if hits:
            branch = branch_at(m.start)
            claim.entity = None if branch is None else f"branch {branch + base}"
            wrong = _misattributed(hits, branch, pool)
            topic = _topic_of(rec.text, m)
            band = all(h.name.endswith("band edge") for h in hits)
            if wrong is not None and band and _LIMIT_WORD.search(clause_at(m.start)):
                wrong = None  # "stays inside the 20-40 °C band", "lejos del límite de 40 °C": the band, named
            if wrong is not None:
                actual = f"branch {wrong[1] + base}'s value" if wrong[1] is not None else f"the {_labels(hits)}"
                claim.fails("ungrounded_number", f"{_quote(rec.text, m)} is given for branch {wrong[0] + base} but is "
                            f"{actual}", _labels(hits))  # fmt: skip
            elif branch is None and topic is not None and _off_topic(hits, topic, pool):
                claim.quantity = topic
                claim.fails("ungrounded_number", f"{_quote(rec.text, m)} is given as the {topic.replace('_', ' ')} "
                            f"but is the {_labels(hits)}", _labels(hits))  # fmt: skip
            else:
                res.grounded += 1
                claim.quantity = hits[0].quantity
                claim.holds(_labels(hits))
            continue
        clause = clause_at(m.start)
        if _derived(m, pool, clause, cfg):
            res.grounded += 1
            res.derived += 1
            claim.holds("a difference or sum of the record's values")
            continue
        claim.fails("ungrounded_number", f"{_quote(rec.text, m)} matches no observation, action or fact value"
                    f"{_hint(m, pool, cfg)}")  # fmt: skip
    return res


_VALVE_NAME = re.compile(r"\bvalves?\b|" + vocab.alternation(*(vocab.VALVE_WORDS[lang][0] for lang in ("es", "de", "fr"))),
                         re.IGNORECASE)  # fmt: skip


def _named_valve_fraction(text: str, m: NumberMention) -> bool:
    """A bare decimal from 0 to 1 after a valve word in its clause, with no other quantity named between ("valves
    0.33/0.34/0.53"), is a valve fraction and nothing else (not a percent figure of some other fact)."""
    if m.unit or m.decimals == 0 or not 0 <= m.value <= 1:
        return False
    breaks = [b.end() for b in _CLAUSE_END.finditer(text, 0, m.start)]
    before = text[breaks[-1] if breaks else 0 : m.start]
    names = list(_VALVE_NAME.finditer(before))
    if not names:
        return False
    between = before[names[-1].end() :]
    return not vocab.QUANTITY.search(between) and len(re.findall(r"[\w°%./-]+", between)) <= 8


def _misattributed(hits: list[Fact], branch: int | None, pool: "ValuePool") -> tuple[int, int | None] | None:
    """(claimed, actual or None) 0-based branches when a number said of a branch is not that branch's value: another
    branch's, or a temperature of no branch (a setpoint, a band limit) where the branch's own is known."""
    if branch is None:
        return None
    relevant = [e for e in hits if e.quantity in _BRANCH_QUANTITIES]
    if not relevant:
        return None
    owners = {e.branch if e.branch is not None else e.alias for e in relevant}
    if branch in owners:
        return None
    if None in owners and any(e.quantity != "temp_abs" for e in relevant if e.branch is None and e.alias is None):
        return None  # a power or fraction of no branch ("57 % of the cabinet's 346 kW on branch 2"): a total
    known = any(e.branch == branch for q in {e.quantity for e in relevant} for e in pool.entries.get(q, []))
    if not known:
        return None
    others = sorted(o for o in owners if o is not None)
    return branch, (others[0] if others else None)


# what a temperature is said to be: the nearest name before it in its clause (or right after it: "the 18.6 °C wet
# bulb"); only the setpoints and the wet bulb are checked, the other names stop the search
_TOPIC_NAMES = re.compile(
    r"(?P<wet_bulb>wet[\s-]?bulb|" + vocab.alternation(*vocab.quantity_phrases({"wet_bulb"}, only=True)) + ")"
    r"|(?P<lw_setpoint>(?:leaving[\s-]+water|LWT|tower|(?:condenser|cold)[\s-]+water)"
    r"(?:[\s-]+(?:water|leaving-water|temperature))?[\s-]+"
    r"set[\s-]?points?|" + vocab.alternation(*vocab.quantity_phrases({"lw_setpoint", "lw"}, only=True),
                                            *vocab.TOWER_SETPOINT_WORDS) + ")"
    r"|(?P<supply_setpoint>(?:supply|CDU|coolant)(?:[\s-]+(?:water|coolant|temperature|temp|supply))*[\s-]+"
    r"set[\s-]?points?|" + vocab.alternation(*vocab.quantity_phrases({"supply_setpoint", "supply"}, only=True)) + ")"
    r"|(?P<other>measured|\bmeas\b|deliver\w*|tower\s+water|leaving[\s-]+water|condenser[\s-]+water|return|supply"
    r"|coolant|branch\w*"
    r"|blade\w*|group|approach|above|below|hottest|coolest|warmest|spread|previous\w*"
    r"|limit|band|edge|ceiling|floor|threshold|bound|nears?"
    # the same names in es / de / fr
    r"|medid[oa]s?|gemessen\w*|mesurée?s?|retorno|rücklauf\w*|retour|impulsión|vorlauf\w*|départ|agua\s+de\s+salida"
    r"|austrittswasser\w*|eau\s+de\s+sortie|ramas?|zweig\w*|branches?|banda|bande|límite|grenze|limite"
    r"|\bist\b|\breal\b|\bréel\w*|\bmesure\b|\bactual\b|\bmedición\b)",
    re.IGNORECASE,
)


_SETPOINT_AFTER = re.compile(r"\W*(?:set[\s-]?point|SP|consigna|consigne|soll(?:wert)?)\W*"
                             r"(?:de|of|à|a|en|bei|auf)?\s*$", re.IGNORECASE)  # fmt: skip
_SUPPLY_NAME = re.compile(r"impulsi[oó]n|vorlauf\w*|d[ée]part|supply", re.IGNORECASE)
_LIMIT_WORD = re.compile(r"\b(?:band|banda|bande|band(?:es)?|limit\w*|límite|grenze|edge|borde|bord|ceiling|margin\w*|"
                         r"marge|margen|abstand)\b", re.IGNORECASE)  # fmt: skip
_CLAUSE_END = re.compile(r"[.!?](?=\s)|[;|\n]")
_LIST_ITEM_END = re.compile(r",\s|·|\s[–—-]\s")


def _topic_of(text: str, m: NumberMention) -> str | None:
    end = m.unit_end if m.unit_end > 0 else m.end
    tail = re.split(r"[\n;|#]", text[end : end + 60], maxsplit=1)[0].lstrip()
    after = _TOPIC_NAMES.match(tail)  # "the 17.7 °C leaving-water setpoint"; not the next line's key
    if after and not re.match(r"[\w\s-]*[:=]", tail[after.end() :]):
        return after.lastgroup if after.lastgroup != "other" else None
    breaks = [b.end() for b in _CLAUSE_END.finditer(text, 0, m.start)]
    before = text[breaks[-1] if breaks else 0 : m.start]
    # "Vorlauf-Soll 30,0 °C, Turm-Soll 29,4 °C": each list item names its own number
    item = [b.end() for b in _LIST_ITEM_END.finditer(before)]
    if item and _TOPIC_NAMES.search(before, item[-1]):
        before = before[item[-1] :]
    elif item and re.search(r"[^\W\d_]{2,}", before[item[-1] :]):
        return None  # "..., tour 17,7 °C", "FK 18,6 °C": the item names its number by a word of its own
    names = list(_TOPIC_NAMES.finditer(before))
    if not names:
        return None
    last = names[-1]
    if len(re.findall(r"[\w°%./-]+", before[last.end() :])) > 8:
        return None
    if last.lastgroup == "other" and _SETPOINT_AFTER.match(before, last.end()):
        # "Impulsión: consigna 12,1 °C", "Vorlauf: Sollwert 30 °C": the setpoint of the supply named before it
        return "supply_setpoint" if _SUPPLY_NAME.fullmatch(last.group()) else None
    return last.lastgroup if last.lastgroup != "other" else None


def _off_topic(hits: list[Fact], topic: str, pool: "ValuePool") -> bool:
    """True when an absolute temperature named as ``topic`` matches only other readings' values."""
    absolute = [e for e in hits if e.quantity == "temp_abs"]
    if not absolute or any(e.topic == topic for e in absolute):
        return False
    return any(e.topic == topic for e in pool.entries.get("temp_abs", []))


def _labels(hits: list[Fact]) -> str:
    return " / ".join(dict.fromkeys(e.name for e in hits[:3]))


def _derived(m: NumberMention, pool: ValuePool, clause: str, cfg: EvalConfig) -> bool:
    diff, total = bool(DIFF_CUE.search(clause)), bool(SUM_CUE.search(clause))
    for q, x, h in m.interpretations:
        if q == "temp_abs" or q == "unitless":
            continue
        tol = tolerance(q, x, h, cfg)
        if diff and pool.derived(q, x, tol, "diff"):
            return True
        if total and q != "temp_delta" and pool.derived(q, x, tol, "sum"):
            return True
    return False


def _hint(m: NumberMention, pool: ValuePool, cfg: EvalConfig) -> str:
    """Name a K/deg C mix-up when swapping the unit would have matched."""
    if m.unit == "K" and pool.direct("temp_abs", m.value + K0, tolerance("temp_abs", 0, m.half_ulp, cfg)):
        return f" (the data has {m.text} °C: K and °C confused)"
    if m.unit == "degC" and pool.direct("temp_abs", m.value, tolerance("temp_abs", 0, m.half_ulp, cfg)):
        return f" (the data has {m.text} K: °C and K confused)"
    return ""


def _quote(text: str, m: NumberMention) -> str:
    end = m.unit_end if m.unit_end > 0 else m.end
    return f"'{text[m.start:end]}'"
