"""Prior classes of the draw (config key ``prior``): ``paper`` is the draw as it always was, bit for bit,
whether the key is given or not; ``perpendicular`` gives K_eff > 0 for every draw, keeps every other
parameter of the sample (so their marginals), and follows its stated law for K_u given M_s."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from forcdecode.config import load_config, shipped_config, validate_config
from forcdecode.core.errors import ConfigError
from forcdecode.core.parameters import DEFAULT_BOUNDS, MU0, k_eff, normalize
from forcdecode.dataset.merge import config_hash, physics_config
from forcdecode.dataset.params import (draw_log_density, draw_parameters, draw_prior_cdf, draw_prior_ppf,
                                       draw_prior_quantiles, perpendicular_floor)
from forcdecode.dataset.stages import draw_stage

OTHERS = ("Ms", "A_ex", "D", "N_pin", "sigma_theta_deg", "sigma_K")


def test_paper_chunks_are_bit_identical_with_and_without_the_key(tmp_path):
    """The laptop config's draw of a few chunks: no key (every config.json before it), ``prior: paper``
    given, and the loader's default filled in give the same parquet values, bit for bit."""
    base = {k: v for k, v in load_config(shipped_config("config")).items() if k != "prior"}
    tables = {}
    for label, cfg in (("absent", dict(base)), ("explicit", {**base, "prior": "paper"}),
                       ("loader", validate_config(dict(base)))):
        parts = [draw_stage(cfg, tmp_path / f"{label}_{chunk}.parquet", chunk=chunk) for chunk in (0, 3, 49)]
        tables[label] = pd.concat([pd.read_parquet(tmp_path / f"{label}_{c}.parquet") for c in (0, 3, 49)])
        assert all(len(p) == base["chunk_size"] for p in parts)
    assert tables["loader"].equals(tables["absent"]) and tables["explicit"].equals(tables["absent"])
    # the draw itself is the one the running dataset was made with (pinned in test_params.py)
    row = tables["absent"].set_index("sample_id").loc[0]
    assert row["K_u"] == 309858.51261384203 and row["Ms"] == 204993.24702100997


def test_the_default_class_keeps_the_config_hash():
    cfg = {k: v for k, v in load_config(shipped_config("config")).items() if k != "prior"}
    assert config_hash(physics_config(cfg)) == config_hash(physics_config({**cfg, "prior": "paper"}))
    assert config_hash(physics_config(cfg)) != config_hash(physics_config({**cfg, "prior": "perpendicular"}))


@pytest.fixture(scope="module")
def pairs():
    ids = range(4000)
    return ([draw_parameters(11, i) for i in ids], [draw_parameters(11, i, prior="perpendicular") for i in ids])


def _column(draws, name):
    return np.array([d[name] for d in draws], dtype=float)


def test_perpendicular_draws_have_positive_keff_and_stay_in_bounds(pairs):
    paper, perp = pairs
    keff = k_eff({"K_u": _column(perp, "K_u"), "Ms": _column(perp, "Ms")})
    assert keff.min() > 0
    lo, hi = DEFAULT_BOUNDS["K_u"]
    assert _column(perp, "K_u").min() >= lo and _column(perp, "K_u").max() <= hi
    # the paper draw of the same seed puts most of its mass in plane (the 65 % is after screening)
    assert np.mean(k_eff({"K_u": _column(paper, "K_u"), "Ms": _column(paper, "Ms")}) < 0) > 0.5


def test_perpendicular_keeps_every_other_parameter_of_the_sample(pairs):
    """Same (seed, sample id): the other parameters are the paper draw's, so their marginals are too."""
    paper, perp = pairs
    for name in OTHERS:
        assert np.array_equal(_column(paper, name), _column(perp, name)), name
    # and the marginals are the stated ones (M_s uniform on its bounds)
    ms = (_column(perp, "Ms") - 2e5) / 1.2e6
    assert stats.kstest(ms, "uniform").pvalue > 0.01


def test_perpendicular_k_u_follows_its_stated_law(pairs):
    """u = normalized log K_u: p(u | M_s) = 2u/(1 − u_f²) above u_f(M_s), so F(u | M_s) is uniform."""
    _, perp = pairs
    ms, ku = _column(perp, "Ms"), _column(perp, "K_u")
    u = normalize("K_u", ku)
    v = draw_prior_cdf("K_u", u, ms, prior="perpendicular")
    assert stats.kstest(v, "uniform").pvalue > 0.01
    assert np.allclose(draw_prior_ppf("K_u", v, ms, prior="perpendicular"), u, atol=1e-9)
    # the paper transform of the same values is not uniform (the class changed the law)
    assert stats.kstest(draw_prior_cdf("K_u", u, ms), "uniform").pvalue < 1e-6
    floor = perpendicular_floor(ms)
    assert np.all(u > floor) and np.allclose(floor, normalize("K_u", MU0 * ms**2 / 2))


@pytest.mark.parametrize("Ms", [3e5, 9e5, 1.35e6])
def test_perpendicular_density_normalizes_and_matches_quantiles(Ms):
    grid = (np.arange(20000) + 0.5) / 20000
    density = np.exp(draw_log_density(grid[:, None], ("K_u",), Ms, prior="perpendicular"))
    assert density.mean() == pytest.approx(1.0, abs=2e-3)
    assert np.all(density[grid < perpendicular_floor(Ms)] == 0)
    median = draw_prior_quantiles("K_u", Ms, [0.5], prior="perpendicular")[0]
    assert draw_prior_cdf("K_u", median, Ms, prior="perpendicular") == pytest.approx(0.5)
    # paper quantiles unchanged by the class argument's default
    assert draw_prior_quantiles("K_u", Ms, [0.5])[0] == pytest.approx(np.sqrt(0.5), abs=1e-3)


def test_a_config_whose_bounds_leave_no_perpendicular_film_is_refused():
    cfg = {"n_samples": 4, "prior": "perpendicular", "bounds": {"Ms": [2e5, 1.6e6]}}
    with pytest.raises(ConfigError, match="prior"):
        validate_config(cfg)
    validate_config({"n_samples": 4, "prior": "perpendicular"})  # the paper's bounds allow it
    with pytest.raises(ConfigError, match="prior"):
        validate_config({"n_samples": 4, "prior": "inplane"})
    with pytest.raises(ConfigError):
        draw_parameters(1, 0, bounds={"Ms": [1.5e6, 1.6e6]}, prior="perpendicular")
