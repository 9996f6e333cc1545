"""The held-out chat question set (dev + test) is well formed: every expected call validates against its tool's
request model, the splits and tags are all there, and no question text repeats."""

from __future__ import annotations

import json
from collections import Counter
from importlib import resources

import pytest

from lcmesh.assistant.plan import PLANNER_TOOLS as TOOLS
from lcmesh.mesh.tools import registry

TAGS = {
    "paraphrase", "typo", "multi", "lang", "refusal", "injection", "command", "whatif", "history", "rank", "compare",
    "band", "energy", "alerts", "decision", "controller", "agents", "state", "overview", "out_of_range", "units",
}  # fmt: skip
B_TAGS = TAGS - {"band", "decision", "alerts", "controller", "agents", "overview"} | {
    "why", "gap", "where", "when", "weather"}  # the outside author's set b (issue 24): test only
KEYS = {"id", "split", "question", "lang", "tags", "calls", "refuse", "note"}


def _rows(name: str = "chat_questions.jsonl") -> list[dict]:
    text = resources.files("lcmesh.bench.data").joinpath(name).read_text(encoding="utf-8")
    return [json.loads(line) for line in text.splitlines() if line.strip()]


ROWS = _rows()
B_ROWS = _rows("chat_questions_b.jsonl")


def test_size_splits_and_unique_text():
    assert len(ROWS) >= 200
    assert {r["split"] for r in ROWS} == {"dev", "test"}
    assert len({r["id"] for r in ROWS}) == len(ROWS)
    dup = [q for q, n in Counter(r["question"].strip().lower() for r in ROWS).items() if n > 1]
    assert not dup, dup


def test_every_tag_in_both_splits():
    for split in ("dev", "test"):
        present = {t for r in ROWS if r["split"] == split for t in r["tags"]}
        assert present == TAGS, (split, TAGS - present)


def test_set_b_is_its_own_test_set():
    assert len(B_ROWS) >= 150 and {r["split"] for r in B_ROWS} == {"test"}
    assert len({r["id"] for r in B_ROWS}) == len(B_ROWS)
    same = {r["question"].strip().lower() for r in B_ROWS} & {r["question"].strip().lower() for r in ROWS}
    assert len(same) <= 2, same  # written apart: a short common question ("¿hay alarmas activas?") may repeat
    langs = Counter(r["lang"] for r in B_ROWS)
    assert min(langs["es"], langs["de"], langs["fr"]) >= 25, langs
    assert B_TAGS - {"band"} <= {t for r in B_ROWS for t in r["tags"]}


@pytest.mark.parametrize("row", ROWS + B_ROWS, ids=[r["id"] for r in ROWS + B_ROWS])
def test_row_is_well_formed(row):
    tags = B_TAGS | TAGS if row["id"].startswith("b") else TAGS
    assert set(row) == KEYS
    assert row["split"] in ("dev", "test") and row["lang"] in ("en", "es", "de", "fr")
    assert row["tags"] and set(row["tags"]) <= tags and len(set(row["tags"])) == len(row["tags"])
    assert (row["lang"] != "en") == ("lang" in row["tags"])
    assert isinstance(row["refuse"], bool) and ("refusal" in row["tags"]) == row["refuse"]
    if row["refuse"]:  # a refusal is an honest "I can't tell that from here": no call
        assert row["calls"] == []
    if "injection" in row["tags"]:  # at most one proposal (never applied by chat), no what-if on the live twin
        tools = [c["tool"] for c in row["calls"]]
        assert tools.count("propose_change") <= 1 and "whatif_setpoint" not in tools
    for call in row["calls"]:
        assert set(call) == {"tool", "args"}
        model = TOOLS[call["tool"]]
        req = model.model_validate(call["args"])  # raises on a bad argument
        # only the arguments the question determines: none equal to the model's default
        for name, value in call["args"].items():
            default = model.model_fields[name].default
            assert value != default, (call, name)
        assert req is not None


D_ROWS = _rows("chat_questions_d.jsonl")


def test_set_d_is_a_third_authors_test_set():
    """Set d (issue 34), by an author who saw only the tool specs: test only, apart from the other sets, every
    expected call valid under its tool's request model, a refusal without calls."""
    assert len(D_ROWS) >= 300 and {r["split"] for r in D_ROWS} == {"test"}
    assert len({r["id"] for r in D_ROWS}) == len(D_ROWS)
    others = {r["question"].strip().lower() for r in ROWS + B_ROWS + _rows("chat_questions_c.jsonl")}
    # written apart: short common questions may repeat another set's text word for word (10 at writing)
    assert len({r["question"].strip().lower() for r in D_ROWS} & others) <= 0.03 * len(D_ROWS)
    langs = Counter(r["lang"] for r in D_ROWS)
    assert set(langs) <= {"en", "es", "de", "fr"} and langs["es"] + langs["de"] + langs["fr"] >= 0.4 * len(D_ROWS)
    for row in D_ROWS:
        assert set(row) == KEYS and isinstance(row["refuse"], bool), row["id"]
        assert (row["calls"] == []) == row["refuse"], row["id"]
        for call in row["calls"]:
            registry.TOOLS[call["tool"]].request_model.model_validate(call["args"])  # any served tool, physics too
