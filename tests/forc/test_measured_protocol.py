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
