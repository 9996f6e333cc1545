"""The chat section of BENCHMARKS.md: a part measured again at a later commit says so under the table."""

from __future__ import annotations

from lcmesh.bench.chat import markdown


def _part(correct: float) -> dict:
    return {"questions": 10, "plan_accuracy": 0.9, "correct": correct, "refusals_correct": None, "wrong_but_grounded": 1,
            "declined": 0, "rule_fallbacks": 2, "latency_p50_s": 0.5, "latency_p99_s": 1.5, "by_tag": {"state": 1.0}}  # fmt: skip


def test_a_part_measured_later_names_its_run_under_the_table():
    report = {"command": "lcmesh bench chat", "site": "a site", "machine": {"cpu": "cpu", "commit": "abc"},
              "planners": {"llm": {"dev": _part(0.7), "test": _part(0.8)}},
              "parts_measured": {"Part test": "again at commit def"}}  # fmt: skip
    text = markdown(report)
    assert "| llm | test | 10 | 90.0% | 80.0% | - | 1 | 0 | 2 | 0.50 | 1.50 |" in text
    assert text.splitlines()[-1] == "Part test: again at commit def."
    assert "Part " not in markdown({**report, "parts_measured": {}})
