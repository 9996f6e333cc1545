"""The LLM controller: batched cabinet and tower decisions, strict parsing, counted per-answer fallback, periods."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.llm.base import Generation
from lcmesh.llm.controller import LlmController
from lcmesh.llm.io_format import answer_text, tower_answer_text
from lcmesh.twin.controllers import Observation, make_controller
from lcmesh.twin.system import PSI_TO_PA
from tests.llm.conftest import ForwardClock, frozen_clock


class ScriptedBackend:
    """A fake at the backend seam: returns scripted answers and records the batches it got."""

    name, model_id = "scripted", "scripted"

    def __init__(self, answers):
        self.answers, self.batches = answers, []

    def chat(self, conversations, *, max_new_tokens, stop=(), drafts=None, time_budget_s=None):
        self.batches.append(len(conversations))
        if isinstance(self.answers, Exception):
            raise self.answers
        return [a if isinstance(a, Generation) else Generation(a, 10, 5, 0.01, "stop") for a in self.answers]


def _obs(plant, lcopt5, k=0):
    out = plant.reset() if k == 0 else plant.out
    power = np.full(lcopt5.n_blade_groups, 60e3)
    return Observation(out, 291.15, power, 15.0 * k), power


GOOD = answer_text(300.15, 30 * PSI_TO_PA, [0.5, 0.3, 0.2])
TOWER = tower_answer_text(4.0)


def test_valid_answers_drive_the_cdu_and_the_towers_and_garbage_falls_back_per_answer(plant, lcopt5):
    answers = [GOOD, "I think 25 C is good", GOOD, '{"supply_c": 55, "dp_psi": 30, "valves": [0.4, 0.3, 0.3]}', GOOD,
               TOWER, '{"approach_k": 12}']  # fmt: skip
    backend = ScriptedBackend(answers)
    ctl = LlmController(lcopt5, backend=backend, fallback="g36", period_steps=1)
    g36 = make_controller("g36", lcopt5)
    obs, _ = _obs(plant, lcopt5)
    action = ctl.act(obs).copy()
    expected = g36.act(obs)
    assert backend.batches == [7]  # one batched call for all 5 cabinets and 2 towers
    for c in (0, 2, 4):
        assert action.supply_temp_setpoint_k[c] == pytest.approx(300.15, abs=0.01)
        np.testing.assert_allclose(action.valve_fractions[c], [0.5, 0.3, 0.2], atol=1e-9)
    for c in (1, 3):  # the fallback's own cabinet action
        assert action.supply_temp_setpoint_k[c] == pytest.approx(expected.supply_temp_setpoint_k[c])
        np.testing.assert_allclose(action.valve_fractions[c], expected.valve_fractions[c])
    assert action.lw_setpoint_k[0] == pytest.approx(obs.wet_bulb_k + 4.0)  # tower 1: wet bulb + the LLM's approach
    assert action.lw_setpoint_k[1] == pytest.approx(expected.lw_setpoint_k[1])  # tower 2's answer was out of bounds
    s = ctl.stats_snapshot()
    assert (s["cabinet_decisions"], s["llm_cabinet_actions"], s["fallbacks"]) == (5, 3, 3)
    assert (s["tower_decisions"], s["llm_tower_actions"]) == (2, 1)
    assert s["fallback_reasons"] == {"not_json": 1, "out_of_bounds": 2}
    assert s["fallbacks_by_kind"] == {"cabinet": 2, "tower": 1}
    assert ctl.last_failures[3] and "supply_c" in ctl.last_failures[3]


def test_backend_exception_falls_back_for_every_cabinet(plant, lcopt5):
    ctl = LlmController(lcopt5, backend=ScriptedBackend(ConnectionError("endpoint down")), fallback="g36")
    obs, _ = _obs(plant, lcopt5)
    action = ctl.act(obs)
    assert np.isfinite(action.supply_temp_setpoint_k).all()
    assert ctl.stats_snapshot()["fallback_reasons"] == {"backend": 7}
    assert "endpoint down" in ctl.last_failures[0]


def test_an_answer_cut_by_the_time_budget_counts_as_timeout(plant, lcopt5):
    cut = Generation('{"supply_c":27.1,"dp_psi":3', 10, 12, 10.0, "timeout")
    done = Generation(GOOD, 10, 39, 10.0, "timeout")  # finished before the budget ran out: usable
    ctl = LlmController(lcopt5, backend=ScriptedBackend([cut, done, cut, done, cut, TOWER, TOWER]), fallback="g36")
    obs, _ = _obs(plant, lcopt5)
    ctl.act(obs)
    s = ctl.stats_snapshot()
    assert s["fallback_reasons"] == {"timeout": 3} and s["llm_cabinet_actions"] == 2


def test_coarse_period_decides_every_k_steps_and_holds(plant, lcopt5):
    backend = ScriptedBackend([GOOD] * 5 + [TOWER] * 2)
    ctl = LlmController(lcopt5, backend=backend, fallback="g36", period_steps=3)
    obs, power = _obs(plant, lcopt5)
    for k in range(7):
        action = ctl.act(obs)
        assert action.dp_setpoint_pa[0] == pytest.approx(30 * PSI_TO_PA, abs=1)
        assert action.lw_setpoint_k[1] == pytest.approx(obs.wet_bulb_k + 4.0)
        out = plant.step(power, obs.wet_bulb_k, action)
        obs = Observation(out, obs.wet_bulb_k, power, 15.0 * (k + 1))
    assert backend.batches == [7, 7, 7]  # steps 0, 3, 6
    assert ctl.stats["decisions"] == 3
    ctl.reset()
    assert ctl.stats["decisions"] == 0


def test_real_model_with_a_tiny_token_budget_falls_back_and_counts(plant, lcopt5, base_backend):
    backend = base_backend.with_clock(frozen_clock)  # no time passes: only the 8 tokens and the parser decide
    ctl = LlmController(lcopt5, backend=backend, fallback="g36", period_steps=1, max_new_tokens=8)
    g36 = make_controller("g36", lcopt5)
    obs, _ = _obs(plant, lcopt5)
    action = ctl.act(obs).copy()
    s = ctl.stats_snapshot()
    assert (s["cabinet_decisions"], s["tower_decisions"]) == (5, 2)
    assert s["fallbacks"] == 7  # 8 tokens cannot hold a complete answer
    assert set(s["fallback_reasons"]) <= {"not_json", "empty", "schema"}
    np.testing.assert_allclose(action.supply_temp_setpoint_k, g36.act(obs).supply_temp_setpoint_k)
    assert 0 < s["new_tokens_total"] <= 7 * 8


def test_a_budget_shorter_than_the_first_pass_falls_back_without_starting_it(plant, lcopt5, base_backend):
    clock = ForwardClock(per_token_s=1e-3)
    backend = base_backend.with_clock(clock, seconds_per_token=1e-3)  # 7 prompts of 100-180 tokens: ~1.1 s expected
    ctl = LlmController(lcopt5, backend=backend, fallback="g36", period_steps=1, decision_budget_s=0.5)
    obs, _ = _obs(plant, lcopt5)
    with clock.driving(base_backend.model):
        ctl.act(obs)
    s = ctl.stats_snapshot()
    assert s["fallback_reasons"] == {"timeout": 7}
    assert clock.passes == 0 and backend.last_forward_passes == 0 and s["new_tokens_total"] == 0
    assert s["latency_s_last"] == 0.0  # on the test clock: the call ended at once


def test_the_decision_budget_stops_decoding_between_steps(plant, lcopt5, base_backend):
    clock = ForwardClock(per_pass_s=0.1)  # every forward pass, prompt or step, takes 0.1 s
    backend = base_backend.with_clock(clock, seconds_per_token=1e-5)
    ctl = LlmController(lcopt5, backend=backend, fallback="g36", period_steps=1, decision_budget_s=0.45)
    obs, _ = _obs(plant, lcopt5)
    with clock.driving(base_backend.model):
        ctl.act(obs)
    s = ctl.stats_snapshot()
    assert clock.now <= 0.45  # the call ended inside its budget: a fifth pass would have ended at 0.5 s
    assert clock.passes == backend.last_forward_passes == 4
    assert s["fallback_reasons"] == {"timeout": 7} and s["new_tokens_total"] == 7 * 4


def test_registry_builds_the_llm_controller(lcopt5):
    ctl = make_controller("llm", lcopt5, backend=ScriptedBackend([GOOD] * 5), fallback="g36", period_steps=2)
    assert ctl.name == "llm" and ctl.period_steps == 2
    assert "fallback=g36" in ctl.version


def test_invalid_period_is_refused(lcopt5):
    with pytest.raises(ValueError, match="period_steps"):
        LlmController(lcopt5, backend=ScriptedBackend([]), fallback="g36", period_steps=-1)
