"""Statistics over plant history: confidence intervals, EWMA, CUSUM, trends and time-to-threshold.

Pure functions and two tiny stateful filters (`Ewma`, `Cusum`) that work on scalars or numpy arrays
(one channel per element), so the fault detector runs one filter over all cabinets at once.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Interval:
    """An estimate with a two-sided confidence interval."""

    estimate: float
    low: float
    high: float
    confidence: float
    n: int
    method: str  # "t" | "bootstrap" | "percentile"

    @property
    def half_width(self) -> float:
        return 0.5 * (self.high - self.low)


@functools.lru_cache(maxsize=256)
def student_t_quantile(probability: float, dof: int) -> float:
    """Quantile of Student's t distribution (scipy.special.stdtrit, imported on first use; cached)."""
    from scipy.special import stdtrit

    return float(stdtrit(dof, probability))


def _clean(samples: Sequence[float] | np.ndarray, minimum: int) -> np.ndarray:
    x = np.asarray(samples, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size < minimum:
        raise ValueError(f"`samples` must hold at least {minimum} finite values, got {x.size}")
    return x


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"`confidence` must be in (0, 1), got {confidence}")


def mean_confidence_interval(samples: Sequence[float] | np.ndarray, confidence: float = 0.95) -> Interval:
    """Student-t interval of the mean: x_bar +- t_{(1+c)/2, n-1} s / sqrt(n) (non-finite samples dropped)."""
    _check_confidence(confidence)
    x = _clean(samples, 2)
    mean, sd = float(x.mean()), float(x.std(ddof=1))
    half = student_t_quantile(0.5 + confidence / 2.0, int(x.size) - 1) * sd / math.sqrt(x.size)
    return Interval(mean, mean - half, mean + half, confidence, int(x.size), "t")


def bootstrap_interval(
    samples: Sequence[float] | np.ndarray,
    confidence: float = 0.95,
    statistic: Callable[[np.ndarray], np.ndarray] | None = None,
    n_resamples: int = 2000,
    seed: int = 0,
) -> Interval:
    """Percentile-bootstrap interval of `statistic` (default: the mean), seeded so it is reproducible.

    `statistic` takes a (n_resamples, n) array and reduces along axis 1 (``np.median`` with axis=1 etc.).
    """
    _check_confidence(confidence)
    if n_resamples < 100:
        raise ValueError(f"`n_resamples` must be >= 100, got {n_resamples}")
    x = _clean(samples, 2)
    stat = statistic or (lambda a: a.mean(axis=1))
    rng = np.random.default_rng(seed)
    draws = stat(x[rng.integers(0, x.size, size=(n_resamples, x.size))])
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(draws, [tail, 100.0 - tail])
    return Interval(float(stat(x[None, :])[0]), float(low), float(high), confidence, int(x.size), "bootstrap")


def percentile_range(samples: Sequence[float] | np.ndarray, confidence: float = 0.95) -> Interval:
    """The central `confidence` share of the samples (where one new sample should fall), the median as estimate."""
    _check_confidence(confidence)
    x = _clean(samples, 1)
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, med, high = np.percentile(x, [tail, 50.0, 100.0 - tail])
    return Interval(float(med), float(low), float(high), confidence, int(x.size), "percentile")


class Ewma:
    """Exponentially weighted moving average: m_k = m_{k-1} + alpha (x_k - m_{k-1}); starts at the first sample."""

    def __init__(self, alpha: float):
        if not 0.0 < alpha <= 1.0:
            raise ValueError(f"`alpha` must be in (0, 1], got {alpha}")
        self.alpha = alpha
        self.value: np.ndarray | None = None

    @classmethod
    def from_time_constant(cls, time_constant_s: float, step_s: float) -> "Ewma":
        """alpha = 1 - exp(-step / tau): the discrete form of a first-order lag with time constant tau."""
        return cls(1.0 - math.exp(-step_s / time_constant_s))

    def update(self, x: float | np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self.value is None:
            self.value = x.copy()
        else:
            self.value = self.value + self.alpha * (x - self.value)
        return self.value

    def reset(self) -> None:
        self.value = None


def ewma(series: Sequence[float] | np.ndarray, alpha: float) -> np.ndarray:
    """EWMA of a whole series (along axis 0)."""
    filt, x = Ewma(alpha), np.asarray(series, dtype=float)
    return np.array([filt.update(v) for v in x])


class MovingRangeSigma:
    """Noise level of a signal from its moving range: sigma = EWMA(|x_k - x_{k-1}|) / 1.128 (d2 for n = 2).

    The individuals-chart estimator: differencing removes the level, so a step in the mean (a fault) moves it
    once, not for good. Non-finite samples are skipped. Works element-wise on arrays.
    """

    def __init__(self, alpha: float = 0.02):
        self._ewma = Ewma(alpha)
        self._last: np.ndarray | None = None

    def update(self, x: float | np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self._last is not None:
            step = np.abs(x - self._last)
            old = self._ewma.value if self._ewma.value is not None else step
            self._ewma.update(np.where(np.isfinite(step), step, np.where(np.isfinite(old), old, 0.0)))
        self._last = np.where(np.isfinite(x), x, self._last if self._last is not None else np.nan)
        return self.sigma

    @property
    def sigma(self) -> np.ndarray:
        return np.zeros(()) if self._ewma.value is None else self._ewma.value / 1.128


class Cusum:
    """Two-sided tabular CUSUM (Page 1954): S+ = max(0, S+ + x - k), S- = max(0, S- - x - k); alarm above h.

    x is a residual with zero mean when healthy; k (the allowance) is about half the shift to detect, h
    sets the false-alarm rate. Works element-wise on arrays.
    """

    def __init__(self, k: float, h: float, shape: tuple[int, ...] = ()):
        if k < 0 or h <= 0:
            raise ValueError(f"`k` must be >= 0 and `h` > 0, got k={k}, h={h}")
        self.k, self.h = k, h
        self.pos = np.zeros(shape)
        self.neg = np.zeros(shape)
        self.n_pos = np.zeros(shape)  # steps since S+ was last zero
        self.n_neg = np.zeros(shape)

    def update(self, x: float | np.ndarray) -> np.ndarray:
        """Add one residual per channel; returns the alarm flags (S+ > h or S- > h)."""
        x = np.asarray(x, dtype=float)
        self.pos = np.maximum(0.0, self.pos + x - self.k)
        self.neg = np.maximum(0.0, self.neg - x - self.k)
        self.n_pos = np.where(self.pos > 0, self.n_pos + 1, 0)
        self.n_neg = np.where(self.neg > 0, self.n_neg + 1, 0)
        return (self.pos > self.h) | (self.neg > self.h)

    @property
    def shift_estimate(self) -> np.ndarray:
        """Size of the shift since the statistic left zero: k + S+/N+ (or -(k + S-/N-)); 0 when both are zero."""
        with np.errstate(divide="ignore", invalid="ignore"):
            up = self.k + self.pos / np.maximum(self.n_pos, 1)
            down = -(self.k + self.neg / np.maximum(self.n_neg, 1))
        return np.where(self.pos >= self.neg, np.where(self.pos > 0, up, 0.0), down)

    @property
    def statistic(self) -> np.ndarray:
        """Signed statistic: S+ where it dominates, else -S-."""
        return np.where(self.pos >= self.neg, self.pos, -self.neg)

    def reset(self, mask: np.ndarray | bool = True) -> None:
        for name in ("pos", "neg", "n_pos", "n_neg"):
            setattr(self, name, np.where(mask, 0.0, getattr(self, name)))


@dataclass(frozen=True)
class Trend:
    """Least-squares line y = intercept + slope t with a confidence interval on the slope."""

    slope: np.ndarray | float  # y units per t unit
    intercept: np.ndarray | float  # y at t = 0
    slope_low: np.ndarray | float
    slope_high: np.ndarray | float
    r2: np.ndarray | float
    n: int
    confidence: float
    t_last: float

    def predict(self, t: float) -> np.ndarray | float:
        return self.intercept + self.slope * t


def linear_trend(t: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, confidence: float = 0.95) -> Trend:
    """OLS slope and its t-interval, slope +- t_{(1+c)/2, n-2} s_e / sqrt(Sxx); `y` is (n,) or (n, channels)."""
    _check_confidence(confidence)
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = t.size
    if n < 3 or y.shape[0] != n:
        raise ValueError(f"`t` and `y` must share a first axis of length >= 3, got {n} and {y.shape}")
    tc = t - t.mean()
    sxx = float(tc @ tc)
    if sxx <= 0:
        raise ValueError("`t` must not be constant")
    yc = y - y.mean(axis=0)
    slope = np.tensordot(tc, yc, axes=(0, 0)) / sxx
    intercept = y.mean(axis=0) - slope * t.mean()
    fitted = intercept + np.multiply.outer(t, slope) if y.ndim > 1 else intercept + slope * t
    sse = ((y - fitted) ** 2).sum(axis=0)
    sst = (yc**2).sum(axis=0)
    se = np.sqrt(sse / (n - 2) / sxx)
    half = student_t_quantile(0.5 + confidence / 2.0, n - 2) * se
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.where(sst > 0, 1.0 - sse / np.where(sst > 0, sst, 1.0), 1.0)

    def out(a):
        return float(a) if np.ndim(a) == 0 else a

    return Trend(out(slope), out(intercept), out(slope - half), out(slope + half), out(r2), n, confidence, float(t[-1]))


def time_to_threshold(trend: Trend, threshold: float, conservative: bool = False) -> np.ndarray | float:
    """Time from the last sample until the trend line reaches `threshold` (inf if it never will).

    Only a slope whose confidence interval excludes zero in the threshold's direction counts. With
    `conservative`, the faster end of the slope interval is used (the earliest plausible crossing).
    """
    now = trend.predict(trend.t_last)
    gap = threshold - np.asarray(now, dtype=float)
    rising = gap > 0
    slope = np.asarray(trend.slope_high if conservative else trend.slope, dtype=float)
    slope = np.where(rising, slope, np.asarray(trend.slope_low if conservative else trend.slope))
    significant = np.where(rising, np.asarray(trend.slope_low) > 0, np.asarray(trend.slope_high) < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.where(significant & (slope != 0), gap / np.where(slope != 0, slope, 1.0), np.inf)
    eta = np.where(gap == 0, 0.0, np.where(eta < 0, np.inf, eta))
    return float(eta) if eta.ndim == 0 else eta
