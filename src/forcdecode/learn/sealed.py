"""The sealed test set: families nobody looked at while the method was being developed.

The test split of the main job has been read during development (architectures, films, gates and
thresholds were compared on it at one time or another), so its figures are spent. The sealed set is a
second id range of the same configuration (``sealed.first_sample_id``, ``sealed.n_samples`` in the
config), simulated by the main job with the same draw, screening and simulator, and scored once, at the
end, by the frozen models:

- it never enters a fit: no weight, no early stopping, no quantile, no conformal or recalibration map,
  no threshold or gate reads it (the workflow's DAG has no path from a sealed file to a fitting rule,
  ``tests/workflow/test_sealed_dag.py``);
- its ids are disjoint from the training dataset's (``check_disjoint``, refused otherwise);
- the trivial baselines it is compared with are fitted on the training dataset's train split exactly as
  for the test split (prior: the train median of u; M_s only: the k-NN median in M_s with k chosen on
  validation), and the images-shuffled baseline permutes the sealed images among the sealed families.

All figures are on normalized parameters u ∈ [0, 1] (log scale for K_u), as the test split's; skill is
1 − MAE/MAE(baseline), with paired percentile-bootstrap 90 % intervals over the sealed families.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import DatasetError
from ..core.streams import stream_rng
from .combinations import alice_combination_metrics
from .data import LearningData
from .scoring import _mae, accuracy_with_intervals, fit_ms_only, knn_median, skill, skill_interval

SEALED_NOTE = ("sealed: a separate id range simulated by the main job and scored once, at its end, by the frozen "
               "models; never used for a choice, a gate or a threshold (the test split was looked at during "
               "development, the sealed set was not)")


def check_disjoint(training: LearningData, sealed: LearningData) -> None:
    """Refuse a sealed set that shares a sample id with the training dataset, or comes from another
    physics configuration (config hash)."""
    if training.config_hash != sealed.config_hash:
        raise DatasetError(f"the sealed set was simulated with another configuration (config hash "
                           f"{sealed.config_hash[:12]} against the training dataset's {training.config_hash[:12]})")
    shared = np.intersect1d(training.sample_id, sealed.sample_id)
    if shared.size:
        raise DatasetError(f"{shared.size} sealed sample id(s) are also in the training dataset "
                           f"(first: {shared[:5].tolist()}); the sealed range must be disjoint")


def trivial_predictors(training: LearningData, name: str, splits: dict, ms_norm_query) -> dict:
    """The trivial predictors of u for ``name`` fitted on the training dataset's train split (k of the
    M_s-only predictor chosen on its validation split), evaluated at ``ms_norm_query``; ``best``: the
    one with the lower validation MAE (chosen before the sealed set is read)."""
    u = training.target(name)
    train, val = splits["train"], splits["validation"]
    prior = float(np.median(u[train]))
    k = fit_ms_only(training.ms_norm[train], u[train], training.ms_norm[val], u[val])
    validation_mae = {"prior": _mae(u[val], np.full(len(val), prior)),
                      "ms_only": _mae(u[val], knn_median(training.ms_norm[train], u[train], training.ms_norm[val], k))}
    query = np.asarray(ms_norm_query, dtype=float)
    return {"prior": np.full(query.size, prior), "ms_only": knn_median(training.ms_norm[train], u[train], query, k),
            "ms_only_k": int(k), "best": min(validation_mae, key=validation_mae.get), "validation_mae": validation_mae}


def parameter_metrics(model, training: LearningData, sealed: LearningData, splits: dict, *, seed: int,
                      n_boot: int, n_shuffles: int) -> tuple[dict, np.ndarray]:
    """One parameter's network (``learn.predictor.ParameterModel``) on the sealed families: MAE, Pearson
    r, skill over prior, M_s-only, the best trivial predictor (chosen on validation) and the
    images-shuffled network, its 90 % conformal coverage; each with a bootstrap 90 % interval. Returns
    (metrics, normalized predictions)."""
    name = model.name
    truth = sealed.target(name)
    ms_si = sealed.values["Ms"]
    predicted = model.predict(sealed.images, ms_si)
    u_hat = np.asarray(predicted["normalized"], dtype=float)
    trivial = trivial_predictors(training, name, splits, sealed.ms_norm)
    if "normalized_90" in predicted:
        low, high = predicted["normalized_90"]
        covered = (truth >= low) & (truth <= high)
    else:
        covered = np.zeros(0)
    rng = stream_rng(seed, "bootstrap", "sealed", name)
    out = {"parameter": name, "n_sealed": int(len(truth)),
           **accuracy_with_intervals(truth, u_hat, trivial["ms_only"], trivial["prior"], covered, rng, n_boot)}
    best = trivial[trivial["best"]]
    out["best_trivial"] = trivial["best"]
    out["skill_vs_best_trivial"] = skill(_mae(truth, u_hat), _mae(truth, best))
    out["skill_vs_best_trivial_ci90"] = skill_interval(truth, u_hat, best, rng, n_boot)
    shuffle_rng = stream_rng(seed, "baseline_shuffle", "sealed", name)
    shuffled = []
    for _ in range(n_shuffles):
        permuted = shuffle_rng.permutation(len(truth))
        shuffled.append(float(np.abs(model.predict(sealed.images[permuted], ms_si)["normalized"] - truth).mean()))
    out["baselines"] = {"prior": _mae(truth, trivial["prior"]), "ms_only": _mae(truth, trivial["ms_only"]),
                        "ms_only_k": trivial["ms_only_k"], "images_shuffled": float(np.mean(shuffled)),
                        "images_shuffled_spread": float(np.std(shuffled)),
                        "best_trivial_chosen_on": "validation MAE of the training dataset",
                        "validation_mae": trivial["validation_mae"]}
    out["skill_vs_images_shuffled"] = skill(out["mae"], out["baselines"]["images_shuffled"])
    return out, u_hat


def alice_sealed_metrics(models: dict, training: LearningData, sealed: LearningData, *, seed: int,
                         settings: dict, n_boot: int = 2000) -> dict:
    """``sealed`` of metrics.json: every parameter's frozen network on the sealed families, and the
    derived combinations of their predictions (plug-in, as for the test split; normalization and
    baselines from the training dataset's train and validation splits). ``models``: name ->
    ``ParameterModel``; ``settings``: the learning section (its split and protocol)."""
    # loads torch: imported only when this runs
    from .pipeline import N_SHUFFLES, make_splits

    check_disjoint(training, sealed)
    splits = make_splits(training.sample_id, seed, settings)
    parameters, predicted = {}, {}
    for name, model in models.items():
        parameters[name], predicted[name] = parameter_metrics(model, training, sealed, splits, seed=seed,
                                                               n_boot=n_boot, n_shuffles=N_SHUFFLES)
    combinations = _combinations(models, training, sealed, splits, predicted, seed, n_boot, alice_combination_metrics)
    return {"note": SEALED_NOTE, "n_sealed": int(len(sealed)),
            "sample_id_range": [int(sealed.sample_id.min()), int(sealed.sample_id.max())] if len(sealed) else None,
            "parameters": parameters, "combinations": combinations}


def _combinations(models, training, sealed, splits, predicted, seed, n_boot, alice_combination_metrics) -> dict:
    """The plug-in combinations on the sealed families: the training dataset's train and validation
    families (their truth: only the normalization range and the baselines read them) followed by the
    sealed ones labelled "test"."""
    reference = np.concatenate([splits["train"], splits["validation"]])
    n_ref = len(reference)
    split = np.array(["train"] * len(splits["train"]) + ["validation"] * len(splits["validation"])
                     + ["test"] * len(sealed))
    ms_norm = np.concatenate([training.ms_norm[reference], sealed.ms_norm])
    target_u = {n: np.concatenate([training.target(n)[reference], sealed.target(n)]) for n in models}
    prediction_u = {n: np.concatenate([training.target(n)[reference], predicted[n]]) for n in models}
    return alice_combination_metrics(prediction_u, target_u, ms_norm, training.bounds, split,
                                     lambda *keys: stream_rng(seed, "bootstrap", "sealed", "combinations", *keys),
                                     n_boot) if n_ref else {}


def attach_sealed(metrics: dict, sealed: dict) -> dict:
    """``metrics`` (the test split's figures) with the sealed set's beside them under ``sealed``, and
    a note saying which of the two was looked at during development."""
    if "sealed" in metrics:
        raise DatasetError("these metrics already hold sealed figures: the sealed set is scored once")
    return {**metrics, "sealed": sealed, "test_vs_sealed": SEALED_NOTE}


def sealed_lines(metrics: dict) -> list[str]:
    """A short table of the sealed figures (one line per parameter and combination)."""
    lines = [f"sealed set: {metrics['n_sealed']} families, ids {metrics['sample_id_range']}"]
    for name, row in metrics["parameters"].items():
        lo, hi = row["skill_vs_best_trivial_ci90"]
        lines.append(f"  {name}: MAE {row['mae']:.3f} (prior {row['baselines']['prior']:.3f}, M_s only "
                     f"{row['baselines']['ms_only']:.3f}); skill vs best trivial ({row['best_trivial']}) "
                     f"{row['skill_vs_best_trivial']:.2f} [{lo:.2f}, {hi:.2f}]; coverage 90 % {row['coverage_90']:.2f}")
    for name, row in (metrics.get("combinations") or {}).items():
        if "mae" in row:
            lo, hi = row["skill_vs_ms_only_ci90"]
            lines.append(f"  {name} (plug-in): MAE {row['mae']:.3f}; skill vs M_s only {row['skill_vs_ms_only']:.2f} "
                         f"[{lo:.2f}, {hi:.2f}] on {row['n_scored']}")
    return lines


__all__ = ["SEALED_NOTE", "attach_sealed", "check_disjoint", "trivial_predictors", "parameter_metrics", "alice_sealed_metrics",
           "sealed_lines"]
