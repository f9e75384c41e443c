import numpy as np
import pytest

from forcdecode.dataset.params import DEFAULT_BOUNDS, MU0, denormalize, draw_parameters, normalize


def test_draws_of_the_running_dataset_stay_bit_identical():
    """Pinned: samples of the laptop config (seed 20261122) as the dataset drew them before the
    random streams moved to core.streams (results/params.parquet of that run)."""
    assert draw_parameters(20261122, 0) == {
        "Ms": 204993.24702100997, "A_ex": 3.3041527696672888e-12, "K_u": 309858.51261384203,
        "D": 0.00491996895268772, "N_pin": 153, "sigma_theta_deg": 0.9319279415915149, "sigma_K": 0.12033176862664048}
    assert draw_parameters(20261122, 57) == {
        "Ms": 633727.5290946022, "A_ex": 1.9157767501634773e-11, "K_u": 310097.12618754647,
        "D": 0.00431126059118882, "N_pin": 209, "sigma_theta_deg": 0.09815543509706037, "sigma_K": 0.17221342970951437}


def test_draws_are_reproducible_and_independent_per_sample():
    assert draw_parameters(1, 5) == draw_parameters(1, 5)
    assert draw_parameters(1, 5) != draw_parameters(1, 6)
    assert draw_parameters(1, 5) != draw_parameters(2, 5)


@pytest.fixture(scope="module")
def draws():
    return [draw_parameters(3, i) for i in range(3000)]


def test_draws_respect_the_paper_bounds(draws):
    for name, (lo, hi) in DEFAULT_BOUNDS.items():
        values = np.array([d[name] for d in draws])
        assert values.min() >= lo and values.max() <= hi, name
    l_ex = np.array([np.sqrt(2 * d["A_ex"] / (MU0 * d["Ms"] ** 2)) for d in draws])
    assert l_ex.min() > 5e-9


def test_distributions(draws):
    Ms = np.array([d["Ms"] for d in draws])
    assert Ms.mean() == pytest.approx(8e5, rel=0.03)  # U(200, 1400) kA/m
    # ln K triangular with mode at the maximum: P(ln K > midpoint) = 3/4
    lnK = np.log([d["K_u"] for d in draws])
    mid = 0.5 * (np.log(1e3) + np.log(1.5e6))
    assert np.mean(lnK > mid) == pytest.approx(0.75, abs=0.03)
    N_pin = np.array([d["N_pin"] for d in draws])
    assert set(np.unique(N_pin)) <= set(range(256)) and N_pin.max() >= 250


def test_exchange_follows_the_target_length_where_it_fits(draws):
    """Low M_s: A = l² μ0 M_s²/2 with l ~ N(10 nm, 1 nm) lies inside 1–35 pJ/m and is used as is."""
    low = [d for d in draws if d["Ms"] < 4e5]
    l_ex = np.array([np.sqrt(2 * d["A_ex"] / (MU0 * d["Ms"] ** 2)) for d in low])
    assert l_ex.mean() == pytest.approx(10e-9, rel=0.05)
    assert l_ex.std() == pytest.approx(1e-9, rel=0.25)


@pytest.mark.parametrize("name", list(DEFAULT_BOUNDS))
def test_normalization_round_trip_uses_bounds(name):
    lo, hi = DEFAULT_BOUNDS[name]
    assert normalize(name, lo) == pytest.approx(0.0, abs=1e-12)
    assert normalize(name, hi) == pytest.approx(1.0)
    mid = denormalize(name, 0.37)
    assert normalize(name, mid) == pytest.approx(0.37)


def test_a_sample_that_cannot_be_simulated_is_recorded_not_raised():
    import json

    from forcdecode.config import load_config, shipped_config
    from forcdecode.dataset.simulate import screen, simulate

    cfg = load_config(shipped_config("test"))  # validated, defaults filled
    params = draw_parameters(cfg["seed"], 0)
    params["Ms"] = float("nan")  # e.g. a corrupt parameter table
    row = screen(cfg, params, 0)
    assert row["screen_status"] == "failed" and "Ms" in row["screen_reason"]
    result = simulate(cfg, params, 0)
    assert result["status"] == "failed" and "Ms" in result["reason"]
    json.dumps({k: v for k, v in row.items() if k != "traceback"})  # serializable for the table


@pytest.mark.parametrize("Ms", [3e5, 8e5, 1.3e6])  # A_ex: the exchange-length branch; both; the fallback
def test_draw_density_matches_the_draws(Ms):
    """``draw_log_density`` against 20,000 draws at a fixed M_s: the probability of each of 25 bins
    (the density integrated by the midpoint rule on 40 sub-points) against the counts, χ² p > 0.001
    for A_ex | M_s and K_u; the density integrates to 1. Dropping the fallback term of A_ex (or the
    branch) fails at 8e5 and 1.3e6 A/m."""
    from scipy.stats import chisquare

    from forcdecode.dataset.params import draw_log_density

    bounds = {"Ms": (Ms, Ms)}
    draws = [draw_parameters(11, i, bounds) for i in range(20_000)]
    for name in ("A_ex", "K_u"):
        u = np.array([normalize(name, d[name]) for d in draws])
        edges = np.linspace(0, 1, 26)
        counts = np.histogram(u, bins=edges)[0]
        fine = (np.arange(25 * 40) + 0.5) / (25 * 40)
        density = np.exp(draw_log_density(fine[:, None], (name,), Ms))
        probs = density.reshape(25, 40).mean(axis=1) / 25
        assert probs.sum() == pytest.approx(1.0, abs=0.01)
        expected = probs / probs.sum() * counts.sum()
        keep = expected > 5
        assert counts[~keep].sum() <= 10  # nothing drawn where the density says there is nothing
        stat = chisquare(counts[keep], expected[keep] * counts[keep].sum() / expected[keep].sum())
        assert stat.pvalue > 1e-3, (name, Ms, stat)


def test_draw_density_is_minus_infinity_outside_the_box():
    from forcdecode.dataset.params import draw_log_density

    logp = draw_log_density(np.array([[0.5, 0.5], [1.2, 0.5], [0.5, -0.1]]), ("D", "K_u"), 8e5)
    assert np.isfinite(logp[0]) and np.isneginf(logp[1:]).all()
    with pytest.raises(KeyError, match="no draw density"):
        draw_log_density(np.array([[0.5]]), ("Ms",), 8e5)


def test_draw_prior_quantiles_are_the_draws_quantiles():
    """The draw prior's median and 5/95 % quantiles of A_ex | M_s and K_u against 20,000 draws at a
    fixed M_s (within 0.01 in u); K_u's median is the closed form 1/√2 of p(u) = 2u."""
    from forcdecode.dataset.params import draw_prior_quantiles

    Ms = 8e5
    draws = [draw_parameters(12, i, {"Ms": (Ms, Ms)}) for i in range(20_000)]
    for name in ("A_ex", "K_u"):
        u = np.array([normalize(name, d[name]) for d in draws])
        assert np.allclose(draw_prior_quantiles(name, Ms, [0.05, 0.5, 0.95]), np.quantile(u, [0.05, 0.5, 0.95]),
                           atol=0.01)
    assert draw_prior_quantiles("K_u", Ms, [0.5])[0] == pytest.approx(2**-0.5, abs=1e-3)


def test_the_prior_cdf_makes_draws_uniform_and_inverts():
    """The probability integral transform: 4,000 draws (M_s drawn too) mapped by ``draw_prior_cdf``
    are uniform (KS p > 0.001) for A_ex | M_s and K_u; ``draw_prior_ppf`` inverts it within 1e-3
    where the prior has mass."""
    from scipy.stats import kstest

    from forcdecode.dataset.params import draw_prior_cdf, draw_prior_ppf

    draws = [draw_parameters(13, i) for i in range(4_000)]
    Ms = np.array([d["Ms"] for d in draws])
    for name in ("A_ex", "K_u", "D"):
        u = np.array([normalize(name, d[name]) for d in draws])
        v = draw_prior_cdf(name, u, Ms)
        assert kstest(v, "uniform").pvalue > 1e-3, name
        assert np.abs(draw_prior_ppf(name, v, Ms) - u).max() < 1e-3, name
