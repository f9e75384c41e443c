"""How many simulations are needed: a power law MAE(N) = a·N^(−b) fitted to a learning curve.

The curve holds the test MAE of Alice trained on nested subsets of the training split (several sizes,
several seeds: a different subset and different weights per seed). The fit is least squares in
log–log over every (size, seed) point. Its uncertainty comes from a bootstrap over seeds within each
size (a resampled curve per draw, refitted): the 90 % interval of b and of N* = (a/MAE*)^(1/b), the
training-set size at which the law would reach a target MAE* (the paper's figure). The extrapolation
assumes no floor: a curve that flattens (noise in the images, a parameter the image does not carry)
reaches the target later or never, so N* is a lower bound where b is small; b ≤ 0 gives N* = ∞.
"""

from __future__ import annotations

import numpy as np


def fit_power_law(sizes, mae) -> dict:
    """``sizes`` (S,), ``mae`` (S, seeds) with NaN for missing → {"a", "b"} of MAE = a N^(−b)."""
    sizes = np.asarray(sizes, dtype=float)
    mae = np.asarray(mae, dtype=float)
    x = np.repeat(np.log(sizes)[:, None], mae.shape[1], axis=1).ravel()
    y = mae.ravel()
    keep = np.isfinite(y) & (y > 0)
    if np.unique(x[keep]).size < 2:
        return {"a": float("nan"), "b": float("nan")}
    slope, intercept = np.polyfit(x[keep], np.log(y[keep]), 1)
    return {"a": float(np.exp(intercept)), "b": float(-slope)}


def size_for_mae(fit: dict, target_mae: float) -> float:
    """N at which a·N^(−b) equals ``target_mae`` (∞ if the law does not decrease)."""
    a, b = fit["a"], fit["b"]
    if not (np.isfinite(a) and np.isfinite(b)) or b <= 0:
        return float("inf")
    log_n = np.log(a / target_mae) / b
    return float(np.exp(log_n)) if log_n < 700 else float("inf")


def learning_curve_fit(sizes, mae, target_mae: float | None, rng: np.random.Generator, n_boot: int = 1000) -> dict:
    """The fit, its bootstrap 90 % intervals and N* for ``target_mae`` (None: no target)."""
    sizes = np.asarray(sizes, dtype=float)
    mae = np.asarray(mae, dtype=float)
    fit = fit_power_law(sizes, mae)
    b_draws, n_draws = [], []
    seeds = mae.shape[1]
    for _ in range(n_boot):
        resampled = np.stack([row[rng.integers(0, seeds, seeds)] for row in mae])
        draw = fit_power_law(sizes, resampled)
        b_draws.append(draw["b"])
        if target_mae is not None:
            n_draws.append(size_for_mae(draw, target_mae))
    b_draws = np.asarray(b_draws)
    result = {"law": "MAE = a * N^-b (least squares in log-log over every size and seed)", **fit,
              "b_ci90": _interval(b_draws)}
    if target_mae is not None:
        n_draws = np.asarray(n_draws)
        result["n_to_target"] = {"target_mae": float(target_mae), "value": size_for_mae(fit, target_mae),
                                 "ci90": _interval(n_draws), "fraction_infinite": float(np.mean(~np.isfinite(n_draws)))}
    return result


def _interval(values) -> list[float]:
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
    if values.size == 0:
        return [float("nan"), float("nan")]
    ordered = np.sort(values)  # order statistics, not interpolation: N* may be infinite
    last = ordered.size - 1
    return [float(ordered[int(np.floor(0.05 * last))]), float(ordered[int(np.ceil(0.95 * last))])]
