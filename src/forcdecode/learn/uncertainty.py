"""Bob's error model and the intervals built on it: quantile targets, quantile → error mapping,
normalized split-conformal intervals, MC-dropout intervals, error-retention curves.

All errors are absolute errors of a normalized parameter (u ∈ [0, 1]).

- Bob is trained to output the *normalized quantile* q ∈ [0, 1] of Alice's absolute error
  (its rank within the out-of-fold error distribution), not the error itself, so that it has to
  rank every input instead of predicting "small" everywhere (the seed paper's argument).
- ``quantile_to_error`` maps Bob's q back to an error with the empirical quantile function of
  Alice's errors on a held-out set (the paper uses the validation set).
- ``ConformalIntervals``: normalized split conformal prediction (Lei et al. 2018): the score of a
  calibration sample is |e|/σ(x) with σ the difficulty (Bob's error); the interval at level 1 − α is
  ŷ ± q̂·σ(x), q̂ the ⌈(n + 1)(1 − α)⌉-th smallest calibration score. Marginal coverage ≥ 1 − α
  holds for exchangeable calibration and test samples whatever σ is; a good σ makes the intervals
  narrow where Alice is good and wide where she is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import norm, spearmanr


def error_quantile(errors, reference_errors) -> np.ndarray:
    """Normalized quantile of each error within ``reference_errors`` (mid-rank empirical CDF, in [0, 1])."""
    reference = np.sort(np.asarray(reference_errors, dtype=float))
    if reference.size == 0:
        raise ValueError("no reference errors to rank against")
    errors = np.asarray(errors, dtype=float)
    below = np.searchsorted(reference, errors, side="left")
    at_or_below = np.searchsorted(reference, errors, side="right")
    return (below + at_or_below) / (2.0 * reference.size)


def quantile_to_error(q, reference_errors) -> np.ndarray:
    """Inverse of ``error_quantile``: the empirical q-quantile of ``reference_errors`` (Hazen plotting
    positions (i + ½)/n, the mid-ranks ``error_quantile`` gives, map back onto the sorted errors)."""
    reference = np.asarray(reference_errors, dtype=float)
    return np.quantile(reference, np.clip(np.asarray(q, dtype=float), 0.0, 1.0), method="hazen")


def conformal_quantile(scores, level: float) -> float:
    """The ⌈(n + 1)·level⌉-th smallest score (inf when the calibration set is too small for ``level``)."""
    scores = np.sort(np.asarray(scores, dtype=float))
    n = scores.size
    rank = int(np.ceil((n + 1) * level))
    if n == 0 or rank > n:
        return float("inf")
    return float(scores[rank - 1])


@dataclass
class ConformalIntervals:
    """Normalized split-conformal intervals ŷ ± q̂_level·σ(x), fitted on a calibration set."""

    levels: tuple[float, ...]
    quantiles: dict
    sigma_floor: float

    @classmethod
    def fit(cls, abs_errors, sigma, levels=(0.68, 0.9), sigma_floor: float | None = None) -> "ConformalIntervals":
        sigma = np.asarray(sigma, dtype=float)
        if sigma_floor is None:  # keeps scores finite where Bob predicts ~0 error
            sigma_floor = max(1e-4, 0.05 * float(np.median(sigma))) if sigma.size else 1e-4
        scores = np.asarray(abs_errors, dtype=float) / np.maximum(sigma, sigma_floor)
        return cls(tuple(levels), {float(a): conformal_quantile(scores, a) for a in levels}, float(sigma_floor))

    def half_width(self, sigma, level: float) -> np.ndarray:
        return self.quantiles[float(level)] * np.maximum(np.asarray(sigma, dtype=float), self.sigma_floor)

    def interval(self, prediction, sigma, level: float, clip=(0.0, 1.0)):
        h = self.half_width(sigma, level)
        prediction = np.asarray(prediction, dtype=float)
        return np.clip(prediction - h, *clip), np.clip(prediction + h, *clip)


def coverage_and_width(truth, low, high) -> tuple[float, float]:
    """Fraction of ``truth`` inside [low, high] and the mean width."""
    truth, low, high = (np.asarray(a, dtype=float) for a in (truth, low, high))
    if truth.size == 0:
        return float("nan"), float("nan")
    return float(np.mean((truth >= low) & (truth <= high))), float(np.mean(high - low))


def gaussian_interval(mean, std, level: float, clip=(0.0, 1.0)):
    """mean ± z·std with z the two-sided Gaussian quantile of ``level`` (MC-dropout intervals)."""
    z = norm.ppf(0.5 + level / 2)
    mean, std = np.asarray(mean, float), np.asarray(std, float)
    return np.clip(mean - z * std, *clip), np.clip(mean + z * std, *clip)


def retention_curve(abs_errors, score, fractions=None):
    """Error–retention curve: mean error of the retained fraction when the samples with the highest
    ``score`` (predicted difficulty) are rejected first. Returns (fractions, mean errors, area)."""
    abs_errors = np.asarray(abs_errors, dtype=float)
    order = np.argsort(np.asarray(score, dtype=float), kind="stable")
    sorted_errors = abs_errors[order]
    n = sorted_errors.size
    fractions = np.linspace(1.0 / n, 1.0, n) if fractions is None else np.asarray(fractions, float)
    keep = np.maximum(1, np.rint(fractions * n).astype(int))
    cumulative = np.cumsum(sorted_errors)
    curve = cumulative[keep - 1] / keep
    return fractions, curve, float(np.trapezoid(curve, fractions)) if fractions.size > 1 else float(curve[0])


def spearman(a, b) -> float:
    if len(a) < 3:
        return float("nan")
    value = spearmanr(a, b).statistic
    return float(value) if np.isfinite(value) else float("nan")
