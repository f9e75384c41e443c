"""Baselines and bootstrap intervals against results known without the code."""

import numpy as np
import pytest
from scipy.stats import binom

from forcdecode.learn.scoring import (accuracy_with_intervals, binomial_band, bootstrap_interval, fit_ms_only,
                                      knn_median)


def test_knn_median_by_hand():
    x_train = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    y_train = np.array([5.0, 1.0, 2.0, 9.0, 7.0])
    assert knn_median(x_train, y_train, np.array([1.1]), 1)[0] == 1.0
    assert knn_median(x_train, y_train, np.array([1.1]), 3)[0] == 2.0  # neighbours 1, 2, 0 -> y 1, 2, 5
    assert knn_median(x_train, y_train, np.array([9.0]), 99)[0] == 5.0  # k capped at n: median of all


def test_ms_only_k_is_chosen_on_validation():
    rng = np.random.default_rng(0)
    x = rng.random(400)
    exact = fit_ms_only(x[:300], x[:300] ** 2, x[300:], x[300:] ** 2)  # y a function of x: nearest wins
    assert exact == 1
    noisy_y = x ** 2 + 0.3 * rng.standard_normal(400)
    assert fit_ms_only(x[:300], noisy_y[:300], x[300:], noisy_y[300:]) >= 9  # noise: average many


def test_bootstrap_interval_of_a_mean_has_the_textbook_width():
    rng = np.random.default_rng(1)
    z = rng.standard_normal(400)
    low, high = bootstrap_interval(lambda a: float(np.mean(np.abs(a))), [z], np.random.default_rng(2), n_boot=3000)
    expected = 2 * 1.6449 * np.sqrt(1 - 2 / np.pi) / np.sqrt(400)  # sd(|z|) = sqrt(1 - 2/pi)
    assert high - low == pytest.approx(expected, rel=0.15)
    assert low < np.mean(np.abs(z)) < high


def test_accuracy_block_is_paired_and_bounded():
    rng = np.random.default_rng(3)
    truth = rng.random(200)
    ms_only = np.clip(truth + 0.2 * rng.standard_normal(200), 0, 1)
    model = np.clip(truth + 0.05 * rng.standard_normal(200), 0, 1)
    block = accuracy_with_intervals(truth, model, ms_only, np.full(200, 0.5), np.ones(200, bool), rng, n_boot=500)
    assert block["skill_vs_ms_only"] == pytest.approx(1 - block["mae"] / np.mean(np.abs(ms_only - truth)))
    low, high = block["skill_vs_ms_only_ci90"]
    assert 0.5 < low < block["skill_vs_ms_only"] < high < 0.9
    assert block["coverage_90"] == 1.0 and block["r_ci90"][0] > 0.9
    same = accuracy_with_intervals(truth, ms_only, ms_only, np.full(200, 0.5), np.ones(200, bool), rng, n_boot=200)
    assert same["skill_vs_ms_only"] == 0.0 and same["skill_vs_ms_only_ci90"] == [0.0, 0.0]  # paired resamples


def test_binomial_band():
    low, high = binomial_band(22, 0.9)
    assert low == binom.ppf(0.05, 22, 0.9) / 22 and high == binom.ppf(0.95, 22, 0.9) / 22
    assert low < 0.9 <= high <= 1.0
