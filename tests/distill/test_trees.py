"""Trees: numpy evaluation equals sklearn, JSON round trip (no pickle), rules, layout refusal, VIPER data."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.tree import DecisionTreeClassifier, DecisionTreeRegressor

from lcmesh.distill.experience import Experience, collect_experience, resample
from lcmesh.distill.features import FeatureLayout
from lcmesh.distill.trees import Tree, TreeController, load_trees, save_trees, tree_rules
from lcmesh.twin.controllers import make_controller
from lcmesh.twin.controllers.base import Observation
from lcmesh.twin.plant import Plant
from lcmesh.twin.system import parse_system


def _data(n=2000, f=5, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, f))
    y = np.column_stack([np.sin(x[:, 0]) + x[:, 1], x[:, 2] > 0.3])
    return x, y


def test_numpy_tree_predicts_exactly_like_sklearn():
    x, y = _data()
    reg = DecisionTreeRegressor(max_depth=8, random_state=0).fit(x, y[:, :1])
    tree = Tree.from_sklearn(reg, [f"f{i}" for i in range(5)], ["out"])
    np.testing.assert_allclose(tree.predict(x)[:, 0], reg.predict(x))
    clf = DecisionTreeClassifier(max_depth=6, random_state=0).fit(x, (x[:, 0] * 3).astype(int) % 4)
    ctree = Tree.from_sklearn(clf, [f"f{i}" for i in range(5)], ["choice"], classes=clf.classes_)
    np.testing.assert_array_equal(ctree.predict(x)[:, 0], clf.predict(x))
    assert tree.depth == reg.get_depth() and tree.n_leaves == reg.get_n_leaves()


def test_tree_file_round_trip_is_json_and_refuses_foreign_files(tmp_path, lcopt5):
    x, y = _data(f=15)
    layout = FeatureLayout.for_system(lcopt5)
    cdu = Tree.from_sklearn(DecisionTreeRegressor(max_depth=5).fit(x, np.tanh(x[:, :2])), list(layout.cabinet_columns), ["s", "d"])
    valves = Tree.from_sklearn(DecisionTreeRegressor(max_depth=5).fit(x, np.full((len(x), 3), 1 / 3)), list(layout.cabinet_columns), ["v0", "v1", "v2"])
    xt = np.random.default_rng(1).normal(size=(500, 8))
    clf = DecisionTreeClassifier(max_depth=4).fit(xt, (xt[:, 0] > 0).astype(int) * 8)
    tower = Tree.from_sklearn(clf, list(layout.tower_columns), ["i"], classes=clf.classes_)
    path = save_trees(tmp_path / "t.json", {"cdu": cdu, "valves": valves, "tower": tower}, layout, {"version": "test"})
    json.loads(path.read_text())  # plain JSON
    trees, layout2, manifest = load_trees(path)
    assert layout2 == layout and manifest["version"] == "test"
    np.testing.assert_allclose(trees["cdu"].predict(x), cdu.predict(x))
    ctrl = TreeController(lcopt5, path)
    with Plant(lcopt5) as plant:
        action = ctrl.act(Observation(plant.out, 295.0, np.full(lcopt5.n_blade_groups, 60e3), 0.0))
    np.testing.assert_allclose(action.valve_fractions.sum(axis=1), 1.0)
    assert set(np.round(action.lw_setpoint_k - 295.0, 6)) <= {1.5, 8.0}
    data = json.loads(lcopt5.model_dump_json())
    data["towers"]["cells"] = 3
    with pytest.raises(ValueError, match=r"m=2 cells .* has B=3, m=3.*--pool-cells"):
        TreeController(parse_system(data), path)
    three_cells = parse_system(data)
    pooled = TreeController(three_cells, path, pool_cells=True)
    assert pooled.version.endswith("(cells pooled 3->2)")
    with Plant(three_cells) as plant:
        out = {k: np.array(v) for k, v in plant.out.items()}
        out["cell_fan_power_w"] = np.tile([1.0, 0.5, 0.0], three_cells.towers.count) * 1e3
        rows = pooled.features.tower_rows(Observation(out, 295.0, np.full(three_cells.n_blade_groups, 60e3), 0.0))
    nominal = three_cells.towers.cell.fan_power_nominal_w
    # cells [1, 0.5, 0] (kW) over 2 virtual cells: (1 + 0.5/2) / 1.5 and (0.5/2 + 0) / 1.5; the mean is kept
    np.testing.assert_allclose(rows[:, :2] * nominal / 1e3, [[1.25 / 1.5, 0.25 / 1.5]] * three_cells.towers.count)
    data["cabinets"]["branches"] = 4
    with pytest.raises(ValueError, match="Retrain or distill for this system.$"):
        TreeController(parse_system(data), path, pool_cells=True)
    (tmp_path / "bad.json").write_text('{"format": "something-else"}')
    with pytest.raises(ValueError, match="not an lc-mesh tree file"):
        load_trees(tmp_path / "bad.json")


def test_rules_name_features_in_physical_units(lcopt5):
    from lcmesh.distill.trees import feature_in_units

    x, _ = _data(f=15)
    cols = list(FeatureLayout.for_system(lcopt5).cabinet_columns)
    tree = Tree.from_sklearn(DecisionTreeRegressor(max_depth=3).fit(x, x[:, 0]), cols, ["supply_setpoint_u"])
    text = tree_rules(tree, 2, feature_in_units)
    assert text.startswith(f"if {cols[0]} <=") and "degC" in text and "subtree of" in text


def test_experience_records_teacher_and_resamples_by_weight(tmp_path, lcopt5):
    exp = collect_experience(make_controller("g36", lcopt5), lcopt5, ["synthetic:1", "synthetic:2"], n_steps=50)
    assert exp.n_steps == 100 and exp.cabinet_rows.shape == (100, 5, 15) and exp.tower_rows.shape == (100, 2, 8)
    np.testing.assert_allclose(exp.actions["valve_fractions"].sum(axis=2), 1.0, atol=1e-6)
    path = exp.save(tmp_path / "exp.npz")
    back = Experience.load(path)
    assert back.teacher.startswith("g36") and back.traces == ["synthetic:1", "synthetic:2"]
    np.testing.assert_array_equal(back.cabinet_rows, exp.cabinet_rows)
    back.cabinet_weights[:] = 0.0
    back.cabinet_weights[7, 3] = 1.0  # all the weight on one decision
    idx = resample(back, 50, np.random.default_rng(0))
    assert (idx == [7, 3]).all()
    assert len({tuple(r) for r in resample(back, 200, np.random.default_rng(0), uniform=True)}) > 50
