"""The answer a user reads (issue 44 item 5): which parameters and combinations a model reads from the
image, and the identified combinations with their intervals for Alice.

**Read from the image, or prior only.** A parameter (or combination) is *read from the image* only when
the skill of the estimator over the best trivial predictor,

    skill = 1 − MAE(estimate) / min(MAE(prior median), MAE(M_s-only k-NN median)),

has its 90 % paired percentile-bootstrap interval above 0 on the **validation** split (never test). The
trivial predictors are fitted on the training split (the M_s-only k chosen on validation, which can only
favour the baseline), and the better of the two is chosen again on each bootstrap resample
(``scoring.skill_over_best_trivial``). The resamples come from the named stream ``bootstrap`` (keys
"identification" and the name), so the flag is the same on every run. Errors are on the normalized
scale (u ∈ [0, 1] for a parameter; a combination normalized by its training-split reference range,
``core.parameters.normalize_combination``). Validation also chose the networks' early-stopping epoch, so
the skill is a little optimistic; test figures stay the reported ones (metrics.json).

- **Alice**: ``alice_identification`` runs at training time (``pipeline.train_parameter``) and its block
  is saved in the model file (``identification``: the parameter's record, and the validation and
  training records a combination's flag needs: sample ids, truths, predictions, M_s). A combination's
  flag is computed when predicting, from those records of the model files it needs
  (``alice_combination_identification``): the plug-in (the combination of Alice's predictions; an
  undefined plug-in counts as the prior) against the same trivial predictors.
- **Posterior**: ``posterior_identification`` runs at training time on the posterior's draws of the
  validation families (``posterior.training.train_posterior``; estimate = the median of the draws, of
  the defined draws for a combination) and is saved in the model file's metadata.
- A model file saved before the flag existed gives ``read_from_image: None`` with the basis
  ``"unknown (model predates the flag)"``.

**Alice's combinations** (``alice_answer``): Alice gives each parameter a marginal interval (Bob's
conformal 68 and 90 % intervals) and no joint distribution. The combinations' intervals are a Monte
Carlo propagation of those intervals: for each parameter a quantile function in u through its
prediction (the median) and the ends of its intervals (at (1 ∓ level)/2), linear in between, extended
beyond the widest interval with the slope of its outermost segment and clipped to [0, 1]; parameters are
drawn **independently** (stream ``propagation``), each draw mapped to SI and the combination computed per
draw. This ignores the correlations between parameters (the A_ex–D ridge, for one), which the joint
posterior keeps: the intervals say how the marginal uncertainties add up, not the joint one. The value
reported is the plug-in (the combination of the predictions, what ``metrics.json`` scores); the
intervals are the central quantiles of the draws where the combination is defined
(``defined_fraction``: the share of draws where it is).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.parameters import COMBINATION_BY_NAME, TARGETS, normalize, normalize_combination
from ..core.streams import stream_rng
from .combinations import available, combinations_of, references
from .prediction import PRIOR_ONLY, Prediction
from .scoring import fit_ms_only, knn_median, skill_over_best_trivial

FORMAT = "forcdecode-identification/1"
SPLIT = "validation"
RULE = ("read from the image when the skill over the best trivial predictor (the better of the prior median and "
        "the M_s-only k-NN median, both fitted on the training split) has its 90 % bootstrap interval above 0 "
        "on the validation split")
PREDATES = "unknown (model predates the flag)"
ALICE_COMBINATIONS_METHOD = (
    "Monte Carlo through Alice's per-parameter intervals, each parameter drawn independently: this ignores the "
    "correlations between parameters (unlike the joint posterior); value = the combination of the predictions")


PER_FILE_SPAN = 0.8
"""A quantity read from the image on average over the prior is still not read *for this file* when its
90 % interval here spans at least this share of its prior range (``per_file_identification``)."""

NOT_FOR_THIS_FILE = "not read for this file"


# ---------------------------------------------------------------- the flag
def _basis(record: dict) -> str:
    lo, hi = record["skill_ci90"]
    return (f"validation skill over the best trivial predictor {record['skill']:+.2f}, 90 % bootstrap interval "
            f"[{lo:+.2f}, {hi:+.2f}] (n = {record['n']} validation families)")


def identification_record(truth, estimate, train_truth, train_ms_norm, val_ms_norm, rng, n_boot: int = 2000) -> dict:
    """The flag of one parameter or combination from its validation figures: ``truth`` and ``estimate`` on
    the validation families (normalized; a family whose truth is NaN is dropped, a NaN estimate counts as
    the prior), the trivial predictors fitted on ``train_truth`` (NaN dropped) with the M_s-only k chosen
    on validation. Returns ``scoring.skill_over_best_trivial``'s figures with ``read_from_image`` (None
    where fewer than two families are scored), ``basis``, ``split`` and ``ms_only_k``."""
    truth, estimate = np.asarray(truth, float), np.asarray(estimate, float)
    train_truth, train_ms = np.asarray(train_truth, float), np.asarray(train_ms_norm, float)
    val_ms = np.asarray(val_ms_norm, float)
    keep_t, keep_v = np.isfinite(train_truth), np.isfinite(truth)
    truth, estimate, val_ms = truth[keep_v], estimate[keep_v], val_ms[keep_v]
    if keep_t.sum() < 1 or truth.size < 2:
        return {"read_from_image": None, "split": SPLIT, "n": int(truth.size),
                "basis": f"unknown: {int(truth.size)} validation families with a defined value (needs 2)"}
    prior = float(np.median(train_truth[keep_t]))
    estimate = np.where(np.isfinite(estimate), estimate, prior)
    k = fit_ms_only(train_ms[keep_t], train_truth[keep_t], val_ms, truth)
    ms_only = knn_median(train_ms[keep_t], train_truth[keep_t], val_ms, k)
    record = skill_over_best_trivial(truth, estimate, np.full(truth.size, prior), ms_only, rng, n_boot)
    lo = record["skill_ci90"][0]
    record.update(split=SPLIT, ms_only_k=int(k), read_from_image=bool(lo > 0) if np.isfinite(lo) else None)
    record["basis"] = _basis(record) if np.isfinite(lo) else "unknown: no finite bootstrap interval"
    return record


def flag(record: dict | None) -> dict:
    """{"read_from_image": True/False/None, "basis": ...} of a stored record (None: the model predates it)."""
    if not record:
        return {"read_from_image": None, "basis": PREDATES}
    return {"read_from_image": record.get("read_from_image"), "basis": record.get("basis", PREDATES)}


def _rng(seed: int, name: str):
    return stream_rng(int(seed), "bootstrap", "identification", name)


# ---------------------------------------------------------------- Alice: training time
def alice_identification(name: str, u, prediction, ms_norm, sample_id, train, val, seed: int, n_boot: int) -> dict:
    """The ``identification`` block of Alice's model file for parameter ``name``: the parameter's record
    (``identification_record`` on the validation split) and the records a combination's flag needs."""
    u, prediction, ms_norm = (np.asarray(a, float) for a in (u, prediction, ms_norm))
    sample_id = np.asarray(sample_id)
    record = identification_record(u[val], prediction[val], u[train], ms_norm[train], ms_norm[val],
                                   _rng(seed, name), n_boot)
    as_list = lambda a: [float(v) for v in a]  # noqa: E731
    return {"format": FORMAT, "rule": RULE, "split": SPLIT, "seed": int(seed), "n_boot": int(n_boot),
            "parameter": record,
            "records": {"validation": {"sample_id": [int(s) for s in sample_id[val]], "truth": as_list(u[val]),
                                       "prediction": as_list(prediction[val]), "ms_norm": as_list(ms_norm[val])},
                        "train": {"sample_id": [int(s) for s in sample_id[train]], "truth": as_list(u[train]),
                                  "ms_norm": as_list(ms_norm[train])}}}


# ---------------------------------------------------------------- Alice: predict time
def _identification_of(model) -> dict | None:
    block = getattr(model, "payload", {}).get("identification")
    return block if isinstance(block, dict) and block.get("format") == FORMAT else None


def _joined(blocks: dict, split: str, keys) -> tuple[np.ndarray, dict] | None:
    """(sample ids, name -> {key: array}) of ``split`` on the sample ids every block holds; None if none."""
    ids = None
    for block in blocks.values():
        s = set(block["records"][split]["sample_id"])
        ids = s if ids is None else ids & s
    if not ids:
        return None
    ids = np.array(sorted(ids))
    out = {}
    for name, block in blocks.items():
        rows = block["records"][split]
        where = {s: i for i, s in enumerate(rows["sample_id"])}
        index = np.array([where[s] for s in ids])
        out[name] = {k: np.asarray(rows[k], float)[index] for k in keys}
    return ids, out


def alice_combination_identification(models: dict, combinations) -> dict:
    """combination -> record (``identification_record``) of Alice's plug-in on the validation families,
    from the records saved in the model files it needs; None where one of them predates the flag."""
    out = {}
    for c in combinations:
        needed = [n for n in COMBINATION_BY_NAME[c].needs if n != "Ms"]
        blocks = {n: _identification_of(models[n]) for n in needed}
        if any(b is None for b in blocks.values()):
            out[c] = None
            continue
        val = _joined(blocks, "validation", ("truth", "prediction", "ms_norm"))
        train = _joined(blocks, "train", ("truth", "ms_norm"))
        if val is None or train is None:
            out[c] = {"read_from_image": None, "split": SPLIT, "n": 0,
                      "basis": "unknown: the model files hold no common validation families"}
            continue
        bounds = models[needed[0]].bounds
        names = tuple(needed)
        stack = lambda rows, key: np.stack([rows[n][key] for n in names], axis=1)  # noqa: E731
        val_ms, train_ms = val[1][needed[0]]["ms_norm"], train[1][needed[0]]["ms_norm"]
        truth_si = combinations_of(stack(val[1], "truth"), names, val_ms, bounds, (c,))
        plug_in_si = combinations_of(stack(val[1], "prediction"), names, val_ms, bounds, (c,))
        train_si = combinations_of(stack(train[1], "truth"), names, train_ms, bounds, (c,))
        reference = references(train_si, (c,))[c]
        norm = lambda v: normalize_combination(c, v[:, 0], reference)  # noqa: E731
        block = blocks[needed[0]]
        out[c] = identification_record(norm(truth_si), norm(plug_in_si), norm(train_si), train_ms, val_ms,
                                       _rng(block["seed"], c), int(block["n_boot"]))
    return out


def quantile_draws(median: float, intervals: dict, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` draws of u ∈ [0, 1] from the quantile function through ``median`` (at 0.5) and each central
    interval's ends (``intervals``: level -> (lo, hi), at (1 ∓ level)/2): linear in between, extended past
    the widest interval with its outermost segments' slopes, clipped to [0, 1] (monotone)."""
    p, q = [0.5], [float(median)]
    for level, (lo, hi) in intervals.items():
        p += [(1 - level) / 2, (1 + level) / 2]
        q += [float(lo), float(hi)]
    order = np.argsort(p, kind="stable")
    p, q = np.asarray(p)[order], np.maximum.accumulate(np.asarray(q)[order])
    if p.size >= 2:
        low_slope = (q[1] - q[0]) / (p[1] - p[0])
        high_slope = (q[-1] - q[-2]) / (p[-1] - p[-2])
        q = np.concatenate([[q[0] - low_slope * p[0]], q, [q[-1] + high_slope * (1.0 - p[-1])]])
        p = np.concatenate([[0.0], p, [1.0]])
    return np.clip(np.interp(rng.random(n), p, q), 0.0, 1.0)


def alice_answer(models: dict, result: dict, n_draws: int = 4000, seed: int = 0) -> dict:
    """``predict_parameters``' result with, per parameter, ``read_from_image`` and ``basis`` (and the
    ``prior_range`` (SI) of one not read from the image), and ``combinations``: per computable combination
    the plug-in ``value``, the Monte-Carlo ``interval_68``/``interval_90`` (see the module),
    ``defined_fraction``, ``unit``, ``formula`` and its own flag; ``combinations_method`` says how."""
    if n_draws < 1:
        raise ConfigError(f"the combinations' Monte-Carlo draws must be positive, got {n_draws}")
    out = dict(result)
    out["estimator"] = "alice"
    out["identification_rule"] = RULE
    names = [n for n in models if isinstance(result.get(n), dict)]
    for name in names:
        entry = dict(result[name])
        entry.update(flag((_identification_of(models[name]) or {}).get("parameter")))
        if entry["read_from_image"] is False:
            entry["prior_range"] = [float(v) for v in models[name].bounds[name]]
        out[name] = entry
    combos = available(names)
    if not combos:
        return out

    bounds = models[names[0]].bounds
    ms_norm = float(normalize("Ms", result["Ms"], bounds))
    learned = tuple(n for n in names if n in TARGETS)
    rng = stream_rng(int(seed), "propagation", "alice_combinations")
    draws = np.stack([quantile_draws(result[n]["normalized"], _normalized_intervals(result[n]), rng, n_draws)
                      for n in learned], axis=1)
    plug_in = combinations_of(np.array([[result[n]["normalized"] for n in learned]]), learned, [ms_norm], bounds,
                              combos)[0]
    values = combinations_of(draws[None], learned, [ms_norm], bounds, combos)[0]
    flags = alice_combination_identification(models, combos)
    rows = {}
    for k, c in enumerate(combos):
        combination = COMBINATION_BY_NAME[c]
        defined = values[np.isfinite(values[:, k]), k]
        row = {"unit": combination.unit, "formula": combination.formula,
               "value": float(plug_in[k]) if np.isfinite(plug_in[k]) else None,
               "defined_fraction": float(defined.size / max(len(values), 1))}
        if defined.size:
            row["median_of_draws"] = float(np.median(defined))
            for level in (0.68, 0.9):
                row[f"interval_{int(round(level * 100))}"] = [
                    float(v) for v in np.quantile(defined, [(1 - level) / 2, (1 + level) / 2])]
        row.update(flag(flags[c]))
        rows[c] = row
    out["combinations"] = rows
    out["combinations_method"] = f"{ALICE_COMBINATIONS_METHOD}; {n_draws} draws"
    return per_file_identification(out, bounds, seed=seed)


def _normalized_intervals(entry: dict) -> dict:
    """level -> (lo, hi) in u of a ``predict_parameters`` entry (``interval_<tag>_normalized``)."""
    out = {}
    for key, value in entry.items():
        if key.startswith("interval_") and key.endswith("_normalized") and key.count("_") == 2:
            out[int(key.split("_")[1]) / 100] = tuple(value)
    return out


# ---------------------------------------------------------------- per file
def _prior_ranges(result: dict, bounds: dict, names, combos, n_draws: int, seed: int) -> dict:
    """The prior range (1 %–99 % quantiles, SI) of each combination at this file's M_s: the combination of
    parameters drawn uniformly in their normalized coordinates (each parameter's prior range; the prior
    class's joint constraint, K_eff > 0, is not applied, so the range is the wider one)."""
    rng = stream_rng(int(seed), "propagation", "prior_ranges")
    u = rng.random((n_draws, len(names)))
    values = combinations_of(u[None], list(names), [float(normalize("Ms", result["Ms"], bounds))], bounds, combos)[0]
    out = {}
    for k, c in enumerate(combos):
        defined = values[np.isfinite(values[:, k]), k]
        if defined.size:
            out[c] = [float(v) for v in np.quantile(defined, [0.01, 0.99])]
    return out


def _per_file(entry: dict, share: float | None) -> None:
    if share is None or not np.isfinite(share):
        return
    entry["interval_90_prior_share"] = float(share)
    wide = share >= PER_FILE_SPAN
    entry["read_for_this_file"] = bool(entry.get("read_from_image") is not False and not wide)
    if wide and entry.get("read_from_image") is not False:
        entry["per_file_basis"] = (f"{NOT_FOR_THIS_FILE}: its 90 % interval spans {share:.0%} of its prior range "
                                   f"(≥ {PER_FILE_SPAN:.0%}), whatever its skill over the prior on average")


def per_file_identification(result: dict, bounds: dict, n_draws: int = 4000, seed: int = 0) -> dict:
    """Which quantities this file identifies (issue 59 item 5). The flag ``read_from_image`` is a property
    of the model on average over the prior; for one file a quantity is ``read_for_this_file`` only when it
    is read from the image and its 90 % interval here spans less than ``PER_FILE_SPAN`` of its prior
    range: for a parameter the width of ``interval_90_normalized`` (its prior range is 1 in normalized
    units), for a combination the width of ``interval_90`` over its prior range at this M_s
    (``_prior_ranges``). Adds ``interval_90_prior_share``, ``read_for_this_file`` and, where the interval
    is too wide, ``per_file_basis``; ``identified_for_this_file``: the names read for this file."""
    names = [n for n in TARGETS if n in Prediction.from_dict(result).parameters]
    for name in names:
        interval = result[name].get("interval_90_normalized")
        _per_file(result[name], None if interval is None else abs(float(interval[1]) - float(interval[0])))
    combinations = result.get("combinations") or {}
    if combinations and "Ms" in result and names:
        ranges = _prior_ranges(result, bounds, names, list(combinations), n_draws, seed)
        for name, row in combinations.items():
            interval, prior = row.get("interval_90"), ranges.get(name)
            if interval is None or prior is None or not prior[1] > prior[0]:
                continue
            _per_file(row, abs(float(interval[1]) - float(interval[0])) / (prior[1] - prior[0]))
    result["identified_for_this_file"] = (
        [n for n in names if result[n].get("read_for_this_file")]
        + [n for n, row in combinations.items() if row.get("read_for_this_file")])
    result["per_file_rule"] = (f"read for this file when read from the image and its 90 % interval spans less than "
                               f"{PER_FILE_SPAN:.0%} of its prior range")
    return result


# ---------------------------------------------------------------- the posterior
def posterior_identification(draws, u, names, ms_norm, bounds, splits: dict, seed: int, n_boot: int) -> dict:
    """The posterior's ``identification`` block (saved in its model file's metadata): per parameter and per
    computable combination the record (``identification_record``) of the median of its draws on the
    validation families. ``draws`` (n_val, n_draws, len(names)) are the validation families' draws, ``u``
    (n, len(names)) every family's truths, ``ms_norm`` every family's normalized M_s, ``splits`` the
    split indices (its ``train`` and ``validation`` are read)."""
    draws, u, ms_norm = np.asarray(draws, float), np.asarray(u, float), np.asarray(ms_norm, float)
    train, val = np.asarray(splits["train"]), np.asarray(splits["validation"])
    parameters = {}
    for j, name in enumerate(names):
        parameters[name] = identification_record(u[val, j], np.median(draws[:, :, j], axis=1), u[train, j],
                                                 ms_norm[train], ms_norm[val], _rng(seed, name), n_boot)
    combinations = {}
    combos = available(names)
    if combos:
        truth_si = combinations_of(u[val], names, ms_norm[val], bounds, combos)
        train_si = combinations_of(u[train], names, ms_norm[train], bounds, combos)
        draws_si = combinations_of(draws, names, ms_norm[val], bounds, combos)
        reference = references(train_si, combos)
        for k, c in enumerate(combos):
            norm = lambda v: normalize_combination(c, v, reference[c])  # noqa: E731
            drawn = norm(draws_si[:, :, k])
            with np.errstate(all="ignore"):
                finite = np.isfinite(drawn).any(axis=1)
                median = np.full(len(val), np.nan)
                median[finite] = np.nanmedian(drawn[finite], axis=1)
            combinations[c] = identification_record(norm(truth_si[:, k]), median, norm(train_si[:, k]),
                                                    ms_norm[train], ms_norm[val], _rng(seed, c), n_boot)
    return {"format": FORMAT, "rule": RULE, "split": SPLIT, "seed": int(seed), "n_boot": int(n_boot),
            "estimate": "median of the posterior's draws (of the defined draws for a combination)",
            "parameters": parameters, "combinations": combinations}


def posterior_flags(metadata: dict, result: dict, bounds: dict) -> dict:
    """``posterior_prediction``'s result with each parameter's and combination's flag from the model's
    metadata (``read_from_image`` None where the model predates it) and a prior-only parameter's
    ``prior_range`` (SI)."""
    block = metadata.get("identification")
    block = block if isinstance(block, dict) and block.get("format") == FORMAT else {}
    result["identification_rule"] = RULE
    for name, estimate in Prediction.from_dict(result).parameters.items():
        if name in bounds:
            entry = estimate.to_dict()
            entry.update(flag((block.get("parameters") or {}).get(name)))
            if entry["read_from_image"] is False:
                entry["prior_range"] = [float(v) for v in bounds[name]]
    for name, row in (result.get("combinations") or {}).items():
        row.update(flag((block.get("combinations") or {}).get(name)))
    return per_file_identification(result, bounds)


__all__ = ["FORMAT", "RULE", "PRIOR_ONLY", "PER_FILE_SPAN", "NOT_FOR_THIS_FILE", "per_file_identification", "PREDATES", "ALICE_COMBINATIONS_METHOD", "identification_record", "flag",
           "alice_identification", "alice_combination_identification", "quantile_draws", "alice_answer",
           "posterior_identification", "posterior_flags"]
