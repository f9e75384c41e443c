"""Ambiguity as an answer (``loop.effects.equivalent_candidates``): candidates that explain the
held-out residual equally are reported together, on per-curve errors made by hand."""

import numpy as np

from forcdecode.core.streams import stream_rng
from forcdecode.loop.effects import (HAMILTONIAN_CHANGE, beats_floor, bootstrap_resamples, equivalent_candidates,
                                     nested, separating_measurements)


def _errors(level, n=24, spread=0.1, seed=0):
    """Per-curve held-out mean-square errors around ``level`` (positive, curve-to-curve scatter)."""
    rng = np.random.default_rng(seed)
    return level * (1 + spread * rng.standard_normal(n)) ** 2


def test_two_unrelated_candidates_that_fit_equally_are_ambiguous_and_nested_ones_are_not():
    none = _errors(1.0, seed=1)
    tilt = _errors(0.20, seed=2)
    errors = {"none": none, "field_tilt": tilt, HAMILTONIAN_CHANGE: tilt * (1 + 0.01 * np.sin(np.arange(24))),
              "background": _errors(0.6, seed=3), "background+field_tilt": tilt * 0.99}
    rng = stream_rng(0, "bootstrap", "test")
    same = equivalent_candidates(errors, "field_tilt", rng)
    # the K_u change explains as much; the background explains less (field_tilt beats it);
    # background+field_tilt contains the chosen candidate (parsimony decides, not ambiguity)
    assert same == [HAMILTONIAN_CHANGE]
    assert nested("background", "background+field_tilt") and not nested("field_tilt", "K_2")
    text = separating_measurements(["field_tilt", "K_2", HAMILTONIAN_CHANGE, "background+additive_drift", "x"])
    assert "angle" in text["field_tilt"] and "hard-axis" in text["K_2"] and "higher fields" in text["background+additive_drift"]
    assert "differs" in text["x"]


def test_a_clearly_better_chosen_candidate_stands_alone():
    errors = {"none": _errors(1.0, seed=1), "K_2": _errors(0.10, seed=2), HAMILTONIAN_CHANGE: _errors(0.5, seed=4)}
    assert equivalent_candidates(errors, "K_2", stream_rng(0, "bootstrap", "test")) == []
    assert equivalent_candidates(errors, "none", stream_rng(0, "bootstrap", "test")) == []


def test_candidates_equal_within_their_null_gains_are_ambiguous():
    """The refit path's rule (``refit.refit_ambiguity``): a difference no larger than what films without
    an effect give either candidate (their null gains) does not tell them apart, and a candidate whose
    gain over "none" is within its own null gain explains nothing."""
    errors = {"none": _errors(1.0, seed=1), HAMILTONIAN_CHANGE: _errors(0.10, seed=2),
              "field_tilt": _errors(0.30, seed=3)}
    rng = stream_rng(0, "bootstrap", "test")
    assert equivalent_candidates(errors, HAMILTONIAN_CHANGE, rng) == []  # beyond the noise the refit is better
    floors = {HAMILTONIAN_CHANGE: {"relative": 0.5, "mse": 0.3}, "field_tilt": {"relative": 0.2, "mse": 0.1}}
    assert equivalent_candidates(errors, HAMILTONIAN_CHANGE, rng, floors=floors) == ["field_tilt"]
    within_its_floor = {**floors, "field_tilt": {"relative": 0.8, "mse": 0.1}}
    assert equivalent_candidates(errors, HAMILTONIAN_CHANGE, rng, floors=within_its_floor) == []
    assert beats_floor(errors["field_tilt"], errors["none"], None)
    assert beats_floor(errors["field_tilt"], errors["none"], {"relative": 0.6, "mse": 0.6})
    assert not beats_floor(errors["field_tilt"], errors["none"], {"relative": 0.6, "mse": 0.7})


def test_the_same_observable_is_not_an_ambiguity():
    offset = _errors(0.2, seed=2)
    errors = {"none": _errors(1.0, seed=1), "bias_field": offset * 1.001, "field_offset": offset}
    rng = stream_rng(0, "bootstrap", "test")
    assert equivalent_candidates(errors, "field_offset", rng, same_observable=({"field_offset", "bias_field"},)) == []
    assert equivalent_candidates(errors, "field_offset", rng) == ["bias_field"]


def test_comparisons_use_common_random_numbers_whatever_ran_before():
    """The resample depends on the generator's state alone, not on how often it was used: a
    comparison's outcome cannot change with the order of the comparisons (issue 45 item 6)."""
    rng = stream_rng(3, "bootstrap", "test")
    first = bootstrap_resamples(rng, 50, 12)
    for _ in range(5):
        bootstrap_resamples(rng, 50, 7)
    assert np.array_equal(first, bootstrap_resamples(rng, 50, 12))
    assert first.shape == (50, 12) and first.min() >= 0 and first.max() < 12
    assert not np.array_equal(first, bootstrap_resamples(stream_rng(4, "bootstrap", "test"), 50, 12))
