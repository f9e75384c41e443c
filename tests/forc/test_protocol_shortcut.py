"""The protocol's remainder-copy shortcut (``same_state_tol``) against the family computed without it.

A FORC that reaches a state within ``same_state_tol`` (max cell |Δm|) of the descending state at the
same field is ended there and the rest copied from the FORC that reverses at that field; with
``merge_curves`` (the default since 2026-11-25) also where it meets the state of any FORC computed
before it at that field (``StateMemory``). The
reference is the same film, the same protocol and minimizer settings with ``same_state_tol = 0``
(the comparison is strict, so nothing is copied). Compared: the 8-bit images (mean and max |Δ|, in
units of m: one step is 1/127.5 = 0.0078) and the ⟨m_z⟩ curves.

Stated bounds: image mean ≤ one step and max ≤ two steps; curves mean |Δ⟨m_z⟩| ≤ 0.002 and max
≤ same_state_tol = 0.02. (At the copy point |Δ⟨m_z⟩| ≤ max cell |Δm| < same_state_tol exactly; the
max bound says the copied and the computed continuations do not drift apart beyond that.)

Films: two Hamiltonians of the laptop config's draws (Table I ranges; draws 12 and 38 of seed
20261122) with hysteretic FORCs, on 32×32×1 cells of 2×2×4 nm, 32 fields, the laptop minimizer
settings (torque 1e-3 T). Measured on main (shared 2-core machine): film A curves max 1.07e-2, mean
8.2e-5, image max 1 step, mean 7e-5, 91 vs 529 relaxations; film B curves max 9e-5, mean 4e-6, image
max 1 step, mean 4e-5, 371 vs 529 relaxations. The laptop-size check (64×64×1, 64 fields, film B,
~3 min) is marked slow; measured there: curves max 1.9e-4, mean 3e-6, image identical, 1569 vs 2081
relaxations but only 130k vs 154k minimizer iterations (the copied remainders are the cheap
near-saturation ends of the curves).
"""

import numpy as np
import pytest

from forcdecode.forc.protocol import StateMemory, quasistatic_family
from forcdecode.forc.raster import rasterize_grid_family
from forcdecode.micromag import FilmMaterial, Mesh, disordered_film

STEP = 1 / 127.5  # one 8-bit image step in units of m_z
TORQUE_TOL_T, MAX_ITERATIONS = 1e-3, 20_000

# Hamiltonians of draws 12 and 38 of the laptop config (seed 20261122), SI; N_pin on the paper's grid;
# ``seed`` seeds the disorder
FILMS = {
    "A": dict(Ms=325977.0728753011, A_ex=4.980156845738431e-12, K_u=226425.72399142437, D=0.00190167385340575,
              N_pin=181, sigma_theta_deg=8.030540055934152, sigma_K=0.17891258973389826, seed=12),
    "B": dict(Ms=333219.6771602256, A_ex=5.711707437716016e-12, K_u=52104.14124484683, D=0.004103021464072883,
              N_pin=2, sigma_theta_deg=8.010723676273129, sigma_K=0.1733063548789731, seed=38),
}
SAME_STATE_TOL = 0.02


def make_film(name, n):
    p = FILMS[name]
    mesh = Mesh(n, n, 1, 2e-9, 2e-9, 4e-9)
    n_pin = int(round(p["N_pin"] * mesh.n_cells / (256 * 256 * 2)))  # the paper's density
    material = FilmMaterial(Ms=p["Ms"], A_ex=p["A_ex"], K_u=p["K_u"], D=p["D"], sigma_K=p["sigma_K"],
                            sigma_theta_rad=np.radians(p["sigma_theta_deg"]), n_pin=n_pin)
    film, m0, _ = disordered_film(mesh, material, np.random.default_rng(p["seed"]), n_grains=255)
    return film, m0


def compare(film, m0, n_fields, merge_curves=False):
    """(families with and without the shortcut, image |Δ| in units of m, curve |Δ⟨m_z⟩|)."""
    families = [quasistatic_family(film, m0, n_fields=n_fields, B_max_T=1.0, torque_tol_T=TORQUE_TOL_T,
                                   max_iterations=MAX_ITERATIONS, same_state_tol=tol, merge_curves=merge_curves)
                for tol in (SAME_STATE_TOL, 0.0)]
    shortcut, reference = families
    image_delta = np.abs(rasterize_grid_family(shortcut.curves_mz).astype(int)
                         - rasterize_grid_family(reference.curves_mz).astype(int)) * STEP
    curve_delta = np.abs(shortcut.curves_mz - reference.curves_mz)
    return shortcut, reference, image_delta, curve_delta


def check(shortcut, reference, image_delta, curve_delta, label):
    print(f"{label}: image max {image_delta.max() / STEP:.0f} step(s), mean {image_delta.mean():.2e}; "
          f"curves max {np.nanmax(curve_delta):.2e}, mean {np.nanmean(curve_delta):.2e}; relaxations "
          f"{shortcut.stats['relaxations']} vs {reference.stats['relaxations']}, "
          f"wall {shortcut.stats['wall_s']:.1f} s vs {reference.stats['wall_s']:.1f} s")
    assert shortcut.stats["unconverged"] == reference.stats["unconverged"] == 0
    assert reference.stats["curves_shortened"] == 0
    assert shortcut.stats["curves_shortened"] > 0
    # each shortened curve saves at least one relaxation, and the family at least a tenth (film B: 371 of
    # 529 on one machine, 451 on an AVX-512 one after the demag kernel's round-off changed, 2026-12-03)
    assert shortcut.stats["relaxations"] <= reference.stats["relaxations"] - shortcut.stats["curves_shortened"]
    assert shortcut.stats["relaxations"] < 0.9 * reference.stats["relaxations"]
    # the film has hysteresis: FORCs leave the descending branch by far more than the bounds
    spread = np.nanmax(np.abs(reference.curves_mz - reference.descending_mz[None, :]))
    print(f"{label}: largest FORC − descending-branch difference {spread:.2f}")
    assert spread > 0.5
    assert np.array_equal(shortcut.descending_mz, reference.descending_mz)
    assert np.array_equal(np.isnan(shortcut.curves_mz), np.isnan(reference.curves_mz))
    assert image_delta.mean() <= STEP
    assert image_delta.max() <= 2 * STEP
    assert np.nanmax(curve_delta) <= SAME_STATE_TOL
    assert np.nanmean(curve_delta) <= 0.002


@pytest.mark.parametrize("merge_curves", [False, True], ids=["descending-copy", "merge-curves"])
@pytest.mark.parametrize("name", ["A", "B"])
def test_shortcut_matches_reference_family(name, merge_curves):
    film, m0 = make_film(name, 32)
    check(*compare(film, m0, 32, merge_curves), f"film {name}, 32x32x1, 32 fields, merge_curves={merge_curves}")


def test_merging_saves_relaxations_where_curves_meet():
    """Film B's FORCs meet each other before they meet the descending branch: merging ends them there,
    each merged curve saves at least one relaxation, and the family stays the unmerged one (mean |Δm_z|
    ≤ 1e-3). Measured relaxations (unmerged → merged): 324 → 261 with 6 curves merged on an AVX-512
    machine, below 0.7× on an AVX2 one; 4 curves merged on a CI machine without AVX-512 (2026-12-02): film
    B's avalanches depend on the summation order, so the count is held to ≥ 3, the saving to its bound."""
    film, m0 = make_film("B", 32)
    kwargs = dict(n_fields=32, torque_tol_T=TORQUE_TOL_T, max_iterations=MAX_ITERATIONS)
    alone = quasistatic_family(film, m0, merge_curves=False, **kwargs)
    merged = quasistatic_family(film, m0, merge_curves=True, **kwargs)
    assert alone.stats["curves_merged"] == 0
    assert merged.stats["curves_merged"] >= 3
    assert merged.stats["relaxations"] <= alone.stats["relaxations"] - merged.stats["curves_merged"]
    assert merged.stats["relaxations"] < 0.9 * alone.stats["relaxations"]
    assert np.isnan(merged.curves_mz).sum() == np.isnan(alone.curves_mz).sum()
    assert np.nanmean(np.abs(merged.curves_mz - alone.curves_mz)) <= 1e-3
    # the memory budget bounds what is compared with: none at all behaves as the descending copy alone
    starved = quasistatic_family(film, m0, merge_curves=True, merge_memory_MB=0.0, **kwargs)
    assert starved.stats["curves_merged"] == 0
    assert np.array_equal(starved.curves_mz, alone.curves_mz, equal_nan=True)


def test_state_memory_finds_within_tolerance_and_forgets_farthest_curves_first():
    rng = np.random.default_rng(0)
    shape = (3, 1, 4, 4)
    unit = lambda v: v / np.linalg.norm(v, axis=0)  # noqa: E731
    states = {i: unit(rng.normal(size=shape)) for i in range(5)}
    one_state = states[0].astype(np.float32).nbytes
    memory = StateMemory(budget_bytes=3 * one_state)
    for i in (4, 3, 2, 1):  # curves come from the highest reversal index down
        memory.add(7, i, states[i])
    assert memory.nbytes == 3 * one_state  # curve 4, the farthest, was forgotten for curve 1
    assert memory.find((7,), states[4], 0.02) is None
    near = states[2].copy()
    near[0, 0, 1, 1] += 0.015  # one cell 0.015 away, the rest equal
    assert memory.find((7,), near, 0.02) == 2
    assert memory.find((7,), near, 0.02, accept=lambda curve: curve != 2) is None
    near[0, 0, 1, 1] += 0.01  # 0.025 away: not the same state
    assert memory.find((7,), near, 0.02) is None
    assert memory.find((6,), states[2], 0.02) is None  # states are compared at the same field only


@pytest.mark.slow
@pytest.mark.parametrize("merge_curves", [False, True], ids=["descending-copy", "merge-curves"])
def test_shortcut_matches_reference_family_laptop_size(merge_curves):
    film, m0 = make_film("B", 64)
    check(*compare(film, m0, 64, merge_curves), f"film B, 64x64x1, 64 fields, merge_curves={merge_curves}")


@pytest.mark.slow
def test_merging_matches_reference_on_the_avalanche_benchmark_film():
    """The benchmark film of ``forcdecode bench engine`` (K_u = 8e5 J/m³, avalanches on every
    branch), 64×64×1, 64 fields: measured 357 vs 2081 relaxations, image 0.004 levels mean (max 9).

    Here the max bounds of ``check`` do not hold and are not asked: at an avalanche's bifurcation a
    state difference below ``same_state_tol`` (or a change of rounding) can decide which way the
    avalanche goes, so one pixel column may differ by several steps. Asked: the mean (the issue's
    criterion), and that such pixels are rare."""
    from forcdecode.bench.engine import _film

    film, m0, _ = _film("64")
    shortcut, reference, image_delta, curve_delta = compare(film, m0, 64, merge_curves=True)
    print(f"benchmark film: image mean {image_delta.mean() / STEP:.4f} steps, max {image_delta.max() / STEP:.0f}; "
          f"curves mean {np.nanmean(curve_delta):.2e}; relaxations {shortcut.stats['relaxations']} vs "
          f"{reference.stats['relaxations']}, {shortcut.stats['curves_merged']} merges")
    assert shortcut.stats["curves_merged"] >= 10
    assert shortcut.stats["relaxations"] < 0.3 * reference.stats["relaxations"]
    assert image_delta.mean() <= STEP
    assert np.mean(image_delta > 2 * STEP) <= 0.002  # at most ~8 of 4096 pixels beyond two steps
    assert np.nanmean(curve_delta) <= 0.002
