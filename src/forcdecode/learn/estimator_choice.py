"""Which estimator answers a user by default (``--estimator auto``): the one validation shows better.

Both estimators store, at training time, their figures on the same validation families (the hash split
of (seed, sample id); ``learn.answer``'s ``identification`` blocks): Alice per parameter in each model
file, the posterior (the median of its draws) in its model file's metadata. The default is the estimator
with the lower mean validation MAE (normalized units, u ∈ [0, 1]) over the parameters both estimate;
Alice where either lacks validation records (a model saved before they existed), where no posterior
model exists, or on a tie. Validation also chose each network's early-stopping epoch, so these figures
are a little optimistic for both alike; test and sealed figures are never read here.
"""

from __future__ import annotations

import argparse

from pathlib import Path

import numpy as np
from ..core.errors import ModelFileError

RULE = ("the estimator with the lower mean validation MAE over the parameters both estimate (normalized "
        "units; the same validation families); Alice where either lacks validation records or on a tie")


def alice_validation_mae(models: dict) -> dict:
    """name -> Alice's validation MAE (normalized) from each model file's identification block (absent
    for a model saved before it)."""
    out = {}
    for name, model in models.items():
        record = ((getattr(model, "payload", {}) or {}).get("identification") or {}).get("parameter") or {}
        if np.isfinite(record.get("mae", np.nan)):
            out[name] = float(record["mae"])
    return out


def posterior_validation_mae(metadata: dict) -> dict:
    """name -> the posterior's validation MAE (median of its draws, normalized) from its metadata."""
    records = ((metadata or {}).get("identification") or {}).get("parameters") or {}
    return {name: float(r["mae"]) for name, r in records.items() if np.isfinite(r.get("mae", np.nan))}


def choose(alice_mae: dict, posterior_mae: dict | None) -> dict:
    """{"estimator", "basis", "validation_mae"} by ``RULE`` from the two estimators' validation MAEs."""
    shared = sorted(set(alice_mae) & set(posterior_mae or {}))
    record = {"rule": RULE, "validation_mae": {"alice": alice_mae, "posterior": posterior_mae}}
    if posterior_mae is None:
        return {**record, "estimator": "alice", "basis": "no posterior model"}
    if not shared:
        return {**record, "estimator": "alice", "basis": "no validation records shared by both estimators"}
    a = float(np.mean([alice_mae[n] for n in shared]))
    p = float(np.mean([posterior_mae[n] for n in shared]))
    chosen = "posterior" if p < a else "alice"
    return {**record, "estimator": chosen, "parameters": shared,
            "basis": f"mean validation MAE over {', '.join(shared)}: posterior {p:.3f}, Alice {a:.3f}"}


def default_posterior_path(models_dir) -> str:
    """The workflow's layout: the posterior beside the models directory (results/models ->
    results/posterior/model.pt)."""
    return str(Path(models_dir).parent / "posterior" / "model.pt")


def choose_estimator(models_dir, posterior_path) -> dict:
    """The default estimator for the model files in ``models_dir`` and the posterior at
    ``posterior_path`` (``choose``); a missing posterior file means Alice."""
    # loads torch: imported only when this runs
    from .predictor import load_models

    has_posterior = posterior_path is not None and Path(posterior_path).exists()
    try:
        alice = alice_validation_mae(load_models(models_dir))
    except ModelFileError:
        if not has_posterior:  # Alice, whose own reading then says what is missing, where it is needed
            return {"rule": RULE, "estimator": "alice", "basis": f"no model files in {models_dir} nor a posterior"}
        return {"rule": RULE, "estimator": "posterior", "basis": f"no Alice model files in {models_dir}"}
    posterior = None
    if has_posterior:
        # loads torch: imported only when this runs
        from .posterior import PosteriorEstimator

        posterior = posterior_validation_mae(PosteriorEstimator.load(posterior_path).metadata)
    return choose(alice, posterior)


__all__ = ["RULE", "default_posterior_path", "alice_validation_mae", "posterior_validation_mae", "choose", "choose_estimator"]


ESTIMATORS = ("auto", "alice", "posterior")
"""What ``--estimator`` may name: auto (:func:`choose_estimator`), Alice + Bob, or the joint posterior."""


def add_estimator_arguments(parser: argparse.ArgumentParser, auto_note: str = "", after_note: str = "") -> None:
    """``--models``, ``--estimator`` and ``--posterior`` as `predict` and `loop` declare them (one
    declaration; ``auto_note`` adds to auto's rule, ``after_note`` to the end of the help)."""
    parser.add_argument("--models", default=None, help="directory with the trained <parameter>.pt files (default: "
                                                       "the models shipped with the package, learn.shipped; "
                                                       "results/models where none are)")
    parser.add_argument("--estimator", choices=ESTIMATORS, default="auto",
                        help="auto (default): whichever validation shows better (learn.estimator_choice: the lower "
                             f"mean validation MAE; Alice without a posterior model{auto_note}); alice: one network "
                             "per parameter with Bob's conformal intervals; posterior: the joint neural posterior "
                             f"(medians, 68/90 %% intervals, correlations){after_note}")
    parser.add_argument("--posterior", help="posterior model (default: posterior/model.pt beside the --models "
                                            "directory, i.e. results/posterior/model.pt)")
