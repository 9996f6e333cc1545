"""Time budgets of LLM calls: an injectable clock and the expected cost of a call's first forward pass.

A budget bounds the whole call, its first forward pass included. The first pass reads the prompt
(and, with a draft, the whole draft): it is the long one, and a decoder that starts it on a busy
machine can overrun a 3 s budget by a minute. So before it starts, the backend asks ``PassCost``
what it will take: seconds per token measured on this backend (a calibration pass at load, then
every first pass), or, before any measurement, a conservative prior. A call whose first pass is not
expected to end by the deadline does not start it (``finish_reason = "timeout"``, no tokens). Passes
after the first are predicted from the call's own passes, checked between steps.

An estimate measured under load would otherwise refuse every later call and never be measured
again; a refusal on an estimate older than ``REFRESH_S`` first re-measures with a short pass, when
that pass fits in the budget.

Every component that keeps a budget takes a ``clock`` (default ``time.monotonic``), so tests drive
time instead of depending on how busy the machine is.
"""

from __future__ import annotations

from collections.abc import Callable

Clock = Callable[[], float]

# SmolLM2-135M reads a 1,000-token prompt at 0.6-0.9 ms a token on two idle CPU cores (0.5 s for a
# 256-token pass, fixed costs included, on two busy ones); the prior is about three times that
PRIOR_SECONDS_PER_TOKEN = 2e-3
MIN_TOKENS = 128  # a shorter pass costs mostly its fixed overhead: it is costed as this many tokens
PROBE_TOKENS = 256  # the calibration pass
REFRESH_S = 30.0  # an estimate older than this is re-measured before it refuses a call


class PassCost:
    """Expected seconds of a long forward pass, from the passes timed on one backend (newer count more)."""

    def __init__(self, seconds_per_token: float = PRIOR_SECONDS_PER_TOKEN, *, measured_at: float | None = None,
                 weight: float = 0.5):  # fmt: skip
        if seconds_per_token <= 0:
            raise ValueError(f"`seconds_per_token` must be > 0, got {seconds_per_token}")
        self.seconds_per_token, self.weight = seconds_per_token, weight
        self.measured_at = measured_at  # clock time of the latest measurement; None: the prior

    def expect(self, n_tokens: int) -> float:
        """Expected seconds of a pass over ``n_tokens`` (all rows of a batch together)."""
        return self.seconds_per_token * max(n_tokens, MIN_TOKENS)

    def observe(self, n_tokens: int, seconds: float, now: float, *, replace: bool = False) -> None:
        """Fold in a pass timed at ``now``; the first measurement replaces the prior, and so does a calibration pass
        (``replace``: it measures the machine as it is now, where an old estimate may come from a busier moment)."""
        rate = max(seconds, 0.0) / max(n_tokens, MIN_TOKENS)
        if self.measured_at is None or replace:
            self.seconds_per_token = rate
        else:
            self.seconds_per_token += self.weight * (rate - self.seconds_per_token)
        self.seconds_per_token = max(self.seconds_per_token, 1e-9)  # a frozen test clock measures 0
        self.measured_at = now

    def stale(self, now: float) -> bool:
        """Whether the estimate is the prior or older than ``REFRESH_S``."""
        return self.measured_at is None or now - self.measured_at > REFRESH_S

    def fits(self, n_tokens: int, now: float, deadline: float | None) -> bool:
        """Whether a pass over ``n_tokens`` starting ``now`` is expected to end by ``deadline``."""
        return deadline is None or now + self.expect(n_tokens) <= deadline

    def fits_or_remeasured(self, n_tokens: int, clock: Clock, deadline: float | None,
                           measure: Callable[[int], object], probe_tokens: int = PROBE_TOKENS) -> bool:  # fmt: skip
        """``fits``; an estimate that refuses and is stale is first re-measured by ``measure(probe_tokens)`` (which
        times a pass and calls ``observe``), when that probe pass itself fits."""
        if self.fits(n_tokens, clock(), deadline):
            return True
        if self.stale(clock()) and self.fits(probe_tokens, clock(), deadline):
            measure(probe_tokens)
            return self.fits(n_tokens, clock(), deadline)
        return False
