"""The continuation shortcuts of the quasi-static protocol (``forc.protocol.Continuation``) and the
Fourier preconditioner (``micromag.minimize.minimize_bb_fourier``) against the plain minimizer.

Shortcuts: ``warm_step`` (first BB step = the previous relaxation's last) and ``extrapolate``
(start from the previous state advanced by the last reversible linear response). Reference: the
same film, same protocol and remainder-copy shortcut, without them. Both only change where the
minimizer starts, so on reversible parts the same minimum is reached to the torque criterion, and
only avalanche end states may move. Stated bounds (one 8-bit step = 1/127.5): image mean |Δ| ≤ one
step, curves mean |Δ⟨m_z⟩| ≤ 0.005, or 1.25× the film's own sensitivity where that is larger: the same
plain protocol started from m0 moved by 1e-6 (two draws). Film B is chaotic at that level on an
AVX-512 machine (fastmath sums in another order): the 1e-6 start moves its image by 1.38 steps, the
shortcuts by 1.38 (film A: 0.016 and 0.020 steps). Films: the two laptop-draw Hamiltonians of
``test_protocol_shortcut`` on 32×32×1 cells, 32 fields. They are NOT always faster, which is why
the config leaves them off: measured iterations on an AVX2 machine (plain / warm / extrapolate / both) film A 14688 /
13930 / 7942 / 14385, film B (K_u = 5e4 J/m³, soft) 9283 / 20326 / 86248 / 18008 (soft modes take
long BB steps and predicted starts that cross barriers); the 64² benchmark film 147740 / 121045 /
137773 / 142457.
"""

import numpy as np
import pytest

from forcdecode.forc.protocol import quasistatic_family
from forcdecode.forc.raster import rasterize_grid_family
from forcdecode.micromag import FilmMaterial, Mesh, disordered_film
from forcdecode.micromag.minimize import fourier_preconditioner, minimize_bb, minimize_bb_fourier

from test_protocol_shortcut import make_film

STEP = 1 / 127.5


@pytest.mark.parametrize("name", ["A", "B"])
def test_continuation_matches_plain_family(name):
    film, m0 = make_film(name, 32)
    plain = quasistatic_family(film, m0, n_fields=32)
    fast = quasistatic_family(film, m0, n_fields=32, warm_step=True, extrapolate=True)
    image = np.abs(rasterize_grid_family(fast.curves_mz).astype(int)
                   - rasterize_grid_family(plain.curves_mz).astype(int)) * STEP
    curves = np.abs(fast.curves_mz - plain.curves_mz)
    print(f"film {name}: iterations {fast.stats['iterations']} vs {plain.stats['iterations']}, predicted "
          f"{fast.stats.get('predicted', 0)}; image mean {image.mean() / STEP:.3f} steps, max {image.max() / STEP:.0f}; "
          f"curves mean {np.nanmean(curves):.2e}, max {np.nanmax(curves):.2e}")
    assert fast.stats["unconverged"] == plain.stats["unconverged"] == 0
    assert fast.stats.get("predicted", 0) > 0
    floor_image, floor_curves = 0.0, 0.0
    for seed in (0, 1):  # the film's own sensitivity: the plain protocol from a start moved by 1e-6
        nudged = m0 + 1e-6 * np.random.default_rng(seed).standard_normal(m0.shape)
        nudged /= np.linalg.norm(nudged, axis=0, keepdims=True)
        other = quasistatic_family(film, nudged, n_fields=32)
        floor_image = max(floor_image, np.abs(rasterize_grid_family(other.curves_mz).astype(int)
                                              - rasterize_grid_family(plain.curves_mz).astype(int)).mean() * STEP)
        floor_curves = max(floor_curves, float(np.nanmean(np.abs(other.curves_mz - plain.curves_mz))))
    print(f"  the film's own sensitivity: image mean {floor_image / STEP:.3f} steps, curves mean {floor_curves:.2e}")
    assert image.mean() <= max(STEP, 1.25 * floor_image)
    assert np.nanmean(curves) <= max(0.005, 1.25 * floor_curves)


def _uniform_film(n=32, A_ex=1.5e-11):
    mesh = Mesh(n, n, 1, 2e-9, 2e-9, 4e-9)
    material = FilmMaterial(Ms=6e5, A_ex=A_ex, K_u=6e5, D=0.0, sigma_K=0.2, sigma_theta_rad=np.radians(10.0), n_pin=0)
    film, m0, _ = disordered_film(mesh, material, np.random.default_rng(3), n_grains=16)
    return film, m0


def test_extrapolation_predicts_the_reversible_branch():
    """A film far from switching (B from +1 T down to +0.2 T, K_u = 6e5 J/m³): every step is
    reversible, so after the first each relaxation starts from the linear-response prediction, the
    states equal the plain ones to the torque criterion and the iterations drop."""
    from forcdecode.forc.protocol import descending_branch

    film, m0 = _uniform_film()
    fields = np.linspace(0.2, 1.0, 17)
    plain = {"iterations": 0, "relaxations": 0, "unconverged": 0}
    fast = {"iterations": 0, "relaxations": 0, "unconverged": 0}
    d_plain, _, m_plain = descending_branch(film, m0, fields, torque_tol_T=1e-5, stats=plain)
    d_fast, _, m_fast = descending_branch(film, m0, fields, torque_tol_T=1e-5, stats=fast, extrapolate=True,
                                          warm_step=True)
    print(plain, fast)
    assert fast["predicted"] == len(fields) - 2
    assert np.abs(d_fast - d_plain).max() < 1e-5
    assert np.abs(m_fast - m_plain).max() < 1e-3
    assert fast["iterations"] < 0.8 * plain["iterations"]


def test_fourier_preconditioner_reaches_the_same_minimum_in_fewer_iterations():
    """From the same start (the relaxed state at +0.5 T, field stepped to +0.3 T) the Fourier-
    preconditioned minimizer reaches the plain minimizer's minimum (max cell |Δm| < 1e-3 at a torque
    criterion of 1e-5 T) with fewer iterations: the exchange stiffness (2A/M_s)·8/dx² = 100 T at
    A = 1.5e-11 J/m no longer limits the step."""
    film, m0 = _uniform_film()
    m = m0.copy()
    film.minimize(m, 0.5, torque_tol_T=1e-6)
    a, b = m.copy(), m.copy()
    B = np.array([0.0, 0.0, 0.3])
    it_plain, torque_plain, ok_plain, _ = minimize_bb(a, film.model, B, 1e-5, 20_000, 0.5, 0.0)
    it_f, torque_f, ok_f, _ = minimize_bb_fourier(b, film.model, B, 1e-5, 20_000, 0.5, 0.0,
                                                  fourier_preconditioner(film.model, 3.0))
    print(f"plain {it_plain} iterations, fourier {it_f}; max |dm| {np.abs(a - b).max():.2e}")
    assert ok_plain and ok_f and torque_f < 1e-5
    assert np.abs(a - b).max() < 1e-3
    assert it_f < it_plain
