"""The ablation bench: policies found by name, each seed scored per day against G36, mean and std over seeds."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from lcmesh.bench.ablation import ABLATION_DIR, ablation_policies, render_ablation, run_ablation
from lcmesh.bench.suite import days_named


def test_every_case_ships_three_seeds():
    found = ablation_policies()
    assert sorted(found) == [2, 3, 4, 5, 6, 7]
    assert all([seed for seed, _ in runs] == [0, 1, 2] for runs in found.values())


def test_an_empty_folder_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no case"):
        ablation_policies(tmp_path)


def test_two_seeds_on_one_short_day(tmp_path):
    for seed in (0, 1):
        for ext in (".json", ".safetensors"):
            shutil.copy(ABLATION_DIR / f"case6-seed{seed}{ext}", tmp_path / f"case6-seed{seed}{ext}")
    (tmp_path / "notes.json").write_text("{}")  # not a policy name: ignored
    r = run_ablation(Path(tmp_path), days=days_named(["hot-1033"]), hours=0.25, baselines=("g36",))
    case = r["cases"][6]
    assert [s["seed"] for s in case["seeds"]] == [0, 1]
    d = [s["mean"]["d_blade_pct"] for s in case["seeds"]]
    assert case["mean"]["d_blade_pct"] == pytest.approx(sum(d) / 2)
    g36 = r["baselines"]["g36"]["days"]["hot-1033"]["d_blade_pct"]
    for s in case["seeds"]:
        assert s["worst_day_vs_g36"]["points"] == pytest.approx(s["mean"]["d_blade_pct"] - g36)
        assert s["validation_score"] is not None
    text = render_ablation(r)
    assert "| 6 | Multi-agent RL, centralized action | 2 |" in text and "| g36 | baseline |" in text
