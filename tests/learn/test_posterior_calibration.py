"""The calibration measures (SBC ranks and their KS test, central-interval coverage, TARP) on
posteriors whose calibration is known: the exact posterior of a bounded Gaussian model passes, an
overconfident (half-width) and a shifted one fail; a Beta quantile recalibration fitted on held-out
PITs repairs an over-wide and a shifted one on new observations."""

import numpy as np
import pytest
from scipy import stats

from forcdecode.core.errors import DatasetError
from forcdecode.learn.calibration import (calibration_figure, calibration_metrics, conformal_coverage, conformal_widening,
                                         fit_recalibration, probability_integral_transform, recalibrate_draws,
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


def _recalibrated_run(scale_factor, shift, n_fit=200):
    """Beta recalibration fitted on one draw of the model, scored on an independent one."""
    fit_draws, fit_truth = bounded_gaussian(scale_factor, shift, seed=11)
    beta = fit_recalibration(probability_integral_transform(fit_draws[:n_fit], fit_truth[:n_fit]), ("a", "b"))
    draws, truth = bounded_gaussian(scale_factor, shift, seed=12)
    return beta, draws, truth, recalibrate_draws(draws, beta, ("a", "b"))


@pytest.mark.parametrize("scale_factor, shift", [(1.7, 0.0), (1.3, 0.7)])
def test_recalibration_on_held_out_pits_repairs_a_miscalibrated_posterior(scale_factor, shift):
    """Over-wide (1.7 σ) and over-wide + shifted (1.3 σ, 0.7 σ off) posteriors fail SBC (the over-wide
    one also the 50 % coverage) on 600 new observations; after a Beta recalibration fitted on 200
    others they pass (KS p > 0.01, 50 % and 90 % coverage in the 99 % binomial band), and the shifted
    one's median moves towards the exact posterior's."""
    beta, draws, truth, fixed = _recalibrated_run(scale_factor, shift)
    rng = np.random.default_rng(3)
    before = calibration_metrics(draws, truth, ("a", "b"), rng, levels=(0.5, 0.9))["per_parameter"]
    after = calibration_metrics(fixed, truth, ("a", "b"), rng, levels=(0.5, 0.9))["per_parameter"]
    # a Beta is not the exact distortion of a Gaussian's width: judged at the 99 % binomial band
    band50, band90 = binomial_band(N_OBS, 0.5, level=0.99), binomial_band(N_OBS, 0.9, level=0.99)
    for name in ("a", "b"):
        assert before[name]["sbc_ks_p"] < 1e-3
        assert before[name]["coverage_50"] > band50[1] or shift
        assert after[name]["sbc_ks_p"] > 0.01
        assert band50[0] <= after[name]["coverage_50"] <= band50[1]
        assert band90[0] <= after[name]["coverage_90"] <= band90[1]
        assert after[name]["width_90"] < 0.85 * before[name]["width_90"]
        a, b = beta[name]
        assert b > 1.5  # PITs bunched in the middle: b > 1; drawn towards 0 by a shift up: a < b
        assert (a > 1.5) if not shift else (a < b - 0.5)
    exact, _ = bounded_gaussian(1.0, 0.0, seed=12)
    exact_median = np.median(exact, axis=1)
    error_after = np.abs(np.median(fixed, axis=1) - exact_median).mean()
    error_before = np.abs(np.median(draws, axis=1) - exact_median).mean()
    # the shift is taken out; an unshifted median moves by less than 0.3 σ (the fitted a ≠ b by noise)
    assert error_after < 0.6 * error_before if shift else error_after < 0.3 * SIGMA


def test_recalibrating_the_exact_posterior_changes_little_and_keeps_the_dependence():
    """PITs of the exact posterior are uniform: the fitted Beta is near (1, 1) and the draws move by
    less than 0.01 σ-scaled units on average. A monotone map per coordinate keeps each observation's
    rank order within every coordinate, hence any dependence between coordinates."""
    beta, draws, truth, fixed = _recalibrated_run(1.0, 0.0)
    for a, b in beta.values():
        assert abs(a - 1.0) < 0.2 and abs(b - 1.0) < 0.2
    assert np.abs(fixed - draws).mean() < 0.1 * SIGMA
    rank_before = np.argsort(np.argsort(draws, axis=1), axis=1)
    rank_after = np.argsort(np.argsort(fixed + 1e-12 * np.arange(N_DRAWS)[None, :, None], axis=1), axis=1)
    assert (rank_before == rank_after).mean() > 0.99
    assert np.all(fixed >= draws.min(axis=1, keepdims=True) - 1e-12)
    assert np.all(fixed <= draws.max(axis=1, keepdims=True) + 1e-12)


def test_a_few_draws_recalibrated_against_reference_draws_follow_the_recalibrated_law():
    """Four draws per observation mapped through 400 reference draws of the same posterior: pooled over
    600 observations their PITs under the recalibrated reference are uniform (KS p > 0.01)."""
    beta, draws, truth, fixed = _recalibrated_run(1.7, 0.0)
    few = draws[:, :4]
    reference = draws[:, 4:]
    mapped = recalibrate_draws(few, beta, ("a", "b"), reference=reference)
    law = recalibrate_draws(reference, beta, ("a", "b"))
    pit = (law < mapped[:, :1, :]).mean(axis=1)
    for j in range(2):
        assert stats.kstest(pit[:, j], "uniform").pvalue > 0.01
    unmapped_pit = (law < few[:, :1, :]).mean(axis=1)
    assert stats.kstest(unmapped_pit[:, 0], "uniform").pvalue < 1e-3


def test_recalibration_refuses_bad_inputs():
    draws, truth = bounded_gaussian(seed=5)
    pit = probability_integral_transform(draws, truth)
    with pytest.raises(DatasetError, match="at least 20"):
        fit_recalibration(pit[:10], ("a", "b"))
    with pytest.raises(DatasetError, match="PITs"):
        fit_recalibration(pit, ("a",))
    with pytest.raises(DatasetError, match="strictly inside"):
        fit_recalibration(np.clip(pit, 0.0, 0.9) * (np.arange(len(pit)) > 0)[:, None], ("a", "b"))
    with pytest.raises(DatasetError, match="reference draws"):
        recalibrate_draws(draws, {"a": [1.0, 1.0]}, ("a", "b"), reference=draws[:5])


def test_the_likelihood_ratio_supports_a_map_only_where_the_pits_are_miscalibrated():
    """A Beta map fitted to the PITs of a 1.7× too wide posterior beats the identity overwhelmingly;
    one fitted to the exact posterior's PITs does not (p > 0.01 on 200 and on 600 observations)."""
    from forcdecode.learn.calibration import recalibration_likelihood_ratio

    for scale_factor, supported in ((1.7, True), (1.0, False)):
        draws, truth = bounded_gaussian(scale_factor, 0.0, seed=11)
        for n in (200, 600):
            pit = probability_integral_transform(draws[:n], truth[:n])
            beta = fit_recalibration(pit, ("a", "b"))
            p = recalibration_likelihood_ratio(pit, beta, ("a", "b"))
            assert all((v < 1e-6) if supported else (v > 0.01) for v in p.values()), (scale_factor, n, p, beta)


def test_the_gate_applies_a_map_only_where_its_likelihood_ratio_test_rejects_the_identity():
    """Coordinate a from a 1.7× too wide posterior, b from the exact one (200 observations): at the 0.05
    level the gate keeps a's map and drops b's, so b's draws are left exactly as the flow gave them while
    a's 90 % coverage comes back into the binomial band; alpha 1 keeps both maps, 0 none; a level outside
    [0, 1] or a map without its p-value is refused."""
    from forcdecode.core.errors import ConfigError
    from forcdecode.learn.calibration import gate_recalibration, marginal_coverage, recalibration_likelihood_ratio

    wide, wide_truth = bounded_gaussian(1.7, 0.0, seed=21)
    exact, exact_truth = bounded_gaussian(1.0, 0.0, seed=22)
    draws = np.concatenate([wide[:200, :, :1], exact[:200, :, 1:]], axis=2)
    truth = np.concatenate([wide_truth[:200, :1], exact_truth[:200, 1:]], axis=1)
    pit = probability_integral_transform(draws, truth)
    beta = fit_recalibration(pit, ("a", "b"))
    p = recalibration_likelihood_ratio(pit, beta, ("a", "b"))
    gated = gate_recalibration(beta, p, 0.05)
    assert set(gated) == {"a"}, (p, beta)
    fixed = recalibrate_draws(draws, gated, ("a", "b"))
    assert np.array_equal(fixed[:, :, 1], draws[:, :, 1])
    test_draws, test_truth = bounded_gaussian(1.7, 0.0, seed=23)
    before = marginal_coverage(test_draws, test_truth, [0.9])[0.9][0][0]
    after = marginal_coverage(recalibrate_draws(test_draws, gated, ("a", "b")), test_truth, [0.9])[0.9][0][0]
    low, high = binomial_band(len(test_truth), 0.9)
    assert before > high and low <= after <= high, (before, after)
    assert set(gate_recalibration(beta, p, 1.0)) == {"a", "b"} and gate_recalibration(beta, p, 0.0) == {}
    with pytest.raises(ConfigError, match="alpha"):
        gate_recalibration(beta, p, 1.5)
    with pytest.raises(DatasetError, match="likelihood-ratio"):
        gate_recalibration(beta, {"a": 0.0}, 0.05)
