"""Analytic FORC reference: a non-interacting Stoner–Wohlfarth ensemble through the protocol code.

Every cell of a film with exchange, DMI and demag off is an independent Stoner–Wohlfarth particle
(anisotropy + Zeeman only): its own K_u and an easy axis u tilted by ψ from z (field along z). Its
energy density in the plane of u and z is e(θ) = K sin²(θ − ψ) − M_s B cos θ. The branch near +u
exists for B > −B_sw and the one near −u for B < +B_sw, with the astroid field
B_sw = (2K/M_s)/(cos^{2/3}ψ + sin^{2/3}ψ)^{3/2}. So the whole FORC family is known: on the curve
reversed at H_r a particle sits on the −u branch iff H_r < −B_sw and H < +B_sw, else on the +u
branch, and its m_z = cos θ is the minimum of e on that branch (a 1D root of ∂e/∂θ, to 1e-14).
The switching fields are placed half-way between grid fields, so no grid field is near a
critical point; the tilts span 3°–60° (both sides of 45°, where the astroid changes character).

Tolerance: the minimizer stops when every cell's torque |m × B_eff| < τ (tesla); on a branch with
stiffness κ = ∂²e/∂θ²/M_s (tesla) that leaves an angle error ≤ τ/κ, hence |Δm_z| ≤ τ/κ per cell.
The test derives the bound τ/κ_min from the expected states and asserts every FORC point of
⟨m_z⟩ within it. One particle on the wrong branch would move ⟨m_z⟩ by ~2 cos θ/64 ≳ 0.01.
"""

import numpy as np
import pytest
from scipy.optimize import brentq

from forcdecode.forc.protocol import quasistatic_family
from forcdecode.micromag import Film, Mesh

MS = 1.0e6  # A/m
N_FIELDS, B_MAX_T = 20, 1.0
TORQUE_TOL_T = 1e-4
NX, NY = 8, 8


def astroid_switching_field_T(K, psi):
    """Stoner–Wohlfarth switching field (T) for anisotropy K (J/m³) and field-to-axis angle ψ."""
    return (2 * K / MS) / (np.cos(psi) ** (2 / 3) + np.sin(psi) ** (2 / 3)) ** 1.5


def branch_state(B, K, psi, up):
    """(m_z, stiffness κ in T) of the equilibrium in the well centred on ψ (up) or ψ + π (down).

    The minimum is the zero of ∂e/∂θ = K sin 2(θ − ψ) + M_s B sin θ where it changes sign from − to +
    within ±π/2 of the well's centre, bracketed on a fine grid and refined with Brent's method."""
    centre = psi if up else psi + np.pi
    slope = lambda t: K * np.sin(2 * (t - psi)) + MS * B * np.sin(t)
    grid = centre + np.linspace(-np.pi / 2, np.pi / 2, 4001)[1:-1]
    s = slope(grid)
    rising = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
    assert len(rising) == 1, "the branch is absent (or not unique) at this field"
    theta = brentq(slope, grid[rising[0]], grid[rising[0] + 1], xtol=1e-14)
    kappa = (2 * K * np.cos(2 * (theta - psi)) + MS * B * np.cos(theta)) / MS
    assert kappa > 0
    return np.cos(theta), kappa


@pytest.fixture(scope="module")
def ensemble():
    """64 particles: switching fields at the grid's mid-points 0.11–0.84 T, tilts 3°–60°, random azimuths."""
    rng = np.random.default_rng(20240613)
    fields = np.linspace(-B_MAX_T, B_MAX_T, N_FIELDS)
    mids = 0.5 * (fields[1:] + fields[:-1])
    mids = mids[(mids > 0.05) & (mids < 0.9)]
    n = NX * NY
    psi = np.radians(np.linspace(3.0, 60.0, n))
    rng.shuffle(psi)
    B_sw = rng.permutation(np.resize(mids, n))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    K = 0.5 * MS * B_sw * (np.cos(psi) ** (2 / 3) + np.sin(psi) ** (2 / 3)) ** 1.5
    assert np.allclose(astroid_switching_field_T(K, psi), B_sw, rtol=1e-12)
    axis = np.stack([np.sin(psi) * np.cos(phi), np.sin(psi) * np.sin(phi), np.cos(psi)]).reshape(3, 1, NY, NX)
    film = Film(Mesh(NX, NY, 1, 2e-9, 2e-9, 2e-9), Ms=MS, A_ex=0.0, K_u=K.reshape(1, NY, NX), easy_axis=axis,
                terms=("anisotropy", "zeeman"))
    return film, K, psi, B_sw, fields


def closed_form_family(K, psi, B_sw, fields):
    """⟨m_z⟩(H_r, H) of the ensemble (NaN below the diagonal) and the least stiffness κ_min (T) visited.

    ``B_sw`` are the particles' switching thresholds (the astroid fields, or deliberately wrong ones)."""
    n, cells = len(fields), range(len(K))
    mz = {}  # (branch, field index) -> m_z per particle, computed where the branch is visited
    kappa_min = np.inf
    curves = np.full((n, n), np.nan)
    for i, H_r in enumerate(fields):
        for j in range(i, n):
            up = (H_r > -B_sw) | (fields[j] > B_sw)
            values = []
            for c in cells:
                key = (bool(up[c]), j, c)
                if key not in mz:
                    mz[key] = branch_state(fields[j], K[c], psi[c], up[c])
                    kappa_min = min(kappa_min, mz[key][1])
                values.append(mz[key][0])
            curves[i, j] = np.mean(values)
    return curves, kappa_min


@pytest.fixture(scope="module")
def expected_family(ensemble):
    """Closed-form family and its error bound τ/κ_min."""
    _, K, psi, B_sw, fields = ensemble
    curves, kappa_min = closed_form_family(K, psi, B_sw, fields)
    return curves, TORQUE_TOL_T / kappa_min


@pytest.mark.parametrize("same_state_tol", [0.02, 0.0], ids=["shortcut", "no-shortcut"])
def test_protocol_reproduces_stoner_wohlfarth_family(ensemble, expected_family, same_state_tol):
    film, _, _, _, fields = ensemble
    expected, bound = expected_family
    family = quasistatic_family(film, film.uniform(), n_fields=N_FIELDS, B_max_T=B_MAX_T,
                                torque_tol_T=TORQUE_TOL_T, same_state_tol=same_state_tol)
    error = np.abs(family.curves_mz - expected)
    print(f"same_state_tol={same_state_tol}: max |Δ⟨m_z⟩| = {np.nanmax(error):.2e}, "
          f"mean {np.nanmean(error):.2e}, bound τ/κ_min = {bound:.2e}, stats {family.stats}")
    assert family.stats["unconverged"] == 0
    assert np.array_equal(np.isnan(family.curves_mz), np.isnan(expected))
    assert bound < 5e-3  # far below one misplaced particle (≳ 1e-2)
    assert np.nanmax(error) <= bound
    assert np.allclose(family.descending_mz, np.diag(expected), rtol=0, atol=bound)
    # the family is really hysteretic: the major loop spans most of [−1, 1] and FORCs leave it
    assert expected[0, 0] < -0.6 and expected[-1, -1] > 0.9
    assert np.nanmax(np.abs(expected - np.diag(expected)[None, :])) > 0.5
    if same_state_tol > 0:
        assert family.stats["curves_shortened"] > 0  # the copy shortcut was exercised


def test_reference_would_catch_one_misplaced_switching_field(ensemble, expected_family):
    """Lowering one particle's switching field by one grid step changes the family by far more than the bound."""
    _, K, psi, B_sw, fields = ensemble
    expected, bound = expected_family
    shifted = B_sw.copy()
    c = int(np.argmax(B_sw))
    shifted[c] -= fields[1] - fields[0]
    wrong, _ = closed_form_family(K, psi, shifted, fields)
    assert np.nanmax(np.abs(wrong - expected)) > 10 * bound
