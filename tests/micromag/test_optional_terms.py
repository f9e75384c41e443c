"""Optional terms for the residual analysis: second-order anisotropy K_2 and a bias field."""

import numpy as np
import pytest

from forcdecode.micromag import MU0, Film, Mesh

MS, K1, K2 = 6e5, 5e5, 2e5


def uniform_film(**kwargs):
    return Film(Mesh(4, 4, 1, 2e-9, 2e-9, 2e-9), Ms=MS, A_ex=1e-11, K_u=K1, **kwargs)


@pytest.mark.parametrize("theta", [0.0, 0.4, 1.1, np.pi / 2])
def test_second_order_anisotropy_energy_density(theta):
    film = uniform_film(K_2=K2, terms=("anisotropy",))
    m = film.uniform((np.sin(theta), 0.0, np.cos(theta)))
    density = film.energy(m) / (film.mesh.n_cells * film.mesh.cell_volume)
    assert density == pytest.approx(-K1 * np.cos(theta) ** 2 - K2 * np.cos(theta) ** 4, rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("sin_theta", [0.3, 0.5, 0.8])
def test_hard_axis_magnetization_curve_with_K2(sin_theta):
    """Field along the hard axis x: B = sin θ (2K1 + 4K2 cos²θ)/M_s at equilibrium (anisotropy only)."""
    film = uniform_film(K_2=K2, terms=("anisotropy", "zeeman"))
    cos2 = 1 - sin_theta**2
    B = sin_theta * (2 * K1 + 4 * K2 * cos2) / MS
    m = film.uniform((0.1, 0.0, 1.0))
    assert film.minimize(m, np.array([B, 0.0, 0.0]), torque_tol_T=1e-10, max_iterations=100_000).converged
    assert m[0].mean() == pytest.approx(sin_theta, abs=1e-6)


def test_bias_field_shifts_the_switching_field():
    """Easy-axis switching of a uniform film at B_K,eff = 2K/M_s − μ0M_s; a bias B_b along +z moves
    the down-switching field to −(B_K,eff + B_b)."""
    bias = 0.1
    film = uniform_film(B_bias_T=(0.0, 0.0, bias))
    b_k_eff = 2 * K1 / MS - MU0 * MS

    def switches(B):
        m = film.uniform((np.sin(0.01), 0.0, np.cos(0.01)))
        assert film.minimize(m, np.array([0.0, 0.0, -B]), torque_tol_T=1e-9, max_iterations=100_000).converged
        return m[2].mean() < 0

    low, high = 0.0, 2.0 * b_k_eff
    for _ in range(22):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if switches(mid) else (mid, high)
    assert 0.5 * (low + high) == pytest.approx(b_k_eff + bias, rel=2e-3)
