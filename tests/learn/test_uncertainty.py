"""Quantile targets, the quantile → error map, split-conformal coverage, retention curves."""

import numpy as np
import pytest

from forcdecode.learn.uncertainty import (ConformalIntervals, conformal_quantile, coverage_and_width, error_quantile,
                                          gaussian_interval, quantile_to_error, retention_curve, spearman)


def test_error_quantile_is_the_mid_rank_cdf_and_inverts():
    reference = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(error_quantile(reference, reference), [0.125, 0.375, 0.625, 0.875])
    assert error_quantile([0.0], reference)[0] == 0.0 and error_quantile([1.0], reference)[0] == 1.0
    rng = np.random.default_rng(0)
    errors = rng.exponential(0.05, 5000)
    q = error_quantile(errors, errors)
    assert abs(q.mean() - 0.5) < 1e-3 and abs(np.std(q) - np.sqrt(1 / 12)) < 2e-3  # uniform ranks
    np.testing.assert_allclose(quantile_to_error(q, errors), errors, rtol=1e-12)


def test_conformal_quantile_rank():
    scores = np.arange(1, 10, dtype=float)  # n = 9: level 0.9 → rank ceil(10·0.9) = 9
    assert conformal_quantile(scores, 0.9) == 9.0
    assert conformal_quantile(scores, 0.5) == 5.0
    assert conformal_quantile(scores[:3], 0.9) == np.inf  # too few calibration samples for 90 %


@pytest.mark.parametrize("level", [0.68, 0.9])
def test_normalized_conformal_intervals_reach_their_coverage_and_adapt(level):
    """Heteroscedastic errors e ~ N(0, s(x)): with σ = s the intervals cover 1 − α on the whole test set
    and also on its hardest half; with a constant σ the marginal coverage holds but the hard half is
    under-covered (what a difficulty score buys: coverage where it matters)."""
    rng = np.random.default_rng(1)
    n_cal, n_test = 2000, 20000
    s_cal, s_test = rng.uniform(0.01, 0.2, n_cal), rng.uniform(0.01, 0.2, n_test)
    e_cal, e_test = rng.normal(0, s_cal), rng.normal(0, s_test)
    truth = rng.uniform(0.3, 0.7, n_test)
    prediction = truth + e_test
    hard = s_test > 0.105
    adaptive = ConformalIntervals.fit(np.abs(e_cal), s_cal, [level])
    low, high = adaptive.interval(prediction, s_test, level, clip=(-9, 9))
    assert abs(coverage_and_width(truth, low, high)[0] - level) < 0.015
    assert abs(coverage_and_width(truth[hard], low[hard], high[hard])[0] - level) < 0.02
    constant = ConformalIntervals.fit(np.abs(e_cal), np.ones(n_cal), [level])
    low, high = constant.interval(prediction, np.ones(n_test), level, clip=(-9, 9))
    assert abs(coverage_and_width(truth, low, high)[0] - level) < 0.015
    assert coverage_and_width(truth[hard], low[hard], high[hard])[0] < level - 0.08


def test_gaussian_interval_width():
    low, high = gaussian_interval([0.5], [0.1], 0.68, clip=(-9, 9))
    assert high[0] - low[0] == pytest.approx(2 * 0.9945 * 0.1, rel=1e-3)


def test_retention_curves_order_oracle_below_random():
    rng = np.random.default_rng(2)
    errors = rng.exponential(0.1, 500)
    fractions = np.linspace(0.05, 1, 20)
    _, oracle, a_oracle = retention_curve(errors, errors, fractions)
    _, random, a_random = retention_curve(errors, rng.random(500), fractions)
    _, noisy, a_noisy = retention_curve(errors, errors + rng.normal(0, 0.05, 500), fractions)
    assert oracle[-1] == pytest.approx(errors.mean()) and np.all(np.diff(oracle) >= -1e-12)
    assert a_oracle < a_noisy < a_random
    assert spearman(errors, errors + rng.normal(0, 0.05, 500)) > 0.6
