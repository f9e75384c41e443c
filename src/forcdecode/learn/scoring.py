"""Accuracy with its baselines and error bars (all on normalized parameters u ∈ [0, 1]).

Baselines, fitted on the training split only:

- ``prior``: the train median (the best constant under MAE);
- ``ms_only``: what the inputs alone tell without the image: the median of u over the k training
  samples nearest in M_s (k chosen on the validation split) — the constrained A_ex draw ties A_ex to
  M_s, so this is the baseline a network must beat to show that the FORC image carries information;
- ``images_shuffled`` (computed by the pipeline): the trained network with the test images permuted
  among the test samples and M_s kept.

Error bars: percentile bootstrap over test samples (90 % intervals), paired for skill scores.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import pearsonr

KNN_CHOICES = (1, 3, 5, 9, 15, 25)


def knn_median(x_train, y_train, x_query, k: int) -> np.ndarray:
    """Median of ``y_train`` over the ``k`` training points nearest in x (1-D)."""
    x_train, y_train = np.asarray(x_train, float), np.asarray(y_train, float)
    x_query = np.asarray(x_query, float)
    k = max(1, min(int(k), x_train.size))
    distance = np.abs(x_query[:, None] - x_train[None, :])
    nearest = np.argsort(distance, axis=1, kind="stable")[:, :k]
    return np.median(y_train[nearest], axis=1)


def fit_ms_only(ms_train, u_train, ms_val, u_val, choices=KNN_CHOICES) -> int:
    """k of the M_s-only k-NN median with the lowest validation MAE (ties: the larger k)."""
    best_k, best = None, np.inf
    for k in choices:
        if k > len(u_train):
            break
        mae = float(np.mean(np.abs(knn_median(ms_train, u_train, ms_val, k) - u_val)))
        if mae <= best:
            best_k, best = k, mae
    return int(best_k if best_k is not None else 1)


def pearson(truth, prediction) -> float:
    truth, prediction = np.asarray(truth, float), np.asarray(prediction, float)
    if truth.size < 3 or np.std(prediction) == 0 or np.std(truth) == 0:
        return float("nan")
    return float(pearsonr(prediction, truth).statistic)


def bootstrap_interval(statistic, arrays, rng: np.random.Generator, n_boot: int = 2000, level: float = 0.9):
    """Percentile bootstrap interval of ``statistic(*resampled arrays)`` (rows resampled together)."""
    arrays = [np.asarray(a) for a in arrays]
    n = arrays[0].shape[0]
    if n < 2:
        return [float("nan"), float("nan")]
    values = np.empty(n_boot)
    for b in range(n_boot):
        index = rng.integers(0, n, n)
        values[b] = statistic(*(a[index] for a in arrays))
    values = values[np.isfinite(values)]
    if values.size == 0:
        return [float("nan"), float("nan")]
    tail = 100 * (1 - level) / 2
    return [float(np.percentile(values, tail)), float(np.percentile(values, 100 - tail))]


def median_with_interval(values, rng: np.random.Generator, n_boot: int = 2000) -> tuple[float, list]:
    """Median of the finite ``values`` and its percentile bootstrap 90 % interval over them (NaN
    interval below two values)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return float("nan"), [float("nan"), float("nan")]
    return float(np.median(values)), bootstrap_interval(np.median, [values], rng, n_boot)


def _mae(truth, prediction) -> float:
    return float(np.mean(np.abs(np.asarray(prediction, float) - np.asarray(truth, float))))


def skill(mae: float, baseline_mae: float) -> float:
    return 1.0 - mae / baseline_mae if baseline_mae > 0 else float("nan")


def skill_interval(truth, prediction, baseline, rng, n_boot: int = 2000, level: float = 0.9) -> list[float]:
    """Paired percentile-bootstrap interval of the skill 1 − MAE(prediction) / MAE(baseline) (the same
    resamples for the model and its baseline)."""
    return bootstrap_interval(lambda t, p, b: skill(_mae(t, p), _mae(t, b)), [truth, prediction, baseline],
                              rng, n_boot, level)


def skill_over_best_trivial(truth, prediction, prior, ms_only, rng, n_boot: int = 2000, level: float = 0.9) -> dict:
    """Skill 1 − MAE(prediction) / min(MAE(prior), MAE(ms_only)) over the better of the two trivial
    predictors, with its paired percentile-bootstrap interval (the better one chosen again on each
    resample: a model must beat both). Returns the skill, ``skill_ci90`` (NaN below two samples), the
    three MAEs, which trivial predictor is the better on all samples and ``n``."""
    truth, prediction = np.asarray(truth, float), np.asarray(prediction, float)
    prior, ms_only = np.asarray(prior, float), np.asarray(ms_only, float)

    def statistic(t, p, a, b):
        return skill(_mae(t, p), min(_mae(t, a), _mae(t, b)))

    n = int(truth.size)
    if n == 0:
        nan = float("nan")
        return {"skill": nan, "skill_ci90": [nan, nan], "mae": nan, "mae_prior": nan, "mae_ms_only": nan,
                "best_trivial": None, "n": 0}
    mae_prior, mae_ms = _mae(truth, prior), _mae(truth, ms_only)
    return {"skill": statistic(truth, prediction, prior, ms_only),
            "skill_ci90": bootstrap_interval(statistic, [truth, prediction, prior, ms_only], rng, n_boot, level),
            "mae": _mae(truth, prediction), "mae_prior": mae_prior, "mae_ms_only": mae_ms,
            "best_trivial": "prior" if mae_prior <= mae_ms else "ms_only", "n": n}


def accuracy_with_intervals(truth, prediction, ms_only, prior, covered_90, rng, n_boot: int = 2000) -> dict:
    """MAE, Pearson r, skill over the M_s-only and prior baselines and the 90 % coverage, each with a
    bootstrap 90 % interval over the test samples (paired: the same resamples for a model and its
    baseline)."""
    truth, prediction = np.asarray(truth, float), np.asarray(prediction, float)
    ms_only, prior = np.asarray(ms_only, float), np.asarray(prior, float)
    covered = np.asarray(covered_90, float)
    mae, mae_ms, mae_prior = _mae(truth, prediction), _mae(truth, ms_only), _mae(truth, prior)
    return {
        "mae": mae, "mae_ci90": bootstrap_interval(_mae, [truth, prediction], rng, n_boot),
        "pearson_r": pearson(truth, prediction), "r_ci90": bootstrap_interval(pearson, [truth, prediction], rng, n_boot),
        "skill_vs_ms_only": skill(mae, mae_ms),
        "skill_vs_ms_only_ci90": skill_interval(truth, prediction, ms_only, rng, n_boot),
        "skill_vs_prior": skill(mae, mae_prior),
        "skill_vs_prior_ci90": skill_interval(truth, prediction, prior, rng, n_boot),
        "coverage_90": float(covered.mean()) if covered.size else float("nan"),
        "coverage_90_ci90": bootstrap_interval(lambda c: float(c.mean()), [covered], rng, n_boot),
    }


def binomial_band(n: int, p: float = 0.9, level: float = 0.9) -> list[float]:
    """Central ``level`` interval of the coverage fraction of n exchangeable samples at nominal p."""
    from scipy.stats import binom

    if n < 1:
        return [float("nan"), float("nan")]
    tail = (1 - level) / 2
    return [float(binom.ppf(tail, n, p) / n), float(binom.ppf(1 - tail, n, p) / n)]
