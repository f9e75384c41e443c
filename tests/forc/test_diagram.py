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
    from forcdecode.forc.cli import measured_grid
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
