"""Interfacial DMI: cycloid energies and the spiral ground state."""

import numpy as np
import pytest

from forcdecode.micromag import Film, Mesh

MS = 8e5


def cycloid(mesh, q):
    """m = (sin θ, 0, cos θ), θ = −q x."""
    theta = -q * np.arange(mesh.nx) * mesh.dx
    m = np.zeros(mesh.vector_shape)
    m[0] = np.sin(theta)[None, None, :]
    m[2] = np.cos(theta)[None, None, :]
    return m


@pytest.mark.parametrize("D", [3e-3, -2e-3])
@pytest.mark.parametrize("periods", [1, 8])
def test_cycloid_energy(D, periods):
    mesh = Mesh(64, 4, 1, 2e-9, 2e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, D=D, terms=("dmi",))
    q = 2 * np.pi * periods / (mesh.nx * mesh.dx)
    density = film.energy(cycloid(mesh, q)) / (mesh.n_cells * mesh.cell_volume)
    assert density == pytest.approx(-D * np.sin(q * mesh.dx) / mesh.dx, rel=1e-12)


def test_helical_spiral_has_no_interfacial_dmi_energy():
    """A Bloch-type (helical) spiral m = (0, sin qx, cos qx) costs nothing with interfacial DMI."""
    mesh = Mesh(64, 4, 1, 2e-9, 2e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, D=3e-3, terms=("dmi",))
    q = 2 * np.pi * 4 / (mesh.nx * mesh.dx)
    m = cycloid(mesh, q)[[1, 0, 2]].copy()
    assert abs(film.energy(m)) < 1e-30


def test_spiral_ground_state_wavenumber():
    """With exchange + DMI, E(q) = 2A(1 − cos q dx)/dx² − D sin(q dx)/dx is least at tan(q dx) = D dx/(2A).
    Over the wave numbers the periodic box allows, the lowest energy cycloid is the allowed q nearest
    that optimum."""
    A, D = 1e-11, 3e-3
    mesh = Mesh(128, 1, 1, 1e-9, 1e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=A, D=D, terms=("exchange", "dmi"))
    ks = np.arange(1, 20)
    qs = 2 * np.pi * ks / (mesh.nx * mesh.dx)
    energies = [film.energy(cycloid(mesh, q)) for q in qs]
    q_opt = np.arctan(D * mesh.dx / (2 * A)) / mesh.dx
    assert qs[int(np.argmin(energies))] == pytest.approx(qs[np.argmin(np.abs(qs - q_opt))])
    assert 2 * np.pi / q_opt == pytest.approx(4 * np.pi * A / D, rel=0.01)  # continuum period 4πA/D
