"""VIPER tree distillation (LC-Opt Appendix A, Tables 12-15) and the ``tree`` controller.

The PPO teacher is rolled deterministically over training traces; every cabinet and tower decision
gets its VIPER weight ``l(s) = log pi*(a*|s) - min_a log pi*(a|s)``; the dataset is resampled by those
weights; then a classification tree learns the tower's discrete step, one regression tree the CDU
controls (supply setpoint, dp) and one the valve split. Trees are stored as JSON node arrays (no
pickle) and evaluated with numpy, so the controller needs neither sklearn nor torch at run time.
``tree_rules`` prints a tree as nested if/else rules over named features in physical units.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lcmesh.distill.features import (
    APPROACH_LEVELS_K, DEFAULT_HOLD, DP_RANGE_PA, SUPPLY_RANGE_K, FeatureBuilder, FeatureLayout, HoldBand,
    TowerSetpoints, decode_cabinet,
)  # fmt: skip
from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.controllers.g36 import G36Controller
from lcmesh.twin.plant import PlantAction
from lcmesh.twin.system import PSI_TO_PA, SystemDescription

ARTIFACTS = Path(__file__).resolve().parent.parent / "artifacts"
PAPER_TREES = ARTIFACTS / "trees" / "case7.json"  # from the paper-plant case-7 policy
# From the real-load plant's case-7 policy: of its VIPER and naive trees, the naive ones scored higher on the
# validation days (99.90 against 99.87 % in band at the same energy; docs/controllers.md).
DEFAULT_TREES = ARTIFACTS / "trees" / "frontier-case7-naive.json"
READABLE_TREES = ARTIFACTS / "trees" / "frontier-case7-readable-naive.json"  # depth <= 8, 32 leaves a head
TREE_FORMAT = "lcmesh-trees/1"


@dataclass
class Tree:
    """A fitted tree as flat node arrays (sklearn's layout): leaves have ``left == -1``."""

    left: np.ndarray
    right: np.ndarray
    feature: np.ndarray
    threshold: np.ndarray
    value: np.ndarray  # (nodes, outputs): leaf predictions (class index stored as value for classifiers)
    feature_names: list[str]
    output_names: list[str]

    @classmethod
    def from_sklearn(cls, model, feature_names: list[str], output_names: list[str], classes=None) -> "Tree":
        t = model.tree_
        if classes is None:
            value = t.value[:, :, 0].astype(np.float64)  # regression: (nodes, outputs)
        else:
            value = np.asarray(classes, dtype=np.float64)[t.value[:, 0, :].argmax(axis=1)][:, None]
        return cls(t.children_left.copy(), t.children_right.copy(), t.feature.copy(), t.threshold.copy(), value,
                   list(feature_names), list(output_names))  # fmt: skip

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(n, features) -> (n, outputs), walking all rows down the tree at once."""
        node = np.zeros(x.shape[0], dtype=np.int64)
        rows = np.arange(x.shape[0])
        while True:
            internal = self.left[node] >= 0
            if not internal.any():
                return self.value[node]
            n = node[internal]
            go_left = x[rows[internal], self.feature[n]] <= self.threshold[n]
            node[internal] = np.where(go_left, self.left[n], self.right[n])

    @property
    def n_nodes(self) -> int:
        return int(self.left.size)

    @property
    def n_leaves(self) -> int:
        return int((self.left < 0).sum())

    @property
    def depth(self) -> int:
        depth = np.zeros(self.n_nodes, dtype=np.int64)
        for i in range(self.n_nodes):  # parents come before children in sklearn's layout
            if self.left[i] >= 0:
                depth[self.left[i]] = depth[self.right[i]] = depth[i] + 1
        return int(depth.max())

    def to_json(self) -> dict:
        return {"left": self.left.tolist(), "right": self.right.tolist(), "feature": self.feature.tolist(),
                "threshold": self.threshold.tolist(),  # full precision: a rounded threshold moves rows across a split
                "value": self.value.tolist(), "feature_names": self.feature_names,
                "output_names": self.output_names}  # fmt: skip

    @classmethod
    def from_json(cls, d: dict) -> "Tree":
        return cls(np.asarray(d["left"], dtype=np.int64), np.asarray(d["right"], dtype=np.int64),
                   np.asarray(d["feature"], dtype=np.int64), np.asarray(d["threshold"], dtype=np.float64),
                   np.asarray(d["value"], dtype=np.float64), list(d["feature_names"]), list(d["output_names"]))  # fmt: skip


def tree_rules(tree: Tree, max_depth: int = 6, unit_of=None, output_unit_of=None, name_of=None) -> str:
    """Nested if/else rules (down to ``max_depth``; deeper subtrees summarized by their mean output)."""
    lines: list[str] = []

    def leaf_text(i: int) -> str:
        vals = tree.value[i]
        if output_unit_of is not None:
            return ", ".join(output_unit_of(name, v) for name, v in zip(tree.output_names, vals))
        return ", ".join(f"{name} = {v:.3f}" for name, v in zip(tree.output_names, vals))

    def walk(i: int, depth: int) -> None:
        pad = "  " * depth
        if tree.left[i] < 0:
            lines.append(f"{pad}-> {leaf_text(i)}")
            return
        if depth >= max_depth:
            lines.append(f"{pad}-> (subtree of {_count(tree, i)} nodes) ~ {leaf_text(i)}")
            return
        name = tree.feature_names[tree.feature[i]]
        thr = tree.threshold[i]
        shown = unit_of(name, thr) if unit_of else f"{thr:.3f}"
        label = name_of(name) if name_of else name
        lines.append(f"{pad}if {label} <= {shown}:")
        walk(tree.left[i], depth + 1)
        lines.append(f"{pad}else:  # {label} > {shown}")
        walk(tree.right[i], depth + 1)

    walk(0, 0)
    return "\n".join(lines)


def _count(tree: Tree, i: int) -> int:
    stack, n = [i], 0
    while stack:
        j = stack.pop()
        n += 1
        if tree.left[j] >= 0:
            stack += [tree.left[j], tree.right[j]]
    return n


def feature_in_units(name: str, value: float) -> str:
    """A normalized feature threshold in physical units, for the rules operators read."""
    if "temp" in name or name == "max_blade_temp":
        return f"{value * 5.0 + 35.0:.2f} degC"
    if name == "wet_bulb":
        return f"{value * 10.0 + 20.0:.2f} degC (wet bulb)"
    if name == "approach_setpoint":
        return f"{value * 2.0 + 10.0 / 1.8:.2f} K approach"
    if name.startswith("branch_power"):
        return f"{value + 1.0:.3f} x design branch load"
    return f"{value:.3f}"


def output_in_units(name: str, value: float) -> str:
    """A leaf's output as the action it sends, for the rules operators read."""
    if name == "supply_setpoint_u":
        lo, hi = SUPPLY_RANGE_K
        return f"supply setpoint {lo - 273.15 + (np.clip(value, -1, 1) + 1.0) * 0.5 * (hi - lo):.1f} degC"
    if name == "dp_setpoint_u":
        lo, hi = DP_RANGE_PA
        return f"dp setpoint {(lo + (np.clip(value, -1, 1) + 1.0) * 0.5 * (hi - lo)) / PSI_TO_PA:.1f} psi"
    if name == "approach_step_index":
        level = APPROACH_LEVELS_K[int(np.clip(np.rint(value), 0, len(APPROACH_LEVELS_K) - 1))]
        return f"tower leaving water = wet bulb + {level:g} K"
    if name.startswith("valve_fraction["):
        return f"valve {int(name[15:-1]) + 1} weight {value:.3f}"
    return f"{name} = {value:.3f}"


def person_name(feature: str) -> str:
    """A feature's name as a person reads it: ``branch_power[2]`` -> ``branch 3 power`` (branches from 1)."""
    match = re.fullmatch(r"branch_(\w+)\[(\d+)\]", feature)
    if match:
        return f"branch {int(match.group(2)) + 1} {match.group(1).replace('_', ' ')}"
    return feature.replace("_", " ")


def rules_text(trees: dict[str, Tree], levels: int) -> str:
    """Every tree's rules down to ``levels``, thresholds and actions in physical units (the rules file)."""
    blocks = [f"# {name} tree ({t.n_nodes} nodes, depth {t.depth}); first {levels} levels\n\n"
              + tree_rules(t, levels, feature_in_units, output_in_units, person_name) for name, t in trees.items()]  # fmt: skip
    return "\n\n".join(blocks) + "\n"


def save_trees(path: Path, trees: dict[str, Tree], layout: FeatureLayout, manifest: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": TREE_FORMAT, "layout": layout.to_json(), "trees": {k: t.to_json() for k, t in trees.items()},
           "manifest": manifest}  # fmt: skip
    path.write_text(json.dumps(doc) + "\n")
    return path


def load_trees(path: Path) -> tuple[dict[str, Tree], FeatureLayout, dict]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"tree file {path} not found (make one with `lcmesh distill tree`)")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not JSON: {exc}") from exc
    if not isinstance(doc, dict) or doc.get("format") != TREE_FORMAT:
        raise ValueError(f"{path} is not an lc-mesh tree file (expected format {TREE_FORMAT!r})")
    return {k: Tree.from_json(v) for k, v in doc["trees"].items()}, FeatureLayout(**doc["layout"]), doc.get("manifest", {})


class TreeController:
    """Distilled trees as a controller: ``tower`` (step choice), ``cdu`` (setpoint, dp), ``valves`` (split)."""

    name = "tree"

    def __init__(self, system: SystemDescription, policy: str | Path | None = None, pool_cells: bool = False,
                 hold: HoldBand | None = DEFAULT_HOLD):
        path = Path(policy) if policy is not None else DEFAULT_TREES
        self.hold = hold
        self.trees, layout, self.manifest = load_trees(path)
        self.artifact_files = (path,)  # what a result depends on (the benches' cache keys)
        layout.check(system, f"tree file {path}", pool_cells=pool_cells)
        self.version = str(self.manifest.get("version", "1"))
        self.features = FeatureBuilder(system, layout)
        self.version += self.features.pooling_note
        self.towers = TowerSetpoints(system)
        self.baseline = G36Controller(system)
        C, B, N = system.cabinets.count, system.cabinets.branches, system.towers.count
        self._action = PlantAction(np.zeros(C), np.zeros(C), np.full((C, B), 1.0 / B), np.zeros(N))
        self._u = np.zeros((C, 2 + B))

    def reset(self) -> None:
        self.towers.reset()
        self.baseline.reset()

    def act(self, obs: Observation) -> PlantAction:
        action = self._action
        if not {"cdu", "valves", "tower"} <= self.trees.keys():
            for dst, src in zip(action.astuple(), self.baseline.act(obs).astuple()):
                dst[...] = src
        if "cdu" in self.trees:
            rows = self.features.cabinet_rows(obs)
            self._u[:, :2] = self.trees["cdu"].predict(rows)
            self._u[:, 2:] = self.trees["valves"].predict(rows) if "valves" in self.trees else action.valve_fractions
            decode_cabinet(self._u, action, valves_given=True)
        if "tower" in self.trees:
            choice = self.trees["tower"].predict(self.features.tower_rows(obs))[:, 0]
            self.towers.apply(np.rint(choice).astype(np.int64), obs.wet_bulb_k, action)
        if self.hold is not None:
            self.hold.apply(action, obs.out)
        return action


class ReadableTreeController(TreeController):
    """The readable tree (depth <= 8, 32 leaves a head, its rules in ``READABLE_TREES``' ``.rules.txt``) by name."""

    name = "readable"

    def __init__(self, system: SystemDescription, policy: str | Path | None = None, pool_cells: bool = False,
                 hold: HoldBand | None = DEFAULT_HOLD):
        super().__init__(system, policy if policy is not None else READABLE_TREES, pool_cells, hold)


__all__ = ["APPROACH_LEVELS_K", "ReadableTreeController", "Tree", "TreeController", "load_trees", "output_in_units", "rules_text", "save_trees", "tree_rules"]
