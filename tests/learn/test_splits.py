"""The split is a function of (seed, sample id) alone: growing a dataset never moves a sample."""

import numpy as np
import pytest

from forcdecode.core.errors import ConfigError, DatasetError
from forcdecode.learn.splits import SPLITS, assign_splits, split_labels

FRACTIONS = (0.55, 0.15, 0.15, 0.15)


def membership(ids, seed=11, fractions=FRACTIONS):
    splits = assign_splits(ids, seed, fractions)
    return dict(zip(np.asarray(ids).tolist(), split_labels(len(ids), splits)))


def test_adding_samples_never_moves_a_sample_between_splits():
    small = membership(np.arange(300))
    grown = membership(np.concatenate([np.arange(300), np.arange(1000, 1400)]))  # more samples, a second range
    assert all(grown[i] == small[i] for i in small)
    shuffled = membership(np.random.default_rng(0).permutation(np.arange(300)))  # order does not matter either
    assert shuffled == small


def test_fractions_are_binomial_around_the_request():
    n = 4000
    labels = split_labels(n, assign_splits(np.arange(n), 3, FRACTIONS))
    for name, p in zip(SPLITS, FRACTIONS):
        share = np.mean(labels == name)
        assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / n), (name, share)


def test_seed_changes_the_split_and_splits_are_disjoint():
    ids = np.arange(500)
    a, b = membership(ids, seed=1), membership(ids, seed=2)
    assert np.mean([a[i] != b[i] for i in ids]) > 0.4
    splits = assign_splits(ids, 1, FRACTIONS)
    joined = np.concatenate([splits[k] for k in SPLITS])
    assert np.array_equal(np.sort(joined), ids)


def test_paper_protocol_uses_validation_for_everything_after_training():
    splits = assign_splits(np.arange(1000), 5, FRACTIONS, protocol="paper")
    assert np.array_equal(splits["validation"], splits["test"]) and np.array_equal(splits["test"], splits["calibration"])
    assert abs(len(splits["train"]) / 1000 - 0.8) < 0.05


def test_bad_input_is_a_typed_error():
    with pytest.raises(DatasetError, match="not unique"):
        assign_splits([1, 2, 2], 0, FRACTIONS)
    with pytest.raises(ConfigError, match="sum"):
        assign_splits([1, 2, 3], 0, (0.5, 0.5, 0.5, 0.0))
    with pytest.raises(ConfigError, match="protocol"):
        assign_splits([1, 2, 3], 0, FRACTIONS, protocol="kfold")
