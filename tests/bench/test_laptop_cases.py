"""The effects bench's laptop case set (issue 59 item 3): fixed before any run (the committed file equals
its generator), dev apart from eval (no seed, no Hamiltonian shared), the counts the issue asks for, pinned
films on at least half, the patch numbers 1, 2, 4 and 8 and disorder the engine does not draw on at
least a quarter; every case's magnum.np film gets the pins its N_pin asks for."""

import collections

import pytest
import yaml

from forcdecode.bench import laptop_cases
from forcdecode.bench.effects_user import case_film


@pytest.fixture(scope="module")
def committed():
    return yaml.safe_load(laptop_cases.CASES_FILE.read_text())


def test_the_committed_file_is_its_generator(committed):
    assert committed == yaml.safe_load(yaml.safe_dump(laptop_cases.generate_cases(), sort_keys=False))


def test_dev_and_eval_share_no_seed_and_no_hamiltonian(committed):
    dev, ev = committed["dev"], committed["eval"]
    assert not {c["realisation_seed"] for c in dev} & {c["realisation_seed"] for c in ev}
    assert not {c["hamiltonian_id"] for c in dev} & {c["hamiltonian_id"] for c in ev}
    key = lambda c: tuple(sorted(c["hamiltonian"].items()))  # noqa: E731
    assert not {key(c) for c in dev} & {key(c) for c in ev}
    names = [c["name"] for c in dev + ev]
    assert len(set(names)) == len(names)


def test_eval_counts_pinning_patches_and_disorder(committed):
    ev = committed["eval"]
    classes = collections.Counter(c["class"] for c in ev)
    kinds = collections.Counter(c["kind"] for c in ev)
    assert kinds["control"] >= 24 and kinds["outside"] >= 12
    for name in ("background", "field_offset", "second_phase"):
        assert classes[name] >= 12, name
    assert classes["additive_drift"] + classes["multiplicative_drift"] >= 12
    assert min(classes["additive_drift"], classes["multiplicative_drift"]) >= 1
    for name in ("scale", "K_2", "bias_field", "field_tilt"):
        assert classes[name] >= 6, name
    pinned = [c for c in ev if case_film(c).pinning_cells > 0]
    assert len(pinned) >= len(ev) / 2
    assert {c["patches"] for c in ev} == {1, 2, 4, 8}
    assert all(collections.Counter(c["patches"] for c in ev)[p] >= len(ev) // 5 for p in (1, 2, 4, 8))
    unusual = [c for c in ev if c["sample"]["variant"] != "standard"]
    assert len(unusual) >= len(ev) / 4
    pinned_controls = [c for c in pinned if c["kind"] == "control" and c["patches"] <= 2]
    assert pinned_controls  # the control: pinned and few patches
    for c in ev:
        assert 0.95 <= c["Ms_error_factor"] <= 1.05


def test_a_case_film_carries_its_disorder_variant():
    case = next(c for c in laptop_cases.load_cases("eval") if c["sample"]["variant"] == "pins_along_z"
                and c["hamiltonian"]["N_pin"] >= 64)
    film = case_film(case)
    assert film.pin_orientation == "z" and film.pinning_cells >= 1 and film.sweep_step_T == case["protocol"]["sweep_step_T"]
    lognormal = next(c for c in laptop_cases.load_cases("dev") if c["sample"]["variant"] == "lognormal_grains")
    assert case_film(lognormal).grain_sizes == "lognormal"
    with pytest.raises(Exception, match="dev or eval"):
        laptop_cases.load_cases("test")
