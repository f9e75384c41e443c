"""Refinement by sequential importance sampling on a synthetic problem whose posterior is known on a
grid: a biased, broad "amortized" proposal; the refined median is the exact posterior median within
a stated tolerance (0.02) and the error drops to under half the proposal's; the nested budgets are
exact prefixes of a longer run. (Interval coverage is NOT yet nominal: over 60 repeats at budget 200
both 90 % intervals held the truth in 57–75 % of the runs, against 81–90 % expected; effective sample
sizes ~20–30. Measured, not asserted: see the closing note of stop 17.)"""

import numpy as np
import pytest
from scipy.stats import norm

from forcdecode.loop.fit import _log_jacobian, _logit, refine

K = np.arange(1, 21)
SIGMA = 0.05


def forward(u):
    """(k, 2) in [0, 1]² → (k, 20, 1) 'families' (one point per curve: exact Gaussian likelihood)."""
    u = np.atleast_2d(u)
    x = np.sin(2 * np.pi * K[None, :] * u[:, :1] / 20 + u[:, 1:]) + u[:, 1:] * K[None, :] / 20
    return x[:, :, None]


def proposal(truth, rng, n=4000, bias=0.6, sd=1.0):
    """A broad Gaussian in logit space centred off the truth: the 'amortized posterior' to refine."""
    mean = _logit(truth) + bias
    z = rng.normal(mean, sd, size=(n, 2))
    draws = (1 / (1 + np.exp(-z)) - 1e-4) / (1 - 2e-4)

    def logpdf(u):
        return norm.logpdf(_logit(u), mean, sd).sum(axis=1) + _log_jacobian(u)

    return draws, logpdf


def grid_posterior(observed):
    g = np.linspace(0.0005, 0.9995, 400)
    uu = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    ll = -0.5 * ((forward(uu) - observed[None]) ** 2).sum(axis=(1, 2)) / SIGMA**2
    w = np.exp(ll - ll.max())
    w /= w.sum()
    medians = []
    for j in range(2):
        order = np.argsort(uu[:, j])
        medians.append(np.interp(0.5, np.cumsum(w[order]), uu[order, j]))
    return np.array(medians)


def run(seed, budget=200):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.2, 0.8, 2)
    observed = forward(truth)[0] + SIGMA * rng.normal(size=(20, 1))
    draws, logpdf = proposal(truth, rng)
    result = refine(observed, forward, draws, logpdf, SIGMA**2, budget, 25, rng, ("a", "b"), checkpoints=(50, 100))
    return truth, observed, draws, result


def test_refined_median_is_the_exact_posterior_median_and_beats_the_proposal():
    truth, observed, draws, result = run(0)
    exact = grid_posterior(observed)
    refined = np.array([result["summary"]["parameters"][n]["median"] for n in ("a", "b")])
    amortized = np.median(draws, axis=0)
    print(f"truth {truth}, exact {exact}, refined {refined}, amortized {amortized}, ESS {result['summary']['ess']:.0f}")
    assert np.abs(refined - exact).max() < 0.02
    assert np.abs(refined - truth).sum() < 0.5 * np.abs(amortized - truth).sum()
    assert set(result["by_budget"]) == {50, 100, 200}


def test_nested_budgets_are_prefixes():
    _, _, _, short = run(3, budget=100)
    _, _, _, long = run(3, budget=200)
    assert np.array_equal(long["u"][:100], short["u"])
    assert long["by_budget"][100]["parameters"] == short["by_budget"][100]["parameters"]


def test_effective_observations_of_gaussian_families():
    """R realisations of a family carrying ν independent N(0, σ²) observations (each repeated over the
    points it covers, as a disorder feature covers many points): σ² and ν are recovered."""
    from forcdecode.loop.fit import effective_observations

    rng = np.random.default_rng(5)
    n, nu, sigma = 40, 12, 0.05
    blocks = np.repeat(np.arange(nu), int(np.ceil(n * n / nu)))[: n * n].reshape(n, n)
    fams = np.stack([sigma * rng.normal(size=nu)[blocks] for _ in range(40)])
    s2, est = effective_observations(fams)
    assert s2 == pytest.approx(sigma**2, rel=0.15)
    assert 0.6 * nu < est < 1.6 * nu
