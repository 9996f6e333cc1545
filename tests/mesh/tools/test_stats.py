"""Statistics of the toolbox: intervals, EWMA, CUSUM, trends, time-to-threshold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lcmesh.mesh.tools import stats


def test_t_interval_hand_computed():
    # 1..5: mean 3, s = 1.581139, t(0.975, 4) = 2.776445 -> half width 2.776445 x 1.581139 / sqrt(5) = 1.963243
    iv = stats.mean_confidence_interval([1, 2, 3, 4, 5], 0.95)
    assert iv.estimate == pytest.approx(3.0)
    assert (iv.low, iv.high) == pytest.approx((3 - 1.963243, 3 + 1.963243), abs=1e-6)
    assert iv.n == 5 and iv.method == "t"
    assert stats.student_t_quantile(0.975, 4) == pytest.approx(2.776445, abs=1e-6)


def test_t_interval_drops_non_finite_and_rejects_too_few():
    iv = stats.mean_confidence_interval([1.0, float("nan"), 3.0, float("inf")])
    assert iv.n == 2 and iv.estimate == pytest.approx(2.0)
    with pytest.raises(ValueError, match="at least 2 finite"):
        stats.mean_confidence_interval([1.0])
    with pytest.raises(ValueError, match="confidence"):
        stats.mean_confidence_interval([1.0, 2.0], confidence=1.5)


def test_bootstrap_interval_is_seeded_and_agrees_with_t():
    x = np.random.default_rng(1).normal(10.0, 2.0, 400)
    a = stats.bootstrap_interval(x, seed=3)
    assert a == stats.bootstrap_interval(x, seed=3)
    t = stats.mean_confidence_interval(x)
    assert a.estimate == pytest.approx(x.mean())
    assert a.half_width == pytest.approx(t.half_width, rel=0.2)  # both ~ 1.96 x 2 / 20 = 0.196
    med = stats.bootstrap_interval(x, statistic=lambda d: np.median(d, axis=1), seed=0)
    assert med.low < np.median(x) < med.high


def test_percentile_range():
    iv = stats.percentile_range(np.arange(101.0), 0.90)  # the 5th and 95th percentiles of 0..100
    assert (iv.low, iv.estimate, iv.high) == pytest.approx((5.0, 50.0, 95.0))


def test_ewma():
    f = stats.Ewma(0.5)
    assert [float(f.update(v)) for v in (0.0, 1.0, 1.0)] == [0.0, 0.5, 0.75]
    g = stats.Ewma.from_time_constant(60.0, 15.0)
    assert g.alpha == pytest.approx(1 - math.exp(-0.25))
    np.testing.assert_allclose(stats.ewma([0.0, 1.0, 1.0], 0.5), [0.0, 0.5, 0.75])
    with pytest.raises(ValueError, match="alpha"):
        stats.Ewma(0.0)


def test_cusum_detects_a_shift_and_estimates_it():
    c = stats.Cusum(k=0.5, h=2.0)
    assert not any(c.update(0.0) for _ in range(50))  # in control: stays at zero
    alarms = [bool(c.update(1.5)) for _ in range(3)]  # S+ grows by 1.5 - 0.5 = 1 per step
    assert alarms == [False, False, True]
    assert float(c.shift_estimate) == pytest.approx(1.5)  # k + S+/N+ = 0.5 + 3/3
    c.reset()
    assert float(c.statistic) == 0.0
    many = stats.Cusum(k=0.1, h=0.5, shape=(2,))
    for _ in range(10):
        flags = many.update(np.array([0.0, -0.3]))
    assert flags.tolist() == [False, True] and float(many.shift_estimate[1]) == pytest.approx(-0.3)


def test_linear_trend_exact_and_noisy():
    t = np.arange(10.0)
    tr = stats.linear_trend(t, 2.0 + 0.5 * t)
    assert tr.slope == pytest.approx(0.5) and tr.intercept == pytest.approx(2.0)
    assert tr.slope_high - tr.slope_low == pytest.approx(0.0, abs=1e-9) and tr.r2 == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    t = np.arange(200.0)
    y = np.column_stack([1.0 + 0.02 * t, 5.0 - 0.01 * t]) + rng.normal(0, 0.1, (200, 2))
    multi = stats.linear_trend(t, y)
    assert multi.slope_low[0] < 0.02 < multi.slope_high[0]
    assert multi.slope_low[1] < -0.01 < multi.slope_high[1]
    with pytest.raises(ValueError, match="length >= 3"):
        stats.linear_trend([0.0, 1.0], [0.0, 1.0])


def test_time_to_threshold():
    t = np.arange(10.0)
    tr = stats.linear_trend(t, 2.0 + 0.5 * t)  # 6.5 at t = 9, rising 0.5 per unit -> 10 at t = 16
    assert stats.time_to_threshold(tr, 10.0) == pytest.approx(7.0)
    assert stats.time_to_threshold(tr, 0.0) == math.inf  # rising away from a lower threshold
    flat = stats.linear_trend(t, np.random.default_rng(2).normal(0.0, 1.0, 10))
    assert stats.time_to_threshold(flat, 100.0) == math.inf  # slope CI includes zero: no prediction
    both = stats.linear_trend(t, np.column_stack([t, -t]))
    np.testing.assert_allclose(stats.time_to_threshold(both, 20.0), [11.0, math.inf])


def test_moving_range_sigma_tracks_noise_not_level():
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 0.3, 3000)
    x[1500:] += 5.0  # a step in the level moves the estimate once, not for good
    est = stats.MovingRangeSigma(alpha=0.02)
    for value in x[:1490]:
        est.update(value)
    assert float(est.sigma) == pytest.approx(0.3, rel=0.25)  # E|x_k - x_k-1| = 1.128 sigma
    for value in x[1490:]:
        est.update(value)
    assert float(est.sigma) == pytest.approx(0.3, rel=0.25)
    est.update(float("nan"))  # skipped, not poisoning the estimate
    assert np.isfinite(est.sigma)
