"""A deep ensemble of posterior flows (``posterior.ensemble: K``) against a posterior known exactly:
θ ~ U[0, 1]², x = θ + σ ε (σ = 0.08), so p(θ | x) is N(x, σ²) truncated to [0, 1] per coordinate.

The mixture of K = 3 flows must still be that posterior (mean within 0.25 σ on average, coverage in
the 99 % binomial band, density normalized); its draws must be the stratified mixture (draw d from
member d mod K, each member's own draws), reproducible after a save and a reload; and on a
coordinate the data do not tell (θ_b never enters x) it must be at least as wide as one member."""

import numpy as np
import pytest
import torch

from forcdecode.learn.calibration import calibration_metrics
from forcdecode.learn.posterior import PosteriorEstimator, PosteriorFit, fit_posterior
from forcdecode.learn.scoring import binomial_band

from test_posterior_gaussian import SIGMA, exact_mean, fit_gaussian_problem

N_TRAIN, N_VAL, N_TEST = 800, 200, 400
SETTINGS = {"coordinates": "box", "width": 32, "dropout": 0.0, "epochs": 60, "patience": 10, "batch_size": 64, "lr": 3e-3,
            "transforms": 2, "hidden": 32, "ensemble": 3}


@pytest.fixture(scope="module")
def fitted():
    est, x, theta = fit_gaussian_problem(SETTINGS, N_TRAIN, N_VAL, N_TEST, data_seed=5, fit_seed=2)
    return est, x, theta, est.sample(x, np.zeros(len(x)), 600, seed=4)


def test_three_members_fitted_from_different_weights(fitted):
    est = fitted[0]
    assert len(est.nets) == 3 and len(est.history["ensemble_best_epochs"]) == 3
    first = [p.detach().clone() for p in est.nets[0].flow.parameters()]
    for member in est.nets[1:]:
        assert any(not torch.equal(a, b) for a, b in zip(first, member.flow.parameters()))


def test_the_mixture_is_still_the_exact_posterior(fitted):
    _, x, theta, draws = fitted
    error = np.abs(draws.mean(axis=1) - exact_mean(x))
    assert (error.mean(axis=0) < 0.25 * SIGMA).all(), error.mean(axis=0) / SIGMA
    metrics = calibration_metrics(draws, theta, ["a", "b"], np.random.default_rng(1))
    for level in (0.5, 0.68, 0.9):
        low, high = binomial_band(N_TEST, level, level=0.99)
        for row in metrics["per_parameter"].values():
            assert low <= row[f"coverage_{int(level * 100)}"] <= high, (level, row)


def test_draws_are_the_stratified_mixture_of_the_members(fitted):
    est, x, _, _ = fitted
    draws = est.sample(x[:5], np.zeros(5), 30, seed=9)
    from forcdecode.core.streams import stream_seed

    for k, net in enumerate(est.nets):
        seed = 9 if k == 0 else stream_seed(9, "posterior", "ensemble_member", k)
        own = PosteriorEstimator(net, est.architecture, est.names).sample(x[:5], np.zeros(5), 10, seed=seed)
        np.testing.assert_allclose(draws[:, k::3], own, atol=1e-12)


def test_the_density_is_the_members_mean_and_normalized(fitted):
    est, x, _, _ = fitted
    grid = (np.arange(80) + 0.5) / 80
    uu = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 2)
    obs = np.repeat(x[:1], len(uu), axis=0)
    mixture = np.exp(est.log_prob(uu, obs, np.zeros(len(uu))))
    assert mixture.mean() == pytest.approx(1.0, abs=0.05)
    singles = [np.exp(PosteriorEstimator(net, est.architecture, est.names).log_prob(uu, obs, np.zeros(len(uu))))
               for net in est.nets]
    np.testing.assert_allclose(mixture, np.mean(singles, axis=0), rtol=1e-6)


def test_saved_and_reloaded_ensemble_reproduces_its_draws(fitted, tmp_path):
    est, x, _, _ = fitted
    est.save(tmp_path / "ensemble.pt")
    again = PosteriorEstimator.load(tmp_path / "ensemble.pt")
    assert len(again.nets) == 3
    np.testing.assert_array_equal(est.sample(x[:4], np.zeros(4), 50, seed=7),
                                  again.sample(x[:4], np.zeros(4), 50, seed=7))


def test_an_uninformed_coordinate_is_not_narrower_than_one_member():
    """x carries θ_a only: every member must learn p(θ_b | x) = U[0, 1] from 400 draws and each is off
    in its own way; the mixture's 90 % width for θ_b is at least the members' mean width."""
    torch.set_num_threads(1)
    rng = np.random.default_rng(8)
    theta = rng.random((600, 2))
    x = np.stack([theta[:, 0] + SIGMA * rng.standard_normal(600), rng.standard_normal(600)], axis=1)
    train, val = np.arange(400), np.arange(400, 500)
    est = fit_posterior(x, np.zeros(600), theta, train, val,
                        PosteriorFit(names=("a", "b"), settings=SETTINGS, seed=3, embedding="mlp"))
    test = np.arange(500, 600)
    mixture = est.sample(x[test], np.zeros(100), 300, seed=1)[..., 1]
    widths = [np.diff(np.quantile(PosteriorEstimator(net, est.architecture, est.names).sample(
        x[test], np.zeros(100), 300, seed=1)[..., 1], [0.05, 0.95], axis=1), axis=0).mean() for net in est.nets]
    mixture_width = np.diff(np.quantile(mixture, [0.05, 0.95], axis=1), axis=0).mean()
    assert mixture_width >= np.mean(widths) - 1e-3, (mixture_width, widths)
    assert mixture_width > 0.75, mixture_width  # the prior's 90 % width is 0.9
