"""Exchange against the discrete and continuum spin-spiral energies."""

import numpy as np
import pytest

from forcdecode.micromag import Film, Mesh

A_EX = 1.3e-11
MS = 8e5


def spiral(mesh, q, axis="x"):
    """m = (sin qx, 0, cos qx) (or along y)."""
    m = np.zeros(mesh.vector_shape)
    if axis == "x":
        phase = q * np.arange(mesh.nx) * mesh.dx
        m[0] = np.sin(phase)[None, None, :]
        m[2] = np.cos(phase)[None, None, :]
    else:
        phase = q * np.arange(mesh.ny) * mesh.dy
        m[1] = np.sin(phase)[None, :, None]
        m[2] = np.cos(phase)[None, :, None]
    return m


@pytest.mark.parametrize("periods", [1, 4, 16])
@pytest.mark.parametrize("axis", ["x", "y"])
def test_spiral_energy_discrete_formula(periods, axis):
    mesh = Mesh(64, 32, 2, 2e-9, 1.5e-9, 4e-9)
    film = Film(mesh, Ms=MS, A_ex=A_EX, terms=("exchange",))
    n, d = (mesh.nx, mesh.dx) if axis == "x" else (mesh.ny, mesh.dy)
    q = 2 * np.pi * periods / (n * d)
    density = film.energy(spiral(mesh, q, axis)) / (mesh.n_cells * mesh.cell_volume)
    assert density == pytest.approx(2 * A_EX * (1 - np.cos(q * d)) / d**2, rel=1e-12)


def test_spiral_energy_tends_to_A_q_squared():
    mesh = Mesh(256, 1, 1, 1e-9, 1e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=A_EX, terms=("exchange",))
    q = 2 * np.pi / (mesh.nx * mesh.dx)
    density = film.energy(spiral(mesh, q)) / (mesh.n_cells * mesh.cell_volume)
    assert density == pytest.approx(A_EX * q**2, rel=1e-4)  # (q dx)²/12 = 5e-5


def test_interlayer_exchange_between_two_layers():
    """Two uniform layers at angle φ: E = 2A(1 − cos φ)/dz² · (cells per layer) · V (one bond each)."""
    mesh = Mesh(8, 8, 2, 2e-9, 2e-9, 3e-9)
    film = Film(mesh, Ms=MS, A_ex=A_EX, terms=("exchange",))
    phi = 0.7
    m = np.zeros(mesh.vector_shape)
    m[2, 0] = 1.0
    m[0, 1], m[2, 1] = np.sin(phi), np.cos(phi)
    expected = 2 * A_EX * (1 - np.cos(phi)) / mesh.dz**2 * mesh.nx * mesh.ny * mesh.cell_volume
    assert film.energy(m) == pytest.approx(expected, rel=1e-12)
    # open top/bottom surfaces: the field on the bottom layer comes from its single upper neighbour
    B = film.effective_field(m)
    np.testing.assert_allclose(B[0, 0], 2 * A_EX / (MS * mesh.dz**2) * np.sin(phi), rtol=1e-12)
