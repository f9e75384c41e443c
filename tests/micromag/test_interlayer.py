"""Interlayer exchange coupling across a spacer: E = −J ∫ m_k·m_{k+1} dA, direct exchange cut."""

import numpy as np
import pytest

from forcdecode.micromag import MU0, Film, Mesh

from .field_checks import field_by_finite_difference

MS, A_EX = 6e5, 1e-11


def layerwise(mesh, directions):
    """Magnetization uniform within each layer, layer k along ``directions[k]``."""
    m = np.empty(mesh.vector_shape)
    for k, d in enumerate(directions):
        m[:, k] = (np.asarray(d, dtype=np.float64) / np.linalg.norm(d))[:, None, None]
    return m


def tilted(theta, up=True):
    """Unit vector tilted by ``theta`` from +z (or −z) towards +x."""
    return np.array([np.sin(theta), 0.0, np.cos(theta) if up else -np.cos(theta)])


@pytest.mark.parametrize("J", [1.3e-3, -0.7e-3, 0.0])
def test_uniform_layers_energy(J):
    """Three layer-wise uniform layers, spacer between layers 1 and 2: direct exchange 0–1 gives
    2A·area(1 − m_0·m_1)/dz, the spacer −J·area m_1·m_2, nothing else (in-plane uniform)."""
    mesh = Mesh(4, 4, 3, 2e-9, 2.5e-9, 3e-9)
    film = Film(mesh, Ms=MS, A_ex=A_EX, terms=("exchange",), interlayer_coupling_J_m2=J, spacer_after_layer=1)
    rng = np.random.default_rng(5)
    directions = rng.normal(size=(3, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    area = mesh.nx * mesh.dx * mesh.ny * mesh.dy
    expected = (2 * A_EX * area * (1 - directions[0] @ directions[1]) / mesh.dz
                - J * area * directions[1] @ directions[2])
    assert film.energy(layerwise(mesh, directions)) == pytest.approx(expected, rel=1e-12, abs=1e-30)
    # without the spacer the 1–2 link is direct exchange again
    plain = Film(mesh, Ms=MS, A_ex=A_EX, terms=("exchange",))
    expected_plain = 2 * A_EX * area * (2 - directions[0] @ directions[1] - directions[1] @ directions[2]) / mesh.dz
    assert plain.energy(layerwise(mesh, directions)) == pytest.approx(expected_plain, rel=1e-12)


@pytest.mark.parametrize("terms", [("exchange",), ("exchange", "anisotropy", "dmi", "demag", "zeeman")])
@pytest.mark.parametrize("spacer", [0, 1])
def test_field_is_energy_gradient(terms, spacer):
    """B = −(1/(M_s V)) ∂E/∂m on random states, cells on both sides of the spacer included."""
    mesh = Mesh(6, 5, 3, 2e-9, 2.5e-9, 3e-9)
    rng = np.random.default_rng(11)
    film = Film(mesh, Ms=MS, A_ex=A_EX, K_u=4e5, D=1.5e-3, terms=terms,
                interlayer_coupling_J_m2=-2e-3, spacer_after_layer=spacer)
    m = rng.normal(size=mesh.vector_shape)
    m = np.ascontiguousarray(m / np.linalg.norm(m, axis=0))
    B_ext = np.array([0.1, -0.2, 0.3])
    B = film.effective_field(m, B_ext)
    scale = MS * mesh.cell_volume
    for k in (spacer, spacer + 1, 2 - spacer):
        for _ in range(3):
            index = (rng.integers(3), k, rng.integers(5), rng.integers(6))
            expected = field_by_finite_difference(film.energy, m, index, scale, B_ext)
            assert expected == pytest.approx(B[index], rel=1e-6, abs=1e-9)
    energies = film.energies(m, B_ext)
    assert energies["total"] == pytest.approx(sum(v for key, v in energies.items() if key != "total"), rel=1e-12)


def test_bad_spacer_is_rejected():
    with pytest.raises(ValueError, match="spacer_after_layer"):
        Film(Mesh(4, 4, 1, 2e-9, 2e-9, 2e-9), Ms=MS, A_ex=A_EX, spacer_after_layer=0)
    with pytest.raises(ValueError, match="spacer_after_layer"):
        Film(Mesh(4, 4, 2, 2e-9, 2e-9, 2e-9), Ms=MS, A_ex=A_EX, spacer_after_layer=1)
    with pytest.raises(ValueError, match="needs spacer_after_layer"):
        Film(Mesh(4, 4, 2, 2e-9, 2e-9, 2e-9), Ms=MS, A_ex=A_EX, interlayer_coupling_J_m2=1e-3)


def switching_field(film, m_start, soft_layers, B_max=1.0, bisections=24):
    """Field magnitude (T) at which the soft layers reverse from ``m_start`` under a field along −(their
    m_z): quasi-static jump from ``m_start`` (a slightly tilted collinear state), by bisection."""
    sign = np.sign(m_start[2, soft_layers].mean())

    def reversed_at(b):
        m = m_start.copy()
        assert film.minimize(m, np.array([0.0, 0.0, -sign * b]), torque_tol_T=1e-9, max_iterations=100_000).converged
        return sign * m[2, soft_layers].mean() < 0

    low, high = 0.0, B_max
    for _ in range(bisections):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if reversed_at(mid) else (mid, high)
    return 0.5 * (low + high)


@pytest.mark.parametrize("n_soft_layers", [1, 2])
@pytest.mark.parametrize("J", [1e-4, -1e-4])
def test_minor_loop_of_soft_layer_is_shifted_by_coupling(J, n_soft_layers):
    """A soft perpendicular layer (thickness t) coupled by J to a hard one (held up by 2K/M_s ~ 170 T):
    its minor loop is the Stoner–Wohlfarth loop ±(2K_s/M_s − μ0 M_s) of a thin film, shifted by
    −J/(M_s t) (the hard layer acts on it as a field J/(M_s t) along its own direction)."""
    dz = 2e-9
    mesh = Mesh(4, 4, 1 + n_soft_layers, 2e-9, 2e-9, dz)
    K_soft, K_hard = 2.6e5, 5e7
    K = np.full(mesh.shape, K_soft)
    K[0] = K_hard
    film = Film(mesh, Ms=MS, A_ex=A_EX, K_u=K, interlayer_coupling_J_m2=J, spacer_after_layer=0)
    soft = slice(1, None)
    parallel = layerwise(mesh, [tilted(0.01)] * mesh.nz)
    antiparallel = layerwise(mesh, [tilted(0.01)] + [tilted(0.01, up=False)] * n_soft_layers)
    B_down = -switching_field(film, parallel, soft)  # soft layer up → down
    B_up = switching_field(film, antiparallel, soft)  # soft layer down → up
    shift = 0.5 * (B_down + B_up)
    half_width = 0.5 * (B_up - B_down)
    B_shift = J / (MS * n_soft_layers * dz)
    # measured: shift within 2e-5 of J/(M_s t); half width within 1.4e-3 (coupled-mode and, for two
    # soft layers, internal-exchange corrections ~ B_J/B_K,hard and B_J/(2A/(M_s dz²)))
    assert shift == pytest.approx(-B_shift, rel=1e-3)
    assert half_width == pytest.approx(2 * K_soft / MS - MU0 * MS, rel=5e-3)
    print(f"J={J:g} t={n_soft_layers * dz * 1e9:g} nm: shift {shift:.6f} T vs {-B_shift:.6f} T "
          f"({shift / -B_shift - 1:+.2e}); half width {half_width:.6f} T vs {2 * K_soft / MS - MU0 * MS:.6f} T")


def test_slaved_pinning_next_to_the_spacer_matches_full_treatment():
    """Pinning cells on both sides of the spacer, slaved (held at their local equilibrium in their
    neighbours' field, interlayer field included) relax to the same states as the full treatment."""
    from forcdecode.micromag import FilmExtras, FilmMaterial, disordered_film

    mesh = Mesh(12, 12, 2, 2e-9, 2e-9, 3e-9)
    material = FilmMaterial(Ms=8e5, A_ex=1.2e-11, K_u=6e5, D=1e-3, sigma_K=0.1, sigma_theta_rad=np.radians(5), n_pin=12)
    extras = FilmExtras(spacer_after_layer=0, interlayer_coupling_J_m2=5e-4, layer_K_u_factor=(1.0, 0.7))
    loops = {}
    for pinning in ("full", "slaved"):
        film, m, _ = disordered_film(mesh, material, np.random.default_rng(2), n_grains=5, pinning=pinning,
                                     extras=extras)
        mz = []
        for B in (0.8, -0.2, -0.5, -1.0):
            assert film.minimize(m, B, torque_tol_T=1e-6, max_iterations=200_000).converged
            mz.append(m[2].mean(axis=(1, 2)))
        loops[pinning] = np.array(mz)
    assert loops["full"][0].min() > 0.9 and loops["full"][-1].max() < -0.5  # both layers reverse (pinned cells hold out)
    np.testing.assert_allclose(loops["slaved"], loops["full"], atol=1e-4)
