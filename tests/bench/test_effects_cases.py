"""The effects bench's committed cluster cases (issue 45): dev apart from eval, counts, sizes over and off
the candidates' grids, the file equal to its generator; the generator's outside-library instrument effects;
the oracle path's flag; shards. The user path's scoring, summary and runs: test_effects_user.py."""

import numpy as np
import pytest
import yaml

from forcdecode.bench import effects_independent as bench
from forcdecode.bench.effects_independent import CASES_FILE, LIBRARY_CLASSES, OUTSIDE_CLASSES
from forcdecode.bench.effects_user import clopper_pearson


@pytest.fixture(scope="module")
def cases():
    return yaml.safe_load(CASES_FILE.read_text())


def _hamiltonian_key(h):
    return tuple(sorted(h.items()))


def test_dev_and_eval_share_no_seed_and_no_hamiltonian(cases):
    dev, ev = cases["dev"], cases["eval"]
    assert {c["realisation_seed"] for c in dev}.isdisjoint(c["realisation_seed"] for c in ev)
    assert {_hamiltonian_key(c["hamiltonian"]) for c in dev}.isdisjoint(_hamiltonian_key(c["hamiltonian"]) for c in ev)
    assert {c["hamiltonian_id"] for c in dev}.isdisjoint(c["hamiltonian_id"] for c in ev)
    every = dev + ev
    assert len({c["name"] for c in every}) == len(every)
    assert len({c["realisation_seed"] for c in every}) == len(every)  # no two cases share a realisation either


def test_counts_meet_the_issue_minimums(cases):
    ev, dev = cases["eval"], cases["dev"]
    kinds = [c["kind"] for c in ev]
    assert kinds.count("control") >= 20 and kinds.count("outside") >= 12
    for name in LIBRARY_CLASSES:
        assert sum(c["class"] == name for c in ev) >= 12, name
        assert sum(c["class"] == name for c in dev) >= 1, name
    assert {c["class"] for c in ev if c["kind"] == "outside"} == set(OUTSIDE_CLASSES)
    assert {c["class"] for c in dev if c["kind"] == "outside"} == set(OUTSIDE_CLASSES)
    assert len(dev) < len(ev) and {c["kind"] for c in dev} == {"control", "library", "outside"}
    # 0 false attributions in n can show a rate <= 0.1 at 90 % only from n = 29 on
    assert clopper_pearson(0, kinds.count("control"))[1] <= 0.1
    assert clopper_pearson(0, kinds.count("outside"))[1] <= 0.1


def test_the_file_is_what_the_generator_makes():
    text = bench.CASES_HEADER + yaml.safe_dump(bench.generate_cases(), sort_keys=False, width=120)
    assert CASES_FILE.read_text() == text, "regenerate: python -c 'from forcdecode.bench.effects_independent " \
                                           "import write_cases_file; write_cases_file()'"


def test_effect_sizes_lie_over_and_off_the_candidate_grids(cases):
    for name, (side, key, (lo, hi), signed, grid) in LIBRARY_CLASSES.items():
        rows = [c for c in cases["eval"] if c["class"] == name]
        values = [{**c["physics"], **c["instrument"]}[key] for c in rows]
        sizes = [c["size"] for c in rows]
        assert all(lo * 0.999 <= s <= hi * 1.001 for s in sizes), name
        assert len(set(sizes)) >= 10, name  # spread, not a few repeated values
        assert max(sizes) / min(sizes) > 3, name
        if grid:
            on = [v for v in values if any(np.isclose(v, g) for g in grid)]
            assert 1 <= len(on) <= len(values) // 2, name  # over the grid and mostly off it
        if signed and name != "scale":
            assert min(values) < 0 < max(values), name


def test_cases_are_in_prior_and_the_Ms_error_is_within_five_percent(cases):
    from forcdecode.core.parameters import DEFAULT_BOUNDS

    for c in cases["dev"] + cases["eval"]:
        h = c["hamiltonian"]
        assert c["in_prior"] and bench._screened(h)
        for name, value in h.items():
            lo, hi = DEFAULT_BOUNDS[name]
            assert lo <= value <= hi, (c["name"], name)
        assert 0.95 <= c["Ms_error_factor"] <= 1.05
        assert bench.NOISE[0] <= c["noise"] <= bench.NOISE[1]
        assert (c["size"] is None) == (c["kind"] == "control")
    factors = [c["Ms_error_factor"] for c in cases["eval"]]
    assert min(factors) < 0.98 and max(factors) > 1.02  # the error is real, not ≈ 1 everywhere


def test_the_oracle_path_says_so():
    assert bench.summarize([])["oracle_inputs"] is True


# ------------------------------------------------------------------ the generator's outside-library effects

def _family(n=6):
    from forcdecode.reference.independent import SampleFamily, measurement_protocol

    reversal, fields = measurement_protocol(n)
    curves = [np.tanh((f - 0.1) / 0.2) for f in fields]  # switching near +0.1 T
    return SampleFamily(np.asarray(reversal), fields, curves)


def test_a_training_bias_shifts_the_first_curves_and_trains_away():
    from forcdecode.reference.independent import InstrumentModel, record

    family = _family(24)
    plain = record(family, 1.0, InstrumentModel(noise=0.0), np.random.default_rng(0))[1]
    trained = record(family, 1.0, InstrumentModel(noise=0.0, training_bias_T=0.05, training_curves=2.0),
                     np.random.default_rng(0))[1]
    order = np.argsort(family.reversal_fields_T)[::-1]  # measured from the highest reversal field down
    diff = [float(np.max(np.abs(trained[k][1] - plain[k][1]))) for k in order]
    cycled = [d for k, d in zip(order, diff) if family.curves[k][0] < 0]  # the curves that reverse the film
    assert cycled[0] > 0.1 and cycled[-1] < 0.01 * cycled[0]  # b_0 = 50 mT on a slope of 5 per T, trained away
    assert all(a >= b - 1e-12 for a, b in zip(cycled[1:], cycled[2:]))  # decays reversal by reversal
    first = diff.index(cycled[0])
    assert max(diff[:first - 1] or [0.0]) < cycled[0]  # curves that do not reverse the film do not train it


def test_correlated_noise_is_correlated_and_off_by_default():
    from forcdecode.reference.independent import InstrumentModel, record

    family = _family(24)
    zero = InstrumentModel(noise=0.0)
    base = record(family, 1.0, zero, np.random.default_rng(1))[1]
    again = record(family, 1.0, InstrumentModel(noise=0.0, correlated_noise=0.0, training_bias_T=0.0),
                   np.random.default_rng(1))[1]
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(base, again))  # the defaults change nothing
    noisy = record(family, 1.0, InstrumentModel(noise=0.0, correlated_noise=0.01, correlation_points=8.0),
                   np.random.default_rng(1))[1]
    r = np.concatenate([n[1] - b[1] for n, b in zip(noisy, base) if len(b[1]) > 10])
    lag1 = np.corrcoef(r[:-1], r[1:])[0, 1]
    assert lag1 > 0.5 and 0.003 < r.std() < 0.03


def test_shards_split_a_case_set_without_overlap():
    from forcdecode.bench.cli import _shard
    from forcdecode.core.errors import ConfigError

    names = list(range(31))
    parts = [names[_shard(f"{k}/3", len(names))] for k in (1, 2, 3)]
    assert sorted(sum(parts, [])) == names and all(parts)
    for bad in ("0/2", "3/2", "x", "1-2"):
        with pytest.raises(ConfigError):
            _shard(bad, 10)
