"""Train, cross-fit and evaluate the networks of one parameter: Alice, Bob, their intervals, their baselines.

Protocol (``holdout``, the default): every sample belongs to train / validation / calibration / test
by a hash of (config seed, sample id) (``splits.py``): the same split for every parameter, and adding
samples never moves one between splits.

1. Alice: ``seeds`` networks (different weight seeds, same data), each fitted on train with early
   stopping on validation. Member 0 is *the* Alice that Bob, the intervals and ``predict`` use; the
   members' spread is reported (training-seed error bar) and their standard deviation is one of the
   uncertainty baselines.
2. Out-of-fold errors: K-fold cross-fitting over the train split gives every training sample an
   error Alice did not see while fitting it.
3. Bob: the same network family, trained to output the normalized quantile of Alice's out-of-fold
   error; quantile → error by Alice's validation-set errors; that error is the difficulty σ(x) of a
   normalized split-conformal interval fitted on the calibration set.
4. Uncertainty baselines on the same test samples: v̂ (the variance the distribution-matching output
   carries), MC dropout and the seed ensemble, each conformalized on the same calibration set.
5. Accuracy baselines (``scoring.py``): prior (train median), M_s only (k-NN median, k chosen on
   validation) and the network with the test images shuffled; bootstrap 90 % intervals.
6. Learning curve: Alice on nested random subsets of train (``learning_curve`` fractions × ``seeds``),
   validation fixed; each fit scored on validation (for choices made from curves, e.g. the laptop
   film) and on test (reported); a power law MAE(N) on the test curve and the N at which it would
   reach the paper's MAE (``curve.py``).
7. Everything reported is measured on the test split, on which no choice is made: the test targets
   enter no weight, no quantile and no calibration (a leakage test randomises them).

``paper`` protocol: the seed paper's 80/20 train/validation split; figures are then reported on
that validation set (flagged in the metrics), which also calibrates.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch

from ..config import defaults
from ..core import io
from ..core.errors import DatasetError
from ..core.parameters import DEFAULT_PRIOR_CLASS, LOG_SCALE, denormalize
from ..core.streams import stream_rng, stream_seed
from .answer import alice_identification
from .curve import learning_curve_fit
from .data import PAPER_FIGURES, LearningData
from .encoding import readout, readout_with_variance
from .scoring import accuracy_with_intervals, binomial_band, fit_ms_only, knn_median, pearson
from .splits import SPLITS, assign_splits, split_labels
from .train import AliceSettings, fit_alice, with_float32_default
from .uncertainty import (ConformalIntervals, coverage_and_width, error_quantile, gaussian_interval,
                          quantile_to_error, retention_curve, spearman)

DEFAULT_SETTINGS = defaults("learning")
"""The schema's learning defaults (the one source)."""

N_SHUFFLES = 5
"""Permutations of the test images averaged in the images-shuffled baseline."""


def make_splits(sample_ids, seed: int, settings: dict) -> dict:
    """Index arrays for train / validation / calibration / test (hash of (seed, sample id))."""
    return assign_splits(sample_ids, seed, settings["split"], settings["protocol"])


def _fit(data, target, train, val, settings, seed, log=None):
    training = AliceSettings(model=settings["model"], width=settings["width"], epochs=settings["epochs"],
                             batch_size=settings["batch_size"], lr=settings["lr"], patience=settings["patience"],
                             seed=seed)
    return fit_alice(data.images, data.ms_norm, target, train, val, training, log=log)


def scores(truth, prediction, baseline_value) -> dict:
    """MAE, Pearson r and skill over a constant baseline (used by the head ablation)."""
    truth, prediction = np.asarray(truth, float), np.asarray(prediction, float)
    mae = float(np.mean(np.abs(prediction - truth)))
    baseline = float(np.mean(np.abs(baseline_value - truth)))
    return {"mae": mae, "pearson_r": pearson(truth, prediction), "baseline_mae": baseline,
            "skill": 1.0 - mae / baseline if baseline > 0 else float("nan")}


def _uncertainty_baselines(sigmas: dict, truth, prediction, cal, test, levels) -> dict:
    """Per difficulty score σ(x): Spearman ρ with the true error, conformal coverage and width at each
    level (fitted on calibration, measured on test), error–retention area."""
    fractions = np.linspace(0.05, 1.0, 20)
    abs_error = np.abs(prediction - truth)
    table = {}
    for method, sigma in sigmas.items():
        conformal = ConformalIntervals.fit(abs_error[cal], sigma[cal], levels)
        row = {"spearman": spearman(sigma[test], abs_error[test])}
        for level in levels:
            tag = f"{int(round(level * 100))}"
            low, high = conformal.interval(prediction[test], sigma[test], level)
            row[f"coverage_{tag}"], row[f"width_{tag}"] = coverage_and_width(truth[test], low, high)
        row["retention_area"] = retention_curve(abs_error[test], sigma[test], fractions)[2]
        table[method] = row
    table["oracle_retention_area"] = retention_curve(abs_error[test], abs_error[test], fractions)[2]
    table["random_retention_area"] = float(abs_error[test].mean()) * (fractions[-1] - fractions[0])
    return table


def _finite_sigma(sigma) -> np.ndarray:
    """NaN (no vertex) → the largest finite σ: an output with no peak is the least certain."""
    sigma = np.asarray(sigma, float).copy()
    finite = np.isfinite(sigma)
    sigma[~finite] = float(np.max(sigma[finite])) if finite.any() else 1.0
    return sigma


@dataclass
class _Run:
    """What every stage of ``train_parameter`` reads: the data, the parameter, the merged learning
    settings, the config seed, the normalized target ``u`` (n,), the split indices, the readout method,
    the interval levels (0–1), the number of Alice seeds, the stage timings (s) and the progress log."""

    data: LearningData
    name: str
    settings: dict
    seed: int
    u: np.ndarray
    splits: dict
    log: object
    timings: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.data)

    @property
    def readout(self) -> str:
        return self.settings["readout"]

    @property
    def levels(self) -> list:
        return [float(a) for a in self.settings["levels"]]

    @property
    def n_seeds(self) -> int:
        return int(self.settings["seeds"])


@dataclass(frozen=True)
class ErrorModel:
    """Bob and what turns his output into intervals: ``bob`` (the fitted network; output: the
    normalized quantile of Alice's error), ``validation_errors`` (Alice's absolute errors on the
    validation split, normalized units: the quantile → error map) and ``conformal`` (the Bob-normalized
    split-conformal intervals fitted on the calibration split)."""

    bob: object
    validation_errors: np.ndarray
    conformal: ConformalIntervals


@with_float32_default
def train_parameter(data: LearningData, name: str, settings: dict, seed: int, model_path, predictions_path,
                    log=print) -> dict:
    """Fit Alice and Bob for ``name``; write the model file and the per-sample predictions; return metrics."""
    settings = {**DEFAULT_SETTINGS, **settings}
    splits = _checked_splits(data, name, settings, seed)
    run = _Run(data, name, settings, seed, data.target(name), splits, log)
    alice, members = _fit_members(run)
    throughput = alice.history["samples_seen"] / max(alice.history["train_seconds"], 1e-9)
    outputs = alice.outputs(data.images, data.ms_norm)
    prediction, variance_hat = readout_with_variance(outputs, run.readout)
    predictions = {"prediction": prediction, "softmax": readout(outputs, "softmax"),
                   "members": np.stack([prediction] + [m.predict(data.images, data.ms_norm, run.readout)
                                                       for m in members[1:]])}
    oof_error = _out_of_fold_errors(run)
    errors, bob_q, bob_error = _fit_bob(run, prediction, oof_error)
    mc_mean, mc_std, mc_conformal = _mc_dropout(run, alice, prediction)
    trivial = _trivial_predictors(run)
    # read from the image, or prior only? decided on validation (never test) and saved with the model
    train, val = run.splits["train"], run.splits["validation"]
    identification = alice_identification(name, run.u, prediction, data.ms_norm, data.sample_id, train, val, seed,
                                          int(settings["bootstrap"]))
    curve = _learning_curve(run, predictions["members"], trivial)
    metrics = _accuracy_metrics(run, alice, predictions, errors.conformal, bob_error, trivial)
    metrics.update({"paper": PAPER_FIGURES.get(name), "best_epoch": int(alice.best_epoch),
                    "epochs_run": len(alice.history["val_loss"]), "train_samples_per_s": float(throughput),
                    "wall_s": {k: float(v) for k, v in run.timings.items()}, "learning_curve": curve,
                    "validation_identification": identification["parameter"]})
    _add_linear_scale(run, metrics, prediction)
    bob_metrics, interval_rows = _interval_metrics(run, prediction, errors.conformal, bob_error,
                                                   (mc_mean, mc_std, mc_conformal), oof_error)
    metrics["bob"] = bob_metrics
    n = run.n
    ensemble_std = predictions["members"].std(axis=0, ddof=1) if run.n_seeds > 1 else np.full(n, np.nan)
    vhat_std = _finite_sigma(np.sqrt(variance_hat))
    sigmas = {"bob": bob_error, "vhat": vhat_std, "mc_dropout": mc_std}
    if run.n_seeds > 1:
        sigmas["ensemble"] = ensemble_std
    metrics["uncertainty_baselines"] = _uncertainty_baselines(sigmas, run.u, prediction, run.splits["calibration"],
                                                              run.splits["test"], run.levels)
    metrics["wall_s"]["total"] = float(sum(run.timings.values()))
    abs_error = np.abs(prediction - run.u)
    frame = pd.DataFrame({"sample_id": data.sample_id, "split": split_labels(n, run.splits), "target": run.u,
                          "prediction": prediction, "prediction_softmax": predictions["softmax"],
                          "abs_error": abs_error, "oof_error": oof_error, "bob_quantile": bob_q,
                          "bob_error": bob_error, "mc_mean": mc_mean, "mc_std": mc_std, "vhat_std": vhat_std,
                          "ensemble_std": ensemble_std, "ms_only_prediction": trivial["ms_only"],
                          **{f"prediction_seed_{k}": predictions["members"][k] for k in range(1, run.n_seeds)},
                          **interval_rows})
    io.write_parquet(predictions_path, frame)
    save_model(model_path, name=name, alice=alice, error_model=errors, settings=settings, data=data, metrics=metrics,
               identification=identification)
    _log_summary(run, metrics, identification)
    return metrics


def _checked_splits(data: LearningData, name: str, settings: dict, seed: int) -> dict:
    """The train / validation / calibration / test indices; a ``DatasetError`` where the dataset is
    smaller than ``min_samples`` or a split is empty."""
    n = len(data)
    if n < settings["min_samples"]:
        raise DatasetError(f"the dataset has {n} FORC families; training {name} needs at least "
                           f"{settings['min_samples']} (raise n_samples in the config)")
    splits = make_splits(data.sample_id, seed, settings)
    empty = [k for k in SPLITS if len(splits[k]) == 0]
    if empty:
        raise DatasetError(f"the {', '.join(empty)} split(s) of {n} FORC families are empty; "
                           f"raise n_samples or change learning.split {settings['split']}")
    return splits


def _fit_members(run: _Run) -> tuple:
    """Stage 1: ``seeds`` Alice networks (weight seeds of the ``alice`` stream) on train, early stopping
    on validation; returns (member 0, the reported Alice; all members)."""
    train, val = run.splits["train"], run.splits["validation"]
    started = time.perf_counter()
    members = []
    for k in range(run.n_seeds):
        run.log(f"{run.name}: Alice seed {k + 1}/{run.n_seeds} on {len(train)} training / {len(val)} validation samples")
        members.append(_fit(run.data, run.u, train, val, run.settings, stream_seed(run.seed, "alice", run.name, k)))
    run.timings["alice_s"] = time.perf_counter() - started
    return members[0], members


def _out_of_fold_errors(run: _Run) -> np.ndarray:
    """Stage 2: K-fold cross-fitting over the training split; Alice's absolute out-of-fold error per
    sample (normalized units; NaN outside train)."""
    data, u, train, val = run.data, run.u, run.splits["train"], run.splits["validation"]
    folds = max(2, min(run.settings["folds"], len(train)))
    fold_of = stream_rng(run.seed, "cross_fitting", run.name).permutation(len(train)) % folds
    oof_error = np.full(run.n, np.nan)
    started = time.perf_counter()
    for k in range(folds):
        held, kept = train[fold_of == k], train[fold_of != k]
        run.log(f"{run.name}: out-of-fold Alice {k + 1}/{folds} ({len(kept)} fitted, {len(held)} held)")
        fold_alice = _fit(data, u, kept, val, run.settings, stream_seed(run.seed, "alice_fold", run.name, k))
        oof_error[held] = np.abs(fold_alice.predict(data.images[held], data.ms_norm[held], run.readout) - u[held])
    run.timings["cross_fitting_s"] = time.perf_counter() - started
    return oof_error


def _fit_bob(run: _Run, prediction, oof_error) -> tuple:
    """Stage 3: Bob trained on the normalized quantile of Alice's out-of-fold error, and the
    Bob-normalized split-conformal intervals on the calibration split; returns (``ErrorModel``, Bob's
    quantile per sample, the error it maps to per sample)."""
    data, n, settings = run.data, run.n, run.settings
    train, val, cal = run.splits["train"], run.splits["validation"], run.splits["calibration"]
    abs_error = np.abs(prediction - run.u)
    reference = oof_error[train]
    bob_target = np.zeros(n)
    bob_target[train] = error_quantile(oof_error[train], reference)
    bob_target[val] = error_quantile(abs_error[val], reference)
    run.log(f"{run.name}: Bob on the out-of-fold error quantiles")
    started = time.perf_counter()
    # Bob's target is noisy (an error quantile given x is spread): twice the patience on its validation loss
    bob = _fit(data, bob_target, train, val, {**settings, "patience": 2 * settings["patience"]},
               stream_seed(run.seed, "bob", run.name))
    run.timings["bob_s"] = time.perf_counter() - started
    bob_q = bob.predict(data.images, data.ms_norm, run.readout)
    validation_errors = abs_error[val]
    bob_error = quantile_to_error(bob_q, validation_errors)
    conformal = ConformalIntervals.fit(abs_error[cal], bob_error[cal], run.levels)
    return ErrorModel(bob, validation_errors, conformal), bob_q, bob_error


def _mc_dropout(run: _Run, alice, prediction) -> tuple:
    """Stage 4: MC dropout on the calibration and test samples (mean and std per sample, NaN elsewhere)
    and its std conformalized on the calibration split."""
    data, n = run.data, run.n
    cal, test = run.splits["calibration"], run.splits["test"]
    abs_error = np.abs(prediction - run.u)
    mc_index = np.union1d(cal, test)
    mc_mean, mc_std = np.full(n, np.nan), np.full(n, np.nan)
    mc_mean[mc_index], mc_std[mc_index] = alice.mc_dropout(data.images[mc_index], data.ms_norm[mc_index],
                                                            run.settings["mc_passes"],
                                                            seed=stream_seed(run.seed, "mc_dropout", run.name),
                                                            method=run.readout)
    mc_conformal = ConformalIntervals.fit(abs_error[cal], mc_std[cal], run.levels)
    return mc_mean, mc_std, mc_conformal


def _trivial_predictors(run: _Run) -> dict:
    """Stage 5a: the trivial predictors fitted on train: ``prior`` (the train median of u), ``ms_k`` (the
    M_s-only neighbour count, chosen on validation) and ``ms_only`` (its prediction per sample)."""
    data, u, train, val = run.data, run.u, run.splits["train"], run.splits["validation"]
    prior = float(np.median(u[train]))
    ms_k = fit_ms_only(data.ms_norm[train], u[train], data.ms_norm[val], u[val])
    ms_only = knn_median(data.ms_norm[train], u[train], data.ms_norm, ms_k)
    return {"prior": prior, "ms_k": ms_k, "ms_only": ms_only}


def _learning_curve(run: _Run, member_predictions, trivial: dict) -> dict:
    """Stage 6: Alice on nested random subsets of train, one subset and weight seed per seed; each fit
    scored on validation (where choices such as the laptop film are made) and on test (reported), and a
    power law fitted to the test curve."""
    data, u, name, seed, n_seeds = run.data, run.u, run.name, run.seed, run.n_seeds
    train, val, test = run.splits["train"], run.splits["validation"], run.splits["test"]
    started = time.perf_counter()
    fractions = sorted(float(f) for f in run.settings["learning_curve"])
    sizes = [max(2, int(round(f * len(train)))) for f in fractions]
    curve_mae = {split: np.full((len(sizes), n_seeds), np.nan) for split in ("validation", "test")}
    # every curve fit's validation predictions, so that two runs (e.g. R = 1 and R = 4) can be compared
    # sample by sample on the validation ids they share (forcdecode bench realisations)
    curve_validation = np.full((len(sizes), n_seeds, len(val)), np.nan)
    scored = {"validation": val, "test": test}
    for k in range(n_seeds):
        order = stream_rng(seed, "learning_curve", name, k).permutation(train)
        for i, size in enumerate(sizes):
            if size >= len(train):
                curve_validation[i, k] = member_predictions[k, val]
                for split, index in scored.items():
                    curve_mae[split][i, k] = float(np.abs(member_predictions[k, index] - u[index]).mean())
                continue
            run.log(f"{name}: learning curve, {size} training samples, seed {k + 1}/{n_seeds}")
            partial = _fit(data, u, order[:size], val, run.settings, stream_seed(seed, "learning_curve", name, k, size))
            for split, index in scored.items():
                predicted = partial.predict(data.images[index], data.ms_norm[index], run.readout)
                if split == "validation":
                    curve_validation[i, k] = predicted
                curve_mae[split][i, k] = float(np.abs(predicted - u[index]).mean())
    run.timings["learning_curve_s"] = time.perf_counter() - started
    paper = PAPER_FIGURES.get(name)
    return {"fractions": fractions, "sizes": [min(s, len(train)) for s in sizes],
            "mae": curve_mae["test"].tolist(), "evaluated_on": "test",
            "mae_validation": curve_mae["validation"].tolist(),
            "validation_sample_ids": [int(i) for i in data.sample_id[val]],
            "validation_truth": u[val].tolist(),
            "validation_predictions": curve_validation.tolist(),
            # the trivial predictors on the validation split, to turn its MAE into skill
            "baselines_validation": {"prior": float(np.abs(trivial["prior"] - u[val]).mean()),
                                     "ms_only": float(np.abs(trivial["ms_only"][val] - u[val]).mean())},
            "fit": learning_curve_fit(np.minimum(sizes, len(train)), curve_mae["test"],
                                      paper["mae"] if paper else None,
                                      stream_rng(seed, "bootstrap", name, "curve"))}


def _accuracy_metrics(run: _Run, alice, predictions: dict, conformal, bob_error, trivial: dict) -> dict:
    """Stage 5b: accuracy on the test split with bootstrap intervals, against the prior, the M_s-only
    predictor and the test images shuffled; the seed members' spread; the softmax readout's MAE."""
    data, u, name, seed, settings = run.data, run.u, run.name, run.seed, run.settings
    train, val, cal, test = (run.splits[k] for k in SPLITS)
    prediction, member_predictions = predictions["prediction"], predictions["members"]
    prior, ms_only, n_seeds, levels = trivial["prior"], trivial["ms_only"], run.n_seeds, run.levels
    shuffle_rng = stream_rng(seed, "baseline_shuffle", name)
    shuffled_mae = []
    for _ in range(N_SHUFFLES):
        permuted = test[shuffle_rng.permutation(len(test))]
        shuffled = alice.predict(data.images[permuted], data.ms_norm[test], run.readout)
        shuffled_mae.append(float(np.abs(shuffled - u[test]).mean()))
    low90, high90 = conformal.interval(prediction[test], bob_error[test], 0.9) if 0.9 in levels else (None, None)
    covered_90 = (u[test] >= low90) & (u[test] <= high90) if low90 is not None else np.zeros(0)
    accuracy = accuracy_with_intervals(u[test], prediction[test], ms_only[test], np.full(len(test), prior), covered_90,
                                       stream_rng(seed, "bootstrap", name), n_boot=int(settings["bootstrap"]))
    seed_mae = np.abs(member_predictions[:, test] - u[test]).mean(axis=1)
    return {"parameter": name, "n_train": int(len(train)), "n_validation": int(len(val)),
            "n_calibration": int(len(cal)), "n_test": int(len(test)),
            "reported_on": "validation (paper protocol)" if settings["protocol"] == "paper" else "test",
            "log_scale": name in LOG_SCALE, **accuracy,
            "coverage_90_binomial_band": binomial_band(len(test), 0.9),
            "baseline_mae": float(np.abs(prior - u[test]).mean()), "skill": accuracy["skill_vs_prior"],
            "baselines": {"prior": float(np.abs(prior - u[test]).mean()),
                          "ms_only": float(np.abs(ms_only[test] - u[test]).mean()), "ms_only_k": trivial["ms_k"],
                          "images_shuffled": float(np.mean(shuffled_mae)),
                          "images_shuffled_spread": float(np.std(shuffled_mae))},
            "seeds": {"n": n_seeds, "mae": seed_mae.tolist(), "mean": float(seed_mae.mean()),
                      "std": float(seed_mae.std(ddof=1)) if n_seeds > 1 else 0.0,
                      "ensemble_mae": float(np.abs(member_predictions[:, test].mean(axis=0) - u[test]).mean())},
            "mae_softmax_readout": float(np.abs(predictions["softmax"][test] - u[test]).mean())}


def _add_linear_scale(run: _Run, metrics: dict, prediction) -> None:
    """For a log-scale parameter, the test MAE also on the linear scale (the paper does not say on which
    scale its K_u MAE is; report both), in ``metrics["normalisation"]``."""
    name, u, train, test = run.name, run.u, run.splits["train"], run.splits["test"]
    if name not in LOG_SCALE:
        return
    lo, hi = run.data.bounds[name]
    linear = lambda x: (denormalize(name, x, run.data.bounds) - lo) / (hi - lo)  # noqa: E731
    metrics["normalisation"] = {"log": metrics["mae"],
                                "linear": float(np.abs(linear(prediction[test]) - linear(u[test])).mean()),
                                "linear_prior": float(np.abs(np.median(linear(u[train])) - linear(u[test])).mean())}


def _interval_metrics(run: _Run, prediction, conformal, bob_error, mc: tuple, oof_error) -> tuple:
    """Stage 4b: Bob's and MC dropout's interval figures on the test split (Spearman ρ with the error,
    coverage and width per level, error–retention curves) and every sample's Bob interval per level;
    ``mc`` is (MC-dropout mean, std, conformal intervals). Returns (metrics, interval columns)."""
    u, train, test, levels = run.u, run.splits["train"], run.splits["test"], run.levels
    mc_mean, mc_std, mc_conformal = mc
    abs_error = np.abs(prediction - u)
    bob_metrics = {"bob_spearman": spearman(bob_error[test], abs_error[test]),
                   "mc_dropout_spearman": spearman(mc_std[test], abs_error[test]),
                   "oof_mae": float(np.nanmean(oof_error[train])), "in_sample_mae": float(abs_error[train].mean())}
    interval_rows = {}
    for level in levels:
        tag = f"{int(round(level * 100))}"
        low, high = conformal.interval(prediction[test], bob_error[test], level)
        bob_metrics[f"coverage_{tag}"], bob_metrics[f"width_{tag}"] = coverage_and_width(u[test], low, high)
        interval_rows[f"low_{tag}"], interval_rows[f"high_{tag}"] = conformal.interval(prediction, bob_error, level)
        low, high = gaussian_interval(mc_mean[test], mc_std[test], level)
        bob_metrics[f"mc_coverage_{tag}"], bob_metrics[f"mc_width_{tag}"] = coverage_and_width(u[test], low, high)
        low, high = mc_conformal.interval(prediction[test], mc_std[test], level)
        bob_metrics[f"mc_conformal_coverage_{tag}"], bob_metrics[f"mc_conformal_width_{tag}"] = coverage_and_width(u[test], low, high)
    fractions_kept = np.linspace(0.05, 1.0, 20)
    _, bob_curve, bob_area = retention_curve(abs_error[test], bob_error[test], fractions_kept)
    _, oracle_curve, oracle_area = retention_curve(abs_error[test], abs_error[test], fractions_kept)
    _, mc_curve, mc_area = retention_curve(abs_error[test], mc_std[test], fractions_kept)
    bob_metrics["retention"] = {"fractions": fractions_kept.tolist(), "bob": bob_curve.tolist(), "oracle": oracle_curve.tolist(),
                                "mc_dropout": mc_curve.tolist(), "random": float(abs_error[test].mean()),
                                "area_bob": bob_area, "area_oracle": oracle_area, "area_mc_dropout": mc_area,
                                "area_random": float(abs_error[test].mean()) * (fractions_kept[-1] - fractions_kept[0])}
    return bob_metrics, interval_rows


def _log_summary(run: _Run, metrics: dict, identification: dict) -> None:
    """The two lines a training run ends with: the test figures, and whether the parameter is read."""
    name, base, bob_metrics = run.name, metrics["baselines"], metrics["bob"]
    run.log(f"{name}: test MAE {metrics['mae']:.3f} [{metrics['mae_ci90'][0]:.3f}, {metrics['mae_ci90'][1]:.3f}] "
            f"(M_s only {base['ms_only']:.3f}, prior {base['prior']:.3f}, shuffled images {base['images_shuffled']:.3f}); "
            f"skill vs M_s only {metrics['skill_vs_ms_only']:.2f} {np.round(metrics['skill_vs_ms_only_ci90'], 2).tolist()}; "
            f"r {metrics['pearson_r']:.2f}; Bob Spearman {bob_metrics['bob_spearman']:.2f}; "
            f"coverage 68/90 % {bob_metrics['coverage_68']:.2f}/{bob_metrics['coverage_90']:.2f}")
    run.log(f"{name}: read from the image? {identification['parameter']['read_from_image']} "
            f"({identification['parameter']['basis']})")


def save_model(path, *, name, alice, error_model: ErrorModel, settings, data, metrics, identification=None) -> None:
    """Everything ``predict`` needs: both networks (Alice, and Bob in ``error_model`` with his error
    mapping and conformal intervals), the normalization, the config hash, the prior class of the
    training data (``prior_class``; files without it: paper), and whether the parameter is read from the
    image (``learn.answer.alice_identification``: validation figures and the validation records a
    combination's flag needs)."""
    bob, validation_errors, conformal = error_model.bob, error_model.validation_errors, error_model.conformal
    payload = {
        "format": "forcdecode-alice-bob/1", "parameter": name,
        "architecture": {"model": settings["model"], "width": int(settings["width"]),
                         "image_size": int(data.images.shape[-1])},
        "readout": settings["readout"], "bounds": {k: [float(v[0]), float(v[1])] for k, v in data.bounds.items()},
        "log_scale": name in LOG_SCALE, "config_hash": data.config_hash,
        "prior_class": getattr(data, "prior_class", DEFAULT_PRIOR_CLASS),
        "alice_state": alice.net.state_dict(), "bob_state": bob.net.state_dict(),
        "validation_errors": [float(x) for x in validation_errors],
        "conformal": {"levels": list(conformal.levels), "quantiles": {str(k): float(v) for k, v in conformal.quantiles.items()},
                      "sigma_floor": conformal.sigma_floor},
        "metrics": _plain(metrics),
    }
    if identification is not None:
        payload["identification"] = _plain(identification)
    with io.atomic_path(path) as tmp:
        torch.save(payload, tmp)


def _plain(obj):
    """JSON-like copy (floats, lists, dicts, str, None) of a metrics tree."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if isinstance(obj, (np.integer, int, bool)) and not isinstance(obj, bool):
        return int(obj)
    return obj
