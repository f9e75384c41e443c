"""Power-law learning curves: exact laws recovered, flat curves never reach a target."""

import numpy as np
import pytest

from forcdecode.learn.curve import fit_power_law, learning_curve_fit, size_for_mae


def test_exact_power_law_and_size_for_target():
    sizes = np.array([10, 20, 40, 80])
    mae = np.repeat((2.0 * sizes ** -0.5)[:, None], 3, axis=1)
    fit = fit_power_law(sizes, mae)
    assert fit["a"] == pytest.approx(2.0, rel=1e-10) and fit["b"] == pytest.approx(0.5, rel=1e-10)
    assert size_for_mae(fit, 0.1) == pytest.approx(400.0, rel=1e-9)


def test_noisy_seeds_give_an_interval_around_the_law():
    rng = np.random.default_rng(0)
    sizes = np.array([12, 25, 50, 100])
    mae = 0.8 * sizes[:, None] ** -0.4 * np.exp(0.05 * rng.standard_normal((4, 3)))
    result = learning_curve_fit(sizes, mae, 0.04, np.random.default_rng(1), n_boot=400)
    low, high = result["b_ci90"]
    assert low < 0.4 < high and high - low < 0.2
    n_low, n_high = result["n_to_target"]["ci90"]
    assert n_low < (0.8 / 0.04) ** (1 / 0.4) < n_high


def test_a_flat_curve_never_reaches_the_target():
    sizes = np.array([10, 20, 40, 80])
    mae = np.full((4, 3), 0.2) * np.array([1.0, 1.01, 0.99])
    result = learning_curve_fit(sizes, mae, 0.05, np.random.default_rng(2), n_boot=200)
    assert abs(result["b"]) < 1e-9
    assert result["n_to_target"]["fraction_infinite"] > 0.3
