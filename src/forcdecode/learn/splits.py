"""Train / validation / calibration / test membership of each sample, from a hash of (seed, sample id).

A sample's split depends only on the config seed and its own id: u = a uniform number drawn from the
named stream ``split`` of (seed, sample id), and the split is the bucket of u in the cumulative
fractions. Adding samples to a dataset (a higher ``n_samples``, a second seed range merged in) never
moves an existing sample between splits, and every parameter's networks see the same split.
The realised fractions are binomial around the requested ones.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.streams import stream_rng

SPLITS = ("train", "validation", "calibration", "test")


def split_uniform(seed: int, sample_ids) -> np.ndarray:
    """The per-sample uniform number in [0, 1) that decides its split (stream ``split``)."""
    return np.array([stream_rng(seed, "split", int(s)).random() for s in np.asarray(sample_ids).ravel()])


def assign_splits(sample_ids, seed: int, fractions, protocol: str = "holdout") -> dict:
    """Index arrays (into ``sample_ids``) per split.

    ``holdout``: ``fractions`` = (train, validation, calibration, test). ``paper``: the seed paper's
    80/20 train/validation; validation then also serves as calibration and test (figures flagged)."""
    sample_ids = np.asarray(sample_ids)
    if len(np.unique(sample_ids)) != sample_ids.size:
        raise DatasetError("sample ids are not unique: the split is keyed by sample id")
    if protocol == "paper":
        fractions = (0.8, 0.2, 0.0, 0.0)
    elif protocol != "holdout":
        raise ConfigError(f"unknown learning protocol {protocol!r} (expected 'holdout' or 'paper')")
    fractions = np.asarray(fractions, dtype=float)
    if fractions.size != 4 or np.any(fractions < 0) or not np.isclose(fractions.sum(), 1.0):
        raise ConfigError(f"learning.split must be 4 non-negative fractions summing to 1 (got {fractions.tolist()})")
    u = split_uniform(seed, sample_ids)
    bucket = np.searchsorted(np.cumsum(fractions)[:-1], u, side="right")
    splits = {name: np.flatnonzero(bucket == k) for k, name in enumerate(SPLITS)}
    if protocol == "paper":
        splits["calibration"] = splits["test"] = splits["validation"]
    return splits


def split_labels(n: int, splits: dict) -> np.ndarray:
    """Per-sample split name (paper protocol: validation = calibration = test, labelled "test")."""
    labels = np.empty(n, dtype=object)
    for name in SPLITS:
        labels[splits[name]] = name
    return labels.astype(str)
