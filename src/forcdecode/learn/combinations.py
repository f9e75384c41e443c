"""Identified combinations as outputs (issue 44, item 1): the derived combinations of the parameter
table (``core.parameters.COMBINATIONS``: σ_w, δ_w, D/D_c, Q) scored like the six parameters.

- **Posterior** (``posterior_combination_metrics``): each draw of the joint posterior (u ∈ [0, 1] of its
  parameters, M_s given) is mapped to SI, the combination computed per draw (no new network), and the
  draws, the truths and the baselines normalized by ``core.parameters.normalize_combination`` (a
  reference range from the training split's truths). The metrics are those of the six parameters,
  computed by the same functions: ``calibration_metrics`` (MAE of mean and median, SBC ranks with a KS
  p-value, central-interval coverage and width) and ``scoring.accuracy_with_intervals`` (MAE, Pearson r,
  skill over the prior and M_s-only baselines with paired-bootstrap 90 % intervals, 90 % coverage), plus
  the images-shuffled baseline (the posterior's median on the test images permuted, M_s kept).
- **Undefined draws**: where K_eff ≤ 0 σ_w, δ_w and D/D_c are NaN. A family whose true value is NaN is
  not scored for that combination; a family's NaN draws are replaced by draws picked at random (with
  replacement, a fixed stream) among its defined draws, i.e. the posterior conditioned on the
  combination being defined, so that every scored family keeps the same number of draws (the SBC ranks
  need it). A family with fewer than two defined draws is not scored. Reported: ``n_scored``,
  ``n_truth_undefined``, ``n_too_few_defined_draws`` and ``undefined_draw_fraction`` (mean over scored
  families of the fraction of draws that were undefined).
- **A_ex–D ridge** (``ridge_correlations``): per test family the Pearson correlation of the A_ex and D
  draws in normalized coordinates; its median over the families (``A_ex_D_correlation_median``) with a
  bootstrap 90 % interval, and a figure of the draws of a few families with the σ_w = const lines
  (``ridge_figure``).
- **Alice** (``alice_combination_metrics``): the plug-in estimate, the combination of Alice's predicted
  parameters (each network's readout) with the test family's M_s, against the same prior and M_s-only
  baselines. No coverage or SBC: Alice's marginal intervals do not make a joint distribution.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..core import io
from ..core.parameters import (COMBINATION_BY_NAME, COMBINATION_NAMES, combination_reference, denormalize, k_eff,
                               normalize_combination, wall_energy)
from .calibration import calibration_metrics
from .scoring import (accuracy_with_intervals, fit_ms_only, knn_median, median_with_interval, skill,
                      skill_interval)

RIDGE_PAIR = ("A_ex", "D")
RIDGE_FIGURE_FAMILIES = 4


def available(names) -> tuple:
    """The combinations whose parameters (besides M_s, always given) are all in ``names``."""
    have = set(names) | {"Ms"}
    return tuple(c for c in COMBINATION_NAMES if set(COMBINATION_BY_NAME[c].needs) <= have)


def si_values(u, names, ms_norm, bounds) -> dict:
    """name -> SI array of normalized ``u`` (``[..., len(names)]``), M_s from ``ms_norm`` (broadcast
    along the leading axis: per family, shared by its draws)."""
    u = np.asarray(u, dtype=float)
    out = {n: denormalize(n, u[..., j], bounds) for j, n in enumerate(names)}
    ms = denormalize("Ms", np.asarray(ms_norm, dtype=float), bounds)
    out["Ms"] = ms.reshape(ms.shape + (1,) * (u.ndim - 1 - ms.ndim))
    return out


def combinations_of(u, names, ms_norm, bounds, combinations=None) -> np.ndarray:
    """The combinations (SI) of normalized parameters ``u`` (n, [draws,] len(names)) with M_s per family:
    array (n, [draws,] len(combinations)); NaN where a combination is undefined."""
    combinations = available(names) if combinations is None else tuple(combinations)
    values = si_values(u, names, ms_norm, bounds)
    shape = np.asarray(u).shape[:-1]
    return np.stack([np.broadcast_to(COMBINATION_BY_NAME[c](values), shape) for c in combinations], axis=-1)


def condition_on_defined(draws, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(draws with each family's NaN draws replaced by its defined ones picked at random, the fraction of
    defined draws per family); ``draws`` (n, n_draws). A family without a defined draw stays NaN."""
    draws = np.array(draws, dtype=float)
    defined = np.isfinite(draws)
    fraction = defined.mean(axis=1)
    for i in np.flatnonzero((fraction < 1) & (fraction > 0)):
        good = draws[i, defined[i]]
        draws[i, ~defined[i]] = good[rng.integers(0, good.size, int((~defined[i]).sum()))]
    return draws, fraction


def references(train_truth: np.ndarray, combinations) -> dict:
    """name -> [lo, hi] normalization range of each combination from the training families' true values
    (SI, (n_train, len(combinations)))."""
    return {c: combination_reference(c, train_truth[:, k]) for k, c in enumerate(combinations)}


def _normalized(values, combinations, reference) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    return np.stack([normalize_combination(c, values[..., k], reference[c]) for k, c in enumerate(combinations)], -1)


def accuracy_block(truth, median, ms_norm, reference_u, shuffled_median, covered_90, rng, n_boot: int) -> dict:
    """Accuracy of ``median`` on the test families against the prior (train median), M_s-only (k-NN in
    M_s, k chosen on validation) and images-shuffled baselines: the same figures as Alice's
    (``scoring.accuracy_with_intervals``) plus the skill over the shuffled images (None: not computed).
    ``truth``, ``median``, ``shuffled_median`` on the scored test families; ``ms_norm`` = (train,
    validation, scored test) normalized M_s; ``reference_u`` = (train, validation) truths (NaN rows are
    dropped)."""
    ms_train, ms_val, ms_test = ms_norm
    u_train, u_val = reference_u
    keep_t, keep_v = np.isfinite(u_train), np.isfinite(u_val)
    prior = float(np.median(u_train[keep_t]))
    if keep_v.sum() >= 1 and keep_t.sum() >= 1:
        k = fit_ms_only(ms_train[keep_t], u_train[keep_t], ms_val[keep_v], u_val[keep_v])
    else:
        k = 1
    ms_only = knn_median(ms_train[keep_t], u_train[keep_t], ms_test, k)
    out = accuracy_with_intervals(truth, median, ms_only, np.full(len(truth), prior), covered_90, rng, n_boot)
    mae_shuffled = float(np.mean(np.abs(shuffled_median - truth))) if shuffled_median is not None else float("nan")
    out["skill_vs_images_shuffled"] = skill(out["mae"], mae_shuffled)
    out["skill_vs_images_shuffled_ci90"] = (skill_interval(truth, median, shuffled_median, rng, n_boot)
                                            if shuffled_median is not None else [float("nan")] * 2)
    out["baselines"] = {"prior": float(np.mean(np.abs(prior - truth))), "ms_only": float(np.mean(np.abs(ms_only - truth))),
                        "ms_only_k": int(k), "images_shuffled": mae_shuffled}
    return out


@dataclass(frozen=True)
class ReferenceFamilies:
    """The families whose truths normalize the combinations and fit the trivial baselines:
    ``train_u`` (n_train, len(names)) and ``val_u`` (n_val, len(names)) the training and validation
    families' normalized truths (u in [0, 1]), ``train_ms_norm`` (n_train,) and ``val_ms_norm`` (n_val,)
    their normalized M_s. The normalization range and the prior come from train; the M_s-only
    neighbour count is chosen on validation."""

    train_u: np.ndarray
    train_ms_norm: np.ndarray
    val_u: np.ndarray
    val_ms_norm: np.ndarray


@dataclass(frozen=True)
class CombinationScoring:
    """How the combinations' metrics are scored: ``rng_of(*keys)`` a fresh generator per purpose,
    ``levels`` the central credible-interval levels (fractions in (0, 1)) and ``n_boot`` the bootstrap
    resamples behind each figure's 90 % interval."""

    rng_of: Callable
    levels: Sequence[float]
    n_boot: int = 2000


def posterior_combination_metrics(samples, truth_u, names, ms_norm, bounds, *, reference: ReferenceFamilies,
                                  scoring: CombinationScoring, shuffled=None) -> dict:
    """The combinations' metrics of posterior draws on the test families.

    ``samples`` (n_test, n_draws, len(names)) normalized draws; ``truth_u`` (n_test, len(names)) their
    truths; ``ms_norm`` the test families' normalized M_s; ``reference``: the training and validation
    families' truths (normalization range, prior and M_s-only baselines); ``shuffled``: draws of the
    test images permuted among the test families (M_s kept), or None; ``scoring``: the generators,
    levels and bootstrap size. Returns name -> metrics (see the module) and the normalization ranges,
    or {} where no combination is computable."""
    train_u, train_ms_norm = reference.train_u, reference.train_ms_norm
    val_u, val_ms_norm = reference.val_u, reference.val_ms_norm
    rng_of, levels, n_boot = scoring.rng_of, scoring.levels, scoring.n_boot
    combinations = available(names)
    if not combinations:
        return {}
    ms_norm = np.asarray(ms_norm, dtype=float)
    draws_si = combinations_of(samples, names, ms_norm, bounds, combinations)
    truth_si = combinations_of(truth_u, names, ms_norm, bounds, combinations)
    train_si = combinations_of(train_u, names, train_ms_norm, bounds, combinations)
    val_si = combinations_of(val_u, names, val_ms_norm, bounds, combinations)
    reference = references(train_si, combinations)
    draws_c, truth_c = _normalized(draws_si, combinations, reference), _normalized(truth_si, combinations, reference)
    train_c, val_c = _normalized(train_si, combinations, reference), _normalized(val_si, combinations, reference)
    shuffled_c = None
    if shuffled is not None:
        shuffled_c = _normalized(combinations_of(shuffled, names, ms_norm, bounds, combinations), combinations, reference)
    out = {}
    for k, name in enumerate(combinations):
        c = COMBINATION_BY_NAME[name]
        filled, fraction = condition_on_defined(draws_c[:, :, k], rng_of("condition", name))
        truth_ok = np.isfinite(truth_c[:, k])
        scored = truth_ok & (fraction * samples.shape[1] >= 2)
        row = {"unit": c.unit, "formula": c.formula, "scale": c.scale, "undefined": c.undefined,
               "normalization": {"reference": reference[name], "scale": c.scale,
                                 "reference_from": "training split's true values, 1st-99th percentile"},
               "n_scored": int(scored.sum()), "n_truth_undefined": int((~truth_ok).sum()),
               "n_too_few_defined_draws": int((truth_ok & ~scored).sum()),
               "undefined_draw_fraction": float(1 - fraction[scored].mean()) if scored.any() else float("nan")}
        if scored.sum() >= 2:
            cal = calibration_metrics(filled[scored][:, :, None], truth_c[scored][:, [k]], [name], rng_of("calibration", name),
                                      levels)
            row.update(cal["per_parameter"][name])
            median = np.median(filled[scored], axis=1)
            low, high = np.quantile(filled[scored], [0.05, 0.95], axis=1)
            covered = (truth_c[scored, k] >= low) & (truth_c[scored, k] <= high)
            shuffled_median = None
            if shuffled_c is not None:
                s_filled, _ = condition_on_defined(shuffled_c[:, :, k], rng_of("condition_shuffled", name))
                shuffled_median = np.median(s_filled[scored], axis=1)
                shuffled_median = np.where(np.isfinite(shuffled_median), shuffled_median,
                                           np.nanmedian(train_c[:, k]))  # no defined draw: the prior
            acc = accuracy_block(truth_c[scored, k], median, (train_ms_norm, val_ms_norm, ms_norm[scored]),
                                 (train_c[:, k], val_c[:, k]), shuffled_median, covered, rng_of("bootstrap", name),
                                 n_boot)
            if "coverage_90" in row:  # the calibration's coverage_90 (the same central intervals) is kept
                acc.pop("coverage_90")
            row.update(acc)
        out[name] = row
    return out


def summarize_draws(draws, names, ms_norm: float, bounds, levels=(0.68, 0.9)) -> dict:
    """One observation's draws (n_draws, len(names)) → per computable combination: the median of its
    defined draws (``value``, SI), central intervals ``interval_<level>`` (SI), ``unit``, ``formula`` and
    ``defined_fraction`` (the posterior conditioned on the combination being defined, as in the metrics)."""
    combinations = available(names)
    if not combinations:
        return {}
    draws = np.asarray(draws, dtype=float)
    values = combinations_of(draws[None], names, [ms_norm], bounds, combinations)[0]
    out = {}
    for k, name in enumerate(combinations):
        c = COMBINATION_BY_NAME[name]
        defined = values[np.isfinite(values[:, k]), k]
        row = {"unit": c.unit, "formula": c.formula, "defined_fraction": float(defined.size / max(len(values), 1))}
        if defined.size:
            row["value"] = float(np.median(defined))
            for level in levels:
                row[f"interval_{int(round(level * 100))}"] = [float(q) for q in
                                                               np.quantile(defined, [(1 - level) / 2, (1 + level) / 2])]
        out[name] = row
    return out


def ridge_correlations(samples, names, pair=RIDGE_PAIR) -> np.ndarray | None:
    """Per family the Pearson correlation of the draws of ``pair`` (normalized coordinates); NaN where
    either has no spread; None where ``names`` lacks one of them."""
    if not set(pair) <= set(names):
        return None
    samples = np.asarray(samples, dtype=float)
    a, b = (samples[:, :, list(names).index(n)] for n in pair)
    a, b = a - a.mean(axis=1, keepdims=True), b - b.mean(axis=1, keepdims=True)
    denominator = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denominator > 0, (a * b).sum(axis=1) / np.where(denominator > 0, denominator, 1.0), np.nan)


def ridge_summary(samples, names, rng: np.random.Generator, n_boot: int = 2000) -> dict | None:
    """``A_ex_D_correlation_median`` with its bootstrap 90 % interval and the per-family values."""
    r = ridge_correlations(samples, names)
    if r is None:
        return None
    median, ci = median_with_interval(r, rng, n_boot)
    return {"A_ex_D_correlation_median": median, "A_ex_D_correlation_median_ci90": ci,
            "A_ex_D_correlation_per_family": [float(v) for v in r],
            "A_ex_D_correlation": "Pearson r of the A_ex and D draws per test family, normalized coordinates"}


def ridge_figure(samples, truth_u, names, ms_norm, bounds, out_path, n_families: int = RIDGE_FIGURE_FAMILIES,
                 labels=None) -> bool:
    """The A_ex–D draws (SI: pJ/m, mJ/m²) of ``n_families`` test families, spread over the families'
    correlation quantiles, with the truth and the σ_w = const lines: the truth's σ_w at the true K_eff
    (through the truth), and the 5/50/95 % of the draws' σ_w at the draws' median K_eff (none where that
    is ≤ 0). ``labels``: the families' names in the titles (sample ids; default their index). False
    (nothing written) where the posterior lacks A_ex, D or K_u."""
    if not {"A_ex", "D", "K_u"} <= set(names):
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = ridge_correlations(samples, names)
    order = np.argsort(np.where(np.isfinite(r), r, 0.0), kind="stable")
    picks = order[np.unique(np.linspace(0, len(order) - 1, min(n_families, len(order))).round().astype(int))]
    fig, axes = plt.subplots(1, len(picks), figsize=(3.3 * len(picks), 3.2), squeeze=False)
    for ax, i in zip(axes[0], picks):
        draws = si_values(samples[i], names, np.full(samples.shape[1], ms_norm[i]), bounds)
        truth = si_values(truth_u[i][None], names, np.asarray([ms_norm[i]]), bounds)
        ax.scatter(draws["A_ex"] * 1e12, draws["D"] * 1e3, s=3, alpha=0.25, color="tab:blue", edgecolors="none")
        ax.plot(truth["A_ex"] * 1e12, truth["D"] * 1e3, "r*", ms=9, label="truth")
        a = np.linspace(*np.quantile(draws["A_ex"], [0.0, 1.0]), 50)
        # the truth's σ_w at its own K_eff (through the star); the draws' 5/50/95 % σ_w at their median K_eff
        keff_truth, sigma_truth = float(k_eff(truth)[0]), float(wall_energy(truth)[0])
        if keff_truth > 0:
            ax.plot(a * 1e12, (4 * np.sqrt(a * keff_truth) - sigma_truth) / np.pi * 1e3, "k-", lw=1.0,
                    label=r"$\sigma_w$ of the truth")
        keff, sigma = float(np.median(k_eff(draws))), wall_energy(draws)
        if keff > 0 and np.isfinite(sigma).any():
            for j, s in enumerate(np.nanquantile(sigma, [0.05, 0.5, 0.95])):
                ax.plot(a * 1e12, (4 * np.sqrt(a * keff) - s) / np.pi * 1e3, color="0.5", lw=0.7, ls="--",
                        label=r"draws' $\sigma_w$ 5/50/95 %" if j == 0 else None)
        label = f"{labels[i]}" if labels is not None else f"{i}"
        ax.set(xlabel=r"$A_\mathrm{ex}$ (pJ/m)", ylabel=r"$D$ (mJ/m$^2$)",
               title=f"family {label}: r = {r[i]:.2f}" if np.isfinite(r[i]) else f"family {label}")
        span = np.append(draws["D"], truth["D"]) * 1e3
        ax.set_ylim(span.min() - 0.05, span.max() + 0.05)
    axes[0][0].legend(fontsize=6, title=r"lines: $\sigma_w$ = const", title_fontsize=6)
    fig.tight_layout()
    with io.atomic_path(out_path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return True


def alice_combination_metrics(prediction_u: dict, target_u: dict, ms_norm, bounds, split, rng_of,
                              n_boot: int = 2000, shuffled_u=None) -> dict:
    """Alice's plug-in combinations: ``prediction_u``/``target_u`` name -> normalized array over every
    family (each network's readout and the truth), ``ms_norm`` per family, ``split`` per family
    ("train"/"validation"/"calibration"/"test"). The normalization range and baselines come from the
    training families, the figures from the test ones (MAE, Pearson r, skill vs prior and M_s-only with
    90 % intervals); no coverage (Alice's marginal intervals make no joint). ``shuffled_u``: a list (one
    per permutation of the test images, M_s kept) of name -> normalized predictions over every family
    (only the test ones are read): the images-shuffled baseline, its MAE averaged over the permutations
    (as Alice's per-parameter baseline), the skill interval paired per family on that average."""
    names = tuple(n for n in prediction_u if n in target_u)
    combinations = available(names)
    if not combinations:
        return {}
    split = np.asarray(split)
    ms_norm = np.asarray(ms_norm, dtype=float)
    stack = lambda d: np.stack([np.asarray(d[n], dtype=float) for n in names], axis=1)  # noqa: E731
    predicted = combinations_of(stack(prediction_u), names, ms_norm, bounds, combinations)
    truth = combinations_of(stack(target_u), names, ms_norm, bounds, combinations)
    train, val, test = (np.flatnonzero(split == s) for s in ("train", "validation", "test"))
    reference = references(truth[train], combinations)
    predicted_c, truth_c = _normalized(predicted, combinations, reference), _normalized(truth, combinations, reference)
    shuffled_c = [_normalized(combinations_of(stack(d), names, ms_norm, bounds, combinations), combinations, reference)
                  for d in (shuffled_u or [])]
    out = {}
    for k, name in enumerate(combinations):
        c = COMBINATION_BY_NAME[name]
        scored = test[np.isfinite(truth_c[test, k])]
        # an undefined plug-in (predicted K_eff ≤ 0) is replaced by the prior (train median), and counted
        prior = float(np.nanmedian(truth_c[train, k]))
        plug_in = predicted_c[scored, k]
        undefined = ~np.isfinite(plug_in)
        plug_in = np.where(undefined, prior, plug_in)
        row = {"unit": c.unit, "formula": c.formula, "scale": c.scale, "estimate": "plug-in: the combination of "
               "Alice's predicted parameters", "normalization": {"reference": reference[name], "scale": c.scale},
               "n_scored": int(len(scored)), "n_truth_undefined": int(len(test) - len(scored)),
               "n_plug_in_undefined": int(undefined.sum())}
        if len(scored) >= 2:
            shuffled = None
            if shuffled_c:
                # per family the mean |error| over the permutations, as a prediction at that distance from
                # the truth: its MAE is the permutations' mean MAE, and the bootstrap stays paired per family
                errors = np.mean([np.abs(np.where(np.isfinite(sc[scored, k]), sc[scored, k], prior) - truth_c[scored, k])
                                  for sc in shuffled_c], axis=0)
                shuffled = truth_c[scored, k] + errors
            acc = accuracy_block(truth_c[scored, k], plug_in, (ms_norm[train], ms_norm[val], ms_norm[scored]),
                                 (truth_c[train, k], truth_c[val, k]), shuffled, np.zeros(0), rng_of("bootstrap", name),
                                 n_boot)
            for key in ("coverage_90", "coverage_90_ci90"):
                acc.pop(key, None)
            if shuffled is None:
                for key in ("skill_vs_images_shuffled", "skill_vs_images_shuffled_ci90"):
                    acc.pop(key, None)
                acc["baselines"].pop("images_shuffled", None)
            else:
                acc["baselines"]["images_shuffled_permutations"] = len(shuffled_c)
            row.update(acc)
        out[name] = row
    return out


__all__ = ["RIDGE_PAIR", "available", "si_values", "combinations_of", "condition_on_defined", "references",
           "summarize_draws",
           "accuracy_block", "posterior_combination_metrics", "ridge_correlations", "ridge_summary", "ridge_figure",
           "alice_combination_metrics"]
