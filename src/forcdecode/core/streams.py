"""The registry of named random streams: every random draw of the project derives from the config
seed through one of these names (and integer or string keys such as a sample id or a parameter name).

``stream_rng(seed, "disorder", sample_id)`` gives a NumPy generator, ``stream_seed(...)`` an integer
in [0, 2**63) for libraries seeded by an integer (``torch.manual_seed``). Streams are independent:
each name has a fixed id, and the seed sequence is ``SeedSequence(seed, spawn_key=(id, *keys))``
(the seed is padded to NumPy's pool size before the key, so no two (name, keys) alias).

The dataset's two streams predate this registry and keep their layout bit for bit:
``SeedSequence([seed, sample_id, id])`` with id 0 for ``parameters`` and 1 for ``disorder``
(``dataset.params.sample_rng``); they take exactly one key, the sample id.
"""

from __future__ import annotations

import hashlib

import numpy as np

# name -> (fixed id, one-line description). Ids are never reused or renumbered: that would change
# every draw of the stream. Add a new stream with a new id.
_REGISTRY: dict[str, tuple[int, str]] = {
    "parameters": (0, "Hamiltonian parameters of one dataset sample (key: sample id)"),
    "disorder": (1, "grains, anisotropy disorder and pinning sites of one dataset sample (key: sample id)"),
    "split": (2, "train / validation / calibration / test split of the merged dataset"),
    "alice": (3, "weights and batch order of Alice, the network of one parameter (key: parameter)"),
    "alice_fold": (4, "Alice of one cross-fitting fold (keys: parameter, fold)"),
    "bob": (5, "weights and batch order of Bob, the error model of one parameter (key: parameter)"),
    "mc_dropout": (6, "Monte-Carlo dropout passes of one parameter (key: parameter)"),
    "learning_curve": (7, "Alice trained on a fraction of the training set (keys: parameter, size)"),
    "cross_fitting": (8, "assignment of training samples to cross-fitting folds (key: parameter)"),
    "ensemble": (9, "members of a network ensemble (keys: parameter, member)"),
    "bootstrap": (10, "bootstrap resampling of residuals or scores (keys: purpose)"),
    "closed_loop_subset": (11, "test samples re-simulated by the closed loop"),
    "closed_loop_disorder": (12, "disorder profiles of a re-simulation from a predicted Hamiltonian (keys: sample, profile)"),
    "figure_samples": (13, "samples drawn for a figure (key: figure name)"),
    "baseline_shuffle": (14, "permutations of a shuffled-target baseline (key: parameter)"),
    "instrument_noise": (15, "noise and drift of a simulated measurement (keys: purpose, case)"),
    "bench_film": (16, "disorder of a benchmark film (keys: benchmark, case)"),
    "ablation": (17, "weights and batch order of the head ablation (keys: head, parameter)"),
    "posterior": (18, "weights, batch order, posterior draws and calibration of the neural posterior (keys: purpose)"),
    "null_noise": (19, "measurement noise added to the effect selection's null pseudo-measurements (key: purpose)"),
    "propagation": (20, "Monte-Carlo draws propagating Alice's per-parameter intervals into the combinations (key: purpose)"),
    "disorder_realisation": (21, "grains, anisotropy disorder and pinning sites of disorder realisation r >= 1 of one "
                                 "dataset sample (keys: sample id, r); realisation 0 is the sample's `disorder` stream"),
    "patch_estimate": (22, "noise and subsets of single realisations for the loop's patch estimate and its null films "
                           "(key: purpose)"),
    "thickness_bootstrap": (23, "bootstrap resamples of the thickness study's table (keys: n, thickness in 0.1 nm)"),
}

_LEGACY_PER_SAMPLE = frozenset({"parameters", "disorder"})
"""Streams with the dataset's original layout SeedSequence([seed, sample_id, id])."""

STREAMS: dict[str, str] = {name: description for name, (_, description) in _REGISTRY.items()}
"""Every named random stream, declared once: name -> one-line description."""


def _key(value) -> int:
    """A non-negative integer for one key: integers as they are, strings by a stable hash."""
    if isinstance(value, str):
        return int.from_bytes(hashlib.sha256(value.encode()).digest()[:8], "little")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"stream keys are integers or strings, got {value!r}")
    if value < 0:
        raise ValueError(f"stream keys are non-negative, got {value}")
    return int(value)


def seed_sequence(seed: int, name: str, *keys) -> np.random.SeedSequence:
    """The seed sequence of stream ``name`` for ``keys`` under the config ``seed``."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown random stream {name!r} (declared: {', '.join(_REGISTRY)})")
    if isinstance(seed, str):
        raise TypeError(f"the seed is an integer, got {seed!r}")
    seed = _key(seed)
    stream_id = _REGISTRY[name][0]
    ints = tuple(_key(k) for k in keys)
    if name in _LEGACY_PER_SAMPLE:
        if len(ints) != 1:
            raise ValueError(f"stream {name!r} takes exactly one key (the sample id), got {len(ints)}")
        return np.random.SeedSequence([seed, ints[0], stream_id])
    return np.random.SeedSequence(seed, spawn_key=(stream_id, *ints))


def stream_rng(seed: int, name: str, *keys) -> np.random.Generator:
    """A NumPy generator (PCG64) of stream ``name`` for ``keys``; unknown name: ValueError."""
    return np.random.default_rng(seed_sequence(seed, name, *keys))


def stream_seed(seed: int, name: str, *keys) -> int:
    """An integer seed in [0, 2**63) of stream ``name`` for ``keys`` (for ``torch.manual_seed``)."""
    return int(seed_sequence(seed, name, *keys).generate_state(1, np.uint64)[0] >> np.uint64(1))


__all__ = ["STREAMS", "seed_sequence", "stream_rng", "stream_seed"]
