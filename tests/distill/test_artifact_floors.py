"""KPI floors for every shipped policy and tree on a short held-out window, so a regression fails the suite.

Each artifact runs 2 h on a window it was not trained or selected on, on the plant and scenario it was made for:
the paper policies on lcopt-5-paper under the lcopt scenario (the Frontier day's first 2 h, the paper's test
trace); the real-load ones on lcopt-5 on the Frontier day under the design-day wet bulb from 05:30, where the
load surges from idle (the suite's test day `frontier-hot`). Floors sit about a point under what was measured
when the artifact shipped (docs/controllers.md); the real-load ones must also cool for less than G36 (177 kW
of pumps and fans on this window).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from lcmesh.twin.controllers import make_controller
from lcmesh.twin.plant import Plant
from lcmesh.twin.run import run_twin
from lcmesh.twin.system import load_system
from lcmesh.twin.traces import FRONTIER_DAY, load_trace

ARTIFACTS = Path(__file__).resolve().parents[2] / "lcmesh" / "artifacts"
WINDOW_STEPS = 480  # 2 h
G36_COOLING_KW = 177.1  # G36 on the real-load window, measured like the rows below (177.07, behind the guardrails)

# artifact, kind, D_blade % measured at shipping -> floor
PAPER = [
    ("ppo/case2", "ppo", 80.04, 79.0),
    ("ppo/case3", "ppo", 82.06, 81.0),
    ("ppo/case4", "ppo", 89.29, 88.0),
    ("ppo/case5", "ppo", 84.04, 83.0),
    ("ppo/case6", "ppo", 100.0, 99.0),
    ("ppo/case7", "ppo", 100.0, 99.0),
    ("ppo/case7-64k", "ppo", 100.0, 99.0),
    ("trees/case7.json", "tree", 100.0, 99.0),
    ("trees/case7-naive.json", "tree", 100.0, 99.0),
]
REAL_LOAD = [
    ("ppo/frontier-case7", "ppo", 100.0, 98.5),
    ("ppo/frontier-case7-energy", "ppo", 99.58, 98.5),
    ("trees/frontier-case7.json", "tree", 100.0, 98.5),
    ("trees/frontier-case7-naive.json", "tree", 100.0, 98.5),
    ("trees/frontier-case7-readable.json", "tree", 100.0, 98.5),
    ("trees/frontier-case7-readable-naive.json", "tree", 100.0, 98.5),
]
# The ablation seeds (lcmesh bench ablation): every case 2-7 at seeds 0-2 scored 99.58-100 % on this window
# (measured behind the mesh's guardrails, as every run is since issue 23).
ABLATION_MEASURED = {"case6-seed1": 99.78, "case6-seed2": 99.71, "case7-seed0": 99.58, "case7-seed1": 99.58}
REAL_LOAD += [(f"ppo/frontier/case{c}-seed{s}", "ppo", ABLATION_MEASURED.get(f"case{c}-seed{s}", 100.0), 98.5)
              for c in range(2, 8) for s in range(3)]  # fmt: skip
# The deploy-reward seeds (issue 23; seed 0 ships as ppo/frontier-case7)
REAL_LOAD += [(f"ppo/frontier-deploy/case7-seed{s}", "ppo", 100.0, 98.5) for s in range(3)]


def _window(system_name: str, scenario: str, start_step: int) -> tuple:
    system = load_system(system_name)
    return system, load_trace(FRONTIER_DAY, system, scenario=scenario).slice(start_step, WINDOW_STEPS)


def _kpi(system, trace, kind: str, artifact: str) -> dict:
    with Plant(system) as plant:
        return run_twin(plant, trace, make_controller(kind, system, policy=str(ARTIFACTS / artifact))).kpi


@pytest.mark.parametrize("artifact, kind, measured, floor", PAPER, ids=[a for a, *_ in PAPER])
def test_paper_artifacts_hold_their_floor(artifact, kind, measured, floor):
    system, trace = _window("lcopt-5-paper", "lcopt", 0)
    kpi = _kpi(system, trace, kind, artifact)
    assert kpi["d_blade_pct"] >= floor, f"{artifact}: {kpi['d_blade_pct']:.2f} % (shipped at {measured} %)"


@pytest.mark.parametrize("artifact, kind, measured, floor", REAL_LOAD, ids=[a for a, *_ in REAL_LOAD])
def test_real_load_artifacts_hold_their_floor_and_cool_for_less_than_g36(artifact, kind, measured, floor):
    system, trace = _window("lcopt-5", "design-day", 1320)
    kpi = _kpi(system, trace, kind, artifact)
    cooling_kw = kpi["ct_power_kw_avg"] + kpi["pump_power_kw_avg"]
    assert kpi["d_blade_pct"] >= floor, f"{artifact}: {kpi['d_blade_pct']:.2f} % (shipped at {measured} %)"
    assert cooling_kw < G36_COOLING_KW, f"{artifact}: {cooling_kw:.1f} kW of cooling, G36 {G36_COOLING_KW} kW"


def test_the_g36_reference_of_the_real_load_window():
    system, trace = _window("lcopt-5", "design-day", 1320)
    with Plant(system) as plant:
        kpi = run_twin(plant, trace, make_controller("g36", system)).kpi
    assert kpi["ct_power_kw_avg"] + kpi["pump_power_kw_avg"] == pytest.approx(G36_COOLING_KW, abs=0.5)


def test_every_shipped_policy_and_tree_has_a_floor():
    shipped = {p.relative_to(ARTIFACTS).with_suffix("").as_posix() for p in (ARTIFACTS / "ppo").rglob("*.safetensors")}
    shipped |= {f"trees/{p.name}" for p in (ARTIFACTS / "trees").glob("*.json") if not p.name.endswith(".report.json")}
    assert shipped == {a for a, *_ in PAPER + REAL_LOAD}


def test_the_readable_tree_is_small_by_name_and_its_rules_are_shipped():
    from lcmesh.distill.trees import READABLE_TREES, load_trees

    trees, _, _ = load_trees(READABLE_TREES)
    system = load_system("lcopt-5")
    assert make_controller("readable", system).name == "readable"
    for head, tree in trees.items():
        depth, leaves = tree.depth, tree.n_leaves
        assert depth <= 8 and leaves <= 32, (head, depth, leaves)
    rules = READABLE_TREES.with_suffix(".rules.txt").read_text()
    assert all(f"# {head} tree" in rules for head in trees)
    assert "branch 0 " not in rules and "branch 1 " in rules  # people read branches from 1
