"""The LLM controller on the real runtime: who decided is counted, budgets on a test clock, the period paces the mesh."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.distill.features import SUPPLY_RANGE_K
from lcmesh.llm.controller import LlmController, decided_by_line
from lcmesh.twin.controllers import Observation, make_controller


class PassClock:
    """A clock that moves only when the model runs: each forward pass of the runtime costs ``per_pass_s``."""

    def __init__(self, backend, per_pass_s: float):
        self.now, self.passes, self.per_pass_s = 0.0, 0, per_pass_s
        scorer = backend.scorer
        inner = scorer.logits_after

        def timed(ids):
            self.now += self.per_pass_s
            self.passes += 1
            return inner(ids)

        scorer.logits_after = timed
        self._undo = lambda: setattr(scorer, "logits_after", inner)

    def __call__(self) -> float:
        return self.now

    def close(self) -> None:
        self._undo()


class DeadRuntime:
    """A runtime that fails (a real failure path: the controller must keep the plant controlled)."""

    model_id, runtime = "dead", "dead"

    def decide(self, prompts, fields, deadline=None):
        raise ConnectionError("runtime gone")


def _obs(plant, lcopt5, k=0):
    out = plant.reset() if k == 0 else plant.out
    power = np.full(lcopt5.n_blade_groups, 60e3)
    return Observation(out, 291.15, power, 15.0 * k), power


def test_without_a_deadline_the_llm_answers_every_cabinet_and_tower(plant, lcopt5, control_backend):
    ctl = LlmController(lcopt5, backend=control_backend, fallback="g36", period_steps=2)
    obs, power = _obs(plant, lcopt5)
    for k in range(3):
        action = ctl.act(obs)
        lo, hi = SUPPLY_RANGE_K
        assert np.all((action.supply_temp_setpoint_k >= lo) & (action.supply_temp_setpoint_k <= hi))
        np.testing.assert_allclose(action.valve_fractions.sum(axis=1), 1.0)
        obs = Observation(plant.step(power, obs.wet_bulb_k, action), obs.wet_bulb_k, power, 15.0 * (k + 1))
    s = ctl.stats_snapshot()
    assert s["decisions"] == 2  # steps 0 and 2
    assert (s["llm_cabinet_actions"], s["llm_tower_actions"], s["fallbacks"]) == (10, 4, 0)
    assert s["llm_share"] == 1.0 and s["steps_llm"] == s["steps"] == 3
    # at most 8 decided digits a cabinet and 2 a tower (the grammar fixes the rest, and all of 40.0 and 1.5)
    assert 2 * (5 * 6 + 2 * 1) <= s["forward_passes"] <= 2 * (5 * 8 + 2 * 2)
    assert all(len(a.split()) == 5 for a in ctl.last_answers[:5])  # supply, dp, three valve weights
    report = ctl.decided_by()
    assert report["llm_share"] == 1.0 and "14 of 14" in report["summary"] and "every 2 plant steps" in report["summary"]


def test_a_decision_budget_leaves_late_cabinets_to_the_fallback_and_says_so(plant, lcopt5, control_backend):
    clock = PassClock(control_backend, per_pass_s=0.1)  # a cabinet is 8 passes (6 at 40 degC): 0.8 s
    try:
        backend = control_backend.with_clock(clock)
        ctl = LlmController(lcopt5, backend=backend, fallback="g36", period_steps=1, decision_budget_s=2.0)
        obs, _ = _obs(plant, lcopt5)
        action = ctl.act(obs).copy()
    finally:
        clock.close()
    s = ctl.stats_snapshot()
    # 0.8 + 0.8 s for two cabinets; a third would end at 2.4 s; each tower (2 passes) still fits: 1.8 s, 2.0 s
    assert (s["llm_cabinet_actions"], s["llm_tower_actions"]) == (2, 2)
    assert s["fallback_reasons"] == {"deadline": 3} and s["fallbacks_by_kind"] == {"cabinet": 3}
    g36 = make_controller("g36", lcopt5).act(obs)
    np.testing.assert_allclose(action.supply_temp_setpoint_k[2:], g36.supply_temp_setpoint_k[2:])
    assert "g36 served the other 3 (deadline 3)" in ctl.decided_by()["summary"]


def test_a_failed_runtime_falls_back_for_everything_counted(plant, lcopt5):
    ctl = LlmController(lcopt5, backend=DeadRuntime(), fallback="g36", period_steps=1, clock=lambda: 0.0)
    obs, _ = _obs(plant, lcopt5)
    action = ctl.act(obs)
    np.testing.assert_allclose(action.supply_temp_setpoint_k, make_controller("g36", lcopt5).act(obs).supply_temp_setpoint_k)
    s = ctl.stats_snapshot()
    assert s["fallback_reasons"] == {"runtime_error": 7} and s["llm_share"] == 0.0


def test_pace_sets_the_period_from_the_decision_latency_and_the_wall_step(lcopt5):
    ctl = LlmController(lcopt5, backend=DeadRuntime(), fallback="g36", period_steps=2, clock=lambda: 0.0)
    assert ctl.pace(0.25) == 2 and ctl.decision_budget_s == pytest.approx(0.4)  # nothing measured: the base period
    ctl.stats["decisions"], ctl.stats["latency_s_total"], ctl.stats["latency_s_last"] = 4, 8.0, 2.2
    assert ctl.pace(0.25) == 14  # 2.2 s with the 1.2 margin at most 80 % of k * 0.25 s
    assert ctl.decision_budget_s == pytest.approx(14 * 0.25 * 0.8)
    ctl._recent.extend([1.0, 3.0, 1.0])  # the slowest recent decision counts, not only the latest and the mean
    assert ctl.pace(0.25) == 18
    assert ctl.pace(15.0) == 2  # at 1x the configured period holds
    with pytest.raises(ValueError, match="step_wall_s"):
        ctl.pace(0.0)


def test_the_summary_line_names_share_period_and_reasons():
    snap = {"cabinet_decisions": 50, "tower_decisions": 20, "llm_cabinet_actions": 48, "llm_tower_actions": 20,
            "fallbacks": 2, "fallback_reasons": {"deadline": 2}, "fallback_controller": "ppo", "period_steps": 9}
    assert decided_by_line(snap) == ("the LLM made 68 of 70 cabinet and tower decisions (97.1 %), every 9 plant steps; "
                                     "ppo served the other 2 (deadline 2)")  # fmt: skip


def test_registry_builds_the_llm_controller_on_the_packaged_adapter(lcopt5):
    ctl = make_controller("llm", lcopt5, fallback="g36", period_steps=2)
    assert ctl.name == "llm" and ctl.period_steps == 2
    assert "llama.cpp" in ctl.version and "fallback=g36" in ctl.version and "llm-control" in ctl.version


def test_invalid_settings_are_refused(lcopt5):
    with pytest.raises(ValueError, match="period_steps"):
        LlmController(lcopt5, backend=DeadRuntime(), fallback="g36", period_steps=-1)
    with pytest.raises(ValueError, match="decision_budget_s"):
        LlmController(lcopt5, backend=DeadRuntime(), fallback="g36", decision_budget_s=0.0)
