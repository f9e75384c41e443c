"""Calibration of a saved posterior on families it never saw: a fresh draw of the same physics.

The test split of a laptop run holds ~60 families: a 90 % interval's coverage is then known to ±0.08
and the SBC rank test has little power, and one unlucky split decides a weakly identified parameter's
figure. A second id range of the same configuration (``snakemake --config first_sample_id=F
n_samples=N results_dir=DIR``) is an independent draw from the same prior, screening and simulator:
``fresh_calibration`` scores the posterior on it exactly as ``train_posterior`` scores the test split
(SBC ranks with a KS p-value, central-interval coverage at the configured levels, TARP, MAE of mean and
median, widths; a recalibrated model also on its flow's own draws) and adds the PIT histogram, the
binomial band of each coverage and the OOD check's false-alarm rate (every fresh family is in
distribution, so each flag is a false alarm).

Refused (``DatasetError``): families of another physics configuration (config hash), and families the
posterior was fitted on (sample ids of its train and validation splits, and of the calibration split
when it was recalibrated on it; saved with the model since 2026-11-26; for an older model pass the
training dataset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import defaults
from ..core import io
from ..core.errors import ConfigError, DatasetError
from ..core.streams import stream_rng, stream_seed
from .calibration import calibration_figure, marginal_coverage, probability_integral_transform, recalibrated_calibration
from .combinations import CombinationScoring, ReferenceFamilies, available, posterior_combination_metrics
from .scoring import binomial_band
from .splits import SPLITS, assign_splits

PIT_BINS = 10


def fitted_sample_ids(est, training_data=None) -> np.ndarray:
    """Sample ids the posterior was fitted on (train + validation, + calibration if recalibrated), saved
    with the model; for a model saved without them, every id of ``training_data`` (the dataset it was
    trained on: stricter)."""
    saved = est.metadata.get("sample_ids_fitted")
    if saved is not None:
        return np.asarray(saved, dtype=np.int64)
    if training_data is None:
        raise DatasetError("this posterior model does not list the families it was fitted on (saved before "
                           "2026-11-26): pass the dataset it was trained on (--training-dataset)")
    return np.asarray(training_data.sample_id, dtype=np.int64)


def _fresh_targets(est, data, training_data=None) -> tuple[tuple, np.ndarray]:
    """(parameter names, normalized truths) of a fresh draw ``data``, refused (``DatasetError``) when it
    is of another configuration, holds families ``est`` was fitted on, or lacks a parameter."""
    expected_hash = est.metadata.get("config_hash")
    if expected_hash and data.config_hash != expected_hash:
        raise DatasetError(f"the families were simulated with another configuration (config hash {data.config_hash}, "
                           f"the posterior's {expected_hash}): a fresh draw must repeat the training physics")
    overlap = np.intersect1d(np.asarray(data.sample_id, dtype=np.int64), fitted_sample_ids(est, training_data))
    if overlap.size:
        raise DatasetError(f"{overlap.size} of the {len(data)} families were used to fit the posterior (sample ids "
                           f"{overlap[:5].tolist()}{' …' if overlap.size > 5 else ''}): use another id range "
                           "(first_sample_id) for a fresh draw")
    names = tuple(est.names)
    missing = [n for n in names if n not in data.values]
    if missing:
        raise DatasetError(f"the dataset has no column for {', '.join(missing)}")
    return names, np.stack([data.target(name) for name in names], axis=1)


def fresh_calibration(est, data, *, seed: int, draws: int = 1000, levels=None, training_data=None,
                      learning: dict | None = None, split_seed: int | None = None) -> dict:
    """Calibration metrics of posterior ``est`` on every family of ``data`` (a ``LearningData``) at the
    credibility ``levels`` (default: the posterior section's). With ``training_data`` and ``learning``
    (the learning section: its split) and ``split_seed`` (the config seed that split the training dataset)
    the derived combinations too (``fresh_combinations``)."""
    if int(draws) < 2:
        raise ConfigError(f"the posterior check needs at least 2 draws per family (got {draws})")
    names, u = _fresh_targets(est, data, training_data)
    samples = est.sample(data.images, data.ms_norm, int(draws), seed=stream_seed(seed, "posterior", "fresh_draws"),
                         recalibrated=False)
    levels = [float(a) for a in (defaults("posterior")["levels"] if levels is None else levels)]
    # the posterior the model answers with, and the flow alone on the same draws beside it
    metrics, flow_only, _ = recalibrated_calibration(samples, u, names, est.recalibration,
                                                     lambda: stream_rng(seed, "posterior", "fresh_calibration"), levels)
    metrics["flow_without_recalibration"] = flow_only
    # PIT = SBC rank / draws (the ranks calibration_metrics already counted)
    metrics["pit_histogram"] = {name: np.histogram(np.asarray(metrics["ranks"][name]) / int(draws), bins=PIT_BINS,
                                                   range=(0.0, 1.0))[0].tolist() for name in names}
    metrics["coverage_binomial_band"] = {f"{int(round(a * 100))}": binomial_band(len(u), a) for a in levels}
    # loads torch: imported only when this runs
    from .ood import ood_check

    flags = ood_check(est, data.images, data.ms_norm)
    if isinstance(flags, dict):  # a model saved without the OOD reference
        metrics["ood_false_alarm_fraction"] = None
    else:
        metrics["ood_false_alarm_fraction"] = float(np.mean([r["out_of_distribution"] for r in flags]))
        metrics["ood_alpha"] = est.metadata.get("ood", {}).get("alpha")
    if training_data is not None and learning is not None and split_seed is not None:
        training = TrainingReference(training_data, learning, split_seed)
        metrics["combinations"] = fresh_combinations(est, data, samples, u, training, seed=seed, levels=levels,
                                                     n_boot=int(learning.get("bootstrap", 2000)))
    ids = np.asarray(data.sample_id, dtype=np.int64)
    metrics.update({"reported_on": "fresh families (never seen by the posterior)", "n_fresh": int(len(u)),
                    "sample_id_range": [int(ids.min()), int(ids.max())], "config_hash": data.config_hash,
                    "targets": {"sbc_ks_p_above": 0.01, "coverage_90_within": [0.85, 0.95]}})
    return metrics


@dataclass(frozen=True)
class TrainingReference:
    """The training run a fresh check is scored against: ``data`` (its ``LearningData``), ``learning``
    (its learning section: ``split``, ``protocol``) and ``split_seed`` (the config seed that split it)."""

    data: object
    learning: dict
    split_seed: int


def fresh_combinations(est, data, samples, u, training: TrainingReference, *, seed: int, levels,
                       n_boot: int = 2000) -> dict:
    """The derived combinations (sigma_w, delta_w, D/D_c, Q: ``core.parameters.COMBINATIONS``) of the
    posterior's draws on the fresh families, scored as ``train_posterior`` scores them on test
    (``learn.combinations.posterior_combination_metrics``: coverage, SBC, MAE, skill over the prior,
    M_s-only and images-shuffled baselines with bootstrap intervals). Normalization and trivial baselines
    come from the training run's train and validation splits (hash of (split seed, sample id), its
    ``learning`` split); the images-shuffled draws permute the fresh images among the fresh families."""

    names = tuple(est.names)
    if not available(names):
        return {}
    training_data, learning = training.data, training.learning
    splits = assign_splits(training_data.sample_id, int(training.split_seed), learning["split"], learning["protocol"])
    train, val = splits["train"], splits["validation"]
    train_u = np.stack([training_data.target(n) for n in names], axis=1)
    permuted = stream_rng(seed, "posterior", "fresh_shuffle").permutation(len(u))
    shuffled = est.sample(data.images[permuted], data.ms_norm, samples.shape[1],
                          seed=stream_seed(seed, "posterior", "fresh_shuffled_draws"), recalibrated=False)
    reference = ReferenceFamilies(train_u=train_u[train], train_ms_norm=training_data.ms_norm[train],
                                  val_u=train_u[val], val_ms_norm=training_data.ms_norm[val])
    scoring = CombinationScoring(rng_of=lambda *keys: stream_rng(seed, "posterior", "fresh_combinations", *keys),
                                 levels=levels, n_boot=n_boot)
    return posterior_combination_metrics(samples, u, names, data.ms_norm, data.bounds, reference=reference,
                                         scoring=scoring, shuffled=shuffled)


def fresh_recalibration(est, data, *, seed: int, draws: int = 1000, training_data=None,
                        gate_alpha: float | None = None) -> dict:
    """The quantile recalibration of ``est`` (``learn.calibration``: a Beta map per marginal) fitted on a
    fresh draw ``data`` instead of the laptop run's validation + calibration splits.

    Why: those splits hold ~130 families, which fix a Beta map to about ±0.1 in a and b; measured on the
    laptop posterior, the map fitted there left K_u's and σ_θ's SBC p at 0.028 and 0.007 on a second fresh
    draw (ids 2000–, 463 families), while the same map fitted on 408 fresh families (ids 1000–) gave
    p ≥ 0.05 for every parameter there, and every 90 % coverage within 0.87–0.94 (README). A fresh draw is an
    independent sample of the same prior, screening and simulator, and none of its families entered
    the flow's fit. Returns the model's new ``recalibration`` record: method, ``beta`` per parameter,
    ``likelihood_ratio_p`` of each map against the identity on these PITs, ``n``, ``sample_id_range``,
    ``fitted_on``, and ``previous`` (the record it replaces); ``beta`` holds the maps whose p lies below
    ``gate_alpha`` (default: the model's setting, else the schema's), ``beta_fitted`` all of them.
    Refused like ``fresh_calibration``."""
    # loads torch: imported only when this runs
    from .posterior import gated_recalibration_record

    if int(draws) < 2:
        raise ConfigError(f"the recalibration needs at least 2 draws per family (got {draws})")
    names, u = _fresh_targets(est, data, training_data)
    raw = est.sample(data.images, data.ms_norm, int(draws),
                     seed=stream_seed(seed, "posterior", "fresh_recalibration_draws"), recalibrated=False)
    pit = probability_integral_transform(raw, u)
    if gate_alpha is None:
        gate_alpha = {**defaults("posterior"), **(est.metadata.get("settings") or {})}["recalibration_gate_alpha"]
    ids = np.asarray(data.sample_id, dtype=np.int64)
    return gated_recalibration_record(pit, names, gate_alpha,
                                      fitted_on=f"fresh draw (sample ids {int(ids.min())}–{int(ids.max())})",
                                      sample_id_range=[int(ids.min()), int(ids.max())],
                                      previous=est.metadata.get("recalibration"))


HELD_OUT_SPLITS = tuple(name for name in SPLITS if name != "train")


def split_coverage(est, data, *, seed: int, split_seed: int, learning: dict, draws: int = 1000,
                   levels=None) -> dict:
    """Central-interval coverage of the posterior as it answers (recalibrated where it is) on each
    held-out split of its own training dataset ``data``, split as ``train_posterior`` split it (hash of
    (``split_seed``, sample id), ``learning``'s split and protocol), with the binomial band of a
    calibrated interval at each split's size and the coverage pooled over parameters.

    Why: the validation split chose the flow's epoch (early stopping), so on it the flow looks better
    calibrated than on families that chose nothing; a recalibration fitted there (validation +
    calibration, before ``posterior.recalibration_holdout``) inherits that. Validation against
    calibration and test shows the bias.
    Returns {split: {"n", "mae_median": {name: MAE of the posterior median}, "mae_median_ci90" (bootstrap
    over the split's families), "coverage_<level>": {name: fraction}, "pooled_<level>", "band_<level>"}}."""
    names = tuple(est.names)
    missing = [n for n in names if n not in data.values]
    if missing:
        raise DatasetError(f"the dataset has no column for {', '.join(missing)}")
    if int(draws) < 2:
        raise ConfigError(f"the split coverage needs at least 2 draws per family (got {draws})")
    levels = [float(a) for a in (defaults("posterior")["levels"] if levels is None else levels)]
    splits = assign_splits(data.sample_id, int(split_seed), learning["split"], learning["protocol"])
    u = np.stack([data.target(name) for name in names], axis=1)
    out = {}
    for k, split in enumerate(HELD_OUT_SPLITS):
        idx = np.asarray(splits[split])
        if len(idx) == 0:
            continue
        samples = est.sample(data.images[idx], data.ms_norm[idx], int(draws),
                             seed=stream_seed(seed, "posterior", "split_coverage", k))
        row = {"n": int(len(idx))}
        # the median's error, with a bootstrap interval over the split's families
        error = np.abs(np.median(samples, axis=1) - u[idx])
        boot = stream_rng(seed, "posterior", "split_coverage_bootstrap", k).integers(0, len(idx), (2000, len(idx)))
        means = error[boot].mean(axis=1)
        row["mae_median"] = {n: float(error[:, j].mean()) for j, n in enumerate(names)}
        row["mae_median_ci90"] = {n: np.quantile(means[:, j], [0.05, 0.95]).tolist() for j, n in enumerate(names)}
        for a, (coverage, _) in marginal_coverage(samples, u[idx], levels).items():
            tag = f"{int(round(a * 100))}"
            row[f"coverage_{tag}"] = {n: float(coverage[j]) for j, n in enumerate(names)}
            row[f"pooled_{tag}"] = float(coverage.mean())  # every parameter over the same families
            row[f"band_{tag}"] = binomial_band(len(idx), a)
        out[split] = row
    return out


def split_coverage_lines(table: dict, level: str = "90") -> list[str]:
    """One line per held-out split: its size, each parameter's coverage at ``level`` and the pooled one."""
    names = list(next(iter(table.values()))[f"coverage_{level}"]) if table else []
    lines = [f"{'split':12s} {'n':>4s} " + " ".join(f"{n[:8]:>8s}" for n in names) + f" {'pooled':>7s}  band"]
    for split, row in table.items():
        band = row[f"band_{level}"]
        lines.append(f"{split:12s} {row['n']:4d} " + " ".join(f"{row[f'coverage_{level}'][n]:8.3f}" for n in names)
                     + f" {row[f'pooled_{level}']:7.3f}  {band[0]:.3f}–{band[1]:.3f}")
    lines.append("MAE of the median (90 % bootstrap interval):")
    for split, row in table.items():
        lines.append(f"{split:12s} " + "; ".join(f"{n} {row['mae_median'][n]:.3f} [{row['mae_median_ci90'][n][0]:.3f}, "
                                               f"{row['mae_median_ci90'][n][1]:.3f}]" for n in names))
    return lines


def apply_recalibration(est, recalibration: dict, fresh_ids, training_data=None) -> dict:
    """The metadata of ``est`` with ``recalibration`` as its quantile map and the fresh families it was
    fitted on added to ``sample_ids_fitted`` (so that a later check refuses them as fresh)."""
    fitted = np.union1d(fitted_sample_ids(est, training_data), np.asarray(fresh_ids, dtype=np.int64))
    return {**est.metadata, "recalibration": recalibration, "sample_ids_fitted": fitted.tolist()}


def recalibration_lines(record: dict) -> list[str]:
    """The Beta map per parameter beside the one it replaces."""
    previous = (record.get("previous") or {}).get("beta") or {}
    gate = record.get("gate_alpha")
    lines = [f"recalibrated on {record['n']} families, {record['fitted_on']}"
             + (f"; a map is applied where its LR p < {gate:g}" if gate is not None else ""),
             f"{'parameter':16s} {'a':>6s} {'b':>6s} {'LR p':>8s} {'applied':>8s}   previous a, b"]
    for name, (a, b) in record.get("beta_fitted", record["beta"]).items():
        before = previous.get(name)
        lines.append(f"{name:16s} {a:6.3f} {b:6.3f} {record['likelihood_ratio_p'][name]:8.2g} "
                     f"{'yes' if name in record['beta'] else 'no':>8s}   "
                     + (f"{before[0]:.3f}, {before[1]:.3f}" if before else "none"))
    return lines


def check_lines(metrics: dict) -> list[str]:
    """A plain table of the fresh-family calibration."""
    band = metrics["coverage_binomial_band"].get("90")
    lines = [f"posterior on {metrics['n_fresh']} fresh families (ids {metrics['sample_id_range'][0]}–"
             f"{metrics['sample_id_range'][1]}); 90 % band of a calibrated interval: "
             + (f"{band[0]:.3f}–{band[1]:.3f}" if band else "n/a"),
             f"{'parameter':16s} {'MAE med':>8s} {'SBC p':>7s} {'cov50':>6s} {'cov68':>6s} {'cov90':>6s} {'w90':>6s}"]
    for name, row in metrics["per_parameter"].items():
        lines.append(f"{name:16s} {row['mae_median']:8.3f} {row['sbc_ks_p']:7.3f} {row.get('coverage_50', np.nan):6.3f} "
                     f"{row.get('coverage_68', np.nan):6.3f} {row.get('coverage_90', np.nan):6.3f} "
                     f"{row.get('width_90', np.nan):6.3f}")
    tarp = metrics["joint"]["tarp"]
    lines.append("joint TARP coverage " + " / ".join(f"{v:.3f}" for v in tarp.values()))
    flow = metrics.get("flow_without_recalibration")
    if flow:
        lines.append("the flow before its recalibration: SBC p " + ", ".join(
            f"{name} {row['sbc_ks_p']:.3f}" for name, row in flow["per_parameter"].items()) + "; cov90 " + ", ".join(
            f"{name} {row.get('coverage_90', np.nan):.3f}" for name, row in flow["per_parameter"].items()))
    if metrics.get("ood_false_alarm_fraction") is not None:
        lines.append(f"OOD check: {metrics['ood_false_alarm_fraction']:.3f} of in-distribution families flagged "
                     f"(alpha {metrics.get('ood_alpha')})")
    return lines


def write_check(metrics: dict, out_json, figure=None) -> None:
    """metrics.json-like file (atomic) and, if asked, the rank-histogram / coverage figure."""
    io.write_json(out_json, metrics)
    if figure:
        calibration_figure(metrics, figure)


__all__ = ["apply_recalibration", "fitted_sample_ids", "fresh_calibration", "fresh_recalibration", "check_lines",
           "recalibration_lines", "write_check"]
