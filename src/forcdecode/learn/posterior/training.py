"""The posterior's training (``learn.posterior``): ``fit_posterior`` fits the embedding, the regression
head and the flow on the train split with early stopping on validation (an ensemble of members from
independent weight seeds), and ``train_posterior``, the workflow stage, fits it, recalibrates and
calibrates it on the held-out splits and writes the model, metrics.json and the calibration figure."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from ...config import defaults
from ...core import io
from ...core.errors import ConfigError, DatasetError
from ...core.parameters import LOG_SCALE, TARGETS
from ...core.streams import stream_rng, stream_seed
from ..answer import posterior_identification
from ..calibration import (RECALIBRATION_MIN_SAMPLES, calibration_figure, calibration_metrics, conformal_coverage,
                           conformal_widening, recalibrated_calibration)
from ..combinations import (CombinationScoring, ReferenceFamilies, available, posterior_combination_metrics,
                            ridge_figure, ridge_summary)
from ..ood import fit_ood_reference, ood_check
from ..scoring import binomial_band
from ..splits import SPLITS, assign_splits
from ..train import with_float32_default
from .calibration import (fit_held_out_recalibration, recalibration_families, recalibration_holdout,
                          split_diagnostics)
from .estimator import PosteriorEstimator
from .file_format import FORMAT
from .flow import BOUNDED_SUPPORT, EMBEDDINGS, PosteriorNet, _float32, _make_embedding, posterior_settings, to_latent


@dataclass(frozen=True)
class PosteriorFit:
    """What one posterior fit learns and how.

    - ``names``: the parameters, in the order of the targets' columns;
    - ``settings``: posterior settings over the schema's ``posterior`` defaults (``posterior_settings``;
      None: the defaults);
    - ``seed``: the weight seed (of member 0; the ensemble's other members derive theirs from it);
    - ``embedding``: ``"cnn"`` (uint8 images, square) or ``"mlp"`` (float feature vectors);
    - ``bounds``: name → (low, high) prior bounds of each parameter (SI units), for the draws in SI;
    - ``prior_class``: the draw prior class of the training data (``core.parameters``)."""

    names: tuple
    settings: dict | None = None
    seed: int = 0
    embedding: str = "cnn"
    bounds: dict | None = None
    prior_class: str = "paper"


class _Tensors(NamedTuple):
    """Every family's network inputs and targets: ``x`` (images or features), ``ms`` (normalized M_s,
    (n,)) and ``z`` (standardized latent targets, (n, len(names)))."""

    x: torch.Tensor
    ms: torch.Tensor
    z: torch.Tensor


@_float32
@with_float32_default
def fit_posterior(x, ms_norm, u, train, val, fit: PosteriorFit, *, log=None) -> PosteriorEstimator:
    """Maximum-likelihood fit of the flow and the embedding on ``train`` (AdamW), keeping the weights
    of the epoch with the lowest validation negative log-likelihood; ``x`` are uint8 images (cnn) or
    float vectors (mlp), ``u`` the targets in [0, 1], shape (n, len(fit.names)).

    ``settings["ensemble"]`` = K > 1 fits K members from independent weight seeds (member 0 from
    ``fit.seed`` itself, the others from the ``posterior`` stream's ``ensemble_fit`` keys) on the same
    split; the posterior is their equal mixture (a deep ensemble: members that agree where the data
    speak and disagree where they do not, so the mixture is wider exactly where one flow's
    maximum-likelihood fit on a few hundred families is over-sure)."""
    settings = posterior_settings(fit.settings)
    seed = fit.seed
    members = []
    for k in range(int(settings["ensemble"])):
        member_seed = seed if k == 0 else stream_seed(seed, "posterior", "ensemble_fit", k)
        if log is not None and settings["ensemble"] > 1:
            log(f"posterior ensemble member {k + 1}/{settings['ensemble']}")
        members.append(_fit_member(x, ms_norm, u, train, val, replace(fit, settings=settings, seed=member_seed), log))
    est = members[0]
    est.members = [m.net for m in members[1:]]
    if len(members) > 1:
        est.history["ensemble_best_epochs"] = [int(m.best_epoch) for m in members]
        est.history["ensemble_val_nll"] = [float(m.history["val_nll"][m.best_epoch]) for m in members]
        est.history["train_seconds"] = float(sum(m.history["train_seconds"] for m in members))
    return est


def _fit_member(x, ms_norm, u, train, val, fit: PosteriorFit, log) -> PosteriorEstimator:
    """One flow (and its embedding) fitted from the weight seed ``fit.seed`` with the resolved
    ``fit.settings``: see :func:`fit_posterior`."""
    names, settings, seed, embedding = fit.names, fit.settings, fit.seed, fit.embedding
    bounds, prior_class = fit.bounds, fit.prior_class
    u = np.asarray(u, dtype=float)
    train, val = np.asarray(train), np.asarray(val)
    if u.ndim != 2 or u.shape[1] != len(names) or u.shape[0] != len(np.asarray(x)):
        raise DatasetError(f"targets of shape {u.shape} do not match {len(np.asarray(x))} observations of {len(names)} parameters")
    if not np.isfinite(u).all() or u.min() < 0.0 or u.max() > 1.0:
        raise DatasetError("normalized targets must be finite and inside [0, 1]")
    if len(train) < 2 or len(val) < 1:
        raise DatasetError(f"the posterior needs at least 2 training and 1 validation samples (got {len(train)}, {len(val)})")
    if embedding not in EMBEDDINGS:
        raise ConfigError(f"unknown embedding {embedding!r} (one of {', '.join(EMBEDDINGS)})")
    x = np.asarray(x)
    architecture = {"embedding": embedding, "summary": settings["summary"], "coordinates": settings["coordinates"],
                    "dim": len(names), "width": int(settings["width"]),
                    "dropout": float(settings["dropout"]), "transforms": int(settings["transforms"]),
                    "hidden": int(settings["hidden"]), "bins": int(settings["bins"])}
    if embedding == "cnn":
        if x.ndim != 3 or x.shape[1] != x.shape[2]:
            raise DatasetError(f"the CNN embedding needs square images (n, side, side), got {x.shape}")
        architecture["image_size"] = int(x.shape[-1])
    else:
        if x.ndim != 2:
            raise DatasetError(f"the MLP embedding needs vectors (n, features), got {x.shape}")
        architecture["features"] = int(x.shape[1])
    torch.manual_seed(stream_seed(seed, "posterior", "weights"))
    net = PosteriorNet(architecture)
    est = PosteriorEstimator(net, architecture, tuple(names), dict(bounds or {}), prior_class=prior_class)
    if architecture["coordinates"] == "prior" and not set(names) <= set(TARGETS):
        raise ConfigError(f"coordinates: prior needs the dataset's parameters (a draw prior), got {list(names)}; "
                          "use coordinates: box")
    x_all, ms_all = est._inputs(x, ms_norm)
    z = to_latent(est.to_coordinates(u, ms_all.double().numpy()))
    mean, std = z[train].mean(axis=0), z[train].std(axis=0) + 1e-6
    net.z_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
    net.z_std.copy_(torch.as_tensor(std, dtype=torch.float32))
    z_all = torch.as_tensor((z - mean) / std, dtype=torch.float32)
    generator = torch.Generator().manual_seed(stream_seed(seed, "posterior", "batches"))
    train_t, val_t = torch.as_tensor(train), torch.as_tensor(val)
    started = time.perf_counter()
    history = {}
    mode = settings["summary"]
    if mode == "joint":
        # embedding and flow together, by the flow's likelihood alone
        def nll(index):
            return -net.log_prob(z_all[index], x_all[index], ms_all[index]).mean()

        history["train_nll"], history["val_nll"], best_epoch = _train(net, nll, train_t, val_t, settings, generator,
                                                                      log, "posterior NLL")
    else:
        # 1. the embedding and a linear head as a regression of the standardized logits (early stopping
        #    on validation): learned summaries, estimates of the posterior means
        tensors = _Tensors(x_all, ms_all, z_all)
        history["regression_train_mse"], history["regression_val_mse"], history["regression_best_epoch"] = _fit_regression(
            net.embedding, net.head, tensors, (train_t, val_t), settings, generator, log, "summary regression")
        net.embedding.requires_grad_(False)
        net.head.requires_grad_(False)
        with torch.no_grad():
            ctx_all = net.context(x_all, ms_all)
        if mode == "crossfit":
            # 2. the training samples' summaries out of fold (K regressions, each blind to its fold):
            #    the flow then learns how far summaries of unseen images are from the truth, as at test
            folds = max(2, min(int(settings["folds"]), len(train)))
            fold_of = stream_rng(seed, "posterior", "folds").permutation(len(train)) % folds
            for k in range(folds):
                held, kept = train[fold_of == k], train[fold_of != k]
                torch.manual_seed(stream_seed(seed, "posterior", "fold_weights", k))
                embedding, head = _make_embedding(architecture).float(), nn.Linear(architecture["width"] + 1, len(names)).float()
                _fit_regression(embedding, head, tensors, (torch.as_tensor(kept), val_t), settings,
                                generator, log, f"summary regression, fold {k + 1}/{folds}")
                with torch.no_grad():
                    held_t = torch.as_tensor(held)
                    features = torch.cat([embedding(x_all[held_t], ms_all[held_t]), ms_all[held_t].reshape(-1, 1)], 1)
                    ctx_all[held_t] = torch.cat([head(features), ms_all[held_t].reshape(-1, 1)], dim=1)
        # 3. the flow on the fixed summaries

        def nll(index):
            return -net.flow(ctx_all[index]).log_prob(z_all[index]).mean()

        history["train_nll"], history["val_nll"], best_epoch = _train(net.flow, nll, train_t, val_t, settings,
                                                                      generator, log, "posterior NLL")
        net.embedding.requires_grad_(True)
        net.head.requires_grad_(True)
    history["train_seconds"] = time.perf_counter() - started
    net.eval()
    est.history, est.best_epoch = history, best_epoch
    return est


def _fit_regression(embedding, head, tensors: _Tensors, index: tuple, settings, generator, log, what):
    """Fit ``embedding`` + linear ``head`` by the MSE of the standardized logits ``tensors.z`` on the
    training indices ``index[0]`` (early stopping on the validation indices ``index[1]``); returns
    (train MSEs, validation MSEs, best epoch)."""
    x_all, ms_all, z_all = tensors
    train_t, val_t = index
    module = nn.ModuleDict({"embedding": embedding, "head": head})

    def mse(index):
        features = torch.cat([embedding(x_all[index], ms_all[index]), ms_all[index].reshape(-1, 1)], dim=1)
        return torch.nn.functional.mse_loss(head(features), z_all[index])

    return _train(module, mse, train_t, val_t, settings, generator, log, what)


def _train(module: nn.Module, loss_of, train_t, val_t, settings, generator, log, what: str):
    """AdamW on ``loss_of(batch indices)`` over the training indices; early stopping on the validation
    loss; the module is left with the weights of its best epoch. Returns (train losses, validation
    losses, best epoch)."""
    optimizer = torch.optim.AdamW([p for p in module.parameters() if p.requires_grad], lr=settings["lr"],
                                  weight_decay=settings["weight_decay"])
    train_loss, val_loss = [], []
    best, best_state, best_epoch, waited = np.inf, None, -1, 0
    batch_size, epochs = int(settings["batch_size"]), int(settings["epochs"])
    for epoch in range(epochs):
        module.train()
        order = train_t[torch.randperm(len(train_t), generator=generator)]
        total = 0.0
        for start in range(0, len(order), batch_size):
            batch = order[start:start + batch_size]
            optimizer.zero_grad()
            loss = loss_of(batch)
            loss.backward()
            optimizer.step()
            total += loss.item() * len(batch)
        module.eval()
        with torch.no_grad():
            val = float(loss_of(val_t))
        train_loss.append(total / len(order))
        val_loss.append(val)
        if log is not None and (epoch % 10 == 0 or epoch == epochs - 1):
            log(f"{what}, epoch {epoch + 1}: train {train_loss[-1]:.3f}, validation {val:.3f}")
        if np.isfinite(val) and val < best:
            best, best_epoch, waited = val, epoch, 0
            best_state = {k: v.detach().clone() for k, v in module.state_dict().items()}
        else:
            waited += 1
            if waited >= int(settings["patience"]):
                break
    if best_state is None:
        raise DatasetError(f"the {what} on the validation split was never finite")
    module.load_state_dict(best_state)
    module.eval()
    return train_loss, val_loss, best_epoch


def _regression_summary(history: dict) -> dict | None:
    """Best epoch, epochs run and validation MSE (standardized logits) of the summary regression."""
    if "regression_best_epoch" not in history:
        return None
    best = int(history["regression_best_epoch"])
    return {"best_epoch": best, "epochs_run": len(history["regression_val_mse"]),
            "validation_mse": float(history["regression_val_mse"][best])}



SHUFFLED_DRAWS = 200
"""Draws per test family of the images-shuffled baseline (only its median is used)."""


@dataclass
class _PosteriorRun:
    """What every stage of ``train_posterior`` reads: the data, the merged posterior and learning
    settings, the parameters' names, the config seed, the split indices, the normalized truths ``u``
    (n, len(names)) and the progress log."""

    data: object
    settings: dict
    learning: dict
    names: tuple
    seed: int
    splits: dict
    u: np.ndarray
    log: object

    @property
    def draws(self) -> int:
        """Posterior draws per family."""
        return int(self.settings["draws"])

    @property
    def levels(self) -> list:
        """Central credible-interval levels (fractions in (0, 1))."""
        return [float(a) for a in self.settings["levels"]]

    @property
    def n_boot(self) -> int:
        """Bootstrap resamples behind each figure's interval."""
        return int(self.learning["bootstrap"])

    @property
    def holdout_protocol(self) -> bool:
        return self.learning["protocol"] == "holdout"


def _combinations_and_ridge(run: _PosteriorRun, est, samples, ridge_path):
    """The derived combinations' metrics on the test families (``learn.combinations``: transforms of the
    scored test draws ``samples``, baselines prior / M_s-only / images shuffled) and the A_ex–D ridge
    (per-family correlation, its median, the figure at ``ridge_path``); ({}, None) where the posterior
    learns none of the combinations' parameters."""
    data, u, splits, seed, levels, n_boot = run.data, run.u, run.splits, run.seed, run.levels, run.n_boot
    names = tuple(est.names)
    train, val, test = splits["train"], splits["validation"], splits["test"]
    ridge = ridge_summary(samples, names, stream_rng(seed, "posterior", "ridge"), n_boot)
    if ridge is not None:
        ridge["ridge_figure"] = ridge_path.name if ridge_figure(samples, u[test], names, data.ms_norm[test],
                                                                data.bounds, ridge_path, labels=data.sample_id[test]) else None
    if not available(names):
        return {}, ridge
    permuted = test[stream_rng(seed, "posterior", "shuffle").permutation(len(test))]
    shuffled = est.sample(data.images[permuted], data.ms_norm[test], SHUFFLED_DRAWS,
                          seed=stream_seed(seed, "posterior", "shuffled_draws"))
    reference = ReferenceFamilies(train_u=u[train], train_ms_norm=data.ms_norm[train], val_u=u[val],
                                  val_ms_norm=data.ms_norm[val])
    scoring = CombinationScoring(rng_of=lambda *keys: stream_rng(seed, "posterior", "combinations", *keys),
                                 levels=levels, n_boot=n_boot)
    combinations = posterior_combination_metrics(samples, u[test], names, data.ms_norm[test], data.bounds,
                                                 reference=reference, scoring=scoring, shuffled=shuffled)
    return combinations, ridge


def train_posterior(data, settings: dict | None, learning: dict | None, seed: int, model_path, metrics_path,
                    figure_path, log=print) -> dict:
    """Fit the posterior on the workflow's train split (validation for early stopping) less the part held
    out for its recalibration (``posterior.recalibration_holdout``), recalibrate it on that part and the
    calibration split, calibrate it on the test split; write the model, metrics.json and the calibration
    figure (all atomically)."""
    run = _posterior_run(data, settings, learning, seed, log)
    settings, learning, names, splits, u = run.settings, run.learning, run.names, run.splits, run.u
    train, val, test = splits["train"], splits["validation"], splits["test"]
    # a part of train held out from the flow for its recalibration (none without one)
    recalibrating = settings["recalibrate"] and run.holdout_protocol
    flow_train, holdout = recalibration_holdout(data.sample_id, train, seed,
                                                settings["recalibration_holdout"] if recalibrating else 0.0)
    log(f"posterior: {len(names)} parameters, {len(flow_train)} training / {len(val)} validation / {len(test)} test "
        f"samples" + (f" ({len(holdout)} of the train split held out for the recalibration)" if len(holdout) else ""))
    started = time.perf_counter()
    est = fit_posterior(data.images, data.ms_norm, u, flow_train, val,
                        PosteriorFit(names=names, settings=settings, seed=seed, embedding="cnn", bounds=data.bounds,
                                     prior_class=getattr(data, "prior_class", "paper")), log=log)
    train_s = time.perf_counter() - started
    # calibrated on validation + calibration families (held out from the flow, never test): with ~20 each
    # the conformal p-value can reach 1/42, below the Bonferroni level 0.025 of two scores at alpha 0.05
    est.metadata["ood"] = fit_ood_reference(est, data.images, data.ms_norm, flow_train,
                                            np.union1d(val, splits["calibration"]))
    test_ood = ood_check(est, data.images[test], data.ms_norm[test])
    started = time.perf_counter()
    recalibration = _recalibration(run, est, holdout) if recalibrating else None
    samples = est.sample(data.images[test], data.ms_norm[test], run.draws,
                         seed=stream_seed(seed, "posterior", "test_draws"), recalibrated=False)
    # scored recalibrated, the flow alone on the same test draws reported beside it
    calibration, flow_only, samples = recalibrated_calibration(
        samples, u[test], names, (recalibration or {}).get("beta"),
        lambda: stream_rng(seed, "posterior", "calibration"), run.levels)
    pooled, conformal = _calibration_split_figures(run, est, samples, calibration)
    # "train" there: the families the flow was fitted on (the held-out part of train is not)
    diagnostics = (split_diagnostics(est, data, u, {**splits, "train": flow_train}, run.draws, seed)
                   if run.holdout_protocol else None)
    # read from the image, or prior only: the validation families' draws (as predict draws them), never test
    val_draws = est.sample(data.images[val], data.ms_norm[val], run.draws,
                           seed=stream_seed(seed, "posterior", "validation_draws"))
    identification = posterior_identification(val_draws, u, names, data.ms_norm, data.bounds, splits, seed, run.n_boot)
    combinations, ridge = _combinations_and_ridge(run, est, samples, Path(figure_path).with_name("posterior_ridge.png"))
    calibration_s = time.perf_counter() - started
    metrics = {"format": FORMAT, "reported_on": "validation (paper protocol)" if learning["protocol"] == "paper" else "test",
               "n_train": int(len(flow_train)), "n_recalibration_holdout": int(len(holdout)),
               "n_validation": int(len(val)), "n_test": int(len(test)),
               "parameters": list(names), "log_scale": [p for p in names if p in LOG_SCALE], "units": "normalized u in [0, 1]",
               "bounded_support": BOUNDED_SUPPORT, "estimator": "zuko NSF conditioned on a CNN embedding and M_s",
               "coverage": "central (equal-tailed) marginal credible intervals; joint: TARP",
               "coverage_binomial_band": {f"{int(round(a * 100))}": binomial_band(len(test), a) for a in run.levels},
               "targets": {"sbc_ks_p_above": 0.01, "coverage_90_within": [0.85, 0.95]},
               "best_epoch": int(est.best_epoch), "epochs_run": len(est.history["val_nll"]),
               "validation_nll": float(est.history["val_nll"][est.best_epoch]), "config_hash": data.config_hash,
               "prior_class": est.prior_class,
               "summary": settings["summary"], "summary_regression": _regression_summary(est.history),
               "test_and_calibration_splits": pooled,
               "split_diagnostics": diagnostics,
               "conformal": conformal,
               "recalibration": recalibration, "flow_without_recalibration": flow_only,
               "sample_id_test": [int(s) for s in data.sample_id[test]],
               "ood_test_flagged_fraction": float(np.mean([r["out_of_distribution"] for r in test_ood])),
               "ood_alpha": est.metadata["ood"]["alpha"],
               "settings": settings, "wall_s": {"train": train_s, "calibration": calibration_s}, **calibration,
               "combinations": combinations, **(ridge or {"A_ex_D_correlation_median": None}),
               "identification": identification}
    metrics["wall_s"]["total"] = train_s + calibration_s
    _write_posterior(run, est, metrics, (model_path, metrics_path, figure_path))
    _log_posterior(run, metrics, diagnostics)
    return metrics


def _posterior_run(data, settings: dict | None, learning: dict | None, seed: int, log) -> _PosteriorRun:
    """The merged settings, the split and the truths of a posterior training run; a ``DatasetError``
    where the dataset lacks a parameter's column, is smaller than ``min_samples`` or leaves a split empty."""
    settings = posterior_settings(settings)
    learning = {**defaults("learning"), **(learning or {})}
    names = tuple(settings["parameters"])
    missing = [n for n in names if n not in data.values]
    if missing:
        raise DatasetError(f"the dataset has no column for {', '.join(missing)}")
    n = len(data)
    if n < learning["min_samples"]:
        raise DatasetError(f"the dataset has {n} FORC families; the posterior needs at least {learning['min_samples']}")
    splits = assign_splits(data.sample_id, seed, learning["split"], learning["protocol"])
    empty = [k for k in SPLITS if len(splits[k]) == 0]
    if empty:
        raise DatasetError(f"the {', '.join(empty)} split(s) of {n} FORC families are empty; raise n_samples")
    u = np.stack([data.target(name) for name in names], axis=1)
    return _PosteriorRun(data, settings, learning, names, seed, splits, u, log)


def _recalibration(run: _PosteriorRun, est, holdout) -> dict | None:
    """The quantile recalibration fitted on the held-out families (the train ``holdout`` and the
    calibration split), stored in ``est.metadata``; None (and a log line) where they are too few."""
    families, fitted_on = recalibration_families(run.splits, holdout)
    if len(families) < RECALIBRATION_MIN_SAMPLES:
        run.log(f"posterior not recalibrated: {len(families)} families ({fitted_on}), fewer than "
                f"{RECALIBRATION_MIN_SAMPLES}")
        return None
    est.metadata["recalibration"] = recalibration = fit_held_out_recalibration(
        est, run.data, run.u, families, run.draws, run.seed, run.settings["recalibration_gate_alpha"], fitted_on)
    run.log(f"posterior recalibration fitted on {recalibration['n']} held-out families (Beta a, b; likelihood-"
            f"ratio p; applied below {recalibration['gate_alpha']:g}): "
            + ", ".join(f"{n} {a:.2f} {b:.2f} p {recalibration['likelihood_ratio_p'][n]:.3f}"
                        + (" applied" if n in recalibration["beta"] else " not applied")
                        for n, (a, b) in recalibration["beta_fitted"].items()))
    return recalibration


def _calibration_split_figures(run: _PosteriorRun, est, samples, calibration: dict) -> tuple:
    """The calibration split is held out from the posterior too (only Alice's conformal step uses it):
    test + calibration doubles the samples behind the SBC and coverage figures (``pooled``, reported
    apart), and the calibration split alone conformalizes the reported intervals (measured on test,
    added to ``calibration``'s per-parameter rows). Returns (pooled, conformal); (None, None) outside
    the holdout protocol or without calibration families."""
    data, u, names, seed, levels = run.data, run.u, run.names, run.seed, run.levels
    test, cal = run.splits["test"], run.splits["calibration"]
    held_out = np.union1d(test, cal)
    if not (run.holdout_protocol and len(held_out) > len(test)):
        return None, None
    extra = est.sample(data.images[cal], data.ms_norm[cal], run.draws,
                       seed=stream_seed(seed, "posterior", "calibration_draws"))
    both = np.concatenate([test, cal])
    pooled = calibration_metrics(np.concatenate([samples, extra]), u[both], names,
                                 stream_rng(seed, "posterior", "calibration_pooled"), levels)
    pooled = {"n": int(len(both)), "per_parameter": pooled["per_parameter"], "joint": pooled["joint"]["tarp"]}
    widening = conformal_widening(extra, u[cal], levels)
    conformal = {"n_calibration": int(len(cal)),
                 "widening": {f"{int(round(a * 100))}": {n_: float(q[j]) for j, n_ in enumerate(names)}
                              for a, q in widening.items()}}
    for level, (cov, width) in conformal_coverage(samples, u[test], widening).items():
        tag = f"{int(round(level * 100))}"
        for j, name in enumerate(names):
            calibration["per_parameter"][name][f"coverage_{tag}_conformal"] = float(cov[j])
            calibration["per_parameter"][name][f"width_{tag}_conformal"] = float(width[j])
    return pooled, conformal


def _write_posterior(run: _PosteriorRun, est, metrics: dict, paths: tuple) -> None:
    """The model (with the ids of the families it was fitted on), metrics.json and the calibration
    figure, at ``paths`` = (model, metrics, figure), all atomically."""
    model_path, metrics_path, figure_path = paths
    data, splits = run.data, run.splits
    train, val = splits["train"], splits["validation"]
    recalibration = metrics["recalibration"]
    fitted = np.union1d(train, val) if recalibration is None else np.union1d(np.union1d(train, val), splits["calibration"])
    fitted_ids = np.sort(np.asarray(data.sample_id[fitted], dtype=np.int64)).tolist()
    est.save(model_path, config_hash=data.config_hash, seed=int(run.seed), settings=run.settings,
             sample_ids_fitted=fitted_ids, summary={k: metrics[k] for k in ("n_train", "n_validation", "n_test", "best_epoch")},
             per_parameter=metrics["per_parameter"], ood=est.metadata["ood"], conformal=metrics["conformal"],
             recalibration=recalibration, identification=metrics["identification"])
    io.write_json(metrics_path, metrics)
    calibration_figure(metrics, figure_path)


def _log_posterior(run: _PosteriorRun, metrics: dict, diagnostics) -> None:
    """The lines a posterior training run ends with: per parameter its test figures, the identification
    flags and the split diagnostics."""
    log, identification = run.log, metrics["identification"]
    for name, row in metrics["per_parameter"].items():
        log(f"posterior {name}: MAE mean {row['mae_mean']:.3f} median {row['mae_median']:.3f}; SBC KS p {row['sbc_ks_p']:.3f}; "
            f"coverage 50/68/90 {row.get('coverage_50', float('nan')):.2f}/{row.get('coverage_68', float('nan')):.2f}/"
            f"{row.get('coverage_90', float('nan')):.2f}; width 90 {row.get('width_90', float('nan')):.3f}")
    log("posterior read from the image? " + "; ".join(
        f"{n} {r['read_from_image']} ({r.get('skill', float('nan')):+.2f} {r.get('skill_ci90')})"
        for n, r in {**identification["parameters"], **identification["combinations"]}.items()))
    if diagnostics and "train_vs_held_out_ks_p" in diagnostics:
        log("posterior split diagnostics (train vs held-out marginal KS p; PIT KS p train/validation/calibration/test): "
            + "; ".join(f"{n} {diagnostics['train_vs_held_out_ks_p'][n]:.3f} ("
                        + "/".join(f"{diagnostics['pit'][k][n]['ks_p']:.3f}" for k in SPLITS if k in diagnostics["pit"])
                        + ")" for n in run.names))
