"""The calibration measures (SBC ranks and their KS test, central-interval coverage, TARP) on
posteriors whose calibration is known: the exact posterior of a bounded Gaussian model passes, an
overconfident (half-width) and a shifted one fail."""

import numpy as np
import pytest
from scipy import stats

from forcdecode.core.errors import DatasetError
from forcdecode.learn.calibration import (calibration_figure, calibration_metrics, conformal_coverage, conformal_widening,
                                         sbc_ks_pvalues, sbc_ranks, tarp_coverage)
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


@pytest.mark.parametrize("scale_factor", [0.5, 1.0, 2.0])
def test_conformalized_intervals_cover_whatever_the_flow_width(scale_factor):
    """Overconfident, exact and underconfident posteriors: intervals widened (or narrowed) on 300
    calibration observations cover 300 fresh ones at the level, within 3 standard deviations of the
    coverage of a conformal interval (calibration draw and test draw both vary: α(1 − α)(1/301 + 1/300));
    the exact posterior's widening is ~0, the overconfident one is widened back to the exact width,
    the underconfident one narrowed."""
    draws, truth = bounded_gaussian(scale_factor=scale_factor, seed=3)
    cal, test = slice(0, 300), slice(300, N_OBS)
    widening = conformal_widening(draws[cal], truth[cal], (0.68, 0.9))
    coverage = conformal_coverage(draws[test], truth[test], widening)
    for level, (cov, width) in coverage.items():
        sd = np.sqrt(level * (1 - level) * (1 / 301 + 1 / 300))
        assert np.all(np.abs(cov - level) < 3 * sd), (scale_factor, level, cov)
    q90 = widening[0.9]
    if scale_factor == 1.0:
        assert np.all(np.abs(q90) < 0.3 * SIGMA), q90
    elif scale_factor == 0.5:  # half-width 1.645·σ/2 → the exact 1.645·σ: q ≈ 0.82 σ
        assert np.all((0.5 * SIGMA < q90) & (q90 < 1.1 * SIGMA)), q90
        # the exact interval: 3.29 σ wide, narrower near the bounds where it is clipped to [0, 1] (raw: 1.65 σ)
        assert np.all((2.6 * SIGMA < coverage[0.9][1]) & (coverage[0.9][1] < 3.4 * SIGMA)), coverage[0.9][1]
    else:  # too wide: narrowed (negative widening; the draws' truncation at the bounds keeps it small)
        raw_width = conformal_coverage(draws[test], truth[test], {0.9: np.zeros(2)})[0.9][1]
        assert np.all(q90 < 0) and np.all(coverage[0.9][1] < raw_width - 0.04), (q90, raw_width)


def test_conformal_widening_with_too_few_samples_is_the_whole_support():
    draws, truth = bounded_gaussian(seed=4)
    widening = conformal_widening(draws[:5], truth[:5], (0.9,))  # ⌈6 · 0.9⌉ = 6 > 5
    assert widening[0.9].tolist() == [1.0, 1.0]
    cov, width = conformal_coverage(draws[5:50], truth[5:50], widening)[0.9]
    assert cov.tolist() == [1.0, 1.0] and np.allclose(width, 1.0)
