"""``lcmesh bench chat``: the operator assistant scored on held-out questions against a recorded plant.

The questions (``lcmesh/bench/data/chat_questions.jsonl``) were written by hand, apart from the
planner's training generator, each with its expected tool calls; ``dev`` is for tuning, ``test``
is never used for it. They are asked against a recorded site (``chat_site.py``: a real twin run
with its history, decisions, alerts and configuration changes; a real plant restored at its last
step for what-ifs). The reference answer of a question is what its expected calls return on that
site; an answer is correct when it states the reference's key values (and entities), or refuses
when the reference is a refusal.

Reported per planner (the local LLM, and the regex rules alone): tool-call accuracy (the plan
equals the expected calls), answers correct against state, refusals correct, wrong answers
marked grounded, rule fallbacks, latency p50 / p99.
"""

from __future__ import annotations

import json
import re
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from lcmesh.assistant.facts import format_value, numbers_in
from lcmesh.mesh.tools import registry

QUESTIONS = "chat_questions.jsonl"
# b: written by an outside author for issue 24, test only (never read while tuning); c: by another outside author to the
# same brief, dev only (what the question check and the rules were tuned on after set b was first scored)
QUESTION_SETS = {"a": QUESTIONS, "b": "chat_questions_b.jsonl", "c": "chat_questions_c.jsonl",
                 "d": "chat_questions_d.jsonl", "e": "chat_questions_e.jsonl"}
# e: written for issue 34 by a fifth outside author before the question reader was trained, with follow-ups
# (``previous``: asked first in the same chat session); test only, never read by whoever tunes
SET_SPLITS = {"a": ("dev", "test"), "b": ("test",), "c": ("dev",), "d": ("test",), "e": ("test",)}


@dataclass(frozen=True)
class Question:
    id: str
    split: str
    question: str
    lang: str
    tags: tuple[str, ...]
    calls: tuple[tuple[str, str], ...]  # (tool, canonical args JSON)
    refuse: bool
    previous: str | None = None  # a follow-up: the question asked before it in the same session


def canonical(tool: str, args: dict) -> str:
    """A call's arguments with defaults filled in by its request model, as sorted JSON (for comparing plans)."""
    spec = registry.TOOLS.get(tool)
    if spec is None:
        return json.dumps(args, sort_keys=True)
    try:
        return json.dumps(spec.request_model.model_validate(args).model_dump(mode="json"), sort_keys=True)
    except ValueError:
        return json.dumps(args, sort_keys=True)


def load_questions(split: str | None = None, question_set: str = "a") -> list[Question]:
    """A question set's questions (one split, or all): "a" the first set, "b" the outside author's."""
    text = resources.files("lcmesh.bench.data").joinpath(QUESTION_SETS[question_set]).read_text(encoding="utf-8")
    out = []
    for line in text.splitlines():
        if not line.strip():
            continue
        row = json.loads(line)
        if split is not None and row["split"] != split:
            continue
        calls = tuple((c["tool"], canonical(c["tool"], c["args"])) for c in row["calls"])
        out.append(Question(row["id"], row["split"], row["question"], row["lang"], tuple(row["tags"]), calls,
                            bool(row["refuse"]), row.get("previous")))  # fmt: skip
    return out


# --- the reference answer: key values of the expected calls' results ------------------------------------------------
def _shown(value: float, unit: str) -> str:
    return numbers_in(format_value(value, unit))[0]


def key_values(tool: str, args: dict, result: dict, question: str = "") -> list[str]:
    """What a correct answer to this call must state: number strings as displayed, and names."""
    unit = result.get("unit", "")
    if tool == "plant_state":
        values = [_shown(v["value"], unit) for v in result["values"]]
        return values if len(values) <= 15 else [_shown(result["plant"], unit)]
    if tool == "overview":
        return [_shown(result["hottest"]["value"], "degC"), _shown(result["in_band_pct"], "%")]
    if tool == "history_stat":
        stat = result["stat"]
        return [_shown(abs(result[stat]) if stat == "change" else result[stat], "K" if stat == "change" and
                       unit == "degC" else unit)]  # fmt: skip
    if tool == "rank":
        first = result["ranked"][0]
        return [first["entity"], _shown(first["value"], unit)]
    if tool == "compare":
        return [_shown(v["value"], unit) for v in result["values"]]
    if tool == "band_count":
        return [str(result["inside"]), str(result["total"] - result["inside"])] if result["total"] else []
    if tool == "energy_balance":  # one tool for three questions: the PUE, the heat balance, the cooling power
        if "pue" in question.lower() and result.get("pue") is not None:
            return [_shown(result["pue"], "pue")]
        if re.search(r"reject|rechaz|abgegeben|rejet|balance|bilan|bilanz", question, re.IGNORECASE):
            return [_shown(result["it_power_kw"], "kW"), _shown(result["heat_rejected_kw"], "kW")]
        return [_shown(result["cooling_power_kw"], "kW")]
    if tool == "alerts":
        return [str(result["count"])] + [a["kind"] for a in result["alerts"][:3]]
    if tool == "decision":
        return [str(result["step"])] if result["found"] else []
    if tool == "controller":
        return [x for x in (result.get("configured"), result.get("since")) if x]
    if tool == "agents":
        return [str(result["alive"]), str(result["known"])]
    if tool == "propose_change":
        if result.get("proposed") is not None:
            return [_shown(result["proposed"], result["unit"])]
        return [str(v) for v in result["body"].values()]
    if tool == "whatif_setpoint":
        return [_shown(result["predicted"]["hottest_blade_c"], "degC")]
    if tool == "energy_used":
        return [_shown(result["kwh"], "kWh")]
    if tool == "tracking_gap":
        return [result["largest"], _shown(abs(result["largest_gap_k"]), "K")]
    if tool == "peak":  # the value, where (unless plant-wide) and when (the time of day it happened)
        where = [] if result["entity"] == "plant" else [result["entity"]]
        return [_shown(result["value"], unit), *where, result["at"][11:19]]
    if tool == "weather_effect":
        return [_shown(result["wet_bulb_c"], "degC"), _shown(result["fan_power_kw"], "kW")]
    if tool == "whatif_controller":
        return [_shown(result["current"]["cooling_kwh"], "kWh"), _shown(result["alternative"]["cooling_kwh"], "kWh")]
    return []


def states(answer: str, keys: Iterable[str]) -> list[str]:
    """The keys `answer` does not state (numbers as whole numbers, entities in any language, names as words)."""
    from lcmesh.mesh.tools.semantic import ENTITY, canonical_entity

    numbers = set(numbers_in(answer))
    entities = {canonical_entity(*m.groups()) for m in ENTITY.finditer(answer)}
    low = answer.lower()
    missing = []
    for key in keys:
        if key.replace(".", "", 1).isdigit():
            if key not in numbers:
                missing.append(key)
        elif ENTITY.fullmatch(key):
            if key not in entities:
                missing.append(key)
        elif key.lower() not in low:
            missing.append(key)
    return missing


@dataclass
class Reference:
    refuse: bool
    keys: list[str]
    errors: list[str]  # expected calls the tools refuse (no cabinet 9 ...): the answer must say so


def reference(q: Question, run: Callable[[str, dict], registry.ToolResult]) -> Reference:
    keys, errors = [], []
    for tool, args_json in q.calls:
        args = json.loads(args_json)
        res = run(tool, args)
        if res.ok:
            keys += key_values(tool, args, res.result, q.question)
        else:
            errors.append(res.error or "")
    return Reference(q.refuse, keys, errors)


def judge(answer: dict, ref: Reference) -> bool:
    """Whether `answer` is right against the reference computed from the same state."""
    if ref.refuse:  # "I can't answer that as asked" is an honest refusal
        return bool(answer.get("refused") or answer.get("declined"))
    if answer.get("refused") or answer.get("declined"):  # what it gave instead is not an answer
        return False
    text = answer["answer"]
    if ref.errors and not ref.keys:
        return all(e in text for e in ref.errors)
    return not states(text, ref.keys) and all(e in text for e in ref.errors)


# --- running a planner over a split -----------------------------------------------------------------------------
@dataclass
class Row:
    id: str
    tags: tuple[str, ...]
    plan_ok: bool
    correct: bool
    grounded: bool
    refused: bool
    expected_refusal: bool
    declined: bool  # "I can't answer that as asked", with what it could give instead
    planned_by: str
    seconds: float
    answer: str
    missing: list[str]
    plan: list[dict]  # the calls it made
    lang: str = "en"
    held_answer: bool = False  # declined, though the results it offered instead state every key of the reference


def run_split(questions: list[Question], engine: Any, run_tool: Callable, *, clock: Callable[[], float] =
              time.perf_counter, progress: Callable[[int], None] | None = None) -> list[Row]:  # fmt: skip
    from lcmesh.assistant.sources import NotReady

    rows = []
    for k, q in enumerate(questions):
        ref = reference(q, run_tool)
        session = f"bench-{q.id}" if q.previous else None
        if session:  # a follow-up: its previous question first, in the same session (not scored)
            try:
                engine.ask(q.previous, session=session)
            except NotReady:
                pass
        t0 = clock()
        try:
            answer = engine.ask(q.question, session=session)
        except NotReady as exc:
            answer = {"answer": f"not ready: {exc}", "grounded": False, "refused": False, "plan": [],
                      "planned_by": "?"}  # fmt: skip
        seconds = clock() - t0
        plan = Counter((c["tool"], canonical(c["tool"], c["args"])) for c in answer.get("plan", []))
        missing = states(answer["answer"], ref.keys)
        rows.append(Row(q.id, q.tags, plan == Counter(q.calls), judge(answer, ref), bool(answer["grounded"]),
                        bool(answer.get("refused")), q.refuse, bool(answer.get("declined")),
                        str(answer.get("planned_by", "?")).split(":")[0],
                        seconds, answer["answer"], missing, answer.get("plan", []), q.lang,
                        bool(answer.get("declined")) and not q.refuse and bool(ref.keys) and not missing))  # fmt: skip
        if progress:
            progress(k + 1)
    return rows


def summarize(rows: list[Row]) -> dict[str, Any]:
    n = len(rows)
    refusals = [r for r in rows if r.expected_refusal]
    seconds = np.asarray([r.seconds for r in rows]) if rows else np.zeros(1)
    by_tag: dict[str, list[Row]] = {}
    for r in rows:
        for t in r.tags:
            by_tag.setdefault(t, []).append(r)
    return {
        "questions": n,
        "plan_accuracy": sum(r.plan_ok for r in rows) / n if n else None,
        "correct": sum(r.correct for r in rows) / n if n else None,
        "refusals": len(refusals),
        "refusals_correct": sum(r.correct for r in refusals) / len(refusals) if refusals else None,
        "false_refusals": sum(r.refused and not r.expected_refusal for r in rows),
        "declined": sum(r.declined for r in rows),
        "declined_wrongly": sum(r.declined and not r.expected_refusal and not r.plan_ok for r in rows),
        "declined_holding_answer": sum(r.held_answer for r in rows),
        "by_lang": {lang: round(sum(r.correct for r in rs) / len(rs), 3)
                    for lang, rs in sorted(_group(rows, lambda r: r.lang).items())},
        "wrong_but_grounded": sum(r.grounded and not r.correct for r in rows),
        "rule_fallbacks": sum(r.planned_by == "rules" for r in rows),
        "latency_p50_s": float(np.percentile(seconds, 50)),
        "latency_p99_s": float(np.percentile(seconds, 99)),
        "by_tag": {t: round(sum(r.correct for r in rs) / len(rs), 3) for t, rs in sorted(by_tag.items())},
        "wrong": [{"id": r.id, "answer": r.answer[:300], "missing": r.missing, "plan": r.plan, "by": r.planned_by}
                  for r in rows if not r.correct][:80],
    }


TARGETS = {"correct": 0.90, "wrong_but_grounded": 0, "latency_p99_s": 2.0, "lang": 0.85,
           "declined_holding_answer": 0.03}  # issue 34, on every held-out part


def _group(rows: list[Row], key: Callable[[Row], str]) -> dict[str, list[Row]]:
    out: dict[str, list[Row]] = {}
    for r in rows:
        out.setdefault(key(r), []).append(r)
    return out


def markdown(report: dict[str, Any]) -> str:
    """The chat section of BENCHMARKS.md."""
    m = report.get("machine", {})
    lines = [f"## Operator assistant (`{report['command']}`)", "",
             "Held-out operator questions (`lcmesh/bench/data/chat_questions.jsonl`: 306 written by hand, apart "
             "from the planner's training generator; `dev` for tuning, `test` never used for it), asked against a "
             f"recorded site ({report['site']}). The reference answer of a question is what its expected tool calls "
             "return on that site; an answer is right when it states the reference's key values and entities (in "
             "any of the four languages), or refuses when the reference is a refusal. *Wrong but grounded*: an "
             "answer marked `grounded` that is not right. `oracle` plans with the expected calls themselves: it "
             "measures the writer and the guard, not planning, and is right by construction of the reference.", "",
             "Set `b` (`lcmesh/bench/data/chat_questions_b.jsonl`, all test) was written for issue 24 by an author "
             "who had seen neither the first set nor the planner's generator, with tools the first set did not "
             "have (energy over a window, setpoint gaps, where and when, top-N blade groups, another controller on "
             "the twin, the weather). Set `c` (`chat_questions_c.jsonl`, all dev) was written to the same brief by "
             "a second outside author after set b was first scored, and is what the question check and the rules "
             "were tuned on since (set b and the test split were not read). Set `d` (`chat_questions_d.jsonl`, all "
             "test) was written for issue 34 by a third outside author, given only the tool specs and a brief on how "
             "operators write, before any work on the question reading; nobody who tunes reads it. Set `e` "
             "(`chat_questions_e.jsonl`, all test, with follow-ups asked in one chat session after the question they "
             "continue) was written for issue 34 by a fifth outside author from the tool specs and the authors' "
             "brief, before the question reader was trained; nobody who tunes reads it. *Declined*: "
             "the reply says the question asks for something the results do not give and offers them as what it "
             "can give instead; never grounded, never counted right unless the question is one to refuse.", "",
             "| planner | part | questions | tool calls right | answers right | refusals right | wrong but "
             "grounded | declined | rule plans | p50 s | p99 s |", "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for planner, splits in report["planners"].items():
        for split, s in splits.items():
            refusals = "-" if s["refusals_correct"] is None else f"{s['refusals_correct']:.0%}"
            lines.append(f"| {planner} | {split} | {s['questions']} | {s['plan_accuracy']:.1%} | {s['correct']:.1%} | "
                         f"{refusals} | {s['wrong_but_grounded']} | {s.get('declined', '-')} | {s['rule_fallbacks']} | "
                         f"{s['latency_p50_s']:.2f} | {s['latency_p99_s']:.2f} |")  # fmt: skip
    held_out = [p for p in ("test", "b-test", "d-test", "e-test") if p in report["planners"].get("llm", {})]
    if held_out:
        yes = lambda ok: "yes" if ok else "no"  # noqa: E731
        lines += ["", "| target (local LLM reader, held-out part) | " + " | ".join(held_out) + " |",
                  "|---|" + "---|" * len(held_out)]
        parts = [report["planners"]["llm"][p] for p in held_out]
        lines.append(f"| answers right >= {TARGETS['correct']:.0%} | "
                     + " | ".join(f"{s['correct']:.1%} ({yes(s['correct'] >= TARGETS['correct'])})" for s in parts)
                     + " |")  # fmt: skip
        for lang in ("es", "de", "fr"):
            shares = [s.get("by_lang", {}).get(lang) for s in parts]
            lines.append(f"| {lang} answers right >= {TARGETS['lang']:.0%} | " + " | ".join(
                "-" if v is None else f"{v:.1%} ({yes(v >= TARGETS['lang'])})" for v in shares) + " |")
        lines.append("| wrong but grounded = 0 | " + " | ".join(
            f"{s['wrong_but_grounded']} ({yes(s['wrong_but_grounded'] == 0)})" for s in parts) + " |")
        share = TARGETS["declined_holding_answer"]
        held = [s.get("declined_holding_answer", 0) for s in parts]
        lines.append(f"| declines holding the answer <= {share:.0%} | " + " | ".join(
            f"{h} ({yes(h <= share * s['questions'])})" for h, s in zip(held, parts)) + " |")
        lines.append(f"| p99 <= {TARGETS['latency_p99_s']:g} s per answer (one CPU) | " + " | ".join(
            f"{s['latency_p99_s']:.2f} s ({yes(s['latency_p99_s'] <= TARGETS['latency_p99_s'])})" for s in parts)
            + " |")  # fmt: skip
        for p, s in zip(held_out, parts):
            lines += ["", f"{p}, answers right by tag (local LLM reader): "
                      + ", ".join(f"{t} {v:.0%}" for t, v in s["by_tag"].items()) + "."]
    lines += ["", f"Machine: {m.get('cpu', '?')}, {m.get('logical_cpus', '?')} logical CPUs; commit "
              f"{m.get('commit', '?')}, {m.get('date', '?')}."]
    for part, run in report.get("parts_measured", {}).items():  # "Parts test and b-test": when, if not the above
        lines.append(f"{part}: {run}.")
    from lcmesh.bench.engine import cache_lines

    lines += cache_lines(report.get("cache", {}))
    return "\n".join(lines)


def site_runner(site_path: Path) -> tuple[Any, Callable[[str, dict], registry.ToolResult]]:
    """(sources, tool runner) on a recorded site: data tools on its history, what-ifs on its restored plant."""
    from lcmesh.bench.chat_site import open_site, site_plant
    from lcmesh.assistant.engine import ToolCall, ToolRunner

    data = open_site(site_path)
    runner = ToolRunner(data, plant=site_plant(site_path))

    def run(tool: str, args: dict) -> registry.ToolResult:
        return runner(ToolCall(tool, args))

    run.runner = runner
    return data, run


def part_name(question_set: str, split: str) -> str:
    return split if question_set == "a" else f"{question_set}-{split}"


def run_part(planner: str, question_set: str, split: str, site: str, check: str = "words") -> dict:
    """One unit of ``lcmesh bench chat``: ``planner`` (llm, rules, openai; oracle: the expected calls) on one part's
    questions, on the recorded ``site``; the part's summary."""
    from lcmesh.assistant.plan import make_planner

    sources, run_tool = site_runner(Path(site))
    questions = load_questions(split, question_set)
    made = None if planner == "oracle" else make_planner(planner)
    engine = bench_engine(sources, made or OraclePlanner(questions), run_tool, check=check)
    if made is None:  # the ceiling: the expected calls exactly, no second opinion from the rules
        engine.second_opinion = lambda message, plan: plan
    return summarize(run_split(questions, engine, run_tool))


def part_units(planners: Iterable[str], parts: Iterable[tuple[str, str]], site: Path, check: str = "words") -> list:
    """One engine unit per (planner, part); the key holds the assistant's code, the planner's model and adapter, the
    question files and the recorded site."""
    from lcmesh.bench.engine import Unit, tree_digest

    site_version = f"site:{Path(site).resolve().parent.name}:{tree_digest(Path(site).resolve())}"
    code = tree_digest("assistant", "mesh", "llm", "bench/chat.py", "bench/data", "artifacts/llm-planner", "prompts")
    parts = list(parts)
    return [Unit("lcmesh.bench.chat:run_part", {"planner": name, "question_set": qs, "split": sp,
                                               "site": str(Path(site).resolve()), "check": check},
                 label=f"{name} on {part_name(qs, sp)}", versions=(code, site_version))
            for name in planners for qs, sp in parts]  # fmt: skip


def bench_engine(sources: Any, planner: Any, run_tool: Callable, check: str = "words") -> Any:
    """A chat engine on the site's sources whose what-ifs run on the site's restored plant."""
    from lcmesh.assistant.engine import ChatEngine, ToolRunner

    engine = ChatEngine(sources, planner=planner, check=check)
    engine.runner = getattr(run_tool, "runner", None) or ToolRunner(sources)
    return engine


class OraclePlanner:
    """The expected calls themselves: the ceiling the writer and guard reach with a perfect planner."""

    def __init__(self, questions: Iterable[Question]):
        from lcmesh.assistant.engine import Plan, ToolCall

        self._plans = {q.question: Plan([ToolCall(t, json.loads(a)) for t, a in q.calls], "oracle")
                       for q in questions}  # fmt: skip

    def plan(self, question: str):
        return self._plans[question]
