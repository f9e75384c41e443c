"""No false refusals (issue 45 item 7): the domain check's noise-only tolerance (forc.saturation,
module docstring **Coincidence**) on saturated films that differ from each other by noise alone.

The films are Preisach ensembles (switching fields ±(0.25 ± w) T, erf in the field), saturated at both
ends inside the window, 40 curves, each point with Gaussian noise σ = 0.3 % of M_s and one calibration
point per curve at the top field with noise ``cal``·σ; written to a real instrument file (MicroMag
0015, or a Lake Shore 8600 CSV with time stamps), read back by ``measured.read_forc`` (the reader
drift-corrects each curve by its own calibration point, the path of a user's file) and analysed by
``domain_of_measurement``. No micromagnetics: about 50 ms a film.

Measured on 2026-11-28 (this file, seeds 0..N−1), new rule vs the rule before issue 45
(τ = max(4σ, one image level) on every point):

=====================================================  ======  ===========  ==========
film                                                   seeds   refused now  refused before
=====================================================  ======  ===========  ==========
perpendicular (w = 10 mT, window ±0.5 T), cal = 1      200     0 (0 %)      11 (5.5 %)
w = 40 mT, window ±0.7 T, cal = 3                      200     0 (0 %)      90 (45 %)
Lake Shore CSV (time-interpolated correction), cal = 3  200     0 (0 %)      36 (18 %)
=====================================================  ======  ===========  ==========

Power (perpendicular film, 100 seeds): the lowest curve not closed, 5 % (3 %) of the half loop height
below the others over its first 0.15 T: refused 100 % (100 %), as before; a reversible slope of
1.5 M_s per T left at saturation: 100 %, as before (1.0 M_s/T: 95 %, 100 % before: one training-grid
step of branch at 0.3 % noise resolves a slope of about 5σ/δ ≈ 0.5 M_s/T).

Re-made by ``.venv/bin/python -m pytest -p no:cacheprovider -q tests/forc/test_saturation_noise.py``
(the CSV row: ``-m slow``)."""

import numpy as np
import pytest
from scipy.special import erf, ndtri

from forcdecode.forc.saturation import (ALPHA_FILE, MEDIAN_FACTOR, _difference, _Noise, _sorted,
                                        domain_of_measurement, noise_level)
from forcdecode.measured import read_forc
from forcdecode.measured.writers import write_lakeshore_csv, write_micromag_0015

M_S = 2e-6  # A m²
NOISE = 0.003  # σ, fraction of M_s (the issue's film)


def preisach(h_r, h, h_c=0.25, width=0.04):
    up = 0.5 * (1 + erf((h - h_c) / (width * np.sqrt(2))))
    down = 0.5 * (1 + erf((-h_r - h_c) / (width * np.sqrt(2))))
    return 1 - 2 * down + 2 * np.minimum(down, up)


def measured_film(tmp_path, seed, *, window=0.5, width=0.01, n_curves=40, step=0.02, noise=NOISE, cal=1.0,
                  fmt="frc", gap=0.0, slope=0.0, lowest_offset=0.0):
    """Write and read back a film; ``gap``: the lowest curve lies that fraction of M_s below the others
    over its first 0.15 T (not closed), rejoining them over the next 0.1 T; ``slope``: a reversible
    magnetization of that many M_s per T; ``lowest_offset``: the lowest curve shifted by that
    fraction of M_s (before noise)."""
    rng = np.random.default_rng(seed)
    reversal = np.linspace(-window, window, n_curves)
    curves = []
    for k, h_r in enumerate(reversal):
        h = np.linspace(h_r, window, max(3, int(round((window - h_r) / step)) + 1))
        m = preisach(h_r, h, width=width) + slope * h
        if k == 0:
            m = m - gap * np.clip((h_r + 0.25 - h) / 0.1, 0, 1) + lowest_offset
        curves.append((h, M_S * (m + noise * rng.normal(size=h.size))))
    calibration = M_S * (1 + slope * window + cal * noise * rng.normal(size=n_curves))
    if fmt == "frc":
        path = write_micromag_0015(tmp_path / "film.frc", reversal, curves, calibration_moments_Am2=calibration,
                                   calibration_field_T=window)
    else:
        path = write_lakeshore_csv(tmp_path / "film.csv", reversal, curves, calibration_moments_Am2=calibration,
                                   calibration_field_T=window)
    data = read_forc(path)
    assert data.drift_corrected  # the reader's own correction, as for a user's file
    return data


def refusal_rate(tmp_path, seeds, **film):
    refused = [s for s in range(seeds) if not domain_of_measurement(measured_film(tmp_path, s, **film), 1.0, 64).usable]
    return len(refused) / seeds, refused


@pytest.mark.parametrize("film", [
    pytest.param(dict(), id="perpendicular-cal1"),
    pytest.param(dict(window=0.7, width=0.04, cal=3.0), id="cal3"),
    pytest.param(dict(window=0.7, width=0.04, cal=3.0, fmt="csv"), id="lakeshore-cal3", marks=pytest.mark.slow),
])
def test_noise_only_saturated_films_are_refused_at_most_at_the_stated_rate(tmp_path, film):
    """(a) ≤ ALPHA_FILE = 5 % of noise-only saturated films refused, 200 seeds each (measured: 0 of
    200 in each film; before issue 45: 5.5 %, 45 %, 18 %, module docstring)."""
    rate, refused = refusal_rate(tmp_path, 200, **film)
    assert rate <= ALPHA_FILE, (rate, refused[:10])


@pytest.mark.parametrize("film", [
    pytest.param(dict(gap=0.05), id="lowest-curve-5pc-open"),
    pytest.param(dict(gap=0.03), id="lowest-curve-3pc-open"),
])
def test_a_lowest_curve_that_has_not_closed_is_still_refused(tmp_path, film):
    """(b) power: the lowest curve 5 % (3 %) of the half loop height from the others over its first
    0.15 T: refused in ≥ 95 % of 100 seeds (measured 100 % and 100 %), for its lower end."""
    rate, _ = refusal_rate(tmp_path, 100, **film)
    assert rate >= 0.95
    reason = domain_of_measurement(measured_film(tmp_path, 0, **film), 1.0, 64).reason
    assert reason.startswith("lower") and "not saturated" in reason  # not closed, or closed on a steep branch


def test_a_reversible_slope_left_at_saturation_is_still_refused(tmp_path):
    """(b) power: a paramagnetic slope of 1.5 M_s per T (about 75 % of the half loop height per T):
    refused as 'not saturated ... reversible' in ≥ 95 % of 60 seeds (measured 100 % of 100)."""
    reasons = [domain_of_measurement(measured_film(tmp_path, s, slope=1.5), 1.0, 64).reason for s in range(60)]
    refused = [r for r in reasons if r is not None and "reversible" in r]
    assert len(refused) >= 0.95 * len(reasons)


def test_the_issue_film_is_in_the_domain(tmp_path):
    """(c) the issue's case: a perpendicular film, 40 curves, 0.3 % noise, its two lowest curves 1e-5
    apart before noise; this seed's noise puts their running-median difference above the old
    tolerance max(4σ, one image level) (1.7 % of the half loop height, 5 σ: refused before as 'lower
    end not saturated'), well inside the new one: in the domain."""
    data = measured_film(tmp_path, 169, lowest_offset=1e-5)
    curves = sorted((_sorted(c.field_T, c.moment_Am2) for c in data.curves), key=lambda c: c[0][0])
    sigma = noise_level(curves)
    moments = np.concatenate([y for _, y in curves])
    old_tolerance = max(4 * sigma, 2 / 255 * (moments.max() - moments.min()) / 2)
    worst = max(np.abs(_difference(*curves[k], *curves[0])[1]).max() for k in (1, 2))
    assert worst > old_tolerance  # the old rule refused this film
    domain = domain_of_measurement(data, 1.0, 64)
    assert domain.usable and domain.reason is None, domain.reason
    assert domain.lower_saturated and domain.upper_saturated
    assert domain.summary["correction_noise_relative"] == pytest.approx(NOISE, rel=0.5)


def test_one_check_is_a_bonferroni_quantile_of_the_maximum():
    """The per-check threshold: z_K = Φ⁻¹(1 − α/(2K)); on 2000 noise-only pairs of drift-corrected
    curves (40 points, the reference on other fields, each curve with its own factor error σ_f = σ)
    max_i |d_i|/τ_i exceeds 1 in at most α of them (measured 0.05 % at α = 1 %; the old τ = 4σ:
    3.4 %)."""
    alpha, K = 0.01, 40
    noise = _Noise(sigma=1.0, relative=1.0, level=0.0, alpha=alpha)
    assert noise.z(K) == pytest.approx(-ndtri(alpha / (2 * K)))
    assert noise.spread(1.0) == pytest.approx(np.sqrt(MEDIAN_FACTOR * 2 + 2))
    rng = np.random.default_rng(7)
    exceed, old = 0, 0
    draws = 2000
    for _ in range(draws):
        h = np.sort(np.linspace(-0.7, 0.7, K) + rng.uniform(-0.01, 0.01, K))
        ref_h = np.linspace(-0.75, 0.75, 30)
        # saturated: M = 1 everywhere; white noise σ = 1 per point, factor errors σ_f = 1 per curve
        y = (1 + rng.normal()) + rng.normal(size=K)
        ref_y = (1 + rng.normal()) + rng.normal(size=ref_h.size)
        hh, d = _difference(h, y, ref_h, ref_y)
        exceed += bool(np.any(np.abs(d) > noise.tolerance(np.ones(hh.size) * 1.0)))
        old += bool(np.any(np.abs(d) > 4.0))
    assert exceed / draws <= alpha
    assert old / draws > alpha  # the old tolerance ignored the factor errors
