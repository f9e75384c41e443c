"""Train, cross-fit and evaluate the networks of one parameter: Alice, Bob, their intervals.

Protocol (``holdout``, the default): the dataset is split once, reproducibly from the config seed,
into train / validation / calibration / test, the same split for every parameter.

1. Alice: fitted on train, early stopping and best epoch on validation.
2. Out-of-fold errors: K-fold cross-fitting over the train split (an Alice per fold, fitted on the
   other folds) gives every training sample an error Alice did not see while fitting it.
3. Bob: the same network family, trained to output the normalized quantile of Alice's out-of-fold
   error (validation targets: Alice's validation errors ranked in that distribution).
4. Bob's quantile → error by Alice's validation-set error distribution (the seed paper's recipe);
   that error is the difficulty σ(x) of a normalized split-conformal interval fitted on the
   calibration set; MC dropout (Alice's own dropout) gives the comparison intervals.
5. Everything reported is measured on the test split, which no choice was made on.

``paper`` protocol: the seed paper's 80/20 train/validation split; figures are then reported on
that validation set (flagged in the metrics), which also calibrates.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import torch
from scipy.stats import pearsonr

from ..dataset import io
from ..dataset.params import LOG_SCALE
from .data import PAPER_FIGURES, TARGETS, LearningData
from .encoding import readout
from .train import fit_alice, split_indices
from .uncertainty import (ConformalIntervals, coverage_and_width, error_quantile, gaussian_interval,
                          quantile_to_error, retention_curve, spearman)

DEFAULT_SETTINGS = {
    "parameters": ["N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K"],
    "model": "small", "width": 256, "lr": 1.0, "epochs": 200, "patience": 25, "batch_size": 8,
    "protocol": "holdout", "split": [0.55, 0.15, 0.15, 0.15], "folds": 5, "mc_passes": 30,
    "learning_curve": [0.25, 0.5, 1.0], "levels": [0.68, 0.9], "readout": "parabola", "min_samples": 8,
}

SPLIT_SEED_STREAM = 4_000_004
"""Offset added to the config seed for the split (the same split for every parameter)."""


def make_splits(n: int, seed: int, settings: dict) -> dict:
    """Index arrays for train / validation / calibration / test."""
    if settings["protocol"] == "paper":
        train, val = split_indices(n, seed + SPLIT_SEED_STREAM, (0.8, 0.2))
        return {"train": train, "validation": val, "calibration": val, "test": val}
    train, val, cal, test = split_indices(n, seed + SPLIT_SEED_STREAM, tuple(settings["split"]))
    return {"train": train, "validation": val, "calibration": cal, "test": test}


def _fit(data, target, train, val, settings, seed, log=None):
    return fit_alice(data.images, data.ms_norm, target, train, val, model=settings["model"], width=settings["width"],
                     epochs=settings["epochs"], batch_size=settings["batch_size"], lr=settings["lr"],
                     patience=settings["patience"], seed=seed, log=log)


def scores(truth, prediction, baseline_value) -> dict:
    truth, prediction = np.asarray(truth, float), np.asarray(prediction, float)
    mae = float(np.mean(np.abs(prediction - truth)))
    baseline = float(np.mean(np.abs(baseline_value - truth)))
    r = float(pearsonr(prediction, truth).statistic) if truth.size > 2 and np.std(prediction) > 0 else float("nan")
    return {"mae": mae, "pearson_r": r, "baseline_mae": baseline, "skill": 1.0 - mae / baseline if baseline > 0 else float("nan")}


def train_parameter(data: LearningData, name: str, settings: dict, seed: int, model_path, predictions_path,
                    log=print) -> dict:
    """Fit Alice and Bob for ``name``; write the model file and the per-sample predictions; return metrics."""
    settings = {**DEFAULT_SETTINGS, **settings}
    n = len(data)
    if n < settings["min_samples"]:
        raise SystemExit(f"error: the dataset has {n} FORC families; training {name} needs at least "
                         f"{settings['min_samples']} (raise n_samples in the config)")
    splits = make_splits(n, seed, settings)
    train, val, cal, test = (splits[k] for k in ("train", "validation", "calibration", "test"))
    u = data.target(name)
    net_seed = seed + 17 * (1 + TARGETS.index(name)) if name in TARGETS else seed
    timings = {}

    log(f"{name}: Alice on {len(train)} training / {len(val)} validation samples")
    started = time.perf_counter()
    alice = _fit(data, u, train, val, settings, net_seed)
    timings["alice_s"] = time.perf_counter() - started
    throughput = alice.history["samples_seen"] / max(alice.history["train_seconds"], 1e-9)
    outputs = alice.outputs(data.images, data.ms_norm)
    prediction, prediction_softmax = readout(outputs, settings["readout"]), readout(outputs, "softmax")
    abs_error = np.abs(prediction - u)

    # out-of-fold errors over the training split (K-fold cross-fitting)
    folds = max(2, min(settings["folds"], len(train)))
    fold_of = np.random.default_rng(seed + 99).permutation(len(train)) % folds
    oof_error = np.full(n, np.nan)
    started = time.perf_counter()
    for k in range(folds):
        held, kept = train[fold_of == k], train[fold_of != k]
        log(f"{name}: out-of-fold Alice {k + 1}/{folds} ({len(kept)} fitted, {len(held)} held)")
        fold_alice = _fit(data, u, kept, val, settings, net_seed + 1000 + k)
        oof_error[held] = np.abs(fold_alice.predict(data.images[held], data.ms_norm[held], settings["readout"]) - u[held])
    timings["cross_fitting_s"] = time.perf_counter() - started

    # Bob: normalized quantile of Alice's out-of-fold error
    reference = oof_error[train]
    bob_target = np.zeros(n)
    bob_target[train] = error_quantile(oof_error[train], reference)
    bob_target[val] = error_quantile(abs_error[val], reference)
    log(f"{name}: Bob on the out-of-fold error quantiles")
    started = time.perf_counter()
    # Bob's target is noisy (an error quantile given x is spread): twice the patience on its validation loss
    bob = _fit(data, bob_target, train, val, {**settings, "patience": 2 * settings["patience"]}, net_seed + 2000)
    timings["bob_s"] = time.perf_counter() - started
    bob_q = bob.predict(data.images, data.ms_norm, settings["readout"])
    validation_errors = abs_error[val]
    bob_error = quantile_to_error(bob_q, validation_errors)

    # intervals: Bob-normalized split conformal, and MC dropout (raw and conformalized)
    levels = [float(a) for a in settings["levels"]]
    conformal = ConformalIntervals.fit(abs_error[cal], bob_error[cal], levels)
    mc_index = np.union1d(cal, test)
    mc_mean, mc_std = np.full(n, np.nan), np.full(n, np.nan)
    mc_mean[mc_index], mc_std[mc_index] = alice.mc_dropout(data.images[mc_index], data.ms_norm[mc_index],
                                                            settings["mc_passes"], seed=net_seed + 3000,
                                                            method=settings["readout"])
    mc_conformal = ConformalIntervals.fit(abs_error[cal], mc_std[cal], levels)

    # learning curve (test MAE against the size of the training set; validation fixed)
    curve = []
    for fraction in settings["learning_curve"]:
        size = max(2, int(round(fraction * len(train))))
        if size >= len(train):
            curve.append({"fraction": float(fraction), "n_train": int(len(train)), "test_mae": float(abs_error[test].mean())})
            continue
        log(f"{name}: learning curve, {size} training samples")
        partial = _fit(data, u, train[:size], val, settings, net_seed + 4000 + size)
        curve.append({"fraction": float(fraction), "n_train": int(size),
                      "test_mae": float(np.abs(partial.predict(data.images[test], data.ms_norm[test], settings["readout"]) - u[test]).mean())})

    # metrics on the test split
    baseline_value = float(np.median(u[train]))
    metrics = {"parameter": name, "n_train": int(len(train)), "n_validation": int(len(val)),
               "n_calibration": int(len(cal)), "n_test": int(len(test)),
               "reported_on": "validation (paper protocol)" if settings["protocol"] == "paper" else "test",
               "log_scale": name in LOG_SCALE, **scores(u[test], prediction[test], baseline_value),
               "mae_softmax_readout": float(np.abs(prediction_softmax[test] - u[test]).mean()),
               "paper": PAPER_FIGURES.get(name), "best_epoch": int(alice.best_epoch),
               "epochs_run": len(alice.history["val_loss"]), "train_samples_per_s": float(throughput),
               "wall_s": {k: float(v) for k, v in timings.items()}, "learning_curve": curve}
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
    fractions = np.linspace(0.05, 1.0, 20)
    _, bob_curve, bob_area = retention_curve(abs_error[test], bob_error[test], fractions)
    _, oracle_curve, oracle_area = retention_curve(abs_error[test], abs_error[test], fractions)
    _, mc_curve, mc_area = retention_curve(abs_error[test], mc_std[test], fractions)
    bob_metrics["retention"] = {"fractions": fractions.tolist(), "bob": bob_curve.tolist(), "oracle": oracle_curve.tolist(),
                                "mc_dropout": mc_curve.tolist(), "random": float(abs_error[test].mean()),
                                "area_bob": bob_area, "area_oracle": oracle_area, "area_mc_dropout": mc_area,
                                "area_random": float(abs_error[test].mean()) * (fractions[-1] - fractions[0])}
    metrics["bob"] = bob_metrics
    metrics["wall_s"]["total"] = float(sum(timings.values()))

    split_of = np.empty(n, dtype=object)
    for key in ("train", "validation", "calibration", "test"):
        split_of[splits[key]] = key  # paper protocol: validation = calibration = test ("test" wins)
    frame = pd.DataFrame({"sample_id": data.sample_id, "split": split_of.astype(str), "target": u,
                          "prediction": prediction, "prediction_softmax": prediction_softmax,
                          "abs_error": abs_error, "oof_error": oof_error, "bob_quantile": bob_q,
                          "bob_error": bob_error, "mc_mean": mc_mean, "mc_std": mc_std, **interval_rows})
    io.write_parquet(predictions_path, frame)
    save_model(model_path, name=name, alice=alice, bob=bob, settings=settings, data=data,
               validation_errors=validation_errors, conformal=conformal, metrics=metrics)
    log(f"{name}: test MAE {metrics['mae']:.3f} (baseline {metrics['baseline_mae']:.3f}), r {metrics['pearson_r']:.2f}, "
        f"Bob Spearman {bob_metrics['bob_spearman']:.2f}, coverage 68/90 % {bob_metrics['coverage_68']:.2f}/"
        f"{bob_metrics['coverage_90']:.2f}")
    return metrics


def save_model(path, *, name, alice, bob, settings, data, validation_errors, conformal, metrics) -> None:
    """Everything ``predict`` needs: both networks, the normalization, the error mapping, the config hash."""
    payload = {
        "format": "forcdecode-alice-bob/1", "parameter": name,
        "architecture": {"model": settings["model"], "width": int(settings["width"]),
                         "image_size": int(data.images.shape[-1])},
        "readout": settings["readout"], "bounds": {k: [float(v[0]), float(v[1])] for k, v in data.bounds.items()},
        "log_scale": name in LOG_SCALE, "config_hash": data.config_hash,
        "alice_state": alice.net.state_dict(), "bob_state": bob.net.state_dict(),
        "validation_errors": [float(x) for x in validation_errors],
        "conformal": {"levels": list(conformal.levels), "quantiles": {str(k): float(v) for k, v in conformal.quantiles.items()},
                      "sigma_floor": conformal.sigma_floor},
        "metrics": _plain(metrics),
    }
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
