"""The held-out chat question set (dev + test) is well formed: every expected call validates against its tool's
request model, the splits and tags are all there, and no question text repeats."""

from __future__ import annotations

import json
from collections import Counter
from importlib import resources

import pytest

from lcmesh.mesh.tools import plant_data as pd

TOOLS = {
    "plant_state": pd.StateRequest,
    "overview": pd.OverviewRequest,
    "history_stat": pd.HistoryRequest,
    "rank": pd.RankRequest,
    "compare": pd.CompareRequest,
    "band_count": pd.BandRequest,
    "energy_balance": pd.EnergyRequest,
    "alerts": pd.AlertsRequest,
    "decision": pd.DecisionRequest,
    "controller": pd.ControllerRequest,
    "agents": pd.AgentsRequest,
    "propose_change": pd.ProposeRequest,
    "whatif_setpoint": pd.WhatIfSetpointRequest,
}
TAGS = {
    "paraphrase", "typo", "multi", "lang", "refusal", "injection", "command", "whatif", "history", "rank", "compare",
    "band", "energy", "alerts", "decision", "controller", "agents", "state", "overview", "out_of_range", "units",
}  # fmt: skip
KEYS = {"id", "split", "question", "lang", "tags", "calls", "refuse", "note"}


def _rows() -> list[dict]:
    text = resources.files("lcmesh.bench.data").joinpath("chat_questions.jsonl").read_text(encoding="utf-8")
    return [json.loads(line) for line in text.splitlines() if line.strip()]


ROWS = _rows()


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


@pytest.mark.parametrize("row", ROWS, ids=[r["id"] for r in ROWS])
def test_row_is_well_formed(row):
    assert set(row) == KEYS
    assert row["split"] in ("dev", "test") and row["lang"] in ("en", "es", "de", "fr")
    assert row["tags"] and set(row["tags"]) <= TAGS and len(set(row["tags"])) == len(row["tags"])
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
