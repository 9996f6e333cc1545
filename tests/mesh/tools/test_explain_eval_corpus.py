"""The outside corpus (lcmesh/mesh/tools/explain_eval/corpus/) and the judge's figures on it.

The corpus is data the bench reads; these tests check that it is what docs/explanations.md says:
big enough, in the styles claimed, split by decision, its planted errors labelled by construction, and
rebuilt identically by docs/scripts/make_explain_corpus.py.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from collections import Counter
from pathlib import Path

import pytest

from lcmesh.mesh.tools.explain_eval.bench import (
    CORPUS, JUDGED_KINDS, corpus_markdown, corpus_record, corpus_verdict, load_corpus, load_fresh,
)  # fmt: skip
from lcmesh.mesh.tools.explain_eval import evaluate_record

ROOT = Path(__file__).resolve().parents[3]
RECORDS, TEXTS = load_corpus()


def _script():
    spec = importlib.util.spec_from_file_location("make_explain_corpus", ROOT / "docs/scripts/make_explain_corpus.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look themselves up there
    spec.loader.exec_module(module)
    return module


SCRIPT = _script()


def test_corpus_size_styles_and_sources():
    assert len(TEXTS) >= 300
    styles = Counter(t["style"] for t in TEXTS)
    assert set(SCRIPT.STYLES) <= set(styles) and len(set(styles) - {"smollm2_base"}) >= 6
    assert all(styles[s] >= 30 for s in SCRIPT.STYLES)
    sources = Counter(t["source"] for t in TEXTS)
    assert sources["hand"] >= 50
    assert 20 <= sources["llm"] <= 40 and styles["smollm2_base"] == sources["llm"]
    errors = Counter(t["error"] for t in TEXTS if t["error"])
    assert set(SCRIPT.ERROR_FLAG) <= set(errors) and min(errors[e] for e in SCRIPT.ERROR_FLAG) >= 20
    assert len({t["id"] for t in TEXTS}) == len(TEXTS)


def test_split_is_by_decision_and_disjoint():
    parts = {p: {t["record_key"] for t in TEXTS if t["split"] == p} for p in ("dev", "test")}
    assert parts["dev"] and parts["test"] and not parts["dev"] & parts["test"]
    for t in TEXTS:
        assert RECORDS[t["record_key"]]["split"] == t["split"], t["id"]
    assert abs(len(parts["dev"]) - len(parts["test"])) <= 0.2 * len(RECORDS)


def test_mutations_are_labelled_by_construction():
    correct = {(t["record_key"], t["style"]): t["explanation"] for t in TEXTS
               if t["source"] == "generated" and t["correct"]}  # fmt: skip
    mutated = [t for t in TEXTS if t["source"] == "generated" and not t["correct"]]
    assert mutated
    for t in mutated:
        assert t["expected_flags"] == [SCRIPT.ERROR_FLAG[t["error"]]], t["id"]
        assert t["explanation"] != correct[(t["record_key"], t["style"])], t["id"]
    for t in TEXTS:
        assert t["correct"] == (not t["expected_flags"]) and t["verified"], t["id"]


def test_generated_texts_are_rebuilt_identically():
    """The script's writers and mutations, run on the stored records, give the stored texts (and re-check every
    printed number of the correct ones against the record)."""
    records = [{"record_key": k} | {f: r[f] for f in ("observation", "action", "previous_action", "facts")}
               for k, r in RECORDS.items()]  # fmt: skip
    rebuilt = {t["id"]: t for t in SCRIPT.build(records)}
    stored = {t["id"]: t for t in TEXTS if t["source"] == "generated"}
    assert rebuilt.keys() == stored.keys()
    for key, t in stored.items():
        assert rebuilt[key]["explanation"] == t["explanation"] and rebuilt[key]["split"] == t["split"], key


def test_a_correct_text_checks_its_numbers():
    rec = next(iter(RECORDS.values()))
    view = SCRIPT.make_view(rec)
    view.temps[0] += 1.0  # the writer believes a wrong temperature: the correct-text check refuses to print it
    with pytest.raises(AssertionError):
        SCRIPT.Num(view, check=True)("temp:0", view.temps[0], "degC", 1)


def test_verdict_counts_and_markdown():
    test, dev = corpus_verdict("test"), corpus_verdict("dev")
    for v, part in ((test, "test"), (dev, "dev")):
        assert v["texts"] == sum(t["split"] == part for t in TEXTS)
        assert set(v["per_flag"]) == set(JUDGED_KINDS)
        flawed = [t for t in TEXTS if t["split"] == part and t["expected_flags"]]
        assert sum(x["expected"] for x in v["per_flag"].values()) == sum(len(t["expected_flags"]) for t in flawed)
    # the judge was tuned on dev: it keeps its figures there (a regression check, not evidence)
    assert dev["correct_flagged_share"] <= 0.02
    assert all(x["recall"] >= 0.95 for x in dev["per_flag"].values() if x["recall"] is not None and x["expected"] > 5)
    text = "\n".join(corpus_markdown({"test": test, "dev": dev}))
    assert "| wrong_direction |" in text and "correct texts with any flag" in text


def test_one_corpus_record_is_a_valid_explain_eval_line():
    t = next(t for t in TEXTS if t["error"] == "value_swap")
    item = evaluate_record(json.loads(json.dumps(corpus_record(RECORDS, t))))
    assert item["id"] == t["id"] and "invalid_record" not in {f["kind"] for f in item["flags"]}
    assert CORPUS.is_dir()


@pytest.mark.parametrize("name", ["fresh2.jsonl", "fresh3.jsonl", "fresh4.jsonl", "fresh5.jsonl", "fresh6.jsonl"])
def test_the_new_test_parts_meet_their_brief(name):
    """Issue 35's test parts by outside authors (fresh2: a third author; fresh3: two more, written before the judge
    was tuned for the issue): >= 300 texts on test decisions only, every judged flag kind planted >= 20 times, >= 40 %
    in es/de/fr, one planted flaw per flawed text."""
    records, _ = load_corpus()
    part = load_fresh(name=name)
    assert len(part) >= 300 and len({t["id"] for t in part}) == len(part)
    assert {records[t["record_key"]]["split"] for t in part} == {"test"}
    planted = Counter(k for t in part for k in t["expected_flags"])
    assert all(planted[kind] >= 20 for kind in JUDGED_KINDS), planted
    assert all(len(t["expected_flags"]) == (0 if t["correct"] else 1) for t in part)
    assert sum(t["lang"] in ("es", "de", "fr") for t in part) >= 0.4 * len(part)


def test_the_tuning_part_is_on_dev_decisions_by_other_authors():
    """dev3 (what the judge was tuned on for issue 35) is on dev decisions only, by authors who wrote no test part."""
    records, _ = load_corpus()
    dev3 = load_fresh(name="dev3.jsonl")
    held_out = [t for k in (3, 4, 5, 6) for t in load_fresh(name=f"fresh{k}.jsonl")]
    assert {records[t["record_key"]]["split"] for t in dev3} == {"dev"}
    assert not {t["source"] for t in dev3} & {t["source"] for t in held_out}


def test_the_tuning_part_keeps_its_figures_and_renders():
    """dev3 was tuned on (in-sample, not evidence): a regression check on its false flags, and issue 35's table renders
    a part's figures per flag kind, language and style family (no held-out part is scored here)."""
    from lcmesh.mesh.tools.explain_eval.bench import _summarized, issue35_markdown, style_family

    dev3 = _summarized(corpus_verdict("dev3"))
    assert dev3["correct_flagged_share"] <= 0.06 and set(dev3["per_family"]) == {"free-form", "structured"}
    assert style_family("markdown table") == "structured" and style_family("handover e-mail") == "free-form"
    text = "\n".join(issue35_markdown({"fresh6": dev3, "fresh3": dev3, "dev3": dev3}))
    assert "| correct texts with any flag |" in text and "| physics: recall / precision |" in text
    assert "free-form" in text and "de " in text
