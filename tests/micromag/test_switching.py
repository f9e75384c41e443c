"""Coherent (Stoner–Wohlfarth) reversal of a defect-free periodic film, found by the minimizer."""

import numpy as np
import pytest

from forcdecode.micromag import MU0, Film, Mesh

MS, K = 5e5, 5e5
B_K_EFF = 2 * K / MS - MU0 * MS  # tesla: μ0 H_K,eff = 2K/M_s − μ0 M_s


@pytest.fixture(scope="module")
def film():
    return Film(Mesh(4, 4, 1, 2e-9, 2e-9, 2e-9), Ms=MS, A_ex=1e-11, K_u=K, D=1e-3)


def switches(film, B, psi, tilt):
    """Start near +z (tilted by ``tilt`` in the x–z plane), relax in a field B at angle ψ from −z."""
    m = film.uniform((np.sin(tilt), 0.0, np.cos(tilt)))
    field = B * np.array([np.sin(psi), 0.0, -np.cos(psi)])
    result = film.minimize(m, field, torque_tol_T=1e-9, max_iterations=100_000)
    assert result.converged
    return m[2].mean() < 0


def switching_field(film, psi, tilt=0.0, iterations=22):
    low, high = 0.05 * B_K_EFF, 1.2 * B_K_EFF
    for _ in range(iterations):
        mid = 0.5 * (low + high)
        if switches(film, mid, psi, tilt):
            high = mid
        else:
            low = mid
    return 0.5 * (low + high)


def test_switching_field_along_easy_axis(film):
    """Field antiparallel to the easy axis: the uniform state turns unstable at 2K_u/(μ0 M_s) − M_s."""
    assert switching_field(film, psi=0.0, tilt=0.01) == pytest.approx(B_K_EFF, rel=2e-3)


@pytest.mark.parametrize("psi_deg", [5.0, 30.0, 45.0, 70.0])
def test_switching_field_follows_astroid(film, psi_deg):
    psi = np.radians(psi_deg)
    astroid = B_K_EFF / (np.cos(psi) ** (2 / 3) + np.sin(psi) ** (2 / 3)) ** 1.5
    assert switching_field(film, psi) == pytest.approx(astroid, rel=2e-3)
