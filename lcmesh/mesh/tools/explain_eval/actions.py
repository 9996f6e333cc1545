"""Claims in the text checked against the record: coverage and direction (``consistency.py``: ranking,
physics, bounds).

Rules (docs/explanations.md, "Evaluator rules"):

- coverage: each action dimension is explained: valve j by a span after "branch j" that cites its
  fraction (a percentage there is a share of the flow unless it is named another share: "34 % of the
  load") or talks about its opening, or by a valve sentence listing all fractions in branch order,
  giving them as percentages rounded to sum to 100 % ("33 % / 33 % / 34 %"), or calling the split
  equal (when it is); the supply setpoint, flow, dp and tower action by a sentence naming the dimension
  that cites its value or change, or states its direction.
- direction: "raised/lowered/held" (and "opens branch 2 further", "more flow") claims about this action,
  outside conditions, advice and the RECOMMENDATIONS section, compared with the change against
  ``previous_action`` (or our facts' ``*_change``); valve claims made against the other branches ("more
  than an equal share") or the load ("above its load share") compare with those instead.
"""

from __future__ import annotations

import re
from bisect import bisect_left
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from lcmesh.mesh.tools import vocab
from lcmesh.mesh.tools.claims import Claim, Flag
from lcmesh.mesh.tools.explain_eval import text as tx
from lcmesh.mesh.tools.explain_eval.grounding import ValuePool, tolerance
from lcmesh.mesh.tools.explain_eval.numbers import K0, PSI_TO_PA, NumberMention
from lcmesh.mesh.tools.explain_eval.record import EvalConfig, Record



@dataclass
class Context:
    """What every check reads: the record, its text parsed once, and the branch numbering."""

    rec: Record
    cfg: EvalConfig
    sentences: list[tx.Sentence]
    numbers: list[NumberMention]
    branches: list[tx.BranchMention]
    base: int
    pool: ValuePool
    claims: list[Claim] = field(default_factory=list)  # what the checks read, each with its verdict

    @cached_property
    def rounded_starts(self) -> frozenset[int]:
        """Where the percentages that give the valve split rounded to sum to 100 % start (``rounded_shares``), read once
        for grounding, coverage and the valve lists."""
        return frozenset(m.start for m in rounded_shares(self))

    def claim(self, relation: str, text: str, **kw) -> Claim:
        """Record a claim read from the text (its verdict is set by the check)."""
        c = Claim(relation, text, **kw)  # type: ignore[arg-type]
        self.claims.append(c)
        return c

    def fail(self, relation: str, kind: str, detail: str, text: str = "", **kw) -> Flag:
        """Record a claim that fails and return its flag."""
        return self.claim(relation, text or detail, **kw).fails(kind, detail).flag

    def entity(self, b: tx.BranchMention) -> int:
        return b.raw - 1 if b.ordinal else b.raw - self.base

    def label(self, j: int) -> str:
        return f"branch {j + self.base}"

    def __post_init__(self) -> None:
        self._branch_starts = [b.start for b in self.branches]
        self._measures = [m for m in self.numbers if m.role == "measure"]
        self._measure_starts = [m.start for m in self._measures]

    def branches_in(self, start: int, end: int) -> list[tx.BranchMention]:
        return self.branches[bisect_left(self._branch_starts, start) : bisect_left(self._branch_starts, end)]

    def numbers_in(self, start: int, end: int) -> list[NumberMention]:
        """Measurements starting in [start, end)."""
        return self._measures[bisect_left(self._measure_starts, start) : bisect_left(self._measure_starts, end)]

    def span_of(self, b: tx.BranchMention, sentence: tx.Sentence) -> tuple[int, int]:
        """From the mention (or its list's start) to the next mention outside its list, within the sentence."""
        inside = self.branches_in(sentence.start, sentence.end)
        group = [x for x in inside if b.group >= 0 and x.group == b.group] or [b]
        start = group[0].start
        later = [x.start for x in inside if x.start > group[-1].start and x not in group]
        return start, min(later) if later else sentence.end

    def matches(self, m: NumberMention, quantity: str, value: float) -> bool:
        for q, x, h in m.interpretations:
            if q == quantity and abs(x - value) <= tolerance(q, x, h, self.cfg):
                return True
        return False


# --- coverage -----------------------------------------------------------------------------------


def check_coverage(ctx: Context) -> tuple[dict[str, bool], list[Flag]]:
    rec = ctx.rec
    dims: dict[str, bool] = {}
    if rec.valves is not None:
        covered = _valves_covered(ctx)
        for j in range(rec.valves.size):
            dims[f"valve {ctx.label(j)}"] = j in covered
    scalar = [("supply setpoint", rec.supply_k, tx.SUPPLY_ANY, "temp_abs", "supply"),
              ("flow", rec.flow_kg_s, tx.FLOW, "flow", "flow"), ("dp", rec.dp_pa, tx.DP, "pressure", "dp"),
              ("tower", rec.lw_k, tx.TOWER, "temp_abs", "tower")]  # fmt: skip
    for name, value, pattern, quantity, change_key in scalar:
        if value is None and not (name == "tower" and rec.ct_category is not None):
            continue
        dims[name] = any(_scalar_covered(ctx, s, pattern, quantity, value, change_key) for s in ctx.sentences)
    flags = []
    for name, ok in dims.items():
        if ok:
            ctx.claim("covers", f"the {_describe(ctx, name)} is explained", entity=name).holds("the action")
        else:
            flags.append(ctx.fail("covers", "missing_action_dimension", f"the {_describe(ctx, name)} is not explained",
                                  entity=name))  # fmt: skip
    return dims, flags


def _describe(ctx: Context, name: str) -> str:
    rec = ctx.rec
    if name.startswith("valve "):
        j = int(name.rsplit(" ", 1)[1]) - ctx.base
        return f"valve fraction of {ctx.label(j)} ({rec.valves[j]:.2f})"
    if name == "supply setpoint":
        return f"supply setpoint ({rec.supply_k - K0:.1f} °C)"
    if name == "dp":
        return f"dp setpoint ({rec.dp_pa / PSI_TO_PA:.1f} psi)"
    if name == "flow":
        return f"flow ({rec.flow_kg_s:.2f} kg/s)"
    return "tower action" + (f" ({rec.lw_k - K0:.1f} °C)" if rec.lw_k is not None else f" ({rec.ct_category})")


def _valves_covered(ctx: Context) -> set[int]:
    valves = ctx.rec.valves
    covered: set[int] = set()
    last: int | None = None  # the one branch the previous sentence was about, for "its valve ..."
    previous_valves = False  # the previous sentence talked about valves: "Branches 2 and 3 stay at 0.32." goes on
    plural_before = False
    rounded = ctx.rounded_starts
    for s in ctx.sentences:
        before_sentence = len(covered)
        has_valve_word = bool(tx.VALVE.search(s.text)) or "VALVE" in s.heading or "VALVE" in s.section
        if any(s.start <= p < s.end for p in rounded):
            covered.update(range(valves.size))
        mentions = ctx.branches_in(s.start, s.end)
        # "its valve ...", "Das Ventil geht von 0,440 auf 0,490": the branch the previous sentence was about, before
        # this sentence names another
        head_end = mentions[0].start if mentions else s.end
        head = ctx.rec.text[s.start : head_end]
        if last is not None and has_valve_word and (tx.PRONOUN.search(head) or _THE_VALVE.search(head)):
            if any(ctx.matches(m, "fraction", valves[last]) for m in ctx.numbers_in(s.start, head_end)):
                covered.add(last)
        entities = {ctx.entity(b) for b in mentions}
        last = entities.pop() if len(entities) == 1 else (last if not mentions else None)
        for b in mentions:
            j = ctx.entity(b)
            if not 0 <= j < valves.size:
                continue
            a, z = ctx.span_of(b, s)
            span = ctx.rec.text[a:z]
            text = ctx.rec.text
            before = [m for m in ctx.numbers_in(s.start, b.start) if tx.words_between(text, m.end, b.start) <= 2]
            cited = [m for m in ctx.numbers_in(a, z) + before[-1:] if ctx.matches(m, "fraction", valves[j])
                     and not (m.unit == "%" and other_share(text, m))]  # fmt: skip
            share = any(m.unit == "%" for m in cited)  # "branch 2 gets 41 %": a share of the flow
            talks = tx.VALVE.search(span) and (tx.ANY_DIRECTION.search(span) or tx.EQUAL_SPLIT.search(span))
            exact = any(m.unit == "" and m.decimals >= 2 for m in cited)  # "branche 3 passe de 0,388 à 0,373"
            # a valve sentence that gives branch j a fraction or a move states its valve, right or wrong (grounding
            # and the direction check judge it): "la rama 3 se abre hasta 0,59", "Ventil Zweig 1 | 1,36 | 0,355"
            stated = has_valve_word and (
                any(m.unit in ("", "%") and 0 <= m.value <= (100 if m.unit == "%" else 1.5) and (m.decimals or m.unit)
                    for m in ctx.numbers_in(a, z)) or tx.ANY_DIRECTION.search(span) or _HELD_ALL.search(span)
                or _STAY.search(span))  # fmt: skip
            if (cited and (has_valve_word or previous_valves or exact or tx.VALVE.search(span))) or share or talks \
                    or stated:
                covered.add(j)
        if has_valve_word and mentions:  # "öffnet das Ventil von Zweig 1": a move claimed for a valve states it
            for c in s.clauses:
                covered.update(int(dim.split(":")[1]) for dim, _, _ in direction_claims(ctx, c, valve_context=True)
                               if dim.startswith("valve:") and 0 <= int(dim.split(":")[1]) < valves.size)
        if has_valve_word and mentions and _OTHERS.search(s.text):
            covered.update(range(valves.size))  # "opened branch 3 while the other two valves kept their share"
        previous_valves = has_valve_word or len(covered) > before_sentence
        asked = plural_before  # the previous sentence asked about the valves: "Et les vannes ?" "Toujours à un tiers"
        plural_before = bool(_PLURAL_VALVES.search(s.text)) and s.text.rstrip().endswith("?")  # "¿Las válvulas?"
        if not (has_valve_word or asked or _PLURAL_BRANCHES.search(s.text)):
            continue
        specific = [b for b in mentions if not _COUNT_BEFORE.search(ctx.rec.text, max(0, b.start - 12), b.start)]
        if not specific and (_PLURAL_VALVES.search(s.text) or _PLURAL_BRANCHES.search(s.text) or asked) \
                and tx.ANY_DIRECTION.search(s.text) and _HELD_ALL.search(s.text) \
                and not any(m.unit == "%" or (m.unit == "" and m.value <= 1) for m in ctx.numbers_in(s.start, s.end)):
            covered.update(range(valves.size))  # "Ventile unverändert", "todas siguen con el mismo reparto"
        fractions = [m for m in ctx.numbers_in(s.start, s.end) if any(q == "fraction" for q, _, _ in m.interpretations)]
        if _in_order(ctx, fractions, valves) or _valve_list(ctx, s, ctx.numbers_in(s.start, s.end), valves.size):
            covered.update(range(valves.size))
        equal = float(np.ptp(valves)) < 0.01
        given = {round(m.value, 6) for m in fractions if (m.unit == "" and m.value <= 1) or m.unit == "%"}
        if not mentions and tx.EACH.search(s.text) and len(given) == 1:
            covered.update(range(valves.size))  # "vannes à 0,5 chacune": every valve is given (bounds judge 0,5)
        one_share = bool(fractions) and all(ctx.matches(m, "fraction", valves[0]) for m in fractions) \
            and (bool(_PLURAL_VALVES.search(s.text)) or asked) \
            and not any(b.start < fractions[-1].start for b in mentions)
        if equal and (tx.EQUAL_SPLIT.search(s.text) or one_share or (tx.EACH.search(s.text) and any(
                ctx.matches(m, "fraction", valves[0]) for m in fractions))):
            # "split evenly for branch 1 and branch 3" explains those two; with no branches named its scope, every one
            scope = [b for b in mentions if _SCOPE_BEFORE.search(ctx.rec.text, max(0, b.start - 12), b.start)]
            covered.update({ctx.entity(b) for b in scope} if scope else range(valves.size))  # fmt: skip
    return covered


_THE_VALVE = re.compile(r"\b(?:the\s+valve|das\s+ventil|la\s+vanne|la\s+válvula|sein\s+ventil|su\s+válvula|sa\s+vanne)\b",
                        re.IGNORECASE)  # fmt: skip
_SLASH_PERCENT = re.compile(r"(?:\s*/\s*\d+(?:\.\d+)?)+\s*%")  # "79/16/5 %", "33.7 / 32.3 / 34.1 %": percentages
_STAY = re.compile(r"\b(?:stay(?:s|ed)?|remain(?:s|ed)?|kept|keep(?:s)?|sit(?:s)?|stand(?:s)?)\b", re.IGNORECASE)
# "the other two", "los demás", "die beiden anderen", "les deux autres": every branch not named
_OTHERS = re.compile(r"\b(?:the\s+other\s+(?:two|ones|valves|branches)|the\s+others|(?:los|las)\s+(?:otr[oa]s\s+dos|demás)|"
                     r"(?:die\s+)?(?:beiden\s+)?anderen|les\s+(?:deux\s+)?autres)\b", re.IGNORECASE)  # fmt: skip
_PLURAL_BRANCHES = re.compile(r"\b(?:branches|ramas|zweige|str[äa]nge)\b", re.IGNORECASE)
# every valve held, said of all of them: "unchanged", "sin cambios", "unverändert", "inchangées", "the same split"
_HELD_ALL = re.compile(r"\b(?:unchanged|held|no\s+change|same\s+(?:split|distribution)|sin\s+cambios?|igual(?:es)?|"
                       r"mismo\s+reparto|quiet[oa]s?|unverändert|gehalten|gleiche?\s+aufteilung|inchangée?s?|no\s+cambia\w*|"
                       r"sin\s+tocar|ändert\s+sich\s+nicht|ne\s+change\s+pas|untouched|"
                       r"maintenue?s?|même\s+répartition|ne\s+bougent\s+pas)\b", re.IGNORECASE)  # fmt: skip
_COUNT_BEFORE = re.compile(r"(?:all|alle|todas|las|los|toutes|les|die|the)\s+(?:\w+\s+)?$", re.IGNORECASE)
_PLURAL_VALVES = re.compile(r"\b(?:valves|válvulas|ventile|vannes)\b", re.IGNORECASE)
_LIST_JOIN = re.compile(r"\s*(?:/|,|;|-|–|\band\b|\by\b|\bund\b|\bet\b|\be\b)\s*", re.IGNORECASE)


def _valve_list(ctx: Context, s: tx.Sentence, fractions: list, n: int) -> bool:
    """A valve sentence listing one bare fraction per branch in a row ("Ventile 0,69 / 0,053 / 0,169"): it states the
    split (grounding, the bounds and ``check_valve_lists`` judge its values)."""
    return _valve_run(ctx, fractions, n) is not None


def _valve_run(ctx: Context, numbers: list, n: int) -> list | None:
    text = ctx.rec.text
    bare = [m for m in numbers if (m.unit == "" and m.decimals >= 1 and 0 <= m.value <= 1) or m.unit == "%"
            or (m.unit == "" and _SLASH_PERCENT.match(text, m.end))]  # fmt: skip
    for k in range(len(bare) - n + 1):
        run = bare[k : k + n]
        if all(_LIST_JOIN.fullmatch(text, a.unit_end if a.unit_end > 0 else a.end, z.start)
               for a, z in zip(run, run[1:])):
            return run
    return None


def check_valve_lists(ctx: Context) -> list[Flag]:
    """A valve list in branch order ("Valves 33 % / 34 % / 34 %", "Ventile 0,69 / 0,053 / 0,169") gives branch k its
    k-th value: each must be that valve's fraction (now or before) at its precision, else it is ungrounded. A list that
    sums to more than 1 is the bounds check's; percentages rounded to sum to 100 % are the split they round."""
    valves, rec = ctx.rec.valves, ctx.rec
    if valves is None or valves.size < 2:
        return []
    rounded = ctx.rounded_starts
    previous = rec.valves - rec.valve_changes if rec.valve_changes is not None else None
    flags = []
    for s in ctx.sentences:
        if not (tx.VALVE.search(s.text) or "VALVE" in s.heading) or ctx.branches_in(s.start, s.end):
            continue
        run = _valve_run(ctx, ctx.numbers_in(s.start, s.end), valves.size)
        if run is None or any(m.start in rounded for m in run):
            continue
        if sum(m.value / (100.0 if m.unit == "%" or _SLASH_PERCENT.match(rec.text, m.end) else 1.0)
               for m in run) > 1.0 + ctx.cfg.bounds.valve_sum_tol + 0.005 * valves.size:
            continue  # too much in all: out of bounds
        for j, m in enumerate(run):
            share = m.value / 100.0 if m.unit == "%" or _SLASH_PERCENT.match(rec.text, m.end) else m.value
            ok = [valves[j]] + ([previous[j]] if previous is not None else [])
            half = 0.5 * 10.0 ** (-m.decimals) / (100.0 if share != m.value else 1.0)
            if not any(abs(share - v) <= max(half * 1.0001, ctx.cfg.fraction_tol) for v in ok):
                flags.append(ctx.fail("equals", "ungrounded_number", f"'{m.text}' is given for the valve of "
                                      f"{ctx.label(j)} (its place in the list) but that valve is {valves[j]:.3f}",
                                      m.text, start=m.start, end=m.end, entity=ctx.label(j)))  # fmt: skip
    return flags


_SCOPE_BEFORE = re.compile(r"\b(?:for|across|between|among)\s+(?:the\s+)?$", re.I)


# up to four words after a number or three before it, not past another number
_WORDS_AFTER = re.compile(r"(?:[^\w%]*[^\W\d][\w'’-]*){0,4}")
_WORDS_BEFORE = re.compile(r"(?:[^\W\d][\w'’-]*[^\w%]*){0,3}$")


def other_share(text: str, m: NumberMention) -> bool:
    """True when a percentage is named a share of something other than the flow: "34 % of the load", "IT load
    34 %", "34 % de la carga" (within four words after it or three before, not past another number)."""
    end = m.unit_end if m.unit_end > 0 else m.end
    after = _WORDS_AFTER.match(text, end).group()
    before = _WORDS_BEFORE.search(text[max(0, m.start - 60) : m.start]).group()
    return bool(vocab.OTHER_SHARES.search(after) or vocab.OTHER_SHARES.search(before))


def rounded_shares(ctx: Context) -> list[NumberMention]:
    """Percentages that give the valve split rounded to sum to 100 % ("valves 33 % / 33 % / 34 %", "branch 2 gets
    33 % of the flow, branch 1 33 % and branch 3 34 %"): in a valve sentence, one percentage per branch, in branch
    order or each after its branch, each within one unit of its last digit of the branch's share."""
    valves = ctx.rec.valves
    if valves is None:
        return []
    found: list[NumberMention] = []
    for s in ctx.sentences:
        if not (tx.VALVE.search(s.text) or "VALVE" in s.heading or "VALVE" in s.section):
            continue
        shares = [m for m in ctx.numbers_in(s.start, s.end) if m.unit == "%" and not other_share(ctx.rec.text, m)]
        runs = [shares[i : i + valves.size] for i in range(len(shares) - valves.size + 1)]
        by_branch: dict[int, NumberMention] = {}
        for b in ctx.branches_in(s.start, s.end):
            a, z = ctx.span_of(b, s)
            first = next((m for m in shares if a <= m.start < z), None)
            if first is not None and (b.group < 0 or sum(x.group == b.group for x in ctx.branches) == 1):
                by_branch.setdefault(ctx.entity(b), first)
        if sorted(by_branch) == list(range(valves.size)):
            runs.append([by_branch[j] for j in range(valves.size)])
        for run in runs:
            if _sums_to_100(run) and all(abs(m.value - 100 * v) < 10.0 ** -m.decimals + 1e-6
                                         for m, v in zip(run, valves)):  # fmt: skip
                found += run
                break
    return found


def _sums_to_100(shares: list[NumberMention]) -> bool:
    return abs(sum(m.value for m in shares) - 100.0) <= max(m.half_ulp for m in shares) + 1e-6


def _in_order(ctx: Context, mentions: list[NumberMention], valves: np.ndarray) -> bool:
    k = 0
    for m in mentions:
        if k < valves.size and ctx.matches(m, "fraction", valves[k]):
            k += 1
    return k == valves.size


def _scalar_covered(ctx, s: tx.Sentence, pattern, quantity, value, change_key) -> bool:
    if not pattern.search(s.text):
        return change_key == "supply" and _named_with_value(ctx, s, pattern, quantity, change_key)
    if _named_with_value(ctx, s, pattern, quantity, change_key):
        return True
    change = ctx.rec.changes.get(change_key)
    for m in ctx.numbers_in(s.start, s.end):
        if value is not None and ctx.matches(m, quantity, value):
            return True
        if change is not None and ctx.matches(m, "temp_delta" if quantity == "temp_abs" else quantity, abs(change)):
            return True
    if change_key == "tower" and ctx.rec.ct_category is not None and ctx.rec.ct_category.lower() in s.text.lower():
        return True
    strict = {"supply": tx.SUPPLY_SETPOINT, "tower": tx.TOWER_SETPOINT}.get(change_key, pattern)
    if not strict.search(s.text):
        return False
    # a direction claimed for this action ("the LWT setpoint was held"), not a comparative of a rationale ("a lower
    # leaving-water setpoint makes the fans work harder" does not say what the action did)
    return any(dim == change_key for c in s.clauses if not c.hypothetical
               for dim, _, _ in direction_claims(ctx, c, include_valves=False))  # fmt: skip


_BARE_SETPOINT = re.compile(r"^\W*(?:set[\s-]?point|SP|consigna|consigne|sollwert)\W*(?:=|:)?\s*[-+]?\d", re.IGNORECASE)
_SETPOINT_WORD = re.compile(vocab.SETPOINT_WORD.pattern + r"|\bsoll\b|\bcons\b", re.IGNORECASE)


_ITEM_SPLIT = re.compile(r"[,;]\s|\s(?:and|y|und|et|e)\s", re.IGNORECASE)


def _items(s: tx.Sentence) -> list[tx.Clause]:
    """The sentence's list items: split at commas, semicolons and "and", not at a colon ("dp: 25,7 psi" is one)."""
    out, start = [], 0
    for m in list(_ITEM_SPLIT.finditer(s.text)) + [None]:
        end = m.start() if m else len(s.text)
        piece = s.text[start:end]
        if piece.strip():
            hypo = any(c.hypothetical for c in s.clauses if c.start <= s.start + start < c.end)
            out.append(tx.Clause(s.start + start, s.start + end, piece, hypo))
        start = m.end() if m else len(s.text)
    return out


def _named_with_value(ctx, s: tx.Sentence, pattern, quantity, change_key) -> bool:
    """A clause that names the dimension and gives a value of its kind (a temperature for the supply and the tower, a
    pressure for dp, a flow) says what the setting is, right or wrong (grounding judges the number): "soufflage 30,0
    °C", "Turm-Soll 17,7 °C", "el diferencial de presión en 27,5 psi". The measured supply shares the supply's name, so
    there the value must be the setpoint's (now or before), or the clause must name the setpoint or a change."""
    supply, change = ctx.rec.supply_k, ctx.rec.changes.get("supply")
    setpoints = [] if supply is None else [supply] + ([supply - change] if change is not None else [])
    for c in _items(s):
        if c.hypothetical or not pattern.search(c.text):
            continue
        for m in ctx.numbers_in(c.start, c.end):
            if not m.unit or not any(q == quantity for q, _, _ in m.interpretations):
                continue
            if change_key != "supply" or any(ctx.matches(m, quantity, x) for x in setpoints):
                return True
            if tx.SUPPLY_SETPOINT.search(c.text) or _SETPOINT_WORD.search(c.text) or tx.ANY_DIRECTION.search(c.text):
                return True
    for c in _items(s):  # "| SP 30.0 C |": a bare setpoint item whose value is the supply setpoint's
        if change_key == "supply" and _BARE_SETPOINT.match(c.text):
            if any(ctx.matches(m, quantity, x) for m in ctx.numbers_in(c.start, c.end) for x in setpoints):
                return True
    return False


# --- direction ----------------------------------------------------------------------------------

_DIM_PATTERNS = (("supply", tx.SUPPLY_SETPOINT), ("dp", tx.DP), ("tower", tx.TOWER_SETPOINT), ("flow", tx.FLOW))


def direction_claims(
    ctx: Context, clause: tx.Clause, include_valves: bool = True, valve_context: bool = False
) -> list[tuple[str, str, int]]:
    """(dimension, up|down|hold, position) claims of one clause; dimension "valve:j" for branch j. Branch
    mentions are valves when the clause (or, with ``valve_context``, its sentence) talks about valves."""
    text = clause.text
    if not tx.ANY_DIRECTION.search(text):
        return []
    branches = ctx.branches_in(clause.start, clause.end)
    dims: list[tuple[str, int, int]] = []  # (dimension, start, end) relative to the clause
    for name, pattern in _DIM_PATTERNS:
        if name == "flow" and branches:
            continue  # "more flow to branch 2" is the valve split
        dims += [(name, m.start(), m.end()) for m in pattern.finditer(text)]
    single = len(branches) == 1
    valves = valve_context or tx.VALVE.search(text) or tx.VALVE_MORE.search(text) or tx.VALVE_LESS.search(text)
    if include_valves and valves:
        dims += [(f"valve:{ctx.entity(b)}", b.start - clause.start, b.end - clause.start) for b in branches]
    if not dims:
        return []
    best: dict[str, tuple[int, str, int, int]] = {}  # dimension -> (words away, polarity, word at, dimension at)
    # "la válvula más abierta", "the most open valve": a ranking, not a change
    ranked = [(r.start(), r.end()) for _, _, sup in tx.SUPERLATIVES for r in sup.finditer(text)]
    for pol, side, pattern in tx.DIRECTION:
        for w in pattern.finditer(text):
            if any(a <= w.start() < z for a, z in ranked):
                continue
            if tx.NEGATION.search(text[max(0, w.start() - 15) : w.start()]) and not tx.NEGATED_HOLD.match(w.group()):
                continue  # "was not raised" claims no direction; "did not change" is a hold word itself
            if pol == "hold" and any(r.start() - w.end() <= 6 and r.start() >= w.end() for r in _superlatives(text)):
                continue  # "la branche 2 reste la plus chargée": it stays the most loaded, nothing about its valve
            if side == "both" and tx.PASSIVE_AUX.search(text[max(0, w.start() - 25) : w.start()]):
                side = "before"  # "the setpoint was raised": the dimension comes first
            _associate(text, w.start(), w.end(), pol, side, dims, best, single)
    for pol, pattern in (("up", tx.VALVE_MORE), ("down", tx.VALVE_LESS)):
        for w in pattern.finditer(text):
            valve_dims = [d for d in dims if d[0].startswith("valve:")]
            _associate(text, w.start(), w.end(), pol, "both", valve_dims, best, single)
    for b in branches:  # "branches 1 and 3 were cut to 0.37 and 0.37": the list's word is said of each member
        name = f"valve:{ctx.entity(b)}"
        if name in best and best[name][3] == b.start - clause.start:
            for x in branches:
                if x.group == b.group >= 0:
                    best.setdefault(f"valve:{ctx.entity(x)}", best[name])
    return [(dim, pol, clause.start + pos) for dim, (_, pol, pos, _) in best.items()]


# a list of settings separated by commas, bullets or "and": a direction word belongs to its own item
_SEGMENT_BREAK = re.compile(r"[,;·|]|\)|\b(?:and|und|y|et|e|sowie)\b", re.IGNORECASE)


def _superlatives(text: str) -> list[re.Match]:
    return [r for _, _, sup in tx.SUPERLATIVES for r in sup.finditer(text)]


def _associate(text, w0, w1, pol, side, dims, best, single_branch: bool = False) -> None:
    """Give a direction word to the nearest dimension on its side, at most 6 words away and not past the fans, pumps
    or blades an effect is said of; in a clause about one branch, its valve takes the word at that limit ("Branch 1,
    the coolest ..., had its valve raised")."""
    candidates = []
    for name, d0, d1 in dims:
        far = 6 if single_branch and name.startswith("valve:") else None
        if d0 >= w1 and side in ("after", "both"):
            dist, gap = tx.words_between(text, w1, d0), (w1, d0)
        elif d1 <= w0 and side in ("before", "both"):
            dist, gap = tx.words_between(text, d1, w0), (d1, w0)
        else:
            continue
        if tx.EFFECT_SUBJECT.search(text, *gap):
            continue  # "the setpoint lets the tower fans ease off": the fans' direction
        # "Vorlauf-Soll auf 29,6 °C angehoben, Δp 27,5 psi": the word belongs to its own list item first
        across = bool(_SEGMENT_BREAK.search(text, *gap))
        if across:
            dist += 4  # across a list break only when nothing in its own item is near
        candidates.append((across, dist if far is None else min(dist, far), name, d0))
    if not candidates:
        return
    _, dist, name, d0 = min(candidates)
    if dist <= 6 and (name not in best or dist < best[name][0]):
        best[name] = (dist, pol, w0, d0)


def check_direction(ctx: Context) -> tuple[int, int, list[Flag]]:
    """(checked, consistent, flags) over the claims about this action."""
    checked = consistent = 0
    flags: list[Flag] = []
    for s in ctx.sentences:
        if "RECOMMENDATION" in s.section:
            continue
        valve_context = bool(tx.VALVE.search(s.text)) or "VALVE" in s.heading
        if s.text.rstrip().endswith("?"):
            continue  # a question ("why not give it more flow?") claims nothing about the action
        for clause in s.clauses:
            if clause.hypothetical:
                continue
            for dim, pol, _ in direction_claims(ctx, clause, valve_context=valve_context):
                expected = _expected(ctx, dim, clause.text)
                if expected is None or (pol == "hold" and expected[1] == "equal split"):
                    continue
                checked += 1
                if pol == expected[0]:
                    consistent += 1
                    ctx.claim("change", clause.text.strip(), entity=_dim_name(ctx, dim), sign=_SIGN[pol]).holds(
                        f"{_dim_name(ctx, dim)} went {expected[0]} ({expected[1]})")
                else:
                    what = _dim_name(ctx, dim)
                    flags.append(ctx.fail("change", "wrong_direction", f"'{clause.text.strip()}' says {pol} but the "
                                          f"{what} went {expected[0]} ({expected[1]})", clause.text.strip(),
                                          entity=what, sign=_SIGN[pol]))  # fmt: skip
    return checked, consistent, flags


_SIGN = {"up": 1, "down": -1, "hold": 0}


def _dim_name(ctx: Context, dim: str) -> str:
    return f"valve of {ctx.label(int(dim.split(':')[1]))}" if dim.startswith("valve:") else f"{dim} setpoint"


def _expected(ctx: Context, dim: str, clause: str) -> tuple[str, str] | None:
    rec, band = ctx.rec, ctx.cfg.hold_band
    if dim.startswith("valve:"):
        j = int(dim.split(":")[1])
        if rec.valves is None or not 0 <= j < rec.valves.size:
            return None
        if tx.RELATIVE_TO_LOAD.search(clause) and rec.powers_w is not None and rec.powers_w.sum() > 0:
            delta, ref = rec.valves[j] - rec.powers_w[j] / rec.powers_w.sum(), "load share"
        elif tx.RELATIVE_TO_OTHERS.search(clause) or rec.valve_changes is None:
            delta, ref = rec.valves[j] - 1.0 / rec.valves.size, "equal split"
        else:
            delta, ref = rec.valve_changes[j], "previous action"
        if ref == "previous action" and _at_band_edge(float(delta), band["valve"]):
            return None
        return _polarity(float(delta), band["valve"]), ref
    change = rec.changes.get(dim)
    if change is not None:
        return None if _at_band_edge(change, band[dim]) else (_polarity(change, band[dim]), "previous action")
    now = {"flow": rec.flow_kg_s, "dp": rec.dp_pa}.get(dim)
    if now is not None and dim in rec.observed:
        return _polarity(now - rec.observed[dim], band[dim]), "observation"
    return None


def _at_band_edge(delta: float, band: float) -> bool:
    """A change within 2 % of the dead band's edge: its rounding decides hold or move, so neither claim is checkable
    (a writer rounding to 3 decimals and a record rounded to 4 can fall on opposite sides)."""
    return abs(abs(delta) - band) <= 0.02 * band


def _polarity(delta: float, band: float) -> str:
    return "up" if delta > band else "down" if delta < -band else "hold"
