"""Domain by physics (forc.saturation): a family is usable when its major loop saturates inside the
measured window, whatever the window; the training image is completed where the state is known.

The test family is a Preisach ensemble with switching fields ±(0.25 ± 0.04) T (erf in the field): it
saturates at about ±0.4 T (3.75 standard deviations)."""

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.special import erf

from forcdecode.forc.saturation import COMPLETED, MEASURED, UNKNOWN, analyse_saturation, noise_level

MEASURED_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "measured"
M_S = 2e-6  # A m²


def preisach(h_r, h, h_c=0.25, width=0.04):
    """m(H_r, H) of hysterons switching down at −h_c − ξ... (symmetric, one coercivity distribution)."""
    up = 0.5 * (1 + erf((h - h_c) / (width * np.sqrt(2))))
    down = 0.5 * (1 + erf((-h_r - h_c) / (width * np.sqrt(2))))
    return 1 - 2 * down + 2 * np.minimum(down, up)


def family(window, n_curves=60, points=80, noise=0.002, slope_per_T=0.0, end=None, seed=0):
    rng = np.random.default_rng(seed)
    reversal = np.linspace(-window, window, n_curves)
    curves = []
    for h_r in reversal:
        h = np.linspace(h_r, window if end is None else min(window, h_r + end), points)
        m = preisach(h_r, h) + slope_per_T * h + noise * rng.normal(size=h.size)
        curves.append((h, M_S * m))
    return reversal, curves


def test_a_film_saturating_at_0_4_T_measured_to_0_7_T_is_usable_and_completed():
    reversal, curves = family(0.7)
    domain = analyse_saturation(reversal, curves, 1.0, 64)
    assert domain.usable and domain.reason is None
    # closure within a grid step or two of the true saturation field (0.25 + 3.75·0.04 = 0.40 T)
    assert 0.30 < domain.H_plus_T < 0.45 and -0.45 < domain.H_minus_T < -0.30
    assert domain.moment_saturation_Am2 == pytest.approx(M_S, rel=0.01)
    report = domain.report()
    # cells of the 64-point grid over ±1 T on or above the diagonal with H_r and H in ±0.7 T: measured
    grid = np.linspace(-1, 1, 64)
    inside = (np.abs(grid) <= 0.7 + 1e-9)
    expected = sum(int(inside[j]) for i in range(64) if inside[i] for j in range(i, 64)) / (64 * 65 / 2)
    assert report["fraction_measured"] == pytest.approx(expected, abs=0.03)
    assert report["fraction_unknown"] == 0.0
    assert report["fraction_completed"] == pytest.approx(1 - report["fraction_measured"])
    fam, source = domain.family, domain.source
    # rows reversed below the window: the ascending branch, m = −1 where the window has no point
    assert np.all(fam[0, :grid.searchsorted(-0.7)] == -1.0) and np.all(source[0, :grid.searchsorted(-0.7)] == COMPLETED)
    # everything above the window is the saturated upper branch
    top = grid > 0.7
    upper = np.triu(np.ones((64, 64), bool)) & top[None, :]
    assert np.all(fam[upper] == 1.0) and np.all(source[upper] == COMPLETED)
    # measured cells are the measurement: the curve reversed at the nearest field, interpolated
    i = int(np.argmin(np.abs(grid + 0.2)))
    j = int(np.argmin(np.abs(grid - 0.3)))
    k = int(np.argmin(np.abs(reversal - grid[i])))
    assert source[i, j] == MEASURED
    assert fam[i, j] == pytest.approx(np.interp(grid[j], curves[k][0], curves[k][1]) / domain.moment_saturation_Am2
                                      - domain.moment_offset_Am2 / domain.moment_saturation_Am2, abs=1e-12)
    # and follow the physics: the curve reversed at −0.2 T, at +0.3 T
    assert fam[i, j] == pytest.approx(preisach(reversal[k], grid[j]), abs=0.02)


def test_a_window_narrower_than_the_switching_is_out_of_domain_with_a_specific_reason():
    reversal, curves = family(0.3)  # the switching field distribution reaches 0.4 T
    domain = analyse_saturation(reversal, curves, 1.0, 64)
    assert not domain.usable
    assert "lower end not saturated" in domain.reason and "upper end not saturated" in domain.reason
    # by how much, at which field: the ascending branch (from −0.3 T, not saturated) against the
    # descending one, as the model gives them at the reported field
    match = re.search(r"differs from the upper \(descending\) branch by ([0-9.e+-]+) A m² .* at ([+-][0-9.]+) T", domain.reason)
    assert match, domain.reason
    gap, where = float(match.group(1)), float(match.group(2))
    assert 0.25 < where <= 0.3  # within the last training-grid step of the curve
    expected = (preisach(where, where) - preisach(-0.3, where)) * M_S
    assert gap == pytest.approx(expected, rel=0.1) and gap > 0.3 * M_S


def test_a_paramagnetic_slope_is_closed_but_not_saturated():
    reversal, curves = family(0.7, slope_per_T=0.5)
    domain = analyse_saturation(reversal, curves, 1.0, 64)
    assert not domain.usable and "not saturated" in domain.reason and "reversible" in domain.reason
    slopes = [float(x) for x in re.findall(r"slope (\d+) % per T", domain.reason)]
    # 0.5 M_s per T over a half loop height of about 1.35 M_s: 37 %
    assert slopes and all(25 < s < 50 for s in slopes)
    # a slope below the 10 % per T rule is still saturated
    assert analyse_saturation(*family(0.7, slope_per_T=0.02), 1.0, 64).usable


def test_curves_stopped_before_rejoining_the_upper_branch_leave_the_state_unknown():
    # every curve stops 0.25 T above its reversal field: the curves from negative saturation never rejoin
    reversal, curves = family(0.7, end=0.25)
    domain = analyse_saturation(reversal, curves, 1.0, 64)
    assert not domain.usable and "upper end not saturated" in domain.reason
    assert (domain.source == UNKNOWN).sum() > 0


def test_noise_level_recovers_white_noise():
    rng = np.random.default_rng(3)
    h = np.linspace(-1, 1, 400)
    curves = [(h, np.tanh(3 * h) + 1e-3 * rng.normal(size=h.size)) for _ in range(20)]
    assert noise_level(curves) == pytest.approx(1e-3, rel=0.1)


def test_real_rock_magnetic_files_are_out_of_domain_for_a_stated_physical_reason():
    from forcdecode.forc.saturation import domain_of_measurement
    from forcdecode.measured import read_forc

    path = MEASURED_DIR / "UB199BF.frc"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    domain = domain_of_measurement(read_forc(path), 1.0, 64)
    assert not domain.usable and "not saturated" in domain.reason
    # closed at about ±0.1 T, but a reversible slope of several M_half per T remains (measured 349 and 318 %)
    assert -0.12 < domain.summary["closure_field_lower_T"] < -0.06 and 0.09 < domain.summary["closure_field_upper_T"] < 0.16
    assert all(int(s) > 100 for s in re.findall(r"slope (\d+) % per T", domain.reason))
    assert domain.noise_Am2 == pytest.approx(domain.calibration_noise_Am2, rel=0.5)  # two estimates agree
