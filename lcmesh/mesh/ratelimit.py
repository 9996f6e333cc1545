"""Token buckets: how often a client may ask (the chat per client address, the tool queryables per tool).

A bucket holds up to `burst` tokens and refills at `rate_per_s`; a request spends one or is told how long
to wait for it. The clock is injected (``time.monotonic`` by default), so tests advance time by hand.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable


class TokenBuckets:
    """A token bucket per key: `burst` requests at once, then `rate_per_s`; the least recent keys are forgotten
    beyond `max_keys` (a forgotten key starts full again)."""

    def __init__(self, rate_per_s: float, burst: int, *, clock: Callable[[], float] = time.monotonic,
                 max_keys: int = 10_000):  # fmt: skip
        if rate_per_s <= 0 or burst < 1:
            raise ValueError(f"a token bucket needs `rate_per_s` > 0 and `burst` >= 1, got {rate_per_s}, {burst}")
        self.rate_per_s, self.burst, self.max_keys = float(rate_per_s), float(burst), max_keys
        self._clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, when)
        self._lock = threading.Lock()

    def take(self, key: str = "") -> float:
        """0 if `key` may go now (a token is spent), else the seconds until it may (nothing is spent)."""
        now = self._clock()
        with self._lock:
            tokens, stamp = self._buckets.pop(key, (self.burst, now))
            tokens = min(self.burst, tokens + max(now - stamp, 0.0) * self.rate_per_s)
            wait_s = 0.0
            if tokens >= 1.0:
                tokens -= 1.0
            else:
                wait_s = (1.0 - tokens) / self.rate_per_s
            self._buckets[key] = (tokens, now)
            while len(self._buckets) > self.max_keys:
                self._buckets.popitem(last=False)
        return wait_s
