"""The strong rule, the look-ahead ceiling and third-party controllers (issue 13, an honest control benchmark)."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lcmesh.mesh.tools.guardrails import GuardrailLimits
from lcmesh.twin.controllers import ControllerError, Observation, make_controller, mesh_refusal
from lcmesh.twin.controllers.lookahead import NOT_ATTACHED
from lcmesh.twin.controllers.rule import MIN_VALVE_FRACTION
from lcmesh.twin.plant import Plant
from lcmesh.twin.run import run_twin
from lcmesh.twin.traces import FRONTIER_DAY, load_trace

DOCS = Path(__file__).resolve().parents[2] / "docs" / "controllers.md"
TRAINING_DAY = "synthetic:7"  # the look-ahead's tests run training days, never a test or validation day


def _run(system, controller, trace, n_steps):
    """A run on a fresh plant: a plant's history would leak into the spin-up (G36 starts from measured values)."""
    with Plant(system) as plant:
        return run_twin(plant, trace, controller, n_steps=n_steps)


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
    n_steps, period, horizon, hours = 240, 8, 20, 1.0
    trace = load_trace(TRAINING_DAY, lcopt5, hours=hours)  # 240 steps: the last decisions' horizons are cut
    look = make_controller("lookahead", lcopt5, period_steps=period, horizon_steps=horizon)
    ctl = _Recording(look)
    with Plant(lcopt5) as plant:
        outputs = []
        result = run_twin(
            plant, trace, ctl, n_steps=n_steps, on_step=lambda k: outputs.append(plant.out["blade_temp_k"].copy())
        )
        assert plant.n_steps_done == n_steps
        # replay the proposed actions from the spun-up state, without the look-ahead and its guardrails: the same
        # trajectory, bit for bit (so the guardrails changed nothing either)
        plant.reset()
        power = np.zeros(lcopt5.n_blade_groups)
        for k, action in enumerate(ctl.actions):
            out = plant.step(trace.blade_power_w(k, out=power), float(trace.wet_bulb_k[k]), action)
            np.testing.assert_array_equal(out["blade_temp_k"], outputs[k], err_msg=f"step {k}")
    assert result.guardrails["clamped_values"] == 0 and result.guardrails["rejected"] == 0
    assert look.decisions == n_steps // period and look.wall_s > 0
    # a decision simulates the setting in force to the horizon's end, then at most every probe, pick and approach
    # of each pass
    least = sum(min(horizon, trace.n_steps - k) for k in range(0, n_steps, period))
    per_pass = len(look.dp_psi) * len(look.supply_moves_k) + 1 + len(look.approaches_k)
    assert least < look.sim_steps <= (1 + look.passes * per_pass) * least


def test_lookahead_moves_every_setpoint_within_the_guardrails(lcopt5):
    """A cold hour (wet bulb 3-5 C: leaving water floored at 10 C) and settings far from the spin-up's: ramps,
    never a clamp."""
    trace = load_trace(TRAINING_DAY, lcopt5, hours=1.0)
    look = make_controller("lookahead", lcopt5, period_steps=4, horizon_steps=12, approaches_k=(3.0, 10.0))
    ctl = _Recording(look)
    with Plant(lcopt5) as plant:
        result = run_twin(plant, trace, ctl, n_steps=120)
    limits = GuardrailLimits()
    steps = [(a, b, float(trace.wet_bulb_k[k + 1])) for k, (a, b) in enumerate(zip(ctl.actions, ctl.actions[1:]))]
    for a, b, wet_bulb_k in steps:
        assert np.abs(b.supply_temp_setpoint_k - a.supply_temp_setpoint_k).max() <= limits.supply_temp_rate_k
        assert np.abs(b.dp_setpoint_pa - a.dp_setpoint_pa).max() <= limits.dp_rate_pa
        assert b.lw_setpoint_k.min() >= max(wet_bulb_k + limits.min_approach_k, limits.lw_min_k)
    lw_steps = [np.abs(b.lw_setpoint_k - a.lw_setpoint_k).max() for a, b, _ in steps]
    assert max(lw_steps) <= limits.lw_rate_k
    assert result.guardrails["clamped_values"] == 0, result.guardrails


def test_lookahead_minimises_energy_subject_to_the_band(lcopt5):
    """Each decision's pick is the lexicographic minimum of what it tried: the fewest out-of-band blade-steps, then
    the least cooling energy; no setting tried with as few blade-steps out of band uses less energy."""
    trace = load_trace(TRAINING_DAY, lcopt5, scenario="design-day", hours=1.0)
    picks = []

    class Decisions(_Recording):
        def reset(self):
            super().reset()
            picks.clear()

        def act(self, obs):
            action = super().act(obs)
            if self.inner.last_costs and self.inner.decisions > len(picks):
                picks.append((self.inner.setting, dict(self.inner.last_costs)))
            return action

    for search in ("grid", "coordinate"):
        look = make_controller("lookahead", lcopt5, period_steps=20, horizon_steps=20, search=search,
                               supply_moves_k=(-2.0, 0.0, 2.0), dp_psi=(25.0, 33.0), approaches_k=(3.0, 8.0))  # fmt: skip
        with Plant(lcopt5) as plant:
            run_twin(plant, trace, Decisions(look), n_steps=60)
        assert len(picks) == 3
        for setting, costs in picks:
            assert costs[setting] == min(costs.values()), (search, setting, costs)
            out_of_band, kwh = costs[setting]
            assert not [c for c in costs.values() if c[0] <= out_of_band and c[1] < kwh]


def test_lookahead_beats_g36_on_a_hot_hour(lcopt5):
    trace = load_trace("synthetic:3", lcopt5, scenario="design-day", hours=1.0)  # a training day; 0.75 -> 4.8 MW
    n_steps = trace.n_steps
    g36 = _run(lcopt5, make_controller("g36", lcopt5), trace, n_steps)
    look = _run(lcopt5, make_controller("lookahead", lcopt5), trace, n_steps)
    assert look.controller_cost["sim_steps"] >= (n_steps // 8) * 120
    # measured: look-ahead 100 % at 130.2 kWh, G36 100 % at 184.5 kWh (the target: no controller uses less
    # cooling energy at equal or better D_blade)
    assert look.kpi["d_blade_pct"] >= g36.kpi["d_blade_pct"]
    assert look.kpi["cooling_power_kw_avg"] < 0.9 * g36.kpi["cooling_power_kw_avg"]


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
