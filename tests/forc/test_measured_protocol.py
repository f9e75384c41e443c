"""The measured protocol (forc.measured_protocol): the file's own reversal fields and field points,
against ``quasistatic_family`` on the grid protocol (same numbers) and the Stoner–Wohlfarth astroid
for a single-domain film with the field tilted from the normal."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from forcdecode.core.streams import stream_rng
from forcdecode.forc.measured_protocol import (field_direction, grid_protocol, measured_protocol_family,
                                               protocol_to_grid)
from forcdecode.forc.protocol import quasistatic_family
from forcdecode.micromag.build import build_film
from forcdecode.micromag.film import Film
from forcdecode.micromag.mesh import Mesh

ROOT = Path(__file__).resolve().parents[2]
MU0 = 4e-7 * np.pi
# a granular film that switches inside ±1 T (B_K,eff = 2K/M_s − μ0M_s ≈ 0.31 T)
PARAMS = {"Ms": 6e5, "A_ex": 2e-12, "K_u": 4e5, "D": 1e-3, "N_pin": 1, "sigma_theta_deg": 15.0, "sigma_K": 0.3}


@pytest.fixture(scope="module")
def film():
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["n_grains"] = 32
    return cfg, build_film(cfg, PARAMS, rng=stream_rng(cfg["seed"], "bench_film", "measured_protocol", 0))


def test_grid_protocol_gives_the_numbers_of_quasistatic_family(film):
    cfg, (f, m0, _) = film
    tol, it = cfg["minimizer"]["torque_tol_T"], cfg["minimizer"]["max_iterations"]
    reference = quasistatic_family(f, m0, n_fields=16, B_max_T=1.0, torque_tol_T=tol, max_iterations=it)
    reversal, fields = grid_protocol(16, 1.0)
    ours = measured_protocol_family(f, m0, reversal, fields, torque_tol_T=tol, max_iterations=it)
    np.testing.assert_array_equal(protocol_to_grid(ours, 16), reference.curves_mz)
    np.testing.assert_array_equal(ours.descending[::-1], reference.descending_mz)
    assert ours.stats["curves_shortened"] == reference.stats["curves_shortened"] > 0
    # the family switches (not a trivially saturated one): the descending branch crosses zero
    assert reference.descending_mz[0] < -0.9 and reference.descending_mz[-1] > 0.9


def test_an_irregular_measured_protocol_in_file_order(film):
    """Curves in file order (not sorted) with their own irregular fields: the reversal point is the
    descending branch there, and a curve on the grid fields is the grid family's curve exactly (same
    descending path; without the shared-work shortcut, which copies from irregular neighbours)."""
    cfg, (f, m0, _) = film
    tol, it = cfg["minimizer"]["torque_tol_T"], cfg["minimizer"]["max_iterations"]
    grid = np.linspace(-1, 1, 16)
    rng = np.random.default_rng(0)
    order = rng.permutation(16)
    reversal = grid[order]
    fields = [grid[k:] if k % 2 == 0 else np.sort(np.append(rng.uniform(grid[k], 1.0, 7), [grid[k], 1.0]))
              for k in order]
    family = measured_protocol_family(f, m0, reversal, fields, torque_tol_T=tol, max_iterations=it,
                                      same_state_tol=0.0)
    reference = quasistatic_family(f, m0, n_fields=16, B_max_T=1.0, torque_tol_T=tol, max_iterations=it,
                                   same_state_tol=0.0)
    for position, k in enumerate(order):
        assert family.curves[position][0] == reference.descending_mz[k]
        assert family.curves[position].shape == fields[position].shape
        if k % 2 == 0:
            np.testing.assert_array_equal(family.curves[position], reference.curves_mz[k, k:])
    irregular = [family.curves[p] for p, k in enumerate(order) if k % 2 == 1]
    assert all(np.all(np.isfinite(c)) and c[-1] > 0.9 for c in irregular)


@pytest.mark.parametrize("psi_deg", [5.0, 20.0, 40.0])
def test_tilted_field_switches_a_single_domain_film_at_the_astroid(psi_deg):
    """Uniform 2×2×1 film (exchange, K_u, demag, Zeeman): B_K,eff = 2K_u/M_s − μ0M_s and
    B_sw(ψ) = B_K,eff/(cos^{2/3}ψ + sin^{2/3}ψ)^{3/2}; descending branch and the FORC reversed after
    switching, both sampled every 2 mT, jump within one step of it. Recorded: ⟨m⟩·ĥ."""
    Ms, K = 8e5, 1e6
    film = Film(Mesh(2, 2, 1, 2e-9, 2e-9, 2e-9), Ms, 1e-11, K, terms=("exchange", "anisotropy", "demag", "zeeman"))
    B_K = 2 * K / Ms - MU0 * Ms
    psi = np.radians(psi_deg)
    astroid = B_K / (np.cos(psi) ** (2 / 3) + np.sin(psi) ** (2 / 3)) ** 1.5
    H = np.round(np.arange(1.6, -1.6, -0.002), 6)
    reversal = np.concatenate([H, [-1.6]])
    fields = [[h] for h in H] + [np.round(np.arange(-1.6, 1.6, 0.002), 6)]
    family = measured_protocol_family(film, film.uniform(), reversal, fields, direction=field_direction(psi_deg),
                                      torque_tol_T=1e-6, max_iterations=200_000)
    d, levels = family.descending, family.descending_fields_T
    jump = int(np.argmax(np.abs(np.diff(d))))
    assert levels[jump] >= -astroid >= levels[jump + 1] - 1e-9
    assert d[jump] - d[jump + 1] > 0.4  # a real jump (smaller at larger angles: part is rotation)
    curve, up = family.curves[-1], fields[-1]
    k = int(np.argmax(np.abs(np.diff(curve))))
    assert up[k] <= astroid <= up[k + 1] + 1e-9
    # nearly saturated along the field at 1.6 T (measured 0.95 at 40°)
    assert curve[-1] > 0.9 and d[0] > 0.9


@pytest.fixture(scope="module")
def avalanche_film():
    """A 32-grain film without pinning whose ascending branch from saturation runs through a plateau
    and an avalanche near +0.6 T: the minimizer's numerical noise can choose between its branches."""
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["n_grains"] = 32
    params = dict(PARAMS, N_pin=0)
    f, m0, _ = build_film(cfg, params, rng=stream_rng(cfg["seed"], "closed_loop_disorder", "measured", 0))
    return f, m0, 1e-3, cfg["minimizer"]["max_iterations"]


def _sweep(film, reversal, fields, **kw):
    f, m0, tol, it = film
    return measured_protocol_family(f, m0, reversal, fields, torque_tol_T=tol, max_iterations=it, max_step_T=0.005, **kw)


def test_where_the_instrument_takes_its_points_does_not_change_the_sweep(avalanche_film):
    """The same reversal fields measured on two sets of points that share half of them: at the shared
    points the two families agree exactly (the sweep's path lies on its own field lattice; a point is a
    snapshot), with and without joining paths. Stepping through the points themselves, as without
    ``max_step_T``, the path would depend on them."""
    rng = np.random.default_rng(3)
    reversal = np.array([-0.8, -0.77, -0.72, -0.5, -0.3, 0.1])
    shared = [np.append(np.sort(rng.uniform(h, 0.8, 12)), 0.8) for h in reversal]  # both saturate at 0.8 T
    a = [np.concatenate([[h], np.sort(np.concatenate([s, rng.uniform(h, 0.8, 12)]))]) for h, s in zip(reversal, shared)]
    b = [np.concatenate([[h], np.sort(np.concatenate([s, rng.uniform(h, 0.8, 5)]))]) for h, s in zip(reversal, shared)]
    for merge in (True, False):
        fa, fb = _sweep(avalanche_film, reversal, a, merge_curves=merge), _sweep(avalanche_film, reversal, b, merge_curves=merge)
        for k, s in enumerate(shared):
            va, vb = fa.curves[k][np.isin(a[k], s)], fb.curves[k][np.isin(b[k], s)]
            np.testing.assert_array_equal(va, vb)
        np.testing.assert_array_equal(fa.descending, fb.descending)


def test_curves_reversed_from_saturation_follow_one_path(avalanche_film):
    """Curves reversed anywhere in negative saturation, each measured on its own points (60 fields
    moved by k·0.1 µT for curve k, so no two curves share a field, and 40 points of its own between
    them), are one ascending branch: their values agree within 0.01 of the loop (the slope over 0.5 µT is far below that). Measured
    before the sweep's paths could be joined (each curve stepped through its own points; curves met
    only at equal fields): they parted by up to 0.4 of the half-loop height in the avalanche."""
    rng = np.random.default_rng(5)
    reversal = np.array([-0.8, -0.785, -0.77, -0.75, -0.728, -0.71])
    common = np.sort(rng.uniform(-0.6, 0.8, 60))
    fields = [np.concatenate([[h], np.sort(np.concatenate([common + 1e-7 * k, rng.uniform(-0.6, 0.8, 40)]))])
              for k, h in enumerate(reversal)]
    family = _sweep(avalanche_film, reversal, fields)
    assert np.all(family.descending < -0.95)  # every reversal field saturates the film
    values = np.array([c[np.isin(f, common + 1e-7 * k)] for k, (c, f) in enumerate(zip(family.curves, fields))])
    assert np.abs(values - values[0]).max() < 0.01
    assert family.stats["curves_merged"] >= reversal.size - 1
    # the branch has an avalanche to decide (a jump of more than 0.2 between neighbouring points)
    assert np.abs(np.diff(values[0])).max() > 0.2


def test_path_memory_follows_joined_paths_and_forgets_the_oldest_sweep():
    """A path that joined another has that path's states from the join on; a full memory drops the
    sweep filed first, and a path that joined it then has no state there (it is relaxed again)."""
    from forcdecode.forc.measured_protocol import PathMemory

    state = [np.full((3, 1, 2, 2), v, dtype=np.float32) for v in (0.1, 0.2, 0.3, 0.4)]
    memory = PathMemory(budget_bytes=3 * state[0].nbytes)
    memory.add(1, 0, 0, state[0])
    memory.add(1, 1, 0, state[1])
    assert memory.find(1, 1, state[1] + 0.005, tol=0.02) == 0
    assert memory.find(1, 1, state[1] + 0.05, tol=0.02) is None
    assert memory.find(-1, 1, state[1], tol=0.02) is None  # the other direction is another path
    memory.follow(1, 1, 7, 0)  # sweep 7 joined sweep 0 at node 1
    np.testing.assert_array_equal(memory.get(1, 1, 7), state[1])
    assert memory.owner(1, 1, 7) == 0 and memory.get(1, 2, 7) is None
    memory.add(1, 2, 5, state[2])
    memory.add(1, 3, 5, state[3])  # over budget: sweep 0, filed first, is forgotten
    assert memory.get(1, 1, 7) is None and memory.find(1, 1, state[1], tol=0.02) is None
    np.testing.assert_array_equal(memory.get(1, 3, 5), state[3])
    assert memory.nbytes == 2 * state[0].nbytes
