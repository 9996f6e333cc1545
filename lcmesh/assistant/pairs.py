"""Training pairs for the question reader: (question, typed Query), written by several authors, validated by code.

Each author's file (``lcmesh/distill/data/planner_authors/<author>.jsonl``) holds one JSON object a line:
``{"question": str, "lang": "en"|"es"|"de"|"fr", "query": {"asks": [...], "lang"?, "follow_up"?},
"previous"?: str}`` (``previous``: the question a follow-up continues). ``validate_file`` checks every line:
the Query validates, every ask becomes a valid tool call through its spec, the languages agree, no question
repeats, and no question is one of the benchmark's held-out questions (which it reports by count only, so an
author never reads them). ``python -m lcmesh.assistant.pairs FILE...`` prints the report.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from pydantic import ValidationError

from lcmesh.assistant.query import Query, resolve_follow_up
from lcmesh.assistant.tools import PLANNER_TOOLS, call_for

AUTHORS_DIR = Path(__file__).resolve().parents[1] / "distill" / "data" / "planner_authors"


@dataclass
class Pair:
    question: str
    query: Query
    author: str
    previous: str | None = None


@dataclass
class Report:
    path: str
    pairs: list[Pair] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    held_out_hits: int = 0
    duplicates: int = 0

    def summary(self) -> str:
        langs = Counter(p.query.lang for p in self.pairs)
        kinds = Counter(a.ask for p in self.pairs for a in p.query.asks)
        refusals = sum(p.query.refuse for p in self.pairs)
        follow = sum(p.query.follow_up for p in self.pairs)
        lines = [f"{self.path}: {len(self.pairs)} valid pairs, {len(self.errors)} invalid lines, "
                 f"{self.duplicates} repeated questions dropped, {self.held_out_hits} benchmark questions dropped",
                 f"  languages {dict(langs)}; refusals {refusals}; follow-ups {follow}",
                 f"  asks {dict(sorted(kinds.items(), key=lambda kv: -kv[1]))}"]  # fmt: skip
        lines += [f"  line {e}" for e in self.errors[:20]]
        return "\n".join(lines)


def held_out_questions() -> set[str]:
    """Every benchmark question, normalized (a training pair may not be one)."""
    out = set()
    data = resources.files("lcmesh.bench.data")
    for entry in data.iterdir():
        if entry.name.endswith(".jsonl"):
            for line in entry.read_text(encoding="utf-8").splitlines():
                if line.strip():
                    out.add(_norm(json.loads(line)["question"]))
    return out


def _norm(text: str) -> str:
    return " ".join(text.lower().split())


def check_query(query: Query, previous: Query | None = None) -> None:
    """Raise ValueError when a query's asks do not make valid tool calls (a follow-up resolved first)."""
    resolved = resolve_follow_up(query, previous)
    for i, ask in enumerate(resolved.asks):
        tool, args = call_for(ask)
        try:
            PLANNER_TOOLS[tool].model_validate(args)
        except ValidationError as exc:
            first = exc.errors()[0]
            raise ValueError(f"ask {i + 1} -> {tool}: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None


def validate_file(path: str | Path, held_out: set[str] | None = None) -> Report:
    path = Path(path)
    held_out = held_out_questions() if held_out is None else held_out
    report, seen = Report(str(path)), set()
    by_question: dict[str, Query] = {}
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            question = str(row["question"]).strip()
            if not question or len(question) > 500:
                raise ValueError("question empty or over 500 characters")
            query = Query.model_validate({**row["query"], "lang": row.get("lang", row["query"].get("lang", "en"))})
            if row["query"].get("lang", query.lang) != query.lang:
                raise ValueError(f"lang {row.get('lang')!r} and query.lang {row['query'].get('lang')!r} differ")
            previous = row.get("previous")
            if query.follow_up and not previous:
                raise ValueError("a follow-up needs `previous` (the question it continues)")
            prev_query = by_question.get(_norm(previous)) if previous else None
            if previous and prev_query is None and "previous_query" in row:
                prev_query = Query.model_validate(row["previous_query"])
            if query.follow_up and prev_query is None:
                raise ValueError("`previous` is not a question of this file (or give `previous_query`)")
            check_query(query, prev_query)
        except (ValueError, KeyError, TypeError, ValidationError) as exc:
            report.errors.append(f"{n}: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}")
            continue
        key = _norm(question) + "\x00" + _norm(previous or "")
        if _norm(question) in held_out:
            report.held_out_hits += 1
            continue
        if key in seen:
            report.duplicates += 1
            continue
        seen.add(key)
        by_question.setdefault(_norm(question), query)
        report.pairs.append(Pair(question, query, path.stem, previous))
    return report


def load_authors(directory: Path = AUTHORS_DIR) -> list[Pair]:
    """Every author's valid pairs (invalid lines are left out; ``validate_file`` says which)."""
    held_out = held_out_questions()
    pairs = []
    for path in sorted(directory.glob("*.jsonl")):
        pairs += validate_file(path, held_out).pairs
    return pairs


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: python -m lcmesh.assistant.pairs FILE.jsonl [...]", file=sys.stderr)
        return 2
    held_out = held_out_questions()
    bad = 0
    for name in argv:
        report = validate_file(name, held_out)
        print(report.summary())
        bad += len(report.errors)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
