"""The strong rule, the look-ahead ceiling and third-party controllers (issue 13, an honest control benchmark)."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lcmesh.twin.controllers import ControllerError, Observation, make_controller, mesh_refusal
from lcmesh.twin.controllers.lookahead import NOT_ATTACHED
from lcmesh.twin.controllers.rule import MIN_VALVE_FRACTION
from lcmesh.twin.plant import Plant
from lcmesh.twin.run import run_twin
from lcmesh.twin.traces import FRONTIER_DAY, load_trace

DOCS = Path(__file__).resolve().parents[2] / "docs" / "controllers.md"


def _run(system, controller, trace, n_steps):
    """A run on a fresh plant: a plant's history would leak into the spin-up (G36 starts from measured values)."""
    with Plant(system) as plant:
        return run_twin(plant, trace, controller, n_steps=n_steps)


def _cost(kpi: dict, system, hours: float, out_of_band_kwh: float = 1.0) -> float:
    """The look-ahead's objective over a whole run: out-of-band blade-group-steps x 1 kWh + cooling kWh."""
    out_of_band = (1.0 - kpi["d_blade_pct"] / 100.0) * kpi["steps"] * system.n_blade_groups
    return out_of_band_kwh * out_of_band + kpi["cooling_power_kw_avg"] * hours


# --- the strong rule ---------------------------------------------------------------------------------------------
def test_rule_valves_follow_branch_power(lcopt5, plant):
    C, B, G = lcopt5.cabinets.count, lcopt5.cabinets.branches, lcopt5.cabinets.blade_groups_per_branch
    branch_w = np.tile(np.array([50e3, 30e3, 20e3])[:B], (C, 1))
    branch_w[1] = 0.0  # an idle cabinet
    power = np.repeat(branch_w.reshape(-1) / G, G)
    obs = Observation(plant.out, 295.0, power, 0.0)
    rule, g36 = make_controller("rule", lcopt5), make_controller("g36", lcopt5)
    action, reference = rule.act(obs), g36.act(obs)
    floor = MIN_VALVE_FRACTION
    np.testing.assert_allclose(action.valve_fractions[0], floor + (1 - B * floor) * np.array([0.5, 0.3, 0.2]))
    np.testing.assert_allclose(action.valve_fractions[1], 1.0 / B)
    np.testing.assert_allclose(action.valve_fractions.sum(axis=1), 1.0)
    assert rule.name == "rule" and "load-proportional valves" in type(rule).__doc__
    # the rest is G36's
    np.testing.assert_array_equal(action.supply_temp_setpoint_k, reference.supply_temp_setpoint_k)
    np.testing.assert_array_equal(action.lw_setpoint_k, reference.lw_setpoint_k)


def test_rule_beats_g36_under_the_25_to_1_skew(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5, scenario="lcopt", hours=2)
    g36 = _run(lcopt5, make_controller("g36", lcopt5), trace, trace.n_steps).kpi
    rule = _run(lcopt5, make_controller("rule", lcopt5), trace, trace.n_steps).kpi
    assert rule["d_blade_pct"] >= g36["d_blade_pct"]
    # measured 2.6 K cooler hottest blade (35.3 -> 32.8 C): the valves send the flow where the load is
    assert rule["blade_temp_max_c"] < g36["blade_temp_max_c"] - 1.5, (rule["blade_temp_max_c"], g36["blade_temp_max_c"])


# --- the look-ahead ----------------------------------------------------------------------------------------------
class _Recording:
    """Wraps a controller and keeps a copy of every action it returns."""

    def __init__(self, inner):
        self.inner, self.actions = inner, []
        self.name, self.version = inner.name, inner.version

    def attach(self, plant, trace):
        self.inner.attach(plant, trace)

    def reset(self):
        self.inner.reset()
        self.actions = []

    def act(self, obs):
        action = self.inner.act(obs)
        self.actions.append(action.copy())
        return action

    @property
    def sim_steps(self):
        return self.inner.sim_steps


def test_lookahead_leaves_the_plant_where_it_found_it_and_counts_its_steps(lcopt5):
    n_steps, period, horizon, hours = 240, 4, 20, 1.0
    trace = load_trace(FRONTIER_DAY, lcopt5, hours=hours)  # 240 steps: the last decisions' horizons are cut
    look = make_controller("lookahead", lcopt5, period_steps=period, horizon_steps=horizon)
    ctl = _Recording(look)
    with Plant(lcopt5) as plant:
        outputs = []
        run_twin(plant, trace, ctl, n_steps=n_steps, on_step=lambda k: outputs.append(plant.out["blade_temp_k"].copy()))
        assert plant.n_steps_done == n_steps
        # replay the chosen actions from the spun-up state, without the look-ahead: the same trajectory, bit for bit
        plant.reset()
        power = np.zeros(lcopt5.n_blade_groups)
        for k, action in enumerate(ctl.actions):
            out = plant.step(trace.blade_power_w(k, out=power), float(trace.wet_bulb_k[k]), action)
            np.testing.assert_array_equal(out["blade_temp_k"], outputs[k], err_msg=f"step {k}")
    expected = sum(7 * min(horizon, trace.n_steps - k) for k in range(0, n_steps, period))
    assert look.sim_steps == expected and look.decisions == n_steps // period
    assert look.wall_s > 0


def test_lookahead_beats_g36_on_the_design_day(lcopt5):
    hours = 1.0
    trace = load_trace(FRONTIER_DAY, lcopt5, scenario="design-day")
    n_steps = round(hours * 3600 / trace.step_s)
    g36 = _run(lcopt5, make_controller("g36", lcopt5), trace, n_steps)
    look = _run(lcopt5, make_controller("lookahead", lcopt5), trace, n_steps)
    assert look.controller_cost["sim_steps"] == (n_steps // 4) * 7 * 120
    # measured: look-ahead 150.5, G36 182.6 (no blade out of band for either)
    assert _cost(look.kpi, lcopt5, hours) <= _cost(g36.kpi, lcopt5, hours)


def test_lookahead_outside_a_run_says_where_it_runs(lcopt5, plant):
    look = make_controller("lookahead", lcopt5)
    with pytest.raises(RuntimeError, match=re.escape(NOT_ATTACHED)):
        look.act(Observation(plant.out, 295.0, np.zeros(lcopt5.n_blade_groups), 0.0))
    look.attach(plant, load_trace(FRONTIER_DAY, lcopt5, hours=1))
    with pytest.raises(RuntimeError, match="is not step 0 of the attached trace"):
        look.act(Observation(plant.out, 200.0, np.zeros(lcopt5.n_blade_groups), 0.0))


# --- third-party controllers -------------------------------------------------------------------------------------
def _docs_example() -> str:
    """The "Bring your own controller" example of docs/controllers.md, so the docs keep working."""
    section = DOCS.read_text().split("## Bring your own controller", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


@pytest.fixture
def plugin_dir(tmp_path, monkeypatch):
    """A module `my_controllers` (the docs' example) and a broken `bad_controllers`, importable for this test."""
    (tmp_path / "my_controllers.py").write_text(_docs_example())
    (tmp_path / "bad_controllers.py").write_text(
        "class NoAct:\n    name, version = 'no-act', '1'\n\n    def __init__(self, system):\n        pass\n\n"
        "    def reset(self):\n        pass\n\n\nNOT_A_CLASS = 3\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    for name in ("my_controllers", "bad_controllers"):
        sys.modules.pop(name, None)


def test_a_plugin_runs_through_make_controller(lcopt5, plugin_dir):
    ctl = make_controller("my_controllers:FixedApproach", lcopt5, approach_k=3.0)
    assert ctl.name == "fixed-approach" and ctl.approach_k == 3.0
    trace = load_trace(FRONTIER_DAY, lcopt5, hours=0.5)
    result = _run(lcopt5, ctl, trace, trace.n_steps)
    assert result.controller == "fixed-approach" and result.kpi["steps"] == trace.n_steps
    assert result.controller_cost is None


def test_a_plugin_runs_through_the_cli(plugin_dir, tmp_path):
    from lcmesh.cli import app

    out = tmp_path / "run.json"
    result = CliRunner().invoke(app, ["twin", "run", "--controller", "my_controllers:FixedApproach", "--hours", "0.5",
                                      "--json", str(out), "--plot", str(tmp_path / "run.png")])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["controller"] == "fixed-approach"
    bad = CliRunner().invoke(app, ["twin", "run", "--controller", "my_controllers:FixedApproch", "--hours", "0.5"])
    assert bad.exit_code == 2 and "did you mean 'FixedApproach'" in bad.output


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("no_such_module_xyz:Ctl", "no module named 'no_such_module_xyz' (is its package installed or on PYTHONPATH?)"),
        ("my_controllers:FixedApproch", "module 'my_controllers' has no 'FixedApproch'; did you mean 'FixedApproach'?"),
        ("bad_controllers:NoAct", "does not follow the Controller protocol (lcmesh/twin/controllers/base.py)"),
        ("bad_controllers:NoAct", "it lacks a method `act`"),
        ("bad_controllers:NOT_A_CLASS", "'NOT_A_CLASS' is not a class (type int)"),
        (":Ctl", "a third-party controller is named 'package.module:Class'"),
        ("my_controllers:", "a third-party controller is named 'package.module:Class'"),
        ("gg36", "unknown controller 'gg36'; did you mean 'g36'?"),
    ],
)
def test_bad_controller_names_say_what_is_wrong(lcopt5, plugin_dir, name, message):
    with pytest.raises(ControllerError, match=re.escape(message)):
        make_controller(name, lcopt5)


# --- the mesh's allow-list ---------------------------------------------------------------------------------------
def test_the_mesh_loads_a_plugin_only_when_allow_listed(lcopt5, plugin_dir):
    from lcmesh.mesh.agents.control import build_controller
    from lcmesh.mesh.settings import MeshSettings

    ctl, note = build_controller("my_controllers:FixedApproach", lcopt5)
    assert ctl.name == "g36" and "LCMESH_CONTROLLER_PLUGINS" in note and "using 'g36'" in note
    assert "my_controllers" not in sys.modules  # refused before anything was imported

    settings = MeshSettings(controller_plugins="my_controllers:FixedApproach,other.mod:Ctl")
    assert settings.controller_plugins == ["my_controllers:FixedApproach", "other.mod:Ctl"]
    ctl, note = build_controller("my_controllers:FixedApproach", lcopt5, settings.allowed_controller_plugins)
    assert ctl.name == "fixed-approach" and note is None
    own = MeshSettings(controller="my_controllers:FixedApproach")  # the process's own setting is trusted
    assert build_controller(own.controller, lcopt5, own.allowed_controller_plugins)[0].name == "fixed-approach"

    ctl, note = build_controller("lookahead", lcopt5)
    assert ctl.name == "g36" and "perfect-forecast ceiling" in note


def test_the_mesh_settings_and_validators_refuse_what_it_can_not_run():
    from pydantic import ValidationError

    from lcmesh.mesh.agents.ui.schemas import ModeRequest
    from lcmesh.mesh.settings import MeshSettings

    with pytest.raises(ValidationError, match="`controller_plugins` entries must look like 'package.module:Class'"):
        MeshSettings(controller_plugins="not a name")
    assert MeshSettings(controller_plugins='["a.b:C"]').controller_plugins == ["a.b:C"]
    assert mesh_refusal("rule") is None and mesh_refusal("a.b:C", ["a.b:C"]) is None
    assert "listed: none" in mesh_refusal("a.b:C")
    assert ModeRequest(controller="a.b:C").controller == "a.b:C"  # the Configuration agent checks the list
    with pytest.raises(ValidationError, match="perfect-forecast ceiling"):
        ModeRequest(controller="lookahead")
    with pytest.raises(ValidationError, match="did you mean 'g36'"):
        ModeRequest(controller="g63")


def test_the_configuration_store_checks_the_allow_list(tmp_path):
    from lcmesh.mesh.agents.configuration import ConfigStore
    from lcmesh.mesh.bus import QueryError
    from lcmesh.mesh.messages import MeshConfig

    seed = MeshConfig(controller="g36")
    store = ConfigStore(tmp_path / "config.json", seed, None, None, controller_plugins=["a.b:C"])
    assert store.validate({"controller": "a.b:C"}).controller == "a.b:C"
    with pytest.raises(QueryError, match=r"`controller` must be a registered controller or a plugin listed in "
                                         r"LCMESH_CONTROLLER_PLUGINS \(listed: a.b:C\), got 'x.y:Z'"):  # fmt: skip
        store.validate({"controller": "x.y:Z"})
    with pytest.raises(QueryError, match="`controller` must be one of .*did you mean 'g36'"):
        store.validate({"controller": "gg36"})
