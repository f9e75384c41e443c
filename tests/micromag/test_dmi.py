"""Interfacial DMI: cycloid energies along x, along y and oblique (dx ≠ dy), and the spiral ground state."""

import numpy as np
import pytest

from forcdecode.micromag import Film, Mesh

MS = 8e5


def cycloid(mesh, q, axis="x"):
    """Néel cycloid along ``axis``: m = (sin θ, 0, cos θ) (x) or (0, sin θ, cos θ) (y), θ = −q x (or −q y)."""
    m = np.zeros(mesh.vector_shape)
    if axis == "x":
        theta = -q * np.arange(mesh.nx) * mesh.dx
        m[0] = np.sin(theta)[None, None, :]
        m[2] = np.cos(theta)[None, None, :]
    else:
        theta = -q * np.arange(mesh.ny) * mesh.dy
        m[1] = np.sin(theta)[None, :, None]
        m[2] = np.cos(theta)[None, :, None]
    return m


def spacing(mesh, axis):
    """(cells, cell size in m) along ``axis``."""
    return (mesh.nx, mesh.dx) if axis == "x" else (mesh.ny, mesh.dy)


@pytest.mark.parametrize("D", [3e-3, -2e-3])
@pytest.mark.parametrize("periods", [1, 8])
@pytest.mark.parametrize("axis", ["x", "y"])
@pytest.mark.parametrize("cells", [(2e-9, 2e-9), (2e-9, 3.5e-9), (3e-9, 1.5e-9)], ids=["square", "dy>dx", "dy<dx"])
def test_cycloid_energy(D, periods, axis, cells):
    """A cycloid of wave number q along x or y has discrete energy density −D sin(q Δ)/Δ, Δ its cell size
    along the cycloid (whatever the other cell size)."""
    mesh = Mesh(64, 48, 1, cells[0], cells[1], 1e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, D=D, terms=("dmi",))
    n, d = spacing(mesh, axis)
    q = 2 * np.pi * periods / (n * d)
    density = film.energy(cycloid(mesh, q, axis)) / (mesh.n_cells * mesh.cell_volume)
    assert density == pytest.approx(-D * np.sin(q * d) / d, rel=1e-12)


@pytest.mark.parametrize("kx, ky, phi_deg", [(3, 2, 30.0), (1, -5, 120.0), (7, 4, -75.0)])
def test_oblique_cycloid_energy(kx, ky, phi_deg):
    """θ = −(q_x x + q_y y), m = (cos φ sin θ, sin φ sin θ, cos θ) on cells dx ≠ dy: by central
    differences B_DMI = (2D/M_s)[sin θ (s_x, s_y), cos θ (s_x cos φ + s_y sin φ)] with
    s_α = sin(q_α Δ_α)/Δ_α, so the energy density is exactly −D (s_x cos φ + s_y sin φ)."""
    D = 2.5e-3
    mesh = Mesh(40, 30, 2, 2e-9, 3e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, D=D, terms=("dmi",))
    qx, qy, phi = 2 * np.pi * kx / (mesh.nx * mesh.dx), 2 * np.pi * ky / (mesh.ny * mesh.dy), np.radians(phi_deg)
    x = np.arange(mesh.nx) * mesh.dx
    y = np.arange(mesh.ny) * mesh.dy
    theta = -(qx * x[None, :] + qy * y[:, None])[None]
    m = np.stack([np.cos(phi) * np.sin(theta), np.sin(phi) * np.sin(theta), np.cos(theta)])
    m = np.broadcast_to(m, mesh.vector_shape).copy()
    density = film.energy(m) / (mesh.n_cells * mesh.cell_volume)
    s_x, s_y = np.sin(qx * mesh.dx) / mesh.dx, np.sin(qy * mesh.dy) / mesh.dy
    assert density == pytest.approx(-D * (s_x * np.cos(phi) + s_y * np.sin(phi)), rel=1e-12)


def test_helical_spiral_has_no_interfacial_dmi_energy():
    """A Bloch-type (helical) spiral m = (0, sin qx, cos qx) costs nothing with interfacial DMI."""
    mesh = Mesh(64, 4, 1, 2e-9, 2e-9, 1e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, D=3e-3, terms=("dmi",))
    q = 2 * np.pi * 4 / (mesh.nx * mesh.dx)
    m = cycloid(mesh, q)[[1, 0, 2]].copy()
    assert abs(film.energy(m)) < 1e-30


def winding_number(m, axis):
    """Turns of the cycloid angle θ = atan2(m_∥, m_z) along ``axis`` (one row), negative when θ decreases."""
    if axis == "x":
        theta = np.arctan2(m[0, 0, 0, :], m[2, 0, 0, :])
    else:
        theta = np.arctan2(m[1, 0, :, 0], m[2, 0, :, 0])
    return np.angle(np.exp(1j * (np.roll(theta, -1) - theta))).sum() / (2 * np.pi)


def relaxed_spiral_wavenumber(A, D, mesh, axis, seed=0):
    """Ground-state wave number (1/m) found by relaxation.

    In a periodic box the winding number k is conserved by relaxation, so each sector k near the
    optimum is relaxed from a noisy cycloid (noise 0.1 per component) and the lowest energies locate
    the optimum: the vertex of a parabola through the five lowest-energy sectors. Returns
    (vertex q, [(k, relaxed energy density, analytic E(q_k))], allowed-q quantum 2π/L)."""
    film = Film(mesh, Ms=MS, A_ex=A, D=D, terms=("exchange", "dmi"))
    n, d = spacing(mesh, axis)
    length = n * d
    q_guess = np.arctan(D * d / (2 * A)) / d
    k0 = int(round(q_guess * length / (2 * np.pi)))
    rng = np.random.default_rng(seed)
    sectors = []
    for k in range(k0 - 3, k0 + 4):
        q = 2 * np.pi * k / length
        m = cycloid(mesh, q, axis) + 0.1 * rng.normal(size=mesh.vector_shape)
        m = np.ascontiguousarray(m / np.linalg.norm(m, axis=0))
        result = film.minimize(m, 0.0, torque_tol_T=1e-7, max_iterations=100_000)
        assert result.converged
        assert winding_number(m, axis) == pytest.approx(-k, abs=1e-9)  # D > 0: θ decreases
        density = film.energy(m) / (mesh.n_cells * mesh.cell_volume)
        sectors.append((k, density, 2 * A * (1 - np.cos(q * d)) / d**2 - D * np.sin(q * d) / d))
    energies = np.array([s[1] for s in sectors])
    best = int(np.argmin(energies))
    assert 2 <= best <= len(sectors) - 3, "optimum not bracketed"
    qs = 2 * np.pi * np.array([s[0] for s in sectors]) / length
    c2, c1, _ = np.polyfit(qs[best - 2:best + 3], energies[best - 2:best + 3], 2)
    return -c1 / (2 * c2), sectors, 2 * np.pi / length


@pytest.mark.parametrize("axis, mesh", [
    ("x", Mesh(384, 2, 1, 2e-9, 3e-9, 1e-9)),
    ("y", Mesh(2, 384, 1, 3e-9, 2e-9, 1e-9)),
], ids=["along-x", "along-y"])
def test_spiral_ground_state_wavenumber(axis, mesh):
    """Exchange + DMI, E(q) = 2A(1 − cos qΔ)/Δ² − D sin(qΔ)/Δ (Δ the cell size along the spiral) is
    least at tan(qΔ) = DΔ/(2A). Relaxed spirals have exactly E(q_k); the wave number they locate agrees
    with the optimum to 1e-4, and one with 1.02·D lands ~1.7 % away: a 2 % error in D (or in the DMI
    field's prefactor) is 170× the tolerance. The lowest-energy sector is the allowed k next to the optimum."""
    A, D = 1e-11, 5e-3
    _, d = spacing(mesh, axis)
    q_opt = np.arctan(D * d / (2 * A)) / d
    q, sectors, quantum = relaxed_spiral_wavenumber(A, D, mesh, axis)
    for k, relaxed, analytic in sectors:
        assert relaxed == pytest.approx(analytic, rel=1e-9), k
    k_best = min(sectors, key=lambda s: s[1])[0]
    assert abs(k_best - q_opt / quantum) < 1.0
    print(f"{axis}: q/q_opt − 1 = {q / q_opt - 1:+.2e}; quantum/q_opt = {quantum / q_opt:.3f}")
    assert q == pytest.approx(q_opt, rel=1e-4)
    q_wrong, _, _ = relaxed_spiral_wavenumber(A, 1.02 * D, mesh, axis, seed=1)
    print(f"{axis}: 1.02·D gives q/q_opt(D) − 1 = {q_wrong / q_opt - 1:+.2e}")
    assert abs(q_wrong / q_opt - 1) > 100 * 1e-4
