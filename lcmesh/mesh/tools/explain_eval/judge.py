r"""The explanation judge: a text read into claims once, each claim verified against the decision's facts.

``evaluate_record`` normalizes the text (``text.py``), reads its numbers (``numbers.py``) and builds the record's
facts (``record.py``); the checks (``grounding.py``: numbers; ``actions.py``: coverage and directions;
``consistency.py``: rankings, physics, bounds) each turn what they read into ``claims.Claim``\ s with a verdict.
An item lists its claims, its flags (the failed claims, plus missing dimensions and sections) and its scores.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from lcmesh.mesh.tools import vocab
from lcmesh.mesh.tools.claims import Flag
from lcmesh.mesh.tools.explain_eval import text as tx
from lcmesh.mesh.tools.explain_eval.actions import (
    Context, check_coverage, check_direction, check_valve_lists,
)  # fmt: skip
from lcmesh.mesh.tools.explain_eval.consistency import check_bounds, check_physics, check_ranking
from lcmesh.mesh.tools.explain_eval.grounding import _TOPIC_NAMES, ValuePool, check_grounding
from lcmesh.mesh.tools.explain_eval.numbers import extract_numbers
from lcmesh.mesh.tools.explain_eval.record import EvalConfig, RawRecord, build_record, validation_message
from lcmesh.mesh.tools.explain_eval.report import aggregate

LEVEL_SECTIONS: dict[str, tuple[str, ...]] = {
    "short": ("EXPLANATION", "TEMPERATURE IMPACT", "ENERGY EFFICIENCY IMPACT"),
    "detailed": ("EXECUTIVE SUMMARY", "TEMPERATURE STABILITY", "ACTION RATIONALE", "ENERGY EFFICIENCY",
                 "RECOMMENDATIONS"),
    "very_detailed": ("EXECUTIVE SUMMARY", "SYSTEM STATE ANALYSIS", "CABINET CONTROL ANALYSIS",
                      "COOLING TOWER ANALYSIS", "ENERGY EFFICIENCY ANALYSIS", "THERMODYNAMIC IMPLICATIONS",
                      "RECOMMENDATIONS", "SCIENTIFIC INSIGHTS"),
}  # fmt: skip
"""Top-level headings each explanation level must have (LC-Opt Appendix U)."""


def evaluate_record(data: Any, cfg: EvalConfig | None = None, line: int | None = None) -> dict:
    """Score one decoded record; an invalid one becomes an item with an ``invalid_record`` flag."""
    cfg = cfg or EvalConfig()
    where = f"line {line}: " if line is not None else ""
    fallback_id = f"line-{line}" if line is not None else "record"
    if not isinstance(data, dict):
        return _invalid(fallback_id, f"{where}a record must be a JSON object, got {type(data).__name__}")
    try:
        raw = RawRecord.model_validate(data)
    except ValidationError as exc:
        return _invalid(str(data.get("id", fallback_id)), f"{where}{validation_message(exc)}")
    rec = build_record(raw)
    language = vocab.language_of(rec.text)
    if language is None:
        return _not_read(rec.id)
    rec.text = tx.normalize(rec.text, language)
    pool = ValuePool(rec.pool)
    mentions = tx.branch_mentions(rec.text)
    ctx = Context(rec, cfg, tx.sentences(rec.text), extract_numbers(rec.text), mentions,
                  tx.decide_index_base(mentions, rec.n_branches, rec.index_base), pool)  # fmt: skip
    grounding = check_grounding(rec, ctx.numbers, pool, lambda pos: _clause_text(ctx, pos),
                                lambda pos: _branch_at(ctx, pos), cfg, ctx.base,
                                ctx.rounded_starts)  # fmt: skip
    dims, coverage_flags = check_coverage(ctx)
    checked, consistent, direction_flags = check_direction(ctx)
    later = coverage_flags + direction_flags + check_ranking(ctx) + check_bounds(ctx) + check_physics(ctx) \
        + check_valve_lists(ctx)
    # a claim fails once, with its most specific flag: a setpoint the text gives outside the plant's range is
    # out_of_bounds, not also an ungrounded number
    out_of_range = [(c.start, max(c.end, c.start + 1)) for c in ctx.claims
                    if c.relation == "bound" and c.verdict == "fails" and c.start >= 0]  # fmt: skip
    flags = [c.flag for c in grounding.claims if c.flag is not None
             and not any(a <= c.start < z for a, z in out_of_range)] + later  # fmt: skip
    if rec.level is not None:
        found = {s.section for s in ctx.sentences} | _headings(rec.text)
        flags += [Flag("missing_section", f"the {rec.level} level needs a '{h}' section")
                  for h in LEVEL_SECTIONS[rec.level] if h not in found]  # fmt: skip
    claims = sorted(grounding.claims + ctx.claims, key=lambda c: (c.start < 0, c.start))
    return {
        "id": rec.id,
        "language": language,
        "numeric_grounding": grounding.score,
        "coverage": sum(dims.values()) / len(dims) if dims else 1.0,
        "direction_consistency": consistent / checked if checked else 1.0,
        "flags": [{"kind": k, "detail": d} for k, d in _dedupe(flags)],
        "claims": [c.as_dict() for c in claims],
        "numbers": {"checked": grounding.checked, "grounded": grounding.grounded, "derived": grounding.derived,
                    "skipped": grounding.skipped},
        "dimensions": dims,
        "directions": {"checked": checked, "consistent": consistent},
        "index_base": ctx.base,
    }  # fmt: skip


def evaluate_lines(lines: Iterable[str], cfg: EvalConfig | None = None) -> dict:
    """Score JSON lines (blank lines skipped); never raises on bad input."""
    cfg = cfg or EvalConfig()
    items = []
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError as exc:
            items.append(_invalid(f"line-{n}", f"line {n}: not valid JSON ({exc.msg} at column {exc.colno})"))
            continue
        try:
            items.append(evaluate_record(data, cfg, line=n))
        except Exception as exc:  # noqa: BLE001 - one odd record must not stop the run; it is reported
            items.append(_invalid(str(data.get("id", f"line-{n}")) if isinstance(data, dict) else f"line-{n}",
                                  f"line {n}: could not be scored ({type(exc).__name__}: {exc})"))  # fmt: skip
    return {"items": items, "aggregate": aggregate(items)}


def evaluate_file(path: str | Path, cfg: EvalConfig | None = None) -> dict:
    """Score a JSONL file."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        return evaluate_lines(fh, cfg)


def _invalid(record_id: str, detail: str) -> dict:
    return {"id": record_id, "numeric_grounding": 0.0, "coverage": 0.0, "direction_consistency": 0.0,
            "flags": [{"kind": "invalid_record", "detail": detail}]}  # fmt: skip


def _not_read(record_id: str) -> dict:
    """A text in none of the languages the judge reads: reported as such, neither passed nor flagged as wrong."""
    return {"id": record_id, "language": None, "numeric_grounding": 0.0, "coverage": 0.0,
            "direction_consistency": 0.0, "claims": [],
            "flags": [{"kind": "not_read", "detail": "the text is in none of the languages the judge reads "
                                                     "(English, Spanish, German, French); nothing in it was checked"}]}


def _headings(text: str) -> set[str]:
    found = set()
    for line in text.splitlines():
        head = tx.heading_of(line) if line.strip() else None
        if head is not None:
            found.add(head[1].upper())
    return found


def _clause_text(ctx: Context, pos: int) -> str:
    for s in ctx.sentences:
        if s.start <= pos < s.end:
            return next((c.text for c in s.clauses if c.start <= pos < c.end), s.text)
    return ""


# "0.20 for branch 1", "0.20 (branch 1", "0.20 para la rama 1": the number is said of the branch after it
_FOR_BRANCH = re.compile(r"^\s*(?:\S+\s+)?(?:\(\s*|(?:to|on|a|an)\s+" + vocab.ARTICLE + "?|"
                         + vocab.OF_BEFORE_ENTITY.pattern + ")$", re.IGNORECASE)  # fmt: skip


def _branch_at(ctx: Context, pos: int) -> int | None:
    """The branch a number at ``pos`` is said of: "0.20 for branch 1", else "branch 1 ... at 0.20" nearby."""
    for s in ctx.sentences:
        if s.start <= pos < s.end:
            end = next((m.unit_end if m.unit_end > 0 else m.end for m in ctx.numbers if m.start == pos), pos)
            in_list = ctx.rec.text[max(0, pos - 1) : pos] == "/"  # "0.36/0.32/0.32 (branch 1 opened ...)"
            after = [b for b in ctx.branches_in(end, s.end) if _FOR_BRANCH.match(ctx.rec.text[end : b.start])
                     and not (in_list and "(" in ctx.rec.text[end : b.start])]  # fmt: skip
            if after and (after[0].group < 0 or sum(x.group == after[0].group for x in ctx.branches) == 1):
                return ctx.entity(after[0])
            this = next((m for m in ctx.numbers if m.start == pos), None)
            if this is not None and _opens_list(ctx, this):
                return None  # "the loads are 3.0 kW, 84.7 kW, 15.3 kW": a list of values, one per branch
            for b in ctx.branches_in(s.start, s.end):
                a, z = ctx.span_of(b, s)
                group = [x for x in ctx.branches if b.group >= 0 and x.group == b.group]
                near = tx.words_between(ctx.rec.text, b.end, pos) <= 12
                # only the first number of its kind after the mention: "branch 3 gets 0.30, like its 28 %" is
                # about branch 3, "branches 1 and 3 ... their 15 % and 28 %" lists are not attributed
                first = this is None or not any(_kind(m) == _kind(this) for m in ctx.numbers_in(b.end, pos))
                apart = _ATTRIBUTION_BREAK.search(ctx.rec.text, b.end, pos) if b.end <= pos else None
                text = ctx.rec.text
                if text.rfind("(", s.start, b.start) > text.rfind(")", s.start, b.start) and ")" in text[b.end : pos]:
                    apart = True  # "36 % (branch 1, opened), 32 %": the mention sits in brackets closed before
                if a <= pos < z and len(group) <= 1 and b.start <= pos and near and first and apart is None:
                    return ctx.entity(b)
    return None


# a number is not said of a branch named before a clause break or before another quantity's name
_ATTRIBUTION_BREAK = re.compile(r";|\||\b(?:while|whereas|but)\b|" + _TOPIC_NAMES.pattern.split("|(?P<other>")[0],
                                re.IGNORECASE)  # fmt: skip


_LIST_GAP = re.compile(r"\s*(?:,|,?\s*and|/|;)?\s*")


def _opens_list(ctx: Context, m) -> bool:
    """True when the next number is of the same kind and joined to ``m`` only by a comma, "and" or a slash."""
    later = [x for x in ctx.numbers if x.start > m.start]
    if not later or _kind(later[0]) != _kind(m):
        return False
    end = m.unit_end if m.unit_end > 0 else m.end
    return bool(_LIST_GAP.fullmatch(ctx.rec.text, end, later[0].start))


def _kind(m) -> str:
    """A number's kind for attribution: temperature, power, or fraction (bare decimals and percentages)."""
    if m.unit in ("degC", "degF", "K"):
        return "temp"
    if m.unit in ("W", "kW", "MW"):
        return "power"
    return "fraction" if m.unit in ("", "%", "pp") else m.unit


def _dedupe(flags: list[Flag]) -> list[Flag]:
    seen, out = set(), []
    for f in flags:
        if f not in seen:
            seen.add(f)
            out.append(f)
    return out


