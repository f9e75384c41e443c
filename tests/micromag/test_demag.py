"""Demag of the periodic film against results known without our code."""

import numpy as np
import pytest

from forcdecode.micromag import MU0, Film, Mesh
from forcdecode.micromag.demag import build_periodic_film_kernel

MS = 8e5


def demag_only(mesh, n_alias=20):
    return Film(mesh, Ms=MS, A_ex=0.0, terms=("demag",), n_alias=n_alias)


@pytest.mark.parametrize("nz", [1, 2, 3])
def test_uniform_perpendicular_film_has_field_minus_Ms(nz):
    film = demag_only(Mesh(16, 8, nz, 2e-9, 3e-9, 4e-9))
    B = film.effective_field(film.uniform((0, 0, 1)))
    np.testing.assert_allclose(B[2], -MU0 * MS, rtol=1e-12)
    np.testing.assert_allclose(B[:2], 0.0, atol=1e-12)


@pytest.mark.parametrize("direction", [(1, 0, 0), (0, 1, 0), (1, 1, 0)])
def test_uniform_inplane_film_has_no_field(direction):
    film = demag_only(Mesh(16, 8, 2, 2e-9, 2e-9, 4e-9))
    B = film.effective_field(film.uniform(direction))
    assert np.abs(B).max() < 1e-12


def _mode(mesh, component, k_index, layers=None):
    """A single Fourier mode cos(k x) of one magnetization component (linear response, |m| free)."""
    x = (np.arange(mesh.nx) + 0.5) * mesh.dx
    k = 2 * np.pi * k_index / (mesh.nx * mesh.dx)
    m = np.zeros(mesh.vector_shape)
    for layer in range(mesh.nz) if layers is None else layers:
        m[component, layer] = np.cos(k * x)[None, :]
    return m, k, x


def _thin_film_factor(k, t):
    return (1 - np.exp(-k * t)) / (k * t)


@pytest.mark.parametrize("k_index", [1, 2, 4])
def test_single_mode_mz_matches_thin_film_factor(k_index):
    # Long wavelengths (≥ 32 cells): the cell average changes the factor by ≲ (k dx)²/12 < 0.4 %.
    mesh = Mesh(128, 4, 1, 2e-9, 2e-9, 4e-9)
    film = demag_only(mesh)
    m, k, x = _mode(mesh, 2, k_index)
    B = film.effective_field(m)
    # energy of the mode: E = −½ Ms V Σ m·B ; analytic: ½ μ0 Ms² N_zz(k) <cos²> per volume
    energy_density = -0.5 * MS * np.sum(m * B) / mesh.n_cells
    expected = 0.5 * MU0 * MS**2 * _thin_film_factor(k, mesh.dz) * 0.5
    assert energy_density == pytest.approx(expected, rel=4e-3)


@pytest.mark.parametrize("k_index", [1, 3])
def test_single_mode_mx_matches_volume_charge_factor(k_index):
    mesh = Mesh(128, 4, 1, 2e-9, 2e-9, 4e-9)
    film = demag_only(mesh)
    m, k, x = _mode(mesh, 0, k_index)
    B = film.effective_field(m)
    # Cell averaging: the mode keeps weight sinc²(k dx/2) at k; the rest sits on aliases k + G, where
    # the in-plane factor 1 − f(k+G) is ≈ 1 (f(G) ≈ dx/(2πt) ≈ 0.08 changes the result by < 0.2 %).
    s2 = np.sinc(k * mesh.dx / (2 * np.pi)) ** 2
    N_xx = (1 - _thin_film_factor(k, mesh.dz)) * s2 + (1 - s2)
    np.testing.assert_allclose(B[0, 0, 0], -MU0 * MS * N_xx * np.cos(k * x), atol=5e-3 * MU0 * MS * N_xx)


@pytest.mark.parametrize("component", [0, 2])
def test_two_layers_equal_one_layer_of_double_thickness(component):
    """Two coupled layers of thickness t with the same m act as one layer of 2t (exact identity)."""
    two = demag_only(Mesh(32, 16, 2, 2e-9, 2e-9, 2e-9))
    one = demag_only(Mesh(32, 16, 1, 2e-9, 2e-9, 4e-9))
    rng = np.random.default_rng(1)
    m1 = rng.normal(size=(3, 1, 16, 32))
    B1 = one.effective_field(np.ascontiguousarray(m1))
    m2 = np.ascontiguousarray(np.repeat(m1, 2, axis=1))
    B2 = two.effective_field(m2)
    np.testing.assert_allclose(B2.mean(axis=1)[component], B1[component, 0], atol=1e-10 * MU0 * MS)


def test_cross_layer_inplane_field_of_a_charge_stripe():
    """m_z = cos kx in the bottom layer gives H_x = +M_s g sin kx in the top layer (field points
    away from positive surface charge), g = (1 − e^{−kt})² e^{−k(Δ−t)}/(2kt)."""
    mesh = Mesh(128, 4, 2, 2e-9, 2e-9, 3e-9)
    film = demag_only(mesh)
    m, k, x = _mode(mesh, 2, 1, layers=[0])
    B = film.effective_field(m)
    t = mesh.dz
    g = (1 - np.exp(-k * t)) ** 2 / (2 * k * t)  # adjacent layers: Δ = t
    np.testing.assert_allclose(B[0, 1, 0], MU0 * MS * g * np.sin(k * x), atol=5e-3 * MU0 * MS * g)
    np.testing.assert_allclose(B[0, 0, 0], 0.0, atol=1e-12)  # no self x–z coupling
    np.testing.assert_allclose(B[2, 1, 0], MU0 * MS * g * np.cos(k * x), atol=5e-3 * MU0 * MS * g)


def test_kernel_is_symmetric_under_layer_exchange():
    """Reciprocity: N_ij(k) = N_ji(k)^† — even parts equal, odd (x–z) parts change sign."""
    kernel = build_periodic_film_kernel(Mesh(16, 16, 3, 2e-9, 2e-9, 4e-9), n_alias=5)
    for even in (kernel.xx, kernel.yy, kernel.zz, kernel.xy):
        np.testing.assert_allclose(even, even[::-1], atol=1e-15)
    for odd in (kernel.xz_imag, kernel.yz_imag):
        np.testing.assert_allclose(odd, -odd[::-1], atol=1e-15)


def test_alias_sum_converges():
    mesh = Mesh(16, 16, 2, 2e-9, 2e-9, 4e-9)
    fine = build_periodic_film_kernel(mesh, n_alias=40)
    default = build_periodic_film_kernel(mesh, n_alias=20)
    assert np.abs(default.zz - fine.zz).max() < 1e-4
    assert np.abs(default.xx - fine.xx).max() < 1e-4


def test_self_kernel_trace_is_one():
    """N_xx + N_yy + N_zz = 1 for the cell-averaged self kernel at every k ≠ 0 (Σ_G sinc² = 1)."""
    kernel = build_periodic_film_kernel(Mesh(16, 8, 1, 2e-9, 3e-9, 4e-9))
    trace = (kernel.xx + kernel.yy + kernel.zz)[0].ravel()
    assert trace[0] == pytest.approx(1.0, abs=1e-12)  # k = 0: N_zz = 1 alone
    np.testing.assert_allclose(trace[1:], 1.0, atol=2e-4)


def test_splitting_layers_in_two_leaves_the_layer_averaged_field_unchanged():
    """Four layers of t/2 holding the magnetization of two layers of t (pairwise equal), random at the
    cell scale: the field averaged over each pair equals the two-layer field (exact superposition)."""
    rng = np.random.default_rng(2)
    m2 = rng.normal(size=(3, 2, 8, 12))
    m2 = np.ascontiguousarray(m2 / np.linalg.norm(m2, axis=0))
    B2 = demag_only(Mesh(12, 8, 2, 2e-9, 2.5e-9, 3e-9)).effective_field(m2)
    B4 = demag_only(Mesh(12, 8, 4, 2e-9, 2.5e-9, 1.5e-9)).effective_field(np.ascontiguousarray(np.repeat(m2, 2, axis=1)))
    np.testing.assert_allclose(B4.reshape(3, 2, 2, 8, 12).mean(axis=2), B2, atol=1e-12)


def test_odd_components_vanish_only_where_they_are_odd():
    """At the x Nyquist column N_xz and N_xy vanish (odd in q_x) but N_yz (odd in q_y) does not."""
    kernel = build_periodic_film_kernel(Mesh(8, 8, 2, 2e-9, 2e-9, 3e-9), n_alias=10)
    cross = 0  # offset d = −1
    assert np.abs(kernel.xz_imag[cross, :, -1]).max() == 0.0
    assert np.abs(kernel.xy[:, :, -1]).max() == 0.0
    assert np.abs(kernel.yz_imag[cross, 1:4, -1]).min() > 1e-3
