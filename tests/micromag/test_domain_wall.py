"""A 1D domain wall relaxed by the minimizer against the analytic Bloch/Néel wall."""

import numpy as np
import pytest

from forcdecode.micromag import Film, Mesh

A, K, MS = 1e-11, 1e6, 8e5  # δ = √(A/K) = 3.16 nm
DX = 0.25e-9


def relaxed_two_wall_strip(D, seed=0):
    """Periodic strip along x with an up domain and a down domain (two walls), relaxed."""
    mesh = Mesh(1024, 1, 1, DX, 1e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=A, K_u=K, D=D, terms=("exchange", "anisotropy", "dmi"))
    x = (np.arange(mesh.nx) + 0.5) * DX
    L = mesh.nx * DX
    # start from sharp-ish Bloch walls (m_y) plus noise so the minimizer can pick the chirality
    theta = np.pi * (0.5 * (np.tanh((x - L / 4) / 2e-9) - np.tanh((x - 3 * L / 4) / 2e-9)))
    rng = np.random.default_rng(seed)
    m = np.zeros(mesh.vector_shape)
    m[2] = np.cos(theta)
    m[1] = np.sin(theta)
    m[0] = 0.05 * rng.normal(size=mesh.nx)
    m /= np.linalg.norm(m, axis=0)
    m = np.ascontiguousarray(m)
    result = film.minimize(m, torque_tol_T=1e-6, max_iterations=200_000)
    assert result.converged, result
    uniform = film.energy(film.uniform())
    wall_energy = (film.energy(m) - uniform) / 2 / (mesh.ny * mesh.dy * mesh.nz * mesh.dz)
    return mesh, m, x, wall_energy


def test_bloch_wall_energy_and_profile():
    mesh, m, x, sigma = relaxed_two_wall_strip(D=0.0)
    assert sigma == pytest.approx(4 * np.sqrt(A * K), rel=5e-3)
    # profile: m_z = −tanh((x − x0)/δ) around the first wall
    mz = m[2, 0, 0]
    i0 = np.where((mz[:-1] > 0) & (mz[1:] <= 0))[0][0]
    x0 = x[i0] + DX * mz[i0] / (mz[i0] - mz[i0 + 1])
    window = np.abs(x - x0) < 6 * np.sqrt(A / K)
    np.testing.assert_allclose(mz[window], -np.tanh((x[window] - x0) / np.sqrt(A / K)), atol=5e-3)


@pytest.mark.parametrize("D", [1.5e-3, -1.5e-3])
def test_neel_wall_energy_and_chirality(D):
    mesh, m, x, sigma = relaxed_two_wall_strip(D=D)
    assert sigma == pytest.approx(4 * np.sqrt(A * K) - np.pi * abs(D), rel=5e-3)
    mx, my, mz = m[0, 0, 0], m[1, 0, 0], m[2, 0, 0]
    assert np.abs(my).max() < 1e-3  # Néel: the wall turns in the x–z plane
    # winding ∮ (m_z ∂x m_x − m_x ∂x m_z) dx = −2π sign(D) for the two walls of the period
    dmx = (np.roll(mx, -1) - np.roll(mx, 1)) / 2
    dmz = (np.roll(mz, -1) - np.roll(mz, 1)) / 2
    winding = np.sum(mz * dmx - mx * dmz)
    assert winding == pytest.approx(-2 * np.pi * np.sign(D), abs=0.05)
