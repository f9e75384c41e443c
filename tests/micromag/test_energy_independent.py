"""Energies computed independently of the effective field, from each term's definition.

``test_effective_field`` checks B = −(1/(M_s V)) ∂E/∂m, but the engine's energy is built from its
field (E = −(M_s V/2) Σ m·B_bilinear − …), so a wrong prefactor in a field passes it. Here each
term's energy is written from its energy density with numpy finite differences of m (exchange
A|∇m|² by forward differences, DMI D[m_z ∇·m − (m·∇)m_z] by central differences, anisotropy
−K_u(u·m)² − K_2(u·m)⁴, Zeeman −M_s m·B, interlayer −J m_k·m_{k+1} per area) and, for demag, as
the magnetostatic energy (μ0 M_s²/2) Σ m·N m with the film's continuum tensor summed over aliases
in numpy (for states that vary along one in-plane axis, where that sum is one-dimensional and
exact to ~1e-9). The engine must agree with these to 1e-10 (local terms, exact discrete
identities) and 1e-5 (demag, the engine's ±20-alias kernel; 6e-7 with ±80), and a factor 2 must fail; the engine's
field must also equal minus the gradient of the independent energy.
"""

import numpy as np
import pytest

from forcdecode.micromag import MU0, Film, Mesh

from .field_checks import field_by_finite_difference

MS = 7.0e5
A_EX = 1.2e-11
D_DMI = 2.2e-3
K_2 = 1.3e5
J_INTER = 1.5e-4
B_EXT = np.array([0.12, -0.07, 0.31])
B_BIAS = np.array([0.01, 0.0, -0.02])


def smooth_state(mesh, rng, axes="xy", modes=2):
    """Random smooth unit field: per layer and component, an offset plus cosines of the lowest wave
    numbers (along ``axes``) with random amplitudes and phases, normalized."""
    x = np.arange(mesh.nx) * mesh.dx
    y = np.arange(mesh.ny) * mesh.dy
    lx, ly = mesh.nx * mesh.dx, mesh.ny * mesh.dy
    f = np.empty(mesh.vector_shape)
    for c in range(3):
        for k in range(mesh.nz):
            value = np.full((mesh.ny, mesh.nx), (0.3, -0.2, 1.0)[c] * rng.uniform(0.5, 1.5))
            for a in range(-modes, modes + 1):
                for b in range(-modes, modes + 1):
                    if (a == 0 and b == 0) or ("x" not in axes and a) or ("y" not in axes and b):
                        continue
                    phase = 2 * np.pi * (a * x[None, :] / lx + b * y[:, None] / ly) + rng.uniform(0, 2 * np.pi)
                    value = value + rng.normal(0.0, 0.5) * np.cos(phase)
            f[c, k] = value
    return np.ascontiguousarray(f / np.linalg.norm(f, axis=0))


# ----------------------------------------------------------------- independent energies (J)
def exchange_energy(film, m):
    """A ∫|∇m|² by forward differences (periodic in x, y; layers linked unless a spacer cuts them),
    plus the interlayer coupling −J dx dy Σ m_k·m_{k+1} across a spacer."""
    mesh = film.mesh
    volume = mesh.cell_volume
    e = film.A_ex * volume * (np.sum((np.roll(m, -1, axis=3) - m) ** 2) / mesh.dx**2
                              + np.sum((np.roll(m, -1, axis=2) - m) ** 2) / mesh.dy**2)
    for k in range(mesh.nz - 1):
        if k == film.spacer_after_layer:
            e -= film.interlayer_coupling_J_m2 * mesh.dx * mesh.dy * np.sum(m[:, k] * m[:, k + 1])
        else:
            e += film.A_ex * volume * np.sum((m[:, k + 1] - m[:, k]) ** 2) / mesh.dz**2
    return e


def anisotropy_energy(film, m):
    """−Σ V [K_u (u·m)² + K_2 (u·m)⁴] with per-cell K_u and u."""
    projection = np.sum(film.easy_axis * m, axis=0)
    return -film.mesh.cell_volume * np.sum(film.K_u * projection**2 + film.K_2 * projection**4)


def dmi_energy(film, m):
    """D ∫ [m_z (∂x m_x + ∂y m_y) − m_x ∂x m_z − m_y ∂y m_z], central differences, periodic."""
    mesh = film.mesh

    def ddx(a):
        return (np.roll(a, -1, axis=-1) - np.roll(a, 1, axis=-1)) / (2 * mesh.dx)

    def ddy(a):
        return (np.roll(a, -1, axis=-2) - np.roll(a, 1, axis=-2)) / (2 * mesh.dy)

    mx, my, mz = m
    density = mz * (ddx(mx) + ddy(my)) - mx * ddx(mz) - my * ddy(mz)
    return film.D * mesh.cell_volume * np.sum(density)


def zeeman_energy(film, m, B_ext):
    """−M_s V Σ m·(B_ext + B_bias)."""
    B = np.asarray(B_ext) + np.asarray(film.B_bias_T)
    return -film.Ms * film.mesh.cell_volume * np.sum(B[:, None, None, None] * m)


def film_tensor_1d(k, cell, t, d, n_alias=2_000):
    """Cell-averaged demag tensor of the film for wave vectors ±|q| along one in-plane axis ("a"), as
    (aa, zz, az) for layer offset d = observer − source (layers of thickness t, centres |d|t apart).

    Continuum (magnetic charge sheets, φ̂ = σ̂ e^{−q|z|}/(2q)): f = (1 − e^{−qt})/(qt);
    g = (1 − e^{−qt})² e^{−q(|d|t − t)}/(2qt); self: N_aa = 1 − f, N_zz = f; cross: N_aa = g,
    N_zz = −g, N_az = N_za = i sign(d) sign(q_a) g. The perpendicular in-plane axis carries no
    charge (N = 0). The cell average multiplies each alias q = k + 2πn/Δ by sinc²(qΔ/2) (the aliases
    of the uniform axis have zero weight); the non-decaying 1 of the self N_aa is summed exactly,
    Σ_n sinc²(kΔ/2 + πn) = 1, the rest decays like 1/n³."""
    q = k[:, None] + 2 * np.pi * np.arange(-n_alias, n_alias + 1)[None, :] / cell
    weight = np.sinc(q * cell / (2 * np.pi)) ** 2
    aq = np.abs(q)
    safe = np.where(aq > 0, aq, 1.0)
    one_minus = -np.expm1(-safe * t)
    if d == 0:
        f = np.where(aq > 0, one_minus / (safe * t), 1.0)
        zz = np.sum(f * weight, axis=1)
        aa = np.where(k != 0, 1.0, 0.0) - np.sum(np.where(aq > 0, f, 0.0) * weight, axis=1)
        return aa, zz, np.zeros_like(k, dtype=complex)
    g = np.where(aq > 0, one_minus**2 * np.exp(-safe * (abs(d) * t - t)) / (2 * safe * t), 0.0)
    g_sum = np.sum(g * weight, axis=1)
    return g_sum, -g_sum, 1j * np.sign(d) * np.sum(np.sign(q) * g * weight, axis=1)


def demag_energy_1d(film, m, axis, flip_cross_sign=False):
    """(μ0 M_s²/2) V Σ_cells m·N m for m varying along ``axis`` only, in Fourier space (numpy FFT).
    ``flip_cross_sign`` negates N_az (a deliberately wrong layer orientation)."""
    mesh = film.mesh
    a = 0 if axis == "x" else 1
    if axis == "x":
        assert np.allclose(m, m[:, :, :1, :]), "state must be uniform along y"
        line, n, cell, rows = m[:, :, 0, :], mesh.nx, mesh.dx, mesh.ny
    else:
        assert np.allclose(m, m[:, :, :, :1]), "state must be uniform along x"
        line, n, cell, rows = m[:, :, :, 0], mesh.ny, mesh.dy, mesh.nx
    mk = np.fft.fft(line, axis=-1)  # (3, nz, n)
    k = 2 * np.pi * np.fft.fftfreq(n, d=cell)
    total = 0.0
    for i in range(mesh.nz):
        for j in range(mesh.nz):
            aa, zz, az = film_tensor_1d(k, cell, mesh.dz, i - j)
            az = -az if flip_cross_sign else az
            total += np.sum(np.conj(mk[a, i]) * (aa * mk[a, j] + az * mk[2, j])
                            + np.conj(mk[2, i]) * (az * mk[a, j] + zz * mk[2, j]))
    assert abs(total.imag) <= 1e-9 * abs(total.real)
    return 0.5 * MU0 * film.Ms**2 * mesh.cell_volume * rows * total.real / n


# ----------------------------------------------------------------- tests
def agree(code, independent, rel):
    return abs(code - independent) <= rel * abs(independent)


@pytest.fixture(scope="module")
def textured():
    """A film with every local term on and per-cell K_u, easy axes (dx ≠ dy ≠ dz), and a smooth state."""
    mesh = Mesh(14, 11, 3, 2e-9, 2.5e-9, 3e-9)
    rng = np.random.default_rng(11)
    K = 4e5 * (1 + 0.3 * rng.random(mesh.shape))
    axis = rng.normal(size=mesh.vector_shape) * 0.3 + np.array([0, 0, 1.0])[:, None, None, None]
    film = Film(mesh, Ms=MS, A_ex=A_EX, K_u=K, easy_axis=axis, D=D_DMI, K_2=K_2, B_bias_T=tuple(B_BIAS))
    spacer = Film(mesh, Ms=MS, A_ex=A_EX, K_u=K, easy_axis=axis, D=D_DMI, K_2=K_2, B_bias_T=tuple(B_BIAS),
                  spacer_after_layer=1, interlayer_coupling_J_m2=J_INTER)
    return film, spacer, smooth_state(mesh, rng)


INDEPENDENT = {
    "exchange": lambda film, m: exchange_energy(film, m),
    "anisotropy": lambda film, m: anisotropy_energy(film, m),
    "dmi": lambda film, m: dmi_energy(film, m),
    "zeeman": lambda film, m: zeeman_energy(film, m, B_EXT),
}


@pytest.mark.parametrize("term", list(INDEPENDENT))
@pytest.mark.parametrize("with_spacer", [False, True], ids=["no-spacer", "spacer"])
def test_local_term_energy_from_its_definition(textured, term, with_spacer):
    film = textured[1] if with_spacer else textured[0]
    m = textured[2]
    code = film.with_terms((term,)).energy(m, B_EXT)
    independent = INDEPENDENT[term](film, m)
    print(f"{term}: code {code:.6e} J, independent {independent:.6e} J, rel {code / independent - 1:+.1e}")
    assert abs(independent) > 1e-22  # a state where the term is not negligible
    assert agree(code, independent, 1e-10)
    assert not agree(2 * code, independent, 1e-10) and not agree(0.5 * code, independent, 1e-10)


@pytest.mark.parametrize("term", list(INDEPENDENT))
@pytest.mark.parametrize("with_spacer", [False, True], ids=["no-spacer", "spacer"])
def test_field_is_minus_gradient_of_independent_energy(textured, term, with_spacer):
    """The engine's field against finite differences of the independent energy (not of its own)."""
    film = textured[1] if with_spacer else textured[0]
    m = textured[2]
    single = film.with_terms((term,))
    B = single.effective_field(m, B_EXT)
    moment = film.Ms * film.mesh.cell_volume
    rng = np.random.default_rng(5)
    for _ in range(5):
        index = tuple(int(rng.integers(n)) for n in (3,) + film.mesh.shape)
        expected = field_by_finite_difference(lambda mm, b: INDEPENDENT[term](film, mm), m, index, moment, B_EXT)
        assert B[index] == pytest.approx(expected, rel=1e-6, abs=1e-9)
        assert 2 * B[index] != pytest.approx(expected, rel=1e-6, abs=1e-9) or abs(expected) < 1e-9


@pytest.mark.parametrize("n_alias", [20, pytest.param(80, marks=pytest.mark.slow)])  # 80: 5–16 s kernels
@pytest.mark.parametrize("axis", ["x", "y"])
@pytest.mark.parametrize("nz", [1, 2])
def test_demag_energy_from_magnetic_charges(axis, nz, n_alias):
    """Demag energy of smooth states varying along x or along y (dx ≠ dy), one or two layers.

    The engine truncates its alias sum at ±n_alias (its default 20); the remaining difference
    (measured 2e-7 along x, 5e-6 along y at 20) falls as n_alias⁻², so the tolerance is
    1e-5·(20/n_alias)²."""
    nx, ny = (24, 3) if axis == "x" else (3, 24)
    mesh = Mesh(nx, ny, nz, 2e-9, 3e-9, 2.5e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, terms=("demag",), n_alias=n_alias)
    m = smooth_state(mesh, np.random.default_rng(3 + nz), axes=axis, modes=3)
    code = film.energy(m)
    independent = demag_energy_1d(film, m, axis)
    print(f"demag {axis} nz={nz} n_alias={n_alias}: code {code:.8e} J, independent {independent:.8e} J, "
          f"rel {code / independent - 1:+.1e}")
    tolerance = 1e-5 * (20 / n_alias) ** 2
    assert agree(code, independent, tolerance)
    assert not agree(2 * code, independent, tolerance)
    if nz == 2:  # the odd cross-layer coupling N_xz matters: flipping its sign breaks the agreement
        assert not agree(code, demag_energy_1d(film, m, axis, flip_cross_sign=True), 1e-3)
    # the charge-free part alone would be far off: the state has real volume and surface charges
    uniform_only = 0.5 * MU0 * MS**2 * mesh.cell_volume * mesh.n_cells * np.mean(m[2]) ** 2
    assert not agree(uniform_only, independent, 1e-2)


@pytest.mark.parametrize("nz", [1, 2])
def test_demag_energy_of_uniform_tilted_film(nz):
    """A uniform film at angle α from the normal: E = (μ0 M_s²/2) V cos²α (N_zz = 1, in-plane 0)."""
    mesh = Mesh(8, 6, nz, 2e-9, 3e-9, 2.5e-9)
    film = Film(mesh, Ms=MS, A_ex=0.0, terms=("demag",))
    alpha = 0.7
    m = film.uniform((np.sin(alpha) * 0.6, np.sin(alpha) * 0.8, np.cos(alpha)))
    expected = 0.5 * MU0 * MS**2 * mesh.cell_volume * mesh.n_cells * np.cos(alpha) ** 2
    assert film.energy(m) == pytest.approx(expected, rel=1e-12)
