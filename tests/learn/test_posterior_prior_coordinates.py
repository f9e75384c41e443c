"""``coordinates: prior``: the flow models v = F(u | M_s), the CDF of the draw prior given M_s.

On draws of the dataset's own prior (``draw_parameters``, M_s drawn too) with an observation that
tells K_u (x = u_K + 0.05 ε) and nothing about A_ex beyond M_s, the exact posterior of A_ex is its
draw prior given M_s (``draw_prior_quantiles``): a narrow, M_s-dependent law (the exchange length)
that a flow in box coordinates has to learn from the training set. The flow in prior coordinates
must give A_ex's median within 0.02 of the exact one on average and its 90 % interval must hold the
truth within the 99 % binomial band; its draws map back inside [0, 1], and the coordinates invert.
Measured (1,200 training draws): prior coordinates 0.012 mean error (box coordinates, same flow and
data: 0.035), 90 % coverage 0.91 (box 0.91); both densities integrate to 1."""

import numpy as np
import pytest
import torch

from forcdecode.core.parameters import normalize
from forcdecode.dataset.params import draw_parameters, draw_prior_quantiles
from forcdecode.learn.posterior import PosteriorFit, fit_posterior, from_coordinates, to_coordinates
from forcdecode.learn.scoring import binomial_band

N_TRAIN, N_VAL, N_TEST = 1200, 300, 300
SETTINGS = {"ensemble": 1, "width": 32, "dropout": 0.0, "epochs": 60, "patience": 10, "batch_size": 64, "lr": 3e-3,
            "transforms": 3, "hidden": 32}
NAMES = ("A_ex", "K_u")


def data():
    draws = [draw_parameters(21, i) for i in range(N_TRAIN + N_VAL + N_TEST)]
    Ms = np.array([d["Ms"] for d in draws])
    u = np.stack([[normalize(n, d[n]) for n in NAMES] for d in draws])
    x = (u[:, 1] + 0.05 * np.random.default_rng(4).standard_normal(len(u)))[:, None]
    return Ms, normalize("Ms", Ms), u, x


@pytest.fixture(scope="module", params=["prior", "box"])
def fitted(request):
    torch.set_num_threads(1)
    Ms, ms_norm, u, x = data()
    index = np.arange(len(u))
    train, val, test = index[:N_TRAIN], index[N_TRAIN:N_TRAIN + N_VAL], index[N_TRAIN + N_VAL:]
    est = fit_posterior(x, ms_norm, u, train, val,
                        PosteriorFit(names=NAMES, settings={**SETTINGS, "coordinates": request.param}, seed=1,
                                     embedding="mlp"))
    draws = est.sample(x[test], ms_norm[test], 400, seed=3)
    exact = np.array([draw_prior_quantiles("A_ex", m, [0.05, 0.5, 0.95]) for m in Ms[test]])
    return request.param, est, draws, exact, u[test]


def test_a_ex_follows_its_prior_given_ms(fitted):
    coordinates, _, draws, exact, truth = fitted
    error = np.abs(np.median(draws[:, :, 0], axis=1) - exact[:, 1])
    lo, hi = np.quantile(draws[:, :, 0], [0.05, 0.95], axis=1)
    covered = np.mean((lo <= truth[:, 0]) & (truth[:, 0] <= hi))
    print(f"{coordinates}: |median − exact| mean {error.mean():.4f}, max {error.max():.3f}; 90 % coverage {covered:.3f}")
    assert np.all((draws >= 0) & (draws <= 1))
    if coordinates == "prior":
        assert error.mean() < 0.02
        band = binomial_band(N_TEST, 0.9, level=0.99)
        assert band[0] <= covered <= band[1]


def test_log_prob_is_a_density_in_u(fitted):
    """log_prob includes the coordinates' Jacobian: for one observation the density of u integrates to
    1 over the box (a 300 × 300 midpoint grid; within 3 %)."""
    _, est, _, _, _ = fitted
    g = (np.arange(300) + 0.5) / 300
    uu = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    x0, ms0 = np.full((len(uu), 1), 0.7), np.full(len(uu), normalize("Ms", 8e5))
    total = np.exp(est.log_prob(uu, x0, ms0)).sum() / len(uu)
    assert total == pytest.approx(1.0, abs=0.03)


def test_the_coordinates_invert_where_the_prior_has_mass():
    Ms, _, u, _ = data()
    v = to_coordinates(u[:500], Ms[:500], NAMES, {}, "prior")
    assert np.all((v >= 0) & (v <= 1))
    assert np.abs(from_coordinates(v, Ms[:500], NAMES, {}, "prior") - u[:500]).max() < 1e-3
    assert np.array_equal(to_coordinates(u, Ms, NAMES, {}, "box"), u)
