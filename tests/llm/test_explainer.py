"""LLM explanations are scored by the explanation evaluator and replaced by the renderer when they fail."""

from __future__ import annotations

import numpy as np
import pytest

from lcmesh.llm.base import Generation
from lcmesh.llm.explainer import LlmExplainer, explain_messages
from lcmesh.mesh.tools.explain import render_explanation
from lcmesh.mesh.tools.explain_eval import LEVEL_SECTIONS
from lcmesh.mesh.tools.facts import cabinet_decision_facts
from lcmesh.twin.controllers import Observation, make_controller
from tests.llm.conftest import ForwardClock, frozen_clock


class EchoBackend:
    """A fake at the backend seam: answers with a fixed text, or with the draft it was given."""

    name, model_id = "echo", "echo"

    def __init__(self, text=None):
        self.text, self.calls = text, []

    def chat(self, conversations, *, max_new_tokens, stop=(), drafts=None, time_budget_s=None):
        self.calls.append((conversations, drafts))
        text = self.text if self.text is not None else drafts[0]
        return [Generation(text, 100, 50, 0.01, "stop")]


@pytest.fixture
def decision(plant, lcopt5):
    g36 = make_controller("g36", lcopt5)
    out = plant.reset()
    power = np.full(lcopt5.n_blade_groups, 70e3)
    previous = g36.act(Observation(out, 291.15, power, 0.0)).copy()
    out = plant.step(power, 291.15, previous)
    action = g36.act(Observation(out, 291.15, power, 15.0)).copy()
    return out, action, previous


def test_prompt_lists_the_facts_and_the_level_sections(decision, lcopt5):
    out, action, previous = decision
    facts = cabinet_decision_facts(lcopt5, out, action, previous, 291.15, 2)
    system, user = explain_messages(facts, "detailed")
    for heading in LEVEL_SECTIONS["detailed"]:
        assert heading in system["content"]
    assert "Cabinet 3" in user["content"]
    assert all(f"{f.name} = {f.display}" in user["content"] for f in facts)


def test_a_grounded_llm_text_is_used(decision, lcopt5):
    out, action, previous = decision
    backend = EchoBackend()  # writes exactly the draft it is given: the renderer's text
    r = LlmExplainer(lcopt5, backend).explain(out, action, previous, 291.15, 1, "short")
    assert r.source == "llm" and r.fallback_reason is None
    assert r.llm_scores["numeric_grounding"] >= 0.98 and r.llm_scores["coverage"] == 1.0
    assert backend.calls[0][1] is not None  # the rendering went along as the draft


def test_an_ungrounded_llm_text_falls_back_to_the_renderer(decision, lcopt5):
    out, action, previous = decision
    bad = "## EXPLANATION\n\nThe valves moved to 0.91, 0.07 and 0.02 because 77.7 kW.\n"
    explainer = LlmExplainer(lcopt5, EchoBackend(bad))
    r = explainer.explain(out, action, previous, 291.15, 0, "short")
    facts = cabinet_decision_facts(lcopt5, out, action, previous, 291.15, 0)
    assert r.source == "renderer"
    assert r.text == render_explanation(facts, "short")
    assert r.fallback_reason in ("numeric_grounding", "coverage")
    assert explainer.stats["renderer"] == 1 and explainer.stats[f"fallback_{r.fallback_reason}"] == 1


def test_unknown_level_is_refused(decision, lcopt5):
    out, action, previous = decision
    with pytest.raises(ValueError, match="very_detailed"):
        LlmExplainer(lcopt5, EchoBackend()).explain(out, action, previous, 291.15, 0, "long")


def test_the_real_base_model_is_checked_like_any_other(decision, lcopt5, base_backend):
    """Untrained, with a small token budget, its text cannot cover every action dimension: the renderer stands in."""
    from lcmesh.llm import explainer as ex

    out, action, previous = decision
    budget = dict(ex.MAX_NEW_TOKENS)
    ex.MAX_NEW_TOKENS["short"] = 24
    backend = base_backend.with_clock(frozen_clock)  # no time passes: the checks decide, not the machine's load
    try:
        r = LlmExplainer(lcopt5, backend, use_draft=False).explain(out, action, previous, 291.15, 0, "short")
    finally:
        ex.MAX_NEW_TOKENS.update(budget)
    assert r.source == "renderer" and r.fallback_reason not in (None, "timeout")
    assert 0 < r.new_tokens <= 24


def test_a_budget_shorter_than_the_first_pass_leaves_the_text_to_the_renderer(decision, lcopt5, base_backend):
    clock = ForwardClock(per_token_s=1e-3)
    backend = base_backend.with_clock(clock, seconds_per_token=1e-3)  # prompt and draft: ~1,400 tokens, ~1.4 s
    explainer = LlmExplainer(lcopt5, backend, time_budget_s={"short": 0.5})
    out, action, previous = decision
    with clock.driving(base_backend.model):
        r = explainer.explain(out, action, previous, 291.15, 4, "short")
    assert r.source == "renderer" and r.fallback_reason == "timeout"
    assert r.text == render_explanation(cabinet_decision_facts(lcopt5, out, action, previous, 291.15, 4))
    assert clock.passes == 0 and r.new_tokens == 0 and r.seconds == 0.0  # not started: no pass, no time
    assert explainer.stats["fallback_timeout"] == 1


def test_draft_verified_decoding_does_not_start_a_pass_that_would_end_late(decision, lcopt5, base_backend):
    clock = ForwardClock(per_pass_s=0.2)
    backend = base_backend.with_clock(clock, seconds_per_token=1e-5)
    explainer = LlmExplainer(lcopt5, backend, time_budget_s={"short": 0.5})
    out, action, previous = decision
    with clock.driving(base_backend.model):
        r = explainer.explain(out, action, previous, 291.15, 4, "short")
    assert r.fallback_reason == "timeout" and r.new_tokens > 0
    assert clock.passes == backend.last_forward_passes == 2  # a third pass would have ended at 0.6 s
    assert r.seconds == clock.now <= 0.5


def _whatif(decision, lcopt5, cabinet=1):
    from lcmesh.mesh.tools.facts import decision_whatif_facts

    out, action, previous = decision
    facts = cabinet_decision_facts(lcopt5, out, action, previous, 291.15, cabinet)
    return facts, decision_whatif_facts(lcopt5, out, action, previous, 291.15, cabinet)


def test_the_llm_gets_the_whatif_facts_and_a_text_stating_them_counts_its_claims(decision, lcopt5):
    from lcmesh.mesh.tools.explain import render_whatif

    out, action, previous = decision
    facts, extra = _whatif(decision, lcopt5)
    names = {f.name for f in extra}
    assert {"hottest_branch_expected", "hottest_branch_if_held", "pump_power_expected", "top_input"} <= names
    text = render_explanation(facts, "detailed") + "\n" + render_whatif(extra)
    backend = EchoBackend(text)
    explainer = LlmExplainer(lcopt5, backend)
    r = explainer.explain(out, action, previous, 291.15, 1, "detailed")
    user = backend.calls[0][0][0][1]["content"]
    assert "hottest_branch_if_held = " in user and "top_input = " in user
    assert r.source == "llm" and not r.identical_to_rendering
    assert "hottest_branch_expected" in r.whatif_claims
    assert explainer.stats["llm_with_whatif_claim"] == 1 and explainer.stats["llm_identical_to_rendering"] == 0
    assert [f.name for f in r.facts] == [f.name for f in facts + extra]  # what it was judged against, for the mesh
    same = LlmExplainer(lcopt5, EchoBackend()).explain(out, action, previous, 291.15, 1, "detailed")  # the draft only
    assert same.identical_to_rendering and same.whatif_claims == []


class StopAwareEcho(EchoBackend):
    """Writes the draft, then a WHAT IF section, and honours stop strings like the real backend (kept, then cut)."""

    def chat(self, conversations, *, max_new_tokens, stop=(), drafts=None, time_budget_s=None):
        self.calls.append((conversations, drafts, stop))
        text = drafts[0] + "\n## WHAT IF\n\nThe hottest branch should settle near 99.9 °C.\n"
        for s in stop:
            if s in text:
                text = text[: text.index(s) + len(s)]
        return [Generation(text, 100, 50, 0.01, "stop")]


def test_a_short_text_gets_no_whatif_facts_and_stops_at_the_whatif_heading(decision, lcopt5):
    out, action, previous = decision
    backend = StopAwareEcho()
    r = LlmExplainer(lcopt5, backend).explain(out, action, previous, 291.15, 1, "short")
    conversations, _, stop = backend.calls[0]
    assert "hottest_branch_if_held" not in conversations[0][1]["content"] and stop == ("## WHAT IF",)
    assert r.source == "llm" and r.identical_to_rendering and "WHAT IF" not in r.text


def test_a_wrong_whatif_number_is_caught_by_the_judge(decision, lcopt5):
    out, action, previous = decision
    facts, extra = _whatif(decision, lcopt5)
    held = next(f for f in extra if f.name == "hottest_branch_if_held")
    wrong = float(held.value) + 7.3
    text = (render_explanation(facts, "detailed") + f"\n## WHAT IF\n\nHolding the previous setpoint would leave the "
            f"hottest branch near {wrong:.1f} °C.\n")  # fmt: skip
    r = LlmExplainer(lcopt5, EchoBackend(text)).explain(out, action, previous, 291.15, 1, "detailed")
    assert r.source == "renderer" and r.fallback_reason == "whatif_unverified"  # one number in ~60: below the share
    assert r.whatif_claims == []
    short = (render_explanation(facts, "short") + f"\n## WHAT IF\n\nHolding the previous setpoint would leave the "
             f"hottest branch near {wrong:.1f} °C.\n")  # fmt: skip
    r = LlmExplainer(lcopt5, EchoBackend(short)).explain(out, action, previous, 291.15, 1, "short")
    assert r.source == "renderer" and r.fallback_reason == "numeric_grounding"  # a short text fails the share too


def test_whatif_estimates_follow_the_toolbox_relations(decision, lcopt5):
    from lcmesh.mesh.tools.facts import K0, facts_by_name

    out, action, previous = decision
    _, extra = _whatif(decision, lcopt5, cabinet=0)
    f = facts_by_name(extra)
    rise = float(out["branch_max_temp_k"][0].max() - out["supply_temp_k"][0])
    assert f["hottest_branch_expected"].value == pytest.approx(action.supply_temp_setpoint_k[0] - K0 + rise, abs=2e-3)
    dp_ratio = action.dp_setpoint_pa[0] / out["cabinet_dp_pa"][0]
    pump_kw = out["cdu_pump_power_w"][0] / 1e3
    assert f["pump_power_expected"].value == pytest.approx(pump_kw * dp_ratio**1.5, abs=2e-3)  # power ~ dp^1.5
    assert f["dp_tradeoff_pump_power"].value == pytest.approx(
        f["pump_power_expected"].value - f["pump_power_if_dp_held"].value, abs=2e-3)
    assert f["top_input"].value in ("hottest branch temperature", "cabinet load", "wet bulb")


# --- the short level's what-if (the rendering, then the LLM's WHAT IF section) -------------------------------------


def test_a_short_text_with_a_short_backend_is_the_rendering_then_the_llms_verified_whatif(decision, lcopt5):
    from lcmesh.mesh.tools.explain import render_whatif

    out, action, previous = decision
    facts, extra = _whatif(decision, lcopt5)
    claims = [f for f in extra if f.name in ("hottest_branch_expected", "hottest_branch_if_held")]
    short = EchoBackend(render_whatif(claims))
    main = EchoBackend()
    explainer = LlmExplainer(lcopt5, main, short_backend=short)
    r = explainer.explain(out, action, previous, 291.15, 1, "short")
    assert main.calls == []  # the short level goes to the short backend only
    (system, user), = short.calls[0][0]
    assert "Sections: WHAT IF" in system["content"] and "hottest_branch_if_held = " in user["content"]
    assert "dp_setpoint" not in user["content"] and "branch_1_valve" not in user["content"]  # the compact prompt
    assert r.source == "llm" and r.llm_part == "what-if" and r.fallback_reason is None
    assert r.text.startswith(r.rendered.rstrip()) and "## WHAT IF" in r.text
    assert r.rendered == render_explanation(facts, "short")
    assert "hottest_branch_expected" in r.whatif_claims or "hottest_branch_if_held" in r.whatif_claims


@pytest.mark.parametrize("written, reason", [("", "no_whatif"), ("## WHAT IF\n\n", "no_whatif"),
                                             ("The branch is fine.", "no_whatif"),
                                             ("## WHAT IF\n\nThe hottest branch should sit near 99.9 °C.",
                                              "numeric_grounding")])  # fmt: skip: a short text fails the share
def test_a_short_whatif_that_is_missing_or_wrong_leaves_the_rendering(decision, lcopt5, written, reason):
    out, action, previous = decision
    explainer = LlmExplainer(lcopt5, EchoBackend(), short_backend=EchoBackend(written))
    r = explainer.explain(out, action, previous, 291.15, 1, "short")
    assert r.source == "renderer" and r.fallback_reason == reason and r.text == r.rendered
    assert r.llm_part == "what-if" and explainer.stats[f"fallback_{reason}"] == 1


def test_the_packaged_short_adapter_writes_a_verified_whatif_on_llama_cpp(decision, lcopt5):
    """The shipped ``explain-short`` adapter, on the real runtime (no budget: a frozen clock)."""
    from lcmesh.llm.base import LlmBackendSettings
    from lcmesh.llm.explainer import short_backend_for

    short = short_backend_for(LlmBackendSettings())
    if short is None:
        pytest.skip("llama-cpp-python is not installed")
    try:
        explainer = LlmExplainer(lcopt5, EchoBackend(), short_backend=short.with_clock(frozen_clock))
        out, action, previous = decision
        results = [explainer.explain(out, action, previous, 291.15, c, "short") for c in range(lcopt5.cabinets.count)]
    finally:
        short.close()
    assert all(r.llm_part == "what-if" for r in results)
    passed = [r for r in results if r.source == "llm"]
    assert len(passed) >= len(results) - 1, [r.fallback_reason for r in results]
    assert all(r.whatif_claims for r in passed), [r.text.split("## WHAT IF")[-1] for r in passed]
