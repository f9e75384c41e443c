"""The synthetic likelihood read from a family's own simulated images (``infer.fit.image_likelihood``)
on a linear-Gaussian image problem whose likelihood is known in closed form: 16×16 images whose pixels
move with logit u₀ along one pattern (``signal`` grey levels per logit unit) and not with u₁, in pixel
noise of sd 12 grey levels. The exact likelihood of logit u₀ is Gaussian with sd 12/(signal·‖pattern‖)."""

import numpy as np
import pytest
from scipy.stats import norm

from forcdecode.infer.fit import (_inverse_logit, _log_jacobian, _logit, image_likelihood, likelihood_posterior)

PATTERN = np.sin(np.linspace(0, 3 * np.pi, 256)).reshape(16, 16)
NOISE = 12.0


def render(z0, rng, signal, extra=0.0):
    """Images (len(z0), 16, 16) uint8; ``extra``: grey levels of a checkerboard the simulator never makes."""
    checker = np.indices((16, 16)).sum(axis=0) % 2 - 0.5
    x = 128 + signal * np.asarray(z0)[:, None, None] * PATTERN + extra * checker
    return np.clip(np.round(x + NOISE * rng.standard_normal((len(z0), 16, 16))), 0, 255).astype(np.uint8)


def problem(seed, signal=20.0, k=200, extra=0.0):
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((k, 2))
    truth = rng.uniform(0.25, 0.75, 2)
    observed = render(_logit(truth[None])[:, 0], rng, signal, extra)[0]
    return rng, _inverse_logit(z), render(z[:, 0], rng, signal), observed, truth


def test_the_fisher_information_is_the_closed_form_one_and_an_unencoded_parameter_is_not_resolved():
    """The conditional sd of logit u₀, 1/√F₀₀, within 10 % of 12/(signal‖pattern‖) (measured 0.98–1.02×
    on these seeds); the marginal one, √(F⁻¹)₀₀ with u₁ free, within 25 % and never narrower (measured
    1.01–1.16×: the slope of u₁, which the images do not carry, is estimated from 200 noisy images and
    correlates with u₀'s); u₁ unresolved."""
    signal = 20.0
    exact_sd = NOISE / (signal * np.linalg.norm(PATTERN))
    for seed in range(3):
        _, u, images, observed, truth = problem(seed, signal)
        info = image_likelihood(u, images, observed).info
        fisher = np.array(info["fisher"])
        conditional, marginal = 1 / np.sqrt(fisher[0, 0]), np.sqrt(np.linalg.pinv(fisher)[0, 0])
        assert conditional == pytest.approx(exact_sd, rel=0.10), (conditional, exact_sd)
        assert conditional <= marginal < 1.25 * exact_sd, (marginal, exact_sd)
        assert info["resolution"][0] < 0.1 and info["resolution"][1] > 1.5, info["resolution"]
        assert abs(info["z_hat"][0] - _logit(truth)[0]) < 4 * exact_sd


def test_posterior_intervals_from_the_image_likelihood_cover_at_the_nominal_rate():
    """100 replications, a biased Gaussian proposal in logit space (bias 0.3, sd 0.5), the uniform prior:
    the 90 % interval of u₀ holds the truth within the 99 % binomial band 0.82–0.96."""
    hits = 0
    for seed in range(100):
        rng, u, images, observed, truth = problem(100 + seed)
        like = image_likelihood(u, images, observed)
        mean = _logit(truth) + 0.3
        zq = rng.normal(mean, 0.5, size=(4000, 2))
        uq = np.clip(_inverse_logit(zq), 1e-6, 1 - 1e-6)
        log_q = norm.logpdf(_logit(uq), mean, 0.5).sum(axis=1) + _log_jacobian(uq)
        post = likelihood_posterior(like.loglik, uq, log_q, np.zeros(len(uq)), ["a", "b"])
        lo, hi = post["parameters"]["a"]["interval_90"]
        hits += lo <= truth[0] <= hi
    assert 82 <= hits <= 96, hits


def test_an_image_the_simulator_cannot_make_is_told_by_its_misfit():
    """A checkerboard of ±30 grey levels added to the observation (no parameter makes it, and no
    simulation varies along it): its distance from the simulations' components lies beyond every
    simulation's (p = 0); the plain observation's does not (p > 0.01 on both checks)."""
    _, u, images, observed, _ = problem(7)
    plain = image_likelihood(u, images, observed).info
    assert plain["misfit_p"] > 0.01 and plain["outside_components_p"] > 0.01, plain
    _, u, images, odd, _ = problem(7, extra=60.0)
    info = image_likelihood(u, images, odd).info
    assert info["outside_components_p"] == 0.0, info
    assert info["outside_components"] > info["outside_components_simulated_max"]


def test_mismatched_inputs_are_refused():
    _, u, images, observed, _ = problem(3)
    with pytest.raises(ValueError, match="one image of the observed shape"):
        image_likelihood(u, images[:, :8], observed)
    with pytest.raises(ValueError, match="cannot fit"):
        image_likelihood(u[:4], images[:4], observed)
    with pytest.raises(ValueError, match="finite weight"):
        likelihood_posterior(lambda x: np.zeros(len(x)), u, np.zeros(len(u)), np.full(len(u), -np.inf), ["a", "b"])
