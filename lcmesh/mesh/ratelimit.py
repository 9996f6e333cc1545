"""How often, and how much, a client may ask: token buckets and the what-if work budget.

| limit | kept per | used by |
|---|---|---|
| ``TokenBuckets`` | key: a chat client's address; a ``tools/{name}/{role}`` tool and asking role | UI, Sensor |
| ``WorkBudget`` | host: runs at once, and plant minutes per wall minute, all askers together | the Sensor's what-ifs |

A bucket holds up to `burst` tokens and refills at `rate_per_s`; a request spends one (or `cost`) or is
told how long to wait. Over a limit, a caller gets ``RateLimited`` with the seconds to wait; on the bus
its text is ``rate limited: ...; retry in X s`` (``limited_text``), which ``retry_after_s`` reads back
(the UI answers it with HTTP 429 and ``Retry-After``). Clocks are injected (``time.monotonic`` by
default), so tests advance time by hand.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager

_PREFIX = "rate limited: "
_RETRY = re.compile(r"; retry in (\d+(?:\.\d+)?) s$")


def _retry_s(wait_s: float) -> float:
    """`wait_s` rounded up to a tenth of a second: never "retry in 0.0 s"."""
    return math.ceil(wait_s * 10) / 10


def limited_text(detail: str, wait_s: float) -> str:
    """The error text of a refusal over a limit: ``rate limited: {detail}; retry in X s`` (X never 0.0)."""
    return f"{_PREFIX}{detail}; retry in {_retry_s(wait_s):.1f} s"


def retry_after_s(text: str) -> float | None:
    """The seconds to wait named by a ``limited_text`` refusal (anywhere in `text`), or None if it is not one."""
    start = text.find(_PREFIX)
    match = _RETRY.search(text) if start >= 0 else None
    return float(match.group(1)) if match else None


class RateLimited(RuntimeError):
    """A request over a rate limit or budget: nothing ran; `retry_after_s` says when to ask again."""

    def __init__(self, message: str, retry_after_s: float):
        super().__init__(message)
        self.retry_after_s = retry_after_s

    @classmethod
    def over(cls, detail: str, wait_s: float) -> RateLimited:
        """The refusal whose text is ``limited_text(detail, wait_s)``."""
        return cls(limited_text(detail, wait_s), _retry_s(wait_s))


class TokenBuckets:
    """A token bucket per key: `burst` requests at once, then `rate_per_s`; the least recent keys are forgotten
    beyond `max_keys` (a forgotten key starts full again)."""

    def __init__(self, rate_per_s: float, burst: float, *, clock: Callable[[], float] = time.monotonic,
                 max_keys: int = 10_000):  # fmt: skip
        if not (rate_per_s > 0 and burst >= 1):  # `not`: a NaN fails too
            raise ValueError(f"a token bucket needs `rate_per_s` > 0 and `burst` >= 1, got {rate_per_s}, {burst}")
        self.rate_per_s, self.burst, self.max_keys = float(rate_per_s), float(burst), max_keys
        self._clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, when)
        self._lock = threading.Lock()

    def take(self, key: str = "", cost: float = 1.0) -> float:
        """0 if `key` may go now (`cost` tokens are spent), else the seconds until it may (nothing is spent)."""
        now = self._clock()
        with self._lock:
            tokens, stamp = self._buckets.pop(key, (self.burst, now))
            tokens = min(self.burst, tokens + max(now - stamp, 0.0) * self.rate_per_s)
            wait_s = 0.0
            if tokens >= cost:
                tokens -= cost
            else:
                wait_s = (cost - tokens) / self.rate_per_s
            self._buckets[key] = (tokens, now)
            while len(self._buckets) > self.max_keys:
                self._buckets.popitem(last=False)
        return wait_s


class WorkBudget:
    """At most `max_running` runs at once and `units_per_min` units of work per wall minute, for everyone together.

    The units refill continuously up to one minute's worth, so a request of up to `units_per_min` can always
    go once the budget has refilled; a larger one never can (ValueError naming the setting). A run over
    either limit is refused with ``RateLimited`` before it waits for anything, so refused work never queues.
    """

    def __init__(self, max_running: int, units_per_min: float, *, unit: str = "plant minutes",
                 what: str = "what-if", setting: str = "", clock: Callable[[], float] = time.monotonic):  # fmt: skip
        if not (max_running >= 1 and units_per_min > 0):
            raise ValueError(f"a work budget needs `max_running` >= 1 and `units_per_min` > 0, got {max_running}, "
                             f"{units_per_min}")  # fmt: skip
        self.max_running, self.units_per_min, self.unit, self.what = max_running, float(units_per_min), unit, what
        self.setting = setting
        self._units = TokenBuckets(units_per_min / 60.0, units_per_min, clock=clock, max_keys=1)
        self._running = 0
        self._lock = threading.Lock()

    @property
    def running(self) -> int:
        return self._running

    @contextmanager
    def run(self, units: float) -> Iterator[None]:
        """Hold one run of `units` work while the block runs; RateLimited (nothing spent) if over a limit."""
        if units > self.units_per_min:
            where = f" ({self.setting})" if self.setting else ""
            raise ValueError(f"this {self.what} needs {units:g} {self.unit}; the budget is {self.units_per_min:g} "
                             f"{self.unit} a minute{where}: ask for fewer")  # fmt: skip
        with self._lock:
            if self._running >= self.max_running:
                raise RateLimited.over(f"{self._running} {self.what} run(s) already running (at most "
                                       f"{self.max_running} at once)", 1.0)  # fmt: skip
            wait_s = self._units.take("", units)
            if wait_s > 0:
                raise RateLimited.over(f"the {self.what} budget of {self.units_per_min:g} {self.unit} a minute is "
                                       f"spent (this one needs {units:g})", wait_s)  # fmt: skip
            self._running += 1
        try:
            yield
        finally:
            with self._lock:
                self._running -= 1
