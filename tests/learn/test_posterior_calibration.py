"""The calibration measures (SBC ranks and their KS test, central-interval coverage, TARP) on
posteriors whose calibration is known: the exact posterior of a bounded Gaussian model passes, an
overconfident (half-width) and a shifted one fail."""

import numpy as np
import pytest
from scipy import stats

from forcdecode.core.errors import DatasetError
from forcdecode.learn.calibration import calibration_figure, calibration_metrics, sbc_ks_pvalues, sbc_ranks, tarp_coverage
from forcdecode.learn.scoring import binomial_band

SIGMA = 0.08
N_OBS, N_DRAWS = 600, 400


def bounded_gaussian(scale_factor=1.0, shift=0.0, seed=0):
    """θ ~ U[0, 1]², x = θ + σ ε; the exact posterior per coordinate is N(x, σ²) truncated to [0, 1].
    Returns (draws, truth) with the draws taken from the posterior of width ``scale_factor`` σ,
    centred ``shift`` σ off."""
    rng = np.random.default_rng(seed)
    theta = rng.random((N_OBS, 2))
    x = theta + SIGMA * rng.standard_normal(theta.shape)
    scale = scale_factor * SIGMA
    loc = x + shift * SIGMA
    a, b = (0 - loc) / scale, (1 - loc) / scale
    draws = stats.truncnorm.rvs(a[:, None, :], b[:, None, :], loc=loc[:, None, :], scale=scale,
                                size=(N_OBS, N_DRAWS, 2), random_state=rng)
    return draws, theta


def test_ranks_and_tarp_by_hand():
    draws = np.array([[[0.1, 5.0], [0.5, 6.0], [0.9, 7.0]]])  # one observation, 3 draws, 2 parameters
    assert sbc_ranks(draws, np.array([[0.6, 4.0]])).tolist() == [[2, 0]]
    # reference at the origin: draw distances 5.001, 6.02, 7.06; truth (0, 6.5) at 6.5 → 2 of 3 nearer
    coverage = tarp_coverage(draws, np.array([[0.0, 6.5]]), np.array([[0.0, 0.0]]), [0.5, 0.7])
    assert coverage.tolist() == [0.0, 1.0]  # f = 2/3: not below 0.5, below 0.7


def test_the_exact_posterior_is_calibrated():
    draws, truth = bounded_gaussian()
    metrics = calibration_metrics(draws, truth, ["a", "b"], np.random.default_rng(1))
    band = {level: binomial_band(N_OBS, level, level=0.99) for level in (0.5, 0.68, 0.9)}
    for row in metrics["per_parameter"].values():
        assert row["sbc_ks_p"] > 0.01, row
        for level, (low, high) in band.items():
            assert low <= row[f"coverage_{int(level * 100)}"] <= high, (level, row)
        # the 90 % interval of a N(0, σ²) is 3.29 σ wide; truncation near the bounds narrows it a little
        assert 2.9 * SIGMA < row["width_90"] < 3.35 * SIGMA, row["width_90"]
        assert row["mae_median"] < 0.9 * SIGMA
    for level, (low, high) in band.items():
        assert low <= metrics["joint"]["tarp"][f"coverage_{int(level * 100)}"] <= high, metrics["joint"]


def test_an_overconfident_posterior_fails():
    draws, truth = bounded_gaussian(scale_factor=0.5)
    metrics = calibration_metrics(draws, truth, ["a", "b"], np.random.default_rng(1))
    for row in metrics["per_parameter"].values():
        assert row["sbc_ks_p"] < 1e-6 and row["coverage_90"] < 0.7, row
    # TARP with random reference points is the less sensitive test, yet far below the band (0.87–0.93)
    assert metrics["joint"]["tarp"]["coverage_90"] < min(0.8, binomial_band(N_OBS, 0.9, level=0.99)[0])


def test_a_shifted_posterior_fails_sbc_but_not_the_width():
    draws, truth = bounded_gaussian(shift=1.0)
    ranks = sbc_ranks(draws, truth)
    p = sbc_ks_pvalues(ranks, N_DRAWS, np.random.default_rng(0))
    assert (p < 1e-6).all(), p
    assert ranks.mean() < 0.4 * N_DRAWS  # the truth sits low in draws centred above it


def test_bad_inputs_raise_dataset_errors():
    draws, truth = bounded_gaussian()
    with pytest.raises(DatasetError, match="n_obs, n_draws, n_params"):
        sbc_ranks(draws, truth[:, :1])
    with pytest.raises(DatasetError, match="not finite"):
        bad = truth.copy()
        bad[0, 0] = np.nan
        calibration_metrics(draws, bad, ["a", "b"], np.random.default_rng(0))
    with pytest.raises(DatasetError, match="reference"):
        tarp_coverage(draws, truth, truth[:5], [0.5])
    with pytest.raises(DatasetError, match="names"):
        calibration_metrics(draws, truth, ["a"], np.random.default_rng(0))


def test_the_figure_is_written(tmp_path):
    draws, truth = bounded_gaussian()
    metrics = calibration_metrics(draws[:100], truth[:100], ["a", "b"], np.random.default_rng(0))
    calibration_figure(metrics, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").read_bytes()[:4] == b"\x89PNG"
