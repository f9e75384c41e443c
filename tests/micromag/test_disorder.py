"""Statistics of the drawn disorder (``micromag.disorder``) and the pinning count of ``build``.

Each statistic is pooled over independent draws and checked against its stated value within a
band of 4 standard errors (the test's seeds are fixed, so it is deterministic; the band says how
far a correct implementation can stray, and the wrong variants named in each test fall far outside).
"""

from math import erf

import numpy as np
import pytest
from scipy.spatial import cKDTree

from forcdecode.micromag import Mesh
from forcdecode.micromag.build import REFERENCE_CELLS, build_film, pinning_cells
from forcdecode.micromag.disorder import (PINNING_K_U, FilmMaterial, disordered_film, draw_disorder,
                                         periodic_voronoi_labels)

K_U = 8e5  # J/m³


def per_grain(values, labels, n_grains):
    """The value of each grain (layer 0), checking that it is constant over the grain's columns."""
    out = np.empty(n_grains)
    for g in range(n_grains):
        cells = values[labels == g]
        assert np.all(cells == cells[0]), f"grain {g} is not uniform"
        out[g] = cells[0]
    return out


def test_voronoi_labels_are_the_periodic_nearest_seed():
    """Against an independent periodic nearest-neighbour search (scipy cKDTree with boxsize) on the
    same seeds (the function's only draw), on a grid with dx ≠ dy."""
    mesh = Mesh(96, 64, 1, 2e-9, 3e-9, 2e-9)
    n_grains = 40
    labels = periodic_voronoi_labels(mesh, n_grains, np.random.default_rng(8))
    box = (mesh.nx * mesh.dx, mesh.ny * mesh.dy)
    seeds = np.random.default_rng(8).random((n_grains, 2)) * box
    x, y = np.meshgrid((np.arange(mesh.nx) + 0.5) * mesh.dx, (np.arange(mesh.ny) + 0.5) * mesh.dy)
    _, nearest = cKDTree(seeds, boxsize=box).query(np.stack([x.ravel(), y.ravel()], axis=1))
    assert np.array_equal(labels.ravel(), nearest)


def test_grain_count_columns_and_periodic_seam():
    """255 grains on 128×128×2 (64 cells a grain): every grain is present, grains are columns through
    z, the grain areas have the Poisson–Voronoi coefficient of variation (0.529 in 2D), and grain
    boundaries cross the periodic seam as often as any interior column line (a non-periodic distance
    would put a boundary along the whole seam)."""
    mesh = Mesh(128, 128, 2, 2e-9, 2e-9, 2e-9)
    n_grains, draws = 255, 6
    cvs, seam, interior = [], [], []
    for seed in range(draws):
        d = draw_disorder(mesh, K_U, 0.2, 0.1, 0, np.random.default_rng(seed), n_grains)
        labels = d.grain_labels
        assert len(np.unique(labels)) == n_grains and labels.min() == 0 and labels.max() == n_grains - 1
        assert np.array_equal(d.K_u[0], d.K_u[1]) and np.array_equal(d.easy_axis[:, 0], d.easy_axis[:, 1])
        areas = np.bincount(labels.ravel(), minlength=n_grains)
        cvs.append(areas.std() / areas.mean())
        changes = labels != np.roll(labels, -1, axis=1)  # boundary between column i and i + 1
        seam.append(changes[:, -1].mean())
        interior.append(changes[:, :-1].mean())
    cv = np.mean(cvs)
    print(f"grain-area CV {cv:.3f} (Poisson–Voronoi 0.529); boundary rate seam {np.mean(seam):.3f}, "
          f"interior {np.mean(interior):.3f}")
    assert cv == pytest.approx(0.529, abs=0.06)
    # seam: 6 × 128 rows ≈ 768 Bernoulli(p ≈ 0.13) samples: SE ≈ 0.012
    assert abs(np.mean(seam) - np.mean(interior)) < 4 * np.sqrt(np.mean(interior) / (draws * mesh.ny))


def pooled_grains(sigma_K, sigma_theta, draws=20, n_grains=255):
    """Per-grain (K_u, easy axis) of ``draws`` independent disorders (no pinning), pooled."""
    mesh = Mesh(64, 64, 1, 2e-9, 2e-9, 2e-9)
    K, axes = [], []
    for seed in range(draws):
        d = draw_disorder(mesh, K_U, sigma_K, sigma_theta, 0, np.random.default_rng(100 + seed), n_grains)
        present = np.unique(d.grain_labels)
        K.append(per_grain(d.K_u[0], d.grain_labels, n_grains)[present])
        axes.append(np.stack([per_grain(d.easy_axis[c, 0], d.grain_labels, n_grains)[present] for c in range(3)]))
    return np.concatenate(K), np.concatenate(axes, axis=1)


def test_sigma_K_statistics():
    """K_g = K_u(1 + Δ_g), Δ_g ~ N(0, σ_K) per grain: the pooled sample std of K_g/K_u − 1 equals σ_K
    within 4 standard errors σ_K·4/√(2N), and the mean is 0 within 4σ_K/√N (N ≈ 5000 grains)."""
    sigma_K = 0.2
    K, _ = pooled_grains(sigma_K, 0.1)
    delta = K / K_U - 1
    n = delta.size
    print(f"N = {n}: std(Δ) = {delta.std(ddof=1):.4f} (σ_K = {sigma_K}), mean {delta.mean():+.4f}")
    assert n > 4900
    assert abs(delta.std(ddof=1) / sigma_K - 1) < 4 / np.sqrt(2 * (n - 1))
    assert abs(delta.mean()) < 4 * sigma_K / np.sqrt(n)


def test_large_sigma_K_clips_at_zero():
    """With σ_K = 0.8 a fraction Φ(−1/0.8) = 0.106 of grains would get K < 0: they get K = 0 instead."""
    K, _ = pooled_grains(0.8, 0.0, draws=10)
    p = 0.5 * (1 + erf(-1 / 0.8 / np.sqrt(2)))
    zero = np.mean(K == 0.0)
    print(f"clipped fraction {zero:.4f} (expected {p:.4f})")
    assert K.min() == 0.0
    assert abs(zero - p) < 4 * np.sqrt(p * (1 - p) / K.size)


def test_sigma_theta_statistics():
    """Easy axis tilted by θ_g ~ N(0, σ_θ) at a uniform azimuth: unit axes, RMS tilt arccos(u_z) equals
    σ_θ within 4/√(2N) (|θ| is half-normal, E[θ²] = σ_θ²), and the azimuths' mean resultant length
    is below 4/√N (uniform φ)."""
    sigma_theta = np.radians(8.0)
    _, axes = pooled_grains(0.2, sigma_theta)
    n = axes.shape[1]
    assert np.allclose(np.linalg.norm(axes, axis=0), 1.0, atol=1e-14)
    tilt = np.arccos(np.clip(axes[2], -1, 1))
    rms = np.sqrt(np.mean(tilt**2))
    resultant = np.hypot(np.mean(axes[0] / np.sin(tilt)), np.mean(axes[1] / np.sin(tilt)))
    print(f"N = {n}: RMS tilt {np.degrees(rms):.3f}° (σ_θ = 8°), azimuth resultant {resultant:.4f}")
    assert abs(rms / sigma_theta - 1) < 4 / np.sqrt(2 * n)
    assert resultant < 4 / np.sqrt(n)


def test_pinning_sites_count_stiffness_and_isotropic_start():
    """n_pin distinct cells with K = 50 MJ/m³ along z; their initial orientations are uniform on the
    sphere (pooled mean vector within 4/√(3N) per component, ⟨m_z²⟩ = 1/3 within 4·√(4/45/N));
    they fall in each layer in proportion (binomial band); the initial state holds them and is +z
    elsewhere; the "frozen" treatment snaps them to the nearest pole."""
    mesh = Mesh(32, 32, 2, 2e-9, 2e-9, 2e-9)
    n_pin, draws = 150, 20
    material = FilmMaterial(Ms=6e5, A_ex=1e-11, K_u=K_U, D=0.0, sigma_K=0.2, sigma_theta_rad=0.1, n_pin=n_pin)
    initial, in_layer0 = [], 0
    for seed in range(draws):
        film, m0, d = disordered_film(mesh, material, np.random.default_rng(300 + seed), n_grains=20,
                                      terms=("exchange", "anisotropy"))
        mask = d.pinning_mask
        assert mask.sum() == n_pin and d.pinning_initial.shape == (3, n_pin)
        assert np.all(film.K_u[mask] == PINNING_K_U) and np.all(film.K_u[~mask] < 10 * K_U)
        assert np.all(film.easy_axis[2][mask] == 1.0)
        assert np.allclose(np.linalg.norm(d.pinning_initial, axis=0), 1.0, atol=1e-14)
        order = np.argsort(np.ravel_multi_index(d.pinning_index, mesh.shape))  # mask order = C order
        assert np.array_equal(m0[:, mask], d.pinning_initial[:, order])
        assert np.all(m0[2][~mask] == 1.0)
        initial.append(d.pinning_initial)
        in_layer0 += int(mask[0].sum())
    initial = np.concatenate(initial, axis=1)
    n = initial.shape[1]
    assert np.all(np.abs(initial.mean(axis=1)) < 4 / np.sqrt(3 * n))
    assert abs(np.mean(initial[2] ** 2) - 1 / 3) < 4 * np.sqrt(4 / 45 / n)
    assert abs(in_layer0 / n - 0.5) < 4 * np.sqrt(0.25 / n)
    _, m_frozen, d = disordered_film(mesh, material, np.random.default_rng(300), n_grains=20, pinning="frozen",
                                     terms=("exchange", "anisotropy"))
    order = np.argsort(np.ravel_multi_index(d.pinning_index, mesh.shape))
    assert np.array_equal(m_frozen[2][d.pinning_mask], np.sign(d.pinning_initial[2][order]))
    with pytest.raises(ValueError, match="n_pin"):
        draw_disorder(mesh, K_U, 0.2, 0.1, mesh.n_cells + 1, np.random.default_rng(0))


@pytest.mark.parametrize("N_pin", [0, 100, 320, 2000])
def test_scale_to_reference_keeps_the_papers_density(N_pin):
    """N_pin counts sites on the paper's 256×256×2 grid: placed as is there (both settings), and at the
    same density on a smaller grid with ``scale_to_reference`` (round(N_pin·cells/131072)), or as is
    without it."""
    assert REFERENCE_CELLS == 256 * 256 * 2
    paper = Mesh(256, 256, 2, 2e-9, 2e-9, 4e-9)
    laptop = Mesh(64, 64, 1, 2e-9, 2e-9, 4e-9)
    scaled, plain = {"pinning": {"scale_to_reference": True}}, {"pinning": {"scale_to_reference": False}}
    assert pinning_cells(N_pin, paper, scaled) == pinning_cells(N_pin, paper, plain) == N_pin
    assert pinning_cells(N_pin, laptop, plain) == N_pin
    placed = pinning_cells(N_pin, laptop, scaled)
    assert placed == round(N_pin / 32)
    assert abs(placed / laptop.n_cells - N_pin / REFERENCE_CELLS) <= 0.5 / laptop.n_cells


def test_build_film_places_the_scaled_count():
    """End to end: a 64×64×1 film built with scale_to_reference places N_pin/32 pinning cells."""
    cfg = {"mesh": {"nx": 64, "ny": 64, "nz": 1, "dx_nm": 2.0, "dy_nm": 2.0, "dz_nm": 4.0}, "seed": 3,
           "n_grains": 40, "pinning": {"treatment": "full", "scale_to_reference": True}}
    params = {"Ms": 6e5, "A_ex": 1e-11, "K_u": K_U, "D": 1e-3, "sigma_K": 0.1, "sigma_theta_deg": 5.0, "N_pin": 320}
    film, _, disorder = build_film(cfg, params, 0)
    assert disorder.pinning_mask.sum() == 10 and np.sum(film.K_u == PINNING_K_U) == 10
    _, _, unscaled = build_film({**cfg, "pinning": {"treatment": "full", "scale_to_reference": False}}, params, 0)
    assert unscaled.pinning_mask.sum() == 320
