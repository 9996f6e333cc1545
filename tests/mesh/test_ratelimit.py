"""Token buckets on an injected clock: a burst, then the rate, per key (the tool queryables, the chat)."""

from __future__ import annotations

import pytest

from lcmesh.mesh.ratelimit import TokenBuckets


class Clock:
    def __init__(self) -> None:
        self.now_s = 50.0

    def __call__(self) -> float:
        return self.now_s


def test_a_burst_then_the_rate_with_the_wait_until_the_next_token():
    clock = Clock()
    buckets = TokenBuckets(rate_per_s=2.0, burst=3, clock=clock)
    assert [buckets.take("tools/whatif") for _ in range(3)] == [0.0, 0.0, 0.0]
    assert buckets.take("tools/whatif") == pytest.approx(0.5)  # one token takes 1 / 2 s
    clock.now_s += 0.2
    assert buckets.take("tools/whatif") == pytest.approx(0.3)  # a refused query spends nothing
    clock.now_s += 0.3
    assert buckets.take("tools/whatif") == 0.0
    assert buckets.take("tools/whatif") == pytest.approx(0.5)
    assert buckets.take("tools/approach") == 0.0  # a bucket per key


def test_an_idle_bucket_refills_to_its_burst_and_no_further():
    clock = Clock()
    buckets = TokenBuckets(rate_per_s=1.0, burst=2, clock=clock)
    assert [buckets.take() for _ in range(3)] == [0.0, 0.0, 1.0]
    clock.now_s += 3600.0
    assert [buckets.take() for _ in range(3)] == [0.0, 0.0, 1.0]
    clock.now_s -= 10.0  # a clock that steps back refills nothing
    assert buckets.take() == pytest.approx(1.0)


def test_the_least_recent_keys_are_forgotten_beyond_max_keys():
    buckets = TokenBuckets(rate_per_s=1.0, burst=1, clock=Clock(), max_keys=2)
    assert [buckets.take(key) for key in ("a", "b", "c")] == [0.0, 0.0, 0.0]
    assert buckets.take("a") == 0.0  # forgotten: full again
    assert buckets.take("c") == pytest.approx(1.0)


@pytest.mark.parametrize("rate_per_s,burst", [(0.0, 1), (-1.0, 1), (1.0, 0)])
def test_bad_limits_say_what_would_be_valid(rate_per_s, burst):
    with pytest.raises(ValueError, match=r"`rate_per_s` > 0 and `burst` >= 1"):
        TokenBuckets(rate_per_s, burst)
