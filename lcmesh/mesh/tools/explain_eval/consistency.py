"""Claims checked against the record's data and the plant's physics: ranking, physics, bounds.

- ranking: "branch 2 runs hottest / carries the most load / has the largest valve fraction" and
  "branch 1 is hotter than branch 3" against the observation (ties within tolerance pass).
- physics: a cause (a setpoint, flow, dp or valve moving one way) followed by an effect that
  contradicts the plant: a lower supply setpoint or more flow warming the blades, a higher leaving-water
  setpoint costing fan power, less flow costing pump power, tower water below the wet bulb.
- bounds: valve fractions outside [0, 1] or not summing to 1, setpoints outside ``EvalConfig.bounds``,
  a leaving-water setpoint below the wet bulb, a branch that does not exist, a fraction over 1 in text;
  the same limits on the action as the text states it (a setpoint named as such, the valve fractions it gives
  every branch, "all four branches").
"""

from __future__ import annotations

import re

import numpy as np

from lcmesh.mesh.tools.explain_eval import text as tx
from lcmesh.mesh.tools import vocab
from lcmesh.mesh.tools.claims import Flag
from lcmesh.mesh.tools.explain_eval.actions import Context, direction_claims
from lcmesh.mesh.tools.explain_eval.grounding import _CLAUSE_END, DIFF_CUE, _topic_of
from lcmesh.mesh.tools.explain_eval.numbers import K0, PSI_TO_PA


# --- ranking ------------------------------------------------------------------------------------


def check_ranking(ctx: Context) -> list[Flag]:
    rec, flags = ctx.rec, []
    data = {"temp": rec.temps_k, "load": rec.powers_w, "valve": rec.valves}
    for s in ctx.sentences:
        mentions = ctx.branches_in(s.start, s.end)
        if not mentions or s.text.rstrip().endswith("?"):
            continue  # a question ranks nothing ("¿cuál está más fría, la primera o la tercera?")
        for what, extreme, pattern in tx.SUPERLATIVES:
            values = data[what]
            for w in pattern.finditer(s.text):
                if _NOT_ONE.match(s.text, w.end()) or re.search(r"\b(?:between|entre|zwischen)\s+(?:the\s+|la\s+|le\s+|"
                                                                   r"dem\s+)?$", s.text[: w.start()], re.I):
                    continue
                b = _nearest(ctx, s, mentions, s.start + w.start(), s.start + w.end())
                if values is None or b is None or not 0 <= ctx.entity(b) < values.size:
                    continue
                j = ctx.entity(b)
                best = int(values.argmax() if extreme == "max" else values.argmin())
                if what == "valve" and values.size > 1 and float(np.ptp(values)) < 1e-9:
                    flags.append(ctx.fail("rank", "wrong_ranking", f"'{s.text.strip()}': the valves are split equally, no branch has "
                                                   f"the {_RANK_NAMES[what, extreme].removeprefix('branch with the ')}"))
                elif abs(values[j] - values[best]) > _rank_tol(ctx, what, values):
                    flags.append(ctx.fail("rank", "wrong_ranking", f"'{s.text.strip()}': {ctx.label(j)} is not the "
                                          f"{_RANK_NAMES[what, extreme]} ({ctx.label(best)} is)", s.text.strip(),
                                          entity=ctx.label(j), quantity=what))  # fmt: skip
                else:
                    ctx.claim("rank", s.text.strip(), entity=ctx.label(j), quantity=what).holds(
                        f"{ctx.label(j)} is the {_RANK_NAMES[what, extreme]}")
        flags += _comparatives(ctx, s, mentions, data)
    return flags


_RANK_NAMES = {("temp", "max"): "hottest", ("temp", "min"): "coolest", ("load", "max"): "most loaded",
               ("load", "min"): "least loaded", ("valve", "max"): "branch with the largest valve fraction",
               ("valve", "min"): "branch with the smallest valve fraction"}  # fmt: skip


def _rank_tol(ctx: Context, what: str, values: np.ndarray) -> float:
    if what == "temp":
        return ctx.cfg.rank_temp_tol_k
    if what == "valve":
        return ctx.cfg.fraction_tol
    return ctx.cfg.rel_tol * float(np.abs(values).max())


_NEXT_PHRASE = re.compile(r"[,;]|\b(?:and|und|y|e|et|while|whereas|mientras|während|tandis|sowie)\b", re.I)


def _nearest(ctx: Context, s: tx.Sentence, mentions, w0: int, w1: int) -> tx.BranchMention | None:
    """The branch a superlative is said of: the nearest mention in its clause (12 words), else the sentence's
    last mention before it (its subject, 25 words), else a mention right after it (3 words)."""
    clause = next((c for c in s.clauses if c.start <= w0 < c.end), None)
    text = ctx.rec.text

    def dist(b: tx.BranchMention) -> int:
        return tx.words_between(text, b.end, w0) if b.end <= w0 else tx.words_between(text, w1, b.start)

    named = _IS_NAMED.match(text, w1)  # "the hottest is branch 2", "la plus chargée est la branche 3"
    if named:
        after = [b for b in mentions if b.start >= named.end() and tx.words_between(text, named.end(), b.start) <= 1]
        if after:
            return after[0]
    # a mention after the superlative behind "and" / "und" / "y" / "et" or a comma opens the next phrase: "Zweig 2 mit
    # 27,1 °C der kühlste und Zweig 3 der wärmste" ranks Zweig 2 coolest
    in_clause = [b for b in mentions if clause is not None and clause.start <= b.start < clause.end and dist(b) <= 12]
    same = [b for b in in_clause if not (b.start >= w1 and _NEXT_PHRASE.search(text, w1, b.start))]
    if not any(b.end <= w0 for b in same):  # "the most loaded of them, branch 3, takes": an apposition
        same = same or [b for b in in_clause if b.start >= w1 and dist(b) <= 4]
    if same:
        return min(same, key=dist)
    before = [b for b in mentions if b.end <= w0 and dist(b) <= 25]
    if before:
        return before[-1]
    after = [b for b in mentions if b.start >= w1 and dist(b) <= 3 and not _NEXT_PHRASE.search(text, w1, b.start)]
    return after[0] if after else None


_IS_NAMED = re.compile(r"\s*(?:[\w-]+\s*)?(?:(?:is|was|es|era|est|ist|war)\b|[:=])", re.I)  # "la más fría: la 3"
# "the hottest and coolest blades", "between the hottest and the coolest": no one branch is ranked
_NOT_ONE = re.compile(r"^\s*(?:and|y|und|et)\s+(?:the\s+|la\s+|le\s+|die\s+|der\s+)?\w+\s+(?:blades|branches|ramas|"
                      r"zweige|branches|ones)\b|^\s+(?:blades|branches|ones|ramas|zweige)\b", re.I)


def _comparatives(ctx: Context, s: tx.Sentence, mentions, data) -> list[Flag]:
    flags = []
    text = ctx.rec.text
    for what, op, pattern in tx.COMPARATIVES:
        values = data[what]
        if values is None:
            continue
        for w in pattern.finditer(s.text):
            w0, w1 = s.start + w.start(), s.start + w.end()
            than = tx.THAN.search(text, w1, s.end)
            left = [b for b in mentions if b.end <= w0 and tx.words_between(text, b.end, w0) <= 6]
            if than is None or not left or tx.words_between(text, w1, than.start()) > 3:
                continue
            right = [b for b in mentions if b.start >= than.end() and tx.words_between(text, than.end(), b.start) <= 2]
            if not right:
                continue
            a, b = ctx.entity(left[-1]), ctx.entity(right[0])
            if not (0 <= a < values.size and 0 <= b < values.size):
                continue
            diff = values[a] - values[b] if op == "gt" else values[b] - values[a]
            claim = ctx.claim("rank", s.text.strip(), entity=ctx.label(a), quantity=what)
            if diff < -_rank_tol(ctx, what, values):
                flags.append(claim.fails("wrong_ranking", f"'{s.text.strip()}': {ctx.label(a)} is not "
                                         f"{w.group().lower()} than {ctx.label(b)}").flag)  # fmt: skip
            else:
                claim.holds(f"{ctx.label(a)} is {w.group().lower()} than {ctx.label(b)}")
    return flags


# --- physics ------------------------------------------------------------------------------------

# cause (dimension, direction) -> expected effect direction per target
_EXPECT = {
    ("supply", "up"): {"temp": "up", "fan": "down", "energy": "down"},
    ("supply", "down"): {"temp": "down", "fan": "up", "energy": "up"},
    ("flow", "up"): {"temp": "down", "pump": "up", "energy": "up"},
    ("flow", "down"): {"temp": "up", "pump": "down", "energy": "down"},
    ("valve", "up"): {"temp": "down", "pump": "up"},
    ("valve", "down"): {"temp": "up", "pump": "down"},
    ("tower", "up"): {"fan": "down", "energy": "down", "temp": "up"},
    ("tower", "down"): {"fan": "up", "energy": "up", "temp": "down"},
}  # fmt: skip
_SUPPLY_CAUSE = re.compile(
    tx.SUPPLY_SETPOINT.pattern + r"|supply(?:[\s-]+(?:water|coolant))?[\s-]+temperature|coolant[\s-]+temperature"
    r"|\bsupply\b|" + tx.SUPPLY_ANY.pattern,
    re.I,
)
_CAUSE_PATTERNS = (("supply", _SUPPLY_CAUSE),
                   ("flow", re.compile(tx.FLOW.pattern + "|" + tx.DP.pattern, re.I)),
                   ("tower", tx.TOWER_SETPOINT))  # fmt: skip
_OPEN = re.compile(r"\b(?:open(?:s|ed|ing)?|widen(?:s|ed|ing)?|abr(?:ir|e|ió|iera|iendo)|abiert[oa]|ouvr\w*|ouverte?"
                   r"|öffn\w*|geöffnete?[nrs]?)\b(?!\s+(?:loop|circuit))", re.I)
_CLOSE = re.compile(r"\b(?:clos(?:e|es|ed|ing)|throttl(?:e|es|ed|ing)|narrow(?:s|ed|ing)?|cerr\w*|ferm\w*|schließ\w*"
                    r"|geschlossene?[nrs]?|drossel\w*|gedrosselt)\b", re.I)


# a cause reaches an effect within its part of the sentence: not across ";" or "while / während / mientras / tandis"
_CAUSE_BREAK = re.compile(r";|\b(?:while|whereas|während|mientras|tandis|alors\s+que|aunque|obwohl|although)\b", re.I)


def check_physics(ctx: Context) -> list[Flag]:
    flags = []
    for s in ctx.sentences:
        t = s.text
        if tx.BELOW_WET_BULB.search(t) and not tx.NEGATION.search(t):
            flags.append(ctx.fail("cause", "physics", f"'{t.strip()}': a wet tower cannot cool water below the wet bulb"))
        effects = []  # (target, up|down, effect start, target start, target end)
        for target, pattern in tx.TARGETS.items():
            for m in pattern.finditer(t):
                kind = {"temp": "temp", "branch": "heat"}.get(target, "power")
                effect = _effect_direction(t, m.start(), m.end(), kind)
                if effect is not None:
                    effects.append(("temp" if target == "branch" else target, effect[0], effect[1], m.start(), m.end()))
        causes = _causes(ctx, s) if effects else []
        for target, pol, e0, m0, m1 in effects if causes else []:
            if any(c[2] <= m0 < c[3] for c in causes):
                continue  # "supply temperature" is the cause here, not the effect
            first = min(e0, m0)
            before = [c for c in causes if c[3] <= first and not _CAUSE_BREAK.search(t, c[3], first)]
            if not before or tx.REASON.search(t[before[-1][3] : first]):
                continue
            dim, cpol = before[-1][:2]
            want = _EXPECT.get((dim, cpol), {}).get(target)
            what = target if target != "temp" else "blade temperature"
            if want is not None and want != pol:
                flags.append(ctx.fail("cause", "physics", f"'{t.strip()}': {_cause_text(dim, cpol)} should make the "
                                      f"{what} go {want}, not {pol}", t.strip(), quantity=what))  # fmt: skip
            elif want is not None:
                ctx.claim("cause", t.strip(), quantity=what).holds(f"{_cause_text(dim, cpol)} makes the {what} go {want}")
    return flags


def _cause_text(dim: str, pol: str) -> str:
    word = {"up": "raising", "down": "lowering"}[pol]
    return {"supply": f"{word} the supply setpoint", "flow": f"{'more' if pol == 'up' else 'less'} flow",
            "valve": f"{'opening' if pol == 'up' else 'closing'} a valve",
            "tower": f"{word} the leaving-water setpoint"}[dim]  # fmt: skip


def _causes(ctx: Context, s: tx.Sentence) -> list[tuple[str, str, int, int]]:
    """(dimension, up|down, start, end) in sentence coordinates, ordered by position."""
    t = s.text
    claims = direction_claims(ctx, tx.Clause(s.start, s.end, t, False), include_valves=False)
    claimed = [({"dp": "flow"}.get(d, d), p, pos - s.start) for d, p, pos in claims if p != "hold"]
    out = []
    for dim, pattern in _CAUSE_PATTERNS:
        for m in pattern.finditer(t):
            before, after = t[max(0, m.start() - 30) : m.start()], t[m.end() : m.end() + 30]
            if tx.CAUSE_ADJ_UP.search(before) or tx.CAUSE_AFTER_UP.match(after):
                pol = "up"
            elif tx.CAUSE_ADJ_DOWN.search(before) or tx.CAUSE_AFTER_DOWN.match(after):
                pol = "down"
            else:
                near = [p for d, p, pos in claimed if d == dim and abs(pos - m.start()) < 80]
                pol = near[0] if near else None
            if pol is not None:
                out.append((dim, pol, m.start(), m.end()))
    for m in list(_OPEN.finditer(t)) + list(_CLOSE.finditer(t)):
        if ctx.branches_in(s.start + m.end(), s.start + m.end() + 40) or tx.VALVE.search(t[m.end() : m.end() + 30]):
            out.append(("valve", "up" if _OPEN.fullmatch(m.group()) else "down", m.start(), m.end()))
    return sorted(out, key=lambda c: c[2])


def _effect_direction(t: str, a: int, b: int, kind: str) -> tuple[str, int] | None:
    """Direction word within five words of a target (before or after it), not across "but" or a comma."""
    best = None
    for pol, table in (("up", tx.EFFECT_UP), ("down", tx.EFFECT_DOWN)):
        for w in table[kind].finditer(t):
            if w.end() <= a:
                dist, gap = tx.words_between(t, w.end(), a), (w.end(), a)
            elif w.start() >= b:
                dist, gap = tx.words_between(t, b, w.start()), (b, w.start())
            else:
                continue
            if tx.EFFECT_BREAK.search(t, *gap):
                continue
            if dist <= 5 and (best is None or dist < best[0]):
                best = (dist, pol, w.start())
    return None if best is None else (best[1], best[2])


# --- bounds -------------------------------------------------------------------------------------


_OTHER_SETTING = re.compile(tx.SUPPLY_ANY.pattern + "|" + tx.DP.pattern + "|" + tx.TOWER.pattern + "|" + tx.FLOW.pattern,
                            re.I)  # fmt: skip
_VALVE_BEFORE = re.compile(r"(?:" + tx.VALVE.pattern + r")[^.;]{0,40}$", re.I)  # a valve word in any of the four


def check_bounds(ctx: Context) -> list[Flag]:
    rec, b = ctx.rec, ctx.cfg.bounds
    flags: list[Flag] = []
    if rec.valves is not None:
        bad = [f"{v:.3f}" for v in rec.valves if v < -1e-9 or v > 1 + 1e-9]
        if bad:
            flags.append(ctx.fail("bound", "out_of_bounds", f"valve fractions {', '.join(bad)} lie outside [0, 1]"))
        if abs(rec.valves.sum() - 1.0) > b.valve_sum_tol:
            flags.append(ctx.fail("bound", "out_of_bounds", f"valve fractions sum to {rec.valves.sum():.3f}, not 1"))
    for name, value, (lo, hi), unit in (
        ("supply setpoint", None if rec.supply_k is None else rec.supply_k - K0, b.supply_setpoint_c, "°C"),
        ("dp setpoint", None if rec.dp_pa is None else rec.dp_pa / PSI_TO_PA, b.dp_psi, "psi"),
        ("flow", rec.flow_kg_s, b.flow_kg_s, "kg/s"),
        ("leaving-water setpoint", None if rec.lw_k is None else rec.lw_k - K0, b.lw_setpoint_c, "°C"),
    ):
        if value is not None and not lo <= value <= hi and not (name == "flow" and value == lo == 0):
            flags.append(ctx.fail("bound", "out_of_bounds", f"{name} {value:.2f} {unit} lies outside [{lo:g}, {hi:g}] {unit}"))
    if rec.flow_kg_s is not None and rec.flow_kg_s <= 0:
        flags.append(ctx.fail("bound", "out_of_bounds", f"flow {rec.flow_kg_s:.2f} kg/s must be > 0"))
    if rec.lw_k is not None and rec.wet_bulb_k is not None and rec.lw_k < rec.wet_bulb_k:
        flags.append(ctx.fail("bound", "out_of_bounds", f"leaving-water setpoint {rec.lw_k - K0:.1f} °C is below the "
                                       f"{rec.wet_bulb_k - K0:.1f} °C wet bulb"))  # fmt: skip
    n = rec.n_branches
    for bm in ctx.branches:
        if n and not 0 <= ctx.entity(bm) < n:
            flags.append(ctx.fail("bound", "out_of_bounds", f"branch {bm.raw} does not exist ({n} branches, numbered from {ctx.base})"))
    for s in ctx.sentences:
        for c in s.clauses:
            if not tx.VALVE.search(c.text):
                continue
            for m in ctx.numbers_in(c.start, c.end):
                before = ctx.rec.text[c.start : m.start]
                if not _VALVE_BEFORE.search(before) or _OTHER_SETTING.search(before[list(tx.VALVE.finditer(before))[-1].end():]):
                    continue  # "Vlv = (1/3), supply setpoint 30 =, dp 27.5 =": 27.5 is the dp's
                over = (m.unit == "" and m.decimals > 0 and m.value > 1.0) or (m.unit == "%" and m.value > 100)
                if over or (m.unit in ("", "%") and m.value < 0):
                    flags.append(ctx.fail("bound", "out_of_bounds", f"'{m.text}{'%' if m.unit == '%' else ''}' in '{c.text.strip()}'"
                                                   " is not a valid valve fraction"))  # fmt: skip
    return flags + _stated_setpoints(ctx) + _stated_valves(ctx) + _stated_branch_count(ctx)


def _stated(ctx: Context, m, detail: str) -> Flag:
    """A value the text gives for a setting, outside its range: one failed claim at the number (grounding does not
    flag the same number again)."""
    return ctx.fail("bound", "out_of_bounds", detail, ctx.rec.text[m.start : m.unit_end if m.unit_end > 0 else m.end],
                    start=m.start, end=m.end)


def _stated_setpoints(ctx: Context) -> list[Flag]:
    """A temperature named as the supply or leaving-water setpoint (grounding's naming rule) or a pressure in a
    clause naming the dp, outside its range (or, for the leaving water, below the record's wet bulb)."""
    b, flags = ctx.cfg.bounds, []
    wet_bulb_c = None if ctx.rec.wet_bulb_k is None else ctx.rec.wet_bulb_k - K0
    for m in ctx.numbers:
        if m.role != "measure" or _CHANGE_BEFORE.search(ctx.rec.text, max(0, m.start - 12), m.start):
            continue  # "raised by 0.2 °F" is a change, not a setpoint
        if _unit_mixup(ctx, m):
            continue  # "25.2 °F" where the data has 25.2 °C: grounding reports the confused unit
        quote = ctx.rec.text[m.start : m.unit_end if m.unit_end > 0 else m.end]
        if m.unit in ("degC", "degF"):
            c = next(x for q, x, _ in m.interpretations if q == "temp_abs") - K0
            ulp = m.half_ulp * (5 / 9 if m.unit == "degF" else 1.0) + 1e-6  # "64.4 °F" is the 18 °C edge, as written
            topic = _topic_of(ctx.rec.text, m)
            if topic == "supply_setpoint" and not b.supply_setpoint_c[0] - ulp <= c <= b.supply_setpoint_c[1] + ulp:
                flags.append(_stated(ctx, m, f"'{quote}' is given as the supply setpoint, outside "
                                               f"[{b.supply_setpoint_c[0]:g}, {b.supply_setpoint_c[1]:g}] °C"))
            elif topic == "lw_setpoint" and not b.lw_setpoint_c[0] - ulp <= c <= b.lw_setpoint_c[1] + ulp:
                flags.append(_stated(ctx, m, f"'{quote}' is given as the leaving-water setpoint, outside "
                                               f"[{b.lw_setpoint_c[0]:g}, {b.lw_setpoint_c[1]:g}] °C"))
            elif topic == "lw_setpoint" and wet_bulb_c is not None and c < wet_bulb_c - ulp:
                flags.append(_stated(ctx, m, f"'{quote}' is given as the leaving-water setpoint, below the "
                                               f"{wet_bulb_c:.1f} °C wet bulb"))  # fmt: skip
            elif topic in ("supply_setpoint", "lw_setpoint"):
                ctx.claim("bound", quote, quantity=topic, value=c, unit="degC").holds("the plant's limits")
        elif m.unit and m.unit not in ("", "%") and any(q == "flow" for q, _, _ in m.interpretations):
            kg_s = next(x for q, x, _ in m.interpretations if q == "flow")
            lo, hi = b.flow_kg_s
            if not lo < kg_s <= hi * (1 + 1e-9) + m.half_ulp:
                flags.append(_stated(ctx, m, f"'{quote}' is given as a flow, outside ({lo:g}, {hi:g}] kg/s"))
        elif any(q == "pressure" for q, _, _ in m.interpretations) and m.unit:
            psi = next(x for q, x, _ in m.interpretations if q == "pressure") / PSI_TO_PA
            names = list(tx.DP.finditer(_clause_before(ctx, m.start)))
            between = _clause_before(ctx, m.start)[names[-1].end() :] if names else ""
            ulp = m.half_ulp * psi / m.value + 1e-6 if m.value else 1e-6
            if names and not DIFF_CUE.search(between) and not b.dp_psi[0] - ulp <= psi <= b.dp_psi[1] + ulp:
                flags.append(_stated(ctx, m, f"'{quote}' is given as the dp setpoint, outside "
                                               f"[{b.dp_psi[0]:g}, {b.dp_psi[1]:g}] psi"))  # fmt: skip
    return flags


_CHANGE_BEFORE = re.compile(r"(?:\bby|\bum|[+±Δ]|" + tx.ANY_DIRECTION.pattern + r")\s*$", re.I)


def _unit_mixup(ctx: Context, m) -> bool:
    """True when the digits as written are a temperature (pressure) of the data in another temperature (pressure)
    unit: "25.2 °F" where the data has 25.2 °C."""
    if m.unit not in ("degC", "degF", "K") and not any(q == "pressure" for q, _, _ in m.interpretations):
        return False  # a flow or a power: no other unit of the same kind to confuse it with here
    if m.unit in ("degC", "degF"):
        shown = [f(e.value) for e in ctx.pool.entries.get("temp_abs", [])
                 for u, f in (("degC", lambda k: k - K0), ("K", lambda k: k), ("degF", lambda k: k * 9 / 5 - 459.67))
                 if u != m.unit]  # fmt: skip
    else:
        own = next((x for q, x, _ in m.interpretations if q == "pressure"), 0.0) / m.value if m.value else 0.0
        shown = [e.value / f for e in ctx.pool.entries.get("pressure", []) for f in (PSI_TO_PA, 1000.0, 1e5)
                 if abs(f - own) > 1e-6 * f]
    return any(abs(m.value - x) <= m.half_ulp * 1.0001 for x in shown)


def _clause_before(ctx: Context, pos: int) -> str:
    """The text before ``pos`` back to the last sentence or clause end (";", "|", a line end), as in grounding."""
    text = ctx.rec.text
    start = max((x.end() for x in _CLAUSE_END.finditer(text, 0, pos)), default=0)
    return text[start:pos]


_FRACTION_JOIN = re.compile(r"\s*(?:/|,|,?\s*and)\s*")


def _stated_valves(ctx: Context) -> list[Flag]:
    """Valve fractions the text gives that sum to more than the whole flow: a list of one per branch ("valves
    0.33/0.34/0.53"), or those said after each "branch j" in valve sentences (not a change "by 0.05") when even the
    smallest choice of one per branch does."""
    n = ctx.rec.n_branches
    if not n:
        return []
    given: dict[int, set[float]] = {}
    text = ctx.rec.text
    tol = ctx.cfg.bounds.valve_sum_tol + 0.005 * n  # each stated fraction is rounded
    for s in ctx.sentences:
        if not (tx.VALVE.search(s.text) or "VALVE" in s.heading):
            continue
        fractions = [m for m in ctx.numbers_in(s.start, s.end) if m.unit == "" and m.decimals >= 2 and 0 <= m.value <= 1
                     and not _CHANGE_BEFORE.search(text, max(0, m.start - 12), m.start)]  # fmt: skip
        for c in s.clauses:
            run = [m for m in fractions if c.start <= m.start < c.end]
            if len(run) == n and not ctx.branches_in(c.start, c.end) and all(
                    _FRACTION_JOIN.fullmatch(text, a.end, z.start) for a, z in zip(run, run[1:])):
                if sum(m.value for m in run) > 1.0 + tol:  # one list, one split
                    return [ctx.fail("bound", "out_of_bounds", f"the valve fractions '{text[run[0].start : run[-1].end]}' "
                                     "sum to more than 1", start=run[0].start, end=run[-1].end)]
        mentions = ctx.branches_in(s.start, s.end)
        each = [m for m in ctx.numbers_in(s.start, s.end) if m.unit == "" and m.decimals >= 1 and 0 <= m.value <= 1]
        if not mentions and tx.EACH.search(s.text) and len({m.value for m in each}) == 1 and each[0].value * n > 1.0 + tol:
            fractions = each
            return [ctx.fail("bound", "out_of_bounds", f"'{fractions[0].text}' for each of {n} valves sums to "
                             f"{fractions[0].value * n:.2f}, more than 1", start=fractions[0].start,
                             end=fractions[0].end)]  # fmt: skip
        for bm in mentions:
            j = ctx.entity(bm)
            if not 0 <= j < n:
                continue
            a, z = ctx.span_of(bm, s)
            group = [x for x in ctx.branches if bm.group >= 0 and x.group == bm.group]
            if len(group) > 1:  # "valves 2 and 3 trimmed to 0.335 and 0.327": one each, in order
                inside = [m for m in fractions if a <= m.start < z]
                if len(inside) == len(group) and group.index(bm) < len(inside):
                    given.setdefault(j, set()).add(inside[group.index(bm)].value)
                continue
            for m in fractions:
                if a <= m.start < z:
                    given.setdefault(j, set()).add(m.value)
    if len(given) < n or n < 2:
        return []
    smallest = sum(min(given[j]) for j in range(n))
    if smallest <= 1.0 + tol:
        return []
    shown = ", ".join("/".join(f"{v:g}" for v in sorted(given[j])) for j in range(n))
    return [ctx.fail("bound", "out_of_bounds", f"the valve fractions the text gives ({shown}) sum to more than 1")]


_COUNT_WORDS = vocab.COUNT_WORDS
_BRANCH_COUNT = re.compile(r"(?<![\d.,])\b(?P<n>\d+|" + "|".join(_COUNT_WORDS) + r")\s+"
                           r"(?:branches|ramas|zweige|str[äa]nge|blade[\s-]groups|grupos)\b", re.I)  # fmt: skip


def _stated_branch_count(ctx: Context) -> list[Flag]:
    """More branches than the cabinet has, as a count: "the valves stay at 0.33 on all four branches"."""
    n = ctx.rec.n_branches
    flags = []
    for m in _BRANCH_COUNT.finditer(ctx.rec.text) if n else ():
        k = m.group("n").lower()
        count = int(k) if k.isdigit() else _COUNT_WORDS[k]
        if count > n and not re.search(r"\bof\s*$", ctx.rec.text[max(0, m.start() - 6) : m.start()]):
            flags.append(ctx.fail("bound", "out_of_bounds", f"'{m.group()}': the cabinet has {n} branches"))
    return flags
