"""Issue 23, item 1: every run outside the mesh applies the mesh's own guardrails, and says so."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.bench.suite import deploy_checks, render_hru
from lcmesh.distill.ppo_env import Travel, step_rewards
from lcmesh.mesh.tools.guardrails import GuardrailLimits
from lcmesh.twin.controllers import make_controller
from lcmesh.twin.controllers.guarded import Guarded, applied_action, guard
from lcmesh.twin.plant import Plant
from lcmesh.twin.run import run_twin
from lcmesh.twin.traces import load_trace

K = 273.15


class BangBang:
    """Flips every CDU's supply setpoint between 20 and 40 C at every step (the chatter the issue describes)."""

    name, version = "bang-bang", "1"

    def __init__(self, system):
        self.g36 = make_controller("g36", system)
        self.k = 0

    def reset(self) -> None:
        self.g36.reset()
        self.k = 0

    def act(self, obs):
        action = self.g36.act(obs).copy()
        action.supply_temp_setpoint_k[:] = K + (20.0 if self.k % 2 else 40.0)
        self.k += 1
        return action


class Broken(BangBang):
    """Proposes a non-finite setpoint every third step."""

    def act(self, obs):
        action = super().act(obs)
        if self.k % 3 == 0:
            action.dp_setpoint_pa[0] = np.nan
        return action


@pytest.fixture(scope="module")
def runs(lcopt5_module):
    system = lcopt5_module
    trace = load_trace("synthetic:7", system, hours=0.25)
    with Plant(system) as plant:
        bare = run_twin(plant, trace, BangBang(system), guardrails=None, spinup_hours=0.1)
        guarded = run_twin(plant, trace, BangBang(system), spinup_hours=0.1)
        broken = run_twin(plant, trace, Broken(system), spinup_hours=0.1)
    return bare, guarded, broken


@pytest.fixture(scope="module")
def lcopt5_module():
    from lcmesh.twin.system import load_system

    return load_system("lcopt-5")


def test_run_twin_applies_the_mesh_guardrails_by_default_and_reports_them(runs):
    bare, guarded, _ = runs
    assert bare.guardrails == {"guardrails": "off"}
    g = guarded.guardrails
    assert g["guardrails"] == "mesh" and g["steps"] == 60 and g["rejected"] == 0
    # it settles between 38 and 40 C: every flip down is cut to 2 K, the flips back up pass
    assert 29 <= g["clamped_steps"] <= 60 and g["clamped_steps_pct"] == pytest.approx(100.0 * g["clamped_steps"] / 60)
    # the rate limit (2 K per step, GuardrailLimits) bounds the travel: 5 CDUs x 60 steps x 2 K
    assert guarded.kpi["actuator_travel"]["supply_temp_setpoint_k"] <= 5 * 60 * 2.0 + 1e-6
    assert bare.kpi["actuator_travel"]["supply_temp_setpoint_k"] > 5 * 50 * 19.0
    assert guarded.to_json()["guardrails"]["guardrails"] == "mesh"


def test_a_rejected_proposal_holds_the_last_applied_action_and_is_counted(runs):
    *_, broken = runs
    assert broken.guardrails["rejected"] == 20
    assert np.isfinite(broken.kpi["d_blade_pct"])


def test_the_wrapper_passes_through_what_it_does_not_define(lcopt5_module):
    lookahead = make_controller("lookahead", lcopt5_module)
    wrapped = guard(lookahead, lcopt5_module, GuardrailLimits())
    assert isinstance(wrapped, Guarded) and wrapped.name == "lookahead"
    assert wrapped.sim_steps == 0 and callable(wrapped.attach)
    assert guard(wrapped, lcopt5_module, GuardrailLimits()) is wrapped
    assert guard(lookahead, lcopt5_module, None) is lookahead


def test_the_first_action_is_limited_against_what_the_plant_applies(lcopt5_module):
    from lcmesh.twin.controllers.base import Observation

    system = lcopt5_module
    power = np.full(system.n_blade_groups, 1e3)
    with Plant(system) as plant:
        fresh = Observation(plant.out, 285.0, power, 0.0)
        first = Guarded(BangBang(system), system).spinup_action(fresh)  # nothing applied yet: the ranges only
        assert np.all(first.supply_temp_setpoint_k == K + 40.0)
        plant.spin_up(power, 285.0, make_controller("g36", system).act(fresh), hours=0.05)
        out = plant.reset()
        before = applied_action(out)
        action = Guarded(BangBang(system), system).act(Observation(out, 285.0, power, 0.0))
    step = np.abs(action.supply_temp_setpoint_k - before.supply_temp_setpoint_k)
    assert np.all(step <= 2.0 + 1e-9) and np.all(step > 0.0)


def test_the_deploy_reward_charges_travel_and_the_hottest_blade(lcopt5_module):
    system = lcopt5_module
    with Plant(system) as plant:
        out = dict(plant.out)
    C, N = system.cabinets.count, system.towers.count
    action = applied_action(out)
    still = Travel(np.zeros(C), np.zeros(C), np.zeros(N))
    moved = Travel(np.full(C, 2.0), np.full(C, 1.0), np.full(N, 1.0))
    cab0, tow0 = step_rewards(system, out, action, "deploy", still)
    cab1, tow1 = step_rewards(system, out, action, "deploy", moved)
    np.testing.assert_allclose(cab0 - cab1, 2.0 * 0.5 + 1.0 * 0.05)
    np.testing.assert_allclose(tow0 - tow1, 0.1)
    hot = dict(out)
    hot["blade_temp_k"] = out["blade_temp_k"].copy()
    hot["blade_temp_k"][0] = K + 42.0  # cabinet 1's hottest group 3 K above the 39 C limit
    cab2, _ = step_rewards(system, hot, action, "deploy", still)
    energy, _ = step_rewards(system, hot, action, "energy", still)
    assert cab2[0] < energy[0] - 2.0 * 3.0 + 1e-9 and cab2[1:] == pytest.approx(energy[1:])


def _entry(d_blade, kwh, hot, travel):
    days = {"a": {"d_blade_pct": d_blade[0], "cooling_kwh": kwh, "blade_max_c": hot[0],
                  "travel": {"supply_temp_setpoint_k": travel}},
            "b": {"d_blade_pct": d_blade[1], "cooling_kwh": kwh, "blade_max_c": hot[1],
                  "travel": {"supply_temp_setpoint_k": travel}}}  # fmt: skip
    mean = {"d_blade_pct": sum(d_blade) / 2, "cooling_kwh": kwh}
    return {"error": None, "days": days, "mean": mean}


def test_the_deploy_checks_name_each_target_and_whether_it_is_met():
    r = {"days": [{"label": "a"}, {"label": "b"}], "controllers": {
        "g36": _entry((99.0, 99.5), 4000, (40.0, 41.0), 500),
        "rule": _entry((99.0, 99.4), 4000, (40.0, 41.0), 500),
        "ppo": _entry((99.9, 98.0), 3000, (40.5, 43.0), 1200),
        "readable": _entry((99.0, 99.4), 3100, (40.0, 41.0), 900),
        "lookahead": _entry((99.9, 99.9), 3050, (40.0, 41.0), 100)}}  # fmt: skip
    checks = {(c["controller"], c["target"].split(" ")[0]): c for c in deploy_checks(r)}
    assert not checks[("ppo", "no")]["met"]
    assert checks[("ppo", "no")]["measured"].startswith("largest loss 1.50 points (b)")
    assert checks[("ppo", "cooling")]["met"]  # 3000 / 4000 = 0.75x
    assert checks[("ppo", "supply")]["met"]  # 2.4x
    assert not checks[("ppo", "hottest")]["met"]  # +2 K on day b
    assert checks[("readable", "no")]["met"]  # 0.1 points
    la = checks[("lookahead", "no")]
    assert not la["met"] and "ppo on a" in la["measured"]  # ppo: equal D_blade on day a at less energy


def test_the_hru_table_shows_each_controller_without_and_with_the_unit():
    row = {"error": None, "tower_fan_kwh_off": 200.0, "tower_fan_kwh_on": 150.0, "fan_cut_pct": 25.0,
           "cooling_kwh_off": 3000.0, "cooling_kwh_on": 2950.0, "cooling_cut_pct": 1.67, "d_blade_pct_off": 99.9,
           "d_blade_pct_on": 99.8, "heat_recovered_kwh": 5000.0}  # fmt: skip
    r = {"machine": {"cpu": "x", "logical_cpus": 2, "commit": "c", "date": "d"}, "hours": 24.0, "days": ["a"],
         "rows": {"g36": row, "llm": {"error": "build failed"}}, "guardrails": "mesh", "published": "21 %"}  # fmt: skip
    text = render_hru(r)
    assert "| g36 | 200 / 150 | 25.0 | 3,000 / 2,950 | 1.7 | 99.90 / 99.80 | 5,000 |" in text
    assert "| llm | not run: build failed" in text and "21 %" in text
