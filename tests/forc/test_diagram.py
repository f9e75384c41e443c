"""FORC distribution against an analytic Preisach ensemble of square hysterons."""

import numpy as np
import pytest

from forcdecode.forc.diagram import forc_distribution


def hysteron_family(grid, density):
    """m(H_r, H) of hysterons (up at α, down at β ≤ α, moment ±1) with density P on the (α, β) grid
    (normalized to ∫∫P = 1). After positive saturation and descent to H_r, hysterons with β ≥ H_r
    are down; sweeping up to H switches up those with α ≤ H."""
    a, b = np.meshgrid(grid, grid, indexing="ij")  # α index first
    cell = (grid[1] - grid[0]) ** 2
    weights = density(a, b) * (a >= b) * cell
    n = grid.size
    curves = np.full((n, n), np.nan)
    for i, hr in enumerate(grid):
        for j in range(i, n):
            down = (b >= hr) & (a > grid[j])
            curves[i, j] = weights.sum() - 2 * weights[down].sum()
    return curves


def gaussian(a, b, hc0=0.3, sc=0.08, su=0.06):
    hc, hu = (a - b) / 2, (a + b) / 2
    return np.exp(-0.5 * ((hc - hc0) / sc) ** 2 - 0.5 * (hu / su) ** 2) / (2 * np.pi * sc * su) / 2


def test_distribution_of_a_hysteron_ensemble_is_its_switching_field_density():
    grid = np.linspace(-1, 1, 161)
    curves = hysteron_family(grid, gaussian)
    diagram = forc_distribution(grid, grid, curves, smoothing_factor=2)
    i, j = np.meshgrid(np.arange(grid.size), np.arange(grid.size), indexing="ij")
    expected = gaussian(grid[j], grid[i])  # ρ(H_r = β, H = α) = P(α, β)
    inside = (diagram.coercive_T > 0.1) & np.isfinite(diagram.rho)
    peak = expected[inside].max()
    assert np.abs(diagram.rho[inside] - expected[inside]).max() < 0.08 * peak
    # the peak sits at H_c = 0.3 T, H_u = 0
    k = np.nanargmax(np.where(inside, diagram.rho, -np.inf))
    assert diagram.coercive_T.ravel()[k] == pytest.approx(0.3, abs=0.02)
    assert diagram.interaction_T.ravel()[k] == pytest.approx(0.0, abs=0.02)


def test_reversible_background_and_offsets_are_invisible():
    """A linear background χH, a constant offset and a per-curve offset have ∂²/∂H_r∂H = 0."""
    grid = np.linspace(-1, 1, 41)
    base = hysteron_family(grid, gaussian)
    shifted = base + 0.3 * grid[None, :] + 0.1 + 0.05 * grid[:, None]
    a = forc_distribution(grid, grid, base, 3).rho
    b = forc_distribution(grid, grid, shifted, 3).rho
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="shape"):
        forc_distribution(np.zeros(3), np.zeros(4), np.zeros((4, 3)))


def test_diagram_command_on_a_real_measured_file(tmp_path):
    from pathlib import Path

    from forcdecode.cli import main

    data = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "measured" / "UB199BF.frc"
    if not data.exists():
        pytest.skip(f"{data} is absent")
    from forcdecode.forc.render import measured_grid
    from forcdecode.forc.diagram import forc_distribution
    from forcdecode.measured import read_forc

    hr, h, m = measured_grid(read_forc(data))
    diagram = forc_distribution(hr, h, m, 3)
    k = np.nanargmax(diagram.rho)
    # a single-domain-like ridge: peak near H_u = 0 at H_c of tens of mT
    assert abs(diagram.interaction_T.ravel()[k]) < 0.01
    assert 0.03 < diagram.coercive_T.ravel()[k] < 0.09
    out = tmp_path / "d.png"
    assert main(["diagram", str(data), "--out", str(out)]) == 0 and out.stat().st_size > 10_000
    assert main(["diagram", str(tmp_path / "missing.frc"), "--out", str(out)]) == 2
    # the other smoothings of the field's tools from the command line, and a bad VARIFORC setting refused
    for extra in (["--kernel", "loess"], ["--variforc", "3", "7", "3", "7", "0.07", "0.07"]):
        out.unlink()
        assert main(["diagram", str(data), "--out", str(out), *extra]) == 0 and out.stat().st_size > 10_000
    assert main(["diagram", str(data), "--out", str(out), "--variforc", "3", "7", "3", "-7", "0.07", "0.07"]) == 2


def test_all_kernels_recover_the_hysteron_density():
    """A broader ensemble than above: every kernel gives ρ(H_r = β, H = α) = P within 6 % of the
    peak, away from the lowest reversal curves (below them there is no data: one-sided windows)."""
    from functools import partial

    from forcdecode.forc.diagram import Variforc, variforc_distribution

    grid = np.linspace(-1, 1, 121)
    density = partial(gaussian, hc0=0.4, sc=0.15, su=0.12)
    curves = hysteron_family(grid, density)
    i, j = np.meshgrid(np.arange(grid.size), np.arange(grid.size), indexing="ij")
    expected = density(grid[j], grid[i])
    variforc = Variforc(sc0=2, sc1=3, su0=2, su1=3, lambda_c=0.05, lambda_u=0.05)
    for diagram in (forc_distribution(grid, grid, curves, 3), forc_distribution(grid, grid, curves, 3, kernel="loess"),
                    variforc_distribution(grid, grid, curves, variforc)):
        inside = (diagram.coercive_T > 0.1) & np.isfinite(diagram.rho) & (i >= 4)
        assert inside.sum() > 5000
        error = np.abs(diagram.rho[inside] - expected[inside]).max() / expected.max()
        assert error < 0.06, (diagram.method, error)


def test_a_quadratic_surface_is_fitted_exactly_on_irregular_fields():
    """M = c0 + … + c5 H_r H (any quadratic) has ρ = −c5/2 everywhere: every kernel must return it
    to rounding, also with Hall-probe-like jitter of the reversal fields and an edge-clipped patch."""
    from forcdecode.forc.diagram import Variforc, variforc_distribution

    rng = np.random.default_rng(3)
    h = np.linspace(-0.2, 0.2, 41)
    hr = h + rng.uniform(-2e-3, 2e-3, h.size)
    hr.sort()
    R, H = np.meshgrid(hr, h, indexing="ij")
    m = 0.3 + 2.0 * R - 4.0 * R**2 + 1.5 * H + 3.0 * H**2 + 7.0 * R * H
    m[H < R] = np.nan
    for diagram in (forc_distribution(hr, h, m, 2), forc_distribution(hr, h, m, 3, kernel="loess"),
                    variforc_distribution(hr, h, m, Variforc(lambda_c=0.1, lambda_u=0.1))):
        finite = np.isfinite(diagram.rho)
        assert finite.sum() > 300, diagram.method
        np.testing.assert_allclose(diagram.rho[finite], -3.5, rtol=1e-8, err_msg=diagram.method)


def test_compiled_pike_kernel_equals_a_per_node_least_squares_fit():
    """The default estimator is Pike's plain least squares on the square patch: compare with
    np.linalg.lstsq node by node on noisy data with irregular reversal fields and holes."""
    rng = np.random.default_rng(4)
    h = np.linspace(-1, 1, 30)
    hr = np.sort(h + rng.uniform(-0.01, 0.01, h.size))
    curves = hysteron_family(h, gaussian) + rng.normal(0, 1e-3, (h.size, h.size))
    curves[rng.random(curves.shape) < 0.05] = np.nan
    curves[h[None, :] < hr[:, None]] = np.nan
    sf, min_points = 2, 10
    rho = forc_distribution(hr, h, curves, sf, min_points).rho
    expected = np.full(curves.shape, np.nan)
    for i in range(h.size):
        for j in range(h.size):
            if not np.isfinite(curves[i, j]):
                continue
            rows, cols = slice(max(0, i - sf), i + sf + 1), slice(max(0, j - sf), j + sf + 1)
            R, H = np.meshgrid(hr[rows] - hr[i], h[cols] - h[j], indexing="ij")
            ok = np.isfinite(curves[rows, cols])
            if ok.sum() < min_points:
                continue
            x, y = R[ok], H[ok]
            design = np.column_stack([np.ones_like(x), x, x * x, y, y * y, x * y])
            coef, _, rank, _ = np.linalg.lstsq(design, curves[rows, cols][ok], rcond=None)
            if rank == 6:
                expected[i, j] = -0.5 * coef[5]
    assert np.array_equal(np.isfinite(rho), np.isfinite(expected)) and np.isfinite(rho).sum() > 200
    np.testing.assert_allclose(rho, expected, rtol=1e-8, atol=1e-10 * np.nanmax(np.abs(expected)))


def test_variforc_factors_follow_egli():
    """s = min[(1 − λ)s1 + λn, max(s0, n)], floored at 1 (Egli 2013, Eq. 14), n = |H|/ΔH."""
    from forcdecode.forc.diagram import Variforc

    settings = Variforc(sc0=3, sc1=7, su0=2, su1=9, lambda_c=0.1, lambda_u=0.2)
    s_c, s_u = settings.factors(np.array([0.0, 5e-3, 0.1]), np.array([0.0, -5e-3, 0.2]), 1e-3)
    np.testing.assert_allclose(s_c, [3.0, 5.0, 0.9 * 7 + 0.1 * 100])
    np.testing.assert_allclose(s_u, [2.0, 5.0, 0.8 * 9 + 0.2 * 200])
    with pytest.raises(ValueError, match="lambda_u"):
        Variforc(lambda_u=-0.1)
    with pytest.raises(ValueError, match="kernel"):
        forc_distribution(np.zeros(3), np.zeros(3), np.zeros((3, 3)), kernel="gaussian")
