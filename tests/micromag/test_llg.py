"""LLG dynamics against precession, damping and conservation laws."""

import numpy as np
import pytest

from forcdecode.micromag import GAMMA_LL, MU0, Film, Mesh


def macrospin(theta0, terms=("zeeman",)):
    film = Film(Mesh(1, 1, 1, 2e-9, 2e-9, 2e-9), Ms=8e5, A_ex=0.0, terms=terms)
    return film, film.uniform((np.sin(theta0), 0.0, np.cos(theta0)))


def test_larmor_precession_without_damping():
    B, theta0, duration = 1.0, np.radians(30), 200e-12
    film, m = macrospin(theta0)
    result = film.run_llg(m, duration, B, alpha=0.0, tol=1e-9)
    assert result.ok and result.t_s == pytest.approx(duration)
    phase = np.arctan2(m[1, 0, 0, 0], m[0, 0, 0, 0])
    expected = np.angle(np.exp(1j * GAMMA_LL * B * duration))  # f = γB/2π = 28.0 GHz, counter-clockwise
    assert phase == pytest.approx(expected, abs=1e-5)
    assert m[2, 0, 0, 0] == pytest.approx(np.cos(theta0), abs=1e-8)  # energy (m_z) conserved


def test_damped_relaxation_matches_macrospin_solution():
    B, alpha, theta0, duration = 1.0, 0.1, np.radians(60), 50e-12
    film, m = macrospin(theta0)
    film.run_llg(m, duration, B, alpha=alpha, tol=1e-9)
    theta = np.arccos(m[2, 0, 0, 0])
    gamma_prime = GAMMA_LL / (1 + alpha**2)
    expected = 2 * np.arctan(np.tan(theta0 / 2) * np.exp(-alpha * gamma_prime * B * duration))
    assert theta == pytest.approx(expected, rel=1e-6)


def test_kittel_precession_of_uniform_film():
    """Uniform film, easy axis z, field along z: ω = γ(B + (2K/M_s − μ0 M_s) cos θ) for any cone angle."""
    Ms, K, B, theta0, duration = 6e5, 4e5, 0.3, np.radians(20), 100e-12
    film = Film(Mesh(8, 8, 2, 2e-9, 2e-9, 2e-9), Ms=Ms, A_ex=1e-11, K_u=K, D=2e-3)
    m = film.uniform((np.sin(theta0), 0.0, np.cos(theta0)))
    film.run_llg(m, duration, B, alpha=0.0, tol=1e-9)
    omega = GAMMA_LL * (B + (2 * K / Ms - MU0 * Ms) * np.cos(theta0))
    phase = np.arctan2(m[1].mean(), m[0].mean())
    assert phase == pytest.approx(np.angle(np.exp(1j * omega * duration)), abs=1e-5)
    assert np.abs(m - m[:, :1, :1, :1]).max() < 1e-10  # stays uniform


@pytest.fixture(scope="module")
def textured():
    mesh = Mesh(16, 16, 2, 2e-9, 2e-9, 3e-9)
    rng = np.random.default_rng(11)
    K = 6e5 * (1 + 0.2 * rng.normal(size=mesh.shape))
    film = Film(mesh, Ms=7e5, A_ex=1.5e-11, K_u=K, D=2.5e-3)
    x = np.arange(16) * 2 * np.pi / 16
    m = np.zeros(mesh.vector_shape)
    m[0] = 0.6 * np.sin(x)[None, None, :] + 0.1
    m[1] = 0.4 * np.cos(x)[None, :, None]
    m[2] = 1.0
    m /= np.linalg.norm(m, axis=0)
    return film, np.ascontiguousarray(m)


def test_energy_conserved_without_damping(textured):
    film, m0 = textured
    m = m0.copy()
    scale = sum(abs(v) for k, v in film.energies(m, 0.2).items() if k != "total")
    e0 = film.energy(m, 0.2)
    result = film.run_llg(m, 20e-12, 0.2, alpha=0.0, tol=1e-7)
    assert result.ok and result.accepted_steps > 50
    assert abs(film.energy(m, 0.2) - e0) < 1e-5 * scale


def test_energy_never_increases_with_damping(textured):
    film, m0 = textured
    m = m0.copy()
    energies = [film.energy(m, 0.2)]
    for _ in range(10):
        film.run_llg(m, 2e-12, 0.2, alpha=0.3, tol=1e-6)
        energies.append(film.energy(m, 0.2))
    steps = np.diff(energies)
    assert np.all(steps <= 1e-9 * abs(energies[0]))
    assert energies[-1] < energies[0] - 0.05 * abs(energies[0] - energies[-1]) - 1e-30
