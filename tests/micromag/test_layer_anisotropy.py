"""Layers with their own K_u (a second, softer phase): decoupled and exchange-coupled switching."""

import numpy as np
import pytest

from forcdecode.dataset.simulate import build_film
from forcdecode.micromag import MU0, FilmExtras, FilmMaterial, Mesh, disordered_film
from forcdecode.micromag.disorder import PINNING_K_U

MS, A_EX, K_HARD, SOFT_FACTOR = 6e5, 1e-11, 5e5, 0.6
MESH = Mesh(4, 4, 2, 2e-9, 2e-9, 2e-9)
UNIFORM = FilmMaterial(Ms=MS, A_ex=A_EX, K_u=K_HARD, D=0.0, sigma_K=0.0, sigma_theta_rad=0.0, n_pin=0)
GRAINY = FilmMaterial(Ms=MS, A_ex=A_EX, K_u=K_HARD, D=0.0, sigma_K=0.2, sigma_theta_rad=0.1, n_pin=3)


def uniform_bilayer(**kwargs):
    """Two uniform layers (one grain, no disorder, no pinning), layer 1 with K_u × SOFT_FACTOR."""
    film, _, _ = disordered_film(MESH, UNIFORM, np.random.default_rng(0), n_grains=1,
                                 extras=FilmExtras(layer_K_u_factor=(1.0, SOFT_FACTOR), **kwargs))
    return film


def relaxed_from_saturation(film, B):
    """State at field B (T, along z) reached from +z saturation (tilted 0.01 rad to break symmetry)."""
    m = film.uniform((np.sin(0.01), 0.0, np.cos(0.01)))
    assert film.minimize(m, np.array([0.0, 0.0, B]), torque_tol_T=1e-9, max_iterations=100_000).converged
    return m


def step_field(film, mz_below, B_max=2.0, bisections=24):
    """Field magnitude (T) on the descending major loop at which ⟨m_z⟩ first drops below ``mz_below``."""
    low, high = 0.0, B_max
    for _ in range(bisections):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if relaxed_from_saturation(film, -mid)[2].mean() < mz_below else (mid, high)
    return 0.5 * (low + high)


def thin_film_switching_field(K):
    """Stoner–Wohlfarth switching field (T) of a uniform perpendicular film: 2K/M_s − μ0 M_s."""
    return 2 * K / MS - MU0 * MS


def test_layer_factor_scales_grains_not_pinning_sites():
    base, _, base_disorder = disordered_film(MESH, GRAINY, np.random.default_rng(4), n_grains=3)
    scaled, _, disorder = disordered_film(MESH, GRAINY, np.random.default_rng(4), n_grains=3,
                                          extras=FilmExtras(layer_K_u_factor=(1.0, 0.25)))
    pin = disorder.pinning_mask
    assert np.array_equal(pin, base_disorder.pinning_mask)
    expected = base.K_u * np.array([1.0, 0.25])[:, None, None]
    assert np.allclose(scaled.K_u[~pin], expected[~pin], rtol=1e-15)
    assert np.all(scaled.K_u[pin] == PINNING_K_U)
    with pytest.raises(ValueError, match="one factor per layer"):
        disordered_film(MESH, UNIFORM, np.random.default_rng(0), n_grains=1,
                        extras=FilmExtras(layer_K_u_factor=(1.0, 0.5, 0.5)))


def test_build_film_passes_layer_options_through():
    cfg = {"mesh": {"nx": 4, "ny": 4, "nz": 2, "dx_nm": 2.0, "dy_nm": 2.0, "dz_nm": 2.0}, "seed": 7,
           "n_grains": 3, "pinning": {"treatment": "full", "scale_to_reference": False}}
    params = {"Ms": MS, "A_ex": A_EX, "K_u": K_HARD, "D": 1e-3, "sigma_K": 0.1, "sigma_theta_deg": 3.0, "N_pin": 2}
    base, m0_base, _ = build_film(cfg, params, 3)
    film, m0, disorder = build_film(cfg, {**params, "layer_K_u_factor": "1.0,0.5", "spacer_after_layer": 0,
                                          "interlayer_coupling_J_m2": 2e-4}, 3)
    free = ~disorder.pinning_mask
    assert np.allclose(film.K_u[free], (base.K_u * np.array([1.0, 0.5])[:, None, None])[free], rtol=1e-15)
    assert film.model.spacer_after_layer == 0 and film.model.interlayer_J == 2e-4
    assert np.array_equal(m0, m0_base)
    # absent or NaN (a parquet column with gaps): the default film
    default, _, _ = build_film(cfg, {**params, "layer_K_u_factor": None, "spacer_after_layer": np.nan,
                                     "interlayer_coupling_J_m2": np.nan}, 3)
    assert np.array_equal(default.K_u, base.K_u) and default.model.spacer_after_layer == -1


def test_decoupled_layers_switch_at_their_own_fields():
    """Spacer with J = 0: a two-step major loop, each step at its layer's thin-film Stoner–Wohlfarth
    field 2K_i/M_s − μ0 M_s (each layer's demag field is its own −μ0 M_s m_z in an infinite film), and
    a plateau ⟨m_z⟩ = 0 in between (hard layer up, soft layer down)."""
    film = uniform_bilayer(spacer_after_layer=0, interlayer_coupling_J_m2=0.0)
    B_soft, B_hard = thin_film_switching_field(SOFT_FACTOR * K_HARD), thin_film_switching_field(K_HARD)
    first = step_field(film, 0.5)
    second = step_field(film, -0.5)
    print(f"steps {first:.6f} T ({first / B_soft - 1:+.1e}), {second:.6f} T ({second / B_hard - 1:+.1e})")
    assert first == pytest.approx(B_soft, rel=1e-3)
    assert second == pytest.approx(B_hard, rel=1e-3)
    plateau = relaxed_from_saturation(film, -0.5 * (B_soft + B_hard))
    assert plateau[2, 0].mean() == pytest.approx(1.0, abs=1e-6)
    assert plateau[2, 1].mean() == pytest.approx(-1.0, abs=1e-6)


def test_exchange_coupled_layers_switch_together_in_between():
    """No spacer, direct exchange b = 2A/(M_s dz²) ≈ 8 T: one step at the field where the coupled
    collinear state becomes unstable, B_sw = B̄ + b − √(b² + δ²) (B̄, δ: mean and half difference of
    the layers' fields), strictly between the two single-layer fields, both layers reversed after it."""
    film = uniform_bilayer()
    B_soft, B_hard = thin_film_switching_field(SOFT_FACTOR * K_HARD), thin_film_switching_field(K_HARD)
    b = 2 * A_EX / (MS * MESH.dz**2)
    mean, half_difference = 0.5 * (B_soft + B_hard), 0.5 * (B_hard - B_soft)
    expected = mean + b - np.sqrt(b**2 + half_difference**2)
    first = step_field(film, 0.5)
    print(f"coupled step {first:.6f} T vs {expected:.6f} T; single layers {B_soft:.4f}, {B_hard:.4f} T")
    assert B_soft < first < B_hard
    assert first == pytest.approx(expected, rel=1e-3)
    assert step_field(film, -0.5) == pytest.approx(first, rel=1e-6)  # one step, no plateau
    after = relaxed_from_saturation(film, -1.001 * first)
    assert after[2].max() < -0.99
