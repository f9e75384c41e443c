"""The posterior's recalibration and its diagnostics (``learn.posterior``): where a miscalibration
comes from per split (``split_diagnostics``), and the Beta quantile recalibration fitted on held-out
families and applied where a likelihood-ratio test supports it (``recalibration_holdout``,
``recalibration_families``, ``fit_held_out_recalibration``, ``gated_recalibration_record``; the maps themselves in ``learn.calibration``)."""

from __future__ import annotations

import numpy as np

from ...core.streams import stream_rng, stream_seed
from ..calibration import (fit_recalibration, gate_recalibration, probability_integral_transform,
                           recalibration_likelihood_ratio, sbc_ks_pvalues, sbc_ranks)
from ..splits import SPLITS
from .estimator import PosteriorEstimator


def split_diagnostics(est: PosteriorEstimator, data, u, splits: dict, draws: int, seed: int) -> dict:
    """Where a miscalibration comes from, per split and parameter: the KS p-value of the randomized
    PIT of the truth (uniform when calibrated; uniform on train but not on held-out splits is an
    overfit to the training families) with its counts per fifth, and the truths' marginal in the
    flow's coordinates (``prior``: uniform under the draw prior; the screening and the split's own
    sampling tilt it) with the two-sample KS p-value of train against the held-out splits: a training
    marginal unlike the held-out one is what a posterior that learns little from the image returns."""
    from scipy import stats


    out = {"pit": {}, "coordinates_marginal": {}}
    v_of = {}
    for k, name in enumerate(SPLITS):
        idx = np.asarray(splits[name])
        if len(idx) < 2:
            continue
        samples = est.sample(data.images[idx], data.ms_norm[idx], draws, seed=stream_seed(seed, "posterior", "diagnose", k))
        ranks = sbc_ranks(samples, u[idx])
        p = sbc_ks_pvalues(ranks, draws, stream_rng(seed, "posterior", "diagnose_pit", k))
        v = est.to_coordinates(u[idx], data.ms_norm[idx])
        v_of[name] = v
        out["pit"][name] = {n: {"ks_p": float(p[j]), "per_fifth": np.histogram(ranks[:, j] / draws, bins=5,
                                                                               range=(0, 1))[0].tolist()}
                            for j, n in enumerate(est.names)}
        out["coordinates_marginal"][name] = {n: {"ks_p_uniform": float(stats.kstest(v[:, j], "uniform").pvalue),
                                                 "per_fifth": np.histogram(v[:, j], bins=5, range=(0, 1))[0].tolist()}
                                             for j, n in enumerate(est.names)}
    held = [v_of[n] for n in SPLITS if n != "train" and n in v_of]
    if "train" in v_of and held:
        held = np.concatenate(held)
        out["train_vs_held_out_ks_p"] = {n: float(stats.ks_2samp(v_of["train"][:, j], held[:, j]).pvalue)
                                         for j, n in enumerate(est.names)}
    return out



def gated_recalibration_record(pit, names, gate_alpha: float, **record) -> dict:
    """The recalibration record of held-out PITs: every parameter's fitted Beta map (``beta_fitted``), its
    likelihood-ratio p-value against the identity, and under ``beta`` only the maps that test supports at
    ``gate_alpha`` (``learn.calibration.gate_recalibration``): ``beta`` is what the model applies."""

    fitted = fit_recalibration(pit, names)
    p_values = recalibration_likelihood_ratio(pit, fitted, names)
    return {"method": "Beta quantile recalibration (Kuleshov et al. 2018), fitted by maximum likelihood, "
                      "applied where its likelihood-ratio test against the identity gives p < gate_alpha",
            **record, "n": int(len(pit)), "gate_alpha": float(gate_alpha),
            "beta": gate_recalibration(fitted, p_values, gate_alpha), "beta_fitted": fitted,
            "likelihood_ratio_p": p_values}


def recalibration_holdout(sample_ids, train, seed: int, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(flow's training indices, indices held out for the recalibration): the members of ``train`` whose
    uniform of (``seed``, sample id) in the stream posterior/recalibration_holdout lies below
    ``fraction``. Like the split itself, a family's side depends only on the seed and its own id."""
    train = np.asarray(train)
    if fraction <= 0 or train.size == 0:
        return train, train[:0]
    draw = np.array([stream_rng(seed, "posterior", "recalibration_holdout", int(sample_ids[k])).random()
                     for k in train])
    return train[draw >= fraction], train[draw < fraction]


def recalibration_families(splits: dict, holdout) -> tuple[np.ndarray, str]:
    """(indices, description) of the families the recalibration is fitted on: with a train ``holdout``,
    it and the calibration split, families that chose nothing (validation stopped the flow's training,
    and on it the flow looks better calibrated than it is: docs/posterior.md); without one, validation +
    calibration as before 2026-11-29."""
    holdout = np.asarray(holdout, dtype=np.int64)
    if holdout.size:
        return np.union1d(splits["calibration"], holdout), "calibration split + train held out from the flow"
    return np.union1d(splits["validation"], splits["calibration"]), "validation + calibration splits"


def fit_held_out_recalibration(est: PosteriorEstimator, data, u, families, draws: int, seed: int,
                               gate_alpha: float, fitted_on: str) -> dict:
    """Quantile recalibration of ``est`` (``learn.calibration``) fitted on the PITs of ``families``
    (indices into ``data``; ``recalibration_families``), families the flow's weights never saw; a map is
    applied only where its likelihood-ratio test gives p < ``gate_alpha`` (``gated_recalibration_record``)."""

    families = np.asarray(families)
    raw = est.sample(data.images[families], data.ms_norm[families], draws,
                     seed=stream_seed(seed, "posterior", "recalibration_draws"), recalibrated=False)
    pit = probability_integral_transform(raw, u[families])
    return gated_recalibration_record(pit, est.names, gate_alpha, fitted_on=fitted_on)
