"""The posterior estimator against a posterior known exactly: θ ~ U[0, 1]² (a bounded prior, like the
normalized parameters), x = θ + σ ε with σ = 0.08. The exact posterior per coordinate is N(x, σ²)
truncated to [0, 1] (scipy's truncnorm). The flow, trained on 1,600 simulations through the same
code as the FORC posterior (logit space, early stopping on validation), must reproduce the exact
posterior mean within 0.25 σ on average (0.75 σ at worst over 500 test points) and its spread within
20 %, keep its marginal coverage inside the 99 % binomial band at 50/68/90 % (joint TARP: 99.9 %),
and pass SBC (KS p > 0.001)."""

import numpy as np
import pytest
import torch
from scipy import stats

from forcdecode.learn.calibration import calibration_metrics
from forcdecode.learn.posterior import PosteriorFit, fit_posterior
from forcdecode.learn.scoring import binomial_band

SIGMA = 0.08
N_TRAIN, N_VAL, N_TEST = 1600, 400, 500
SETTINGS = {"coordinates": "box", "ensemble": 1, "width": 32, "dropout": 0.0, "epochs": 60, "patience": 10, "batch_size": 64, "lr": 3e-3,
            "transforms": 3, "hidden": 32}


def fit_gaussian_problem(settings, n_train, n_val, n_test, data_seed, fit_seed):
    """θ ~ U[0, 1]², x = θ + σ ε; the posterior fitted on the first n_train draws (early stopping on
    the next n_val); returns (estimator, x and θ of the last n_test draws)."""
    torch.set_num_threads(1)
    rng = np.random.default_rng(data_seed)
    theta = rng.random((n_train + n_val + n_test, 2))
    x = theta + SIGMA * rng.standard_normal(theta.shape)
    index = np.arange(len(theta))
    train, val, test = index[:n_train], index[n_train:n_train + n_val], index[n_train + n_val:]
    est = fit_posterior(x, np.zeros(len(x)), theta, train, val,
                        PosteriorFit(names=("a", "b"), settings=settings, seed=fit_seed, embedding="mlp"))
    return est, x[test], theta[test]


def exact_mean(x):
    """Mean of the exact posterior N(x, σ²) truncated to [0, 1], per coordinate."""
    return stats.truncnorm.mean((0 - x) / SIGMA, (1 - x) / SIGMA, loc=x, scale=SIGMA)


@pytest.fixture(scope="module")
def fitted():
    est, x, theta = fit_gaussian_problem(SETTINGS, N_TRAIN, N_VAL, N_TEST, data_seed=0, fit_seed=1)
    return est, x, theta, est.sample(x, np.zeros(len(x)), 500, seed=3)


def test_the_posterior_mean_is_the_exact_one(fitted):
    _, x, _, draws = fitted
    a, b = (0 - x) / SIGMA, (1 - x) / SIGMA
    error = np.abs(draws.mean(axis=1) - exact_mean(x))
    assert (error.mean(axis=0) < 0.25 * SIGMA).all(), error.mean(axis=0) / SIGMA
    assert (error.max(axis=0) < 0.75 * SIGMA).all(), error.max(axis=0) / SIGMA
    # and the spread: the exact posterior's standard deviation, within 20 % on average
    exact_std = stats.truncnorm.std(a, b, loc=x, scale=SIGMA)
    ratio = draws.std(axis=1).mean(axis=0) / exact_std.mean(axis=0)
    assert (np.abs(ratio - 1) < 0.2).all(), ratio


def test_the_coverage_sits_in_its_binomial_band(fitted):
    _, _, theta, draws = fitted
    metrics = calibration_metrics(draws, theta, ["a", "b"], np.random.default_rng(2))
    for level in (0.5, 0.68, 0.9):
        low, high = binomial_band(N_TEST, level, level=0.99)
        tag = f"coverage_{int(level * 100)}"
        for row in metrics["per_parameter"].values():
            assert low <= row[tag] <= high, (level, row)
        # joint (TARP): its random reference points add noise: the 99.9 % band
        low, high = binomial_band(N_TEST, level, level=0.999)
        assert low <= metrics["joint"]["tarp"][tag] <= high, (level, metrics["joint"]["tarp"])
    for row in metrics["per_parameter"].values():
        # 500 test points make the KS test sharp: a flow fitted on 1,600 simulations is near, not at, the
        # exact posterior (p = 0.004–0.5 across machines for the same seeds); an overconfident or shifted
        # posterior gives p < 1e-6 (tests/learn/test_posterior_calibration.py)
        assert row["sbc_ks_p"] > 0.001, row
        assert 2.6 * SIGMA < row["width_90"] < 3.6 * SIGMA, row  # exact: ≈ 3.2 σ


def test_draws_stay_in_the_bounds_and_the_density_is_normalized(fitted):
    est, x, _, draws = fitted
    assert draws.min() >= 0.0 and draws.max() <= 1.0
    # the density in u (with the change of variables) integrates to one over the unit square
    grid = (np.arange(100) + 0.5) / 100
    uu = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 2)
    density = np.exp(est.log_prob(uu, np.repeat(x[:1], len(uu), axis=0), np.zeros(len(uu))))
    assert density.mean() == pytest.approx(1.0, abs=0.05)
