"""core.parallel: the loop's families on several processes are the families made in one, bit for bit."""

import numpy as np
import pytest

from forcdecode.config import load_config, shipped_config
from forcdecode.core.parallel import active_workers, map_in_order, using_workers
from forcdecode.infer.resimulate import resimulate_with_spread
from forcdecode.loop.physics_effects import physics_candidate_families

PARAMS = {"Ms": 8e5, "A_ex": 1.3e-11, "K_u": 7e5, "D": 1e-3, "N_pin": 40, "sigma_theta_deg": 5.0, "sigma_K": 0.1}


def _square_or_fail(x):
    if x < 0:
        raise ValueError(f"negative {x}")
    return x * x


@pytest.fixture(scope="module")
def cfg():
    return load_config(shipped_config("test"))


def test_map_in_order_keeps_the_order_and_raises_the_first_failure():
    with using_workers(2):
        assert active_workers() == 2
        assert map_in_order(_square_or_fail, [(k,) for k in range(7)]) == [k * k for k in range(7)]
        with pytest.raises(ValueError, match="negative -2"):
            map_in_order(_square_or_fail, [(1,), (-2,), (3,), (-4,)])
    assert active_workers() == 1
    with pytest.raises(ValueError):
        with using_workers(0):
            pass


def test_two_workers_make_the_same_families_as_one(cfg):
    serial_mean, serial_spread = resimulate_with_spread(cfg, PARAMS, n_profiles=3, key="parallel")
    serial_candidates = physics_candidate_families(cfg, PARAMS, key="parallel")
    done = []
    with using_workers(2):
        mean, spread = resimulate_with_spread(cfg, PARAMS, n_profiles=3, key="parallel",
                                              progress=lambda k, n: done.append((k, n)))
        candidates = physics_candidate_families(cfg, PARAMS, key="parallel")
    assert done[-1] == (3, 3)
    assert np.array_equal(mean, serial_mean, equal_nan=True) and np.array_equal(spread, serial_spread, equal_nan=True)
    assert candidates.keys() == serial_candidates.keys()
    for group in ("physics_families", "soft_phase_families", "hamiltonian_families"):
        a, b = candidates[group], serial_candidates[group]
        flat_a = a if group != "physics_families" else {(k, v): f for k, d in a.items() for v, f in d.items()}
        flat_b = b if group != "physics_families" else {(k, v): f for k, d in b.items() for v, f in d.items()}
        assert list(flat_a) == list(flat_b)
        assert all(np.array_equal(flat_a[k], flat_b[k], equal_nan=True) for k in flat_a)
    assert np.array_equal(candidates["physics_reference_family"], serial_candidates["physics_reference_family"],
                          equal_nan=True)
