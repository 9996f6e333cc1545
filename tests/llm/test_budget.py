"""Time budgets bound the whole call: the first pass's cost is estimated, a stale estimate re-measured."""

from __future__ import annotations

import pytest

from lcmesh.llm.budget import MIN_TOKENS, PRIOR_SECONDS_PER_TOKEN, REFRESH_S, PassCost
from tests.llm.conftest import ForwardClock

LONG = [{"role": "user", "content": "List the cooling tower's parts. " * 60}]  # a prompt of ~450 tokens


def test_pass_cost_starts_at_the_prior_and_follows_measurements():
    cost = PassCost()
    assert cost.expect(1000) == pytest.approx(1000 * PRIOR_SECONDS_PER_TOKEN)
    assert cost.expect(1) == cost.expect(MIN_TOKENS)  # a short pass is mostly fixed overhead
    assert cost.stale(0.0)
    cost.observe(1000, 0.5, now=10.0)  # the first measurement replaces the prior
    assert cost.expect(2000) == pytest.approx(1.0) and not cost.stale(10.0 + REFRESH_S)
    cost.observe(1000, 1.5, now=11.0)  # later ones move the estimate halfway
    assert cost.seconds_per_token == pytest.approx(1e-3)
    assert cost.fits(900, now=0.0, deadline=1.0) and not cost.fits(1100, now=0.0, deadline=1.0)
    assert cost.fits(10**9, now=0.0, deadline=None) and cost.stale(11.0 + REFRESH_S + 1)


def test_pass_cost_refuses_a_nonpositive_estimate():
    with pytest.raises(ValueError, match="seconds_per_token"):
        PassCost(0.0)


def test_a_fresh_estimate_that_refuses_does_not_spend_the_budget(base_backend):
    clock = ForwardClock(per_token_s=1e-4)
    backend = base_backend.with_clock(clock, seconds_per_token=2e-3)  # measured now: ~450 tokens, ~0.9 s
    with clock.driving(base_backend.model):
        (gen,) = backend.chat([LONG], max_new_tokens=4, time_budget_s=0.5)
    assert gen.finish_reason == "timeout" and gen.new_tokens == 0 and gen.text == ""
    assert clock.passes == 0 and gen.seconds == 0.0


def test_a_stale_estimate_is_measured_again_before_it_refuses(base_backend):
    clock = ForwardClock(per_token_s=1e-4)  # the machine is 20x faster than the prior says
    backend = base_backend.with_clock(clock)  # the prior: ~450 tokens, ~0.9 s
    with clock.driving(base_backend.model):
        (gen,) = backend.chat([LONG], max_new_tokens=4, time_budget_s=0.6)
    assert backend.pass_cost.seconds_per_token < PRIOR_SECONDS_PER_TOKEN / 2  # re-measured: a probe pass
    assert gen.new_tokens == 4 and gen.finish_reason == "length"
    assert clock.passes == 1 + 4 and clock.now <= 0.6  # the probe, the prompt's pass, three steps
