"""Choose the posterior's architecture on validation data only.

Each candidate (a partial posterior-settings mapping over the config's ``posterior`` section) is
fitted on the train split with early stopping on the validation split (``fit_posterior``), then
scored on the validation split: the negative log-likelihood of the true parameters u ∈ [0, 1] (the
proper score the flow is trained on, taken in u so that candidates modelling other coordinates —
``coordinates: prior`` — compare; lower is better), averaged over ``weight_seeds`` (weights and batch
order; the split stays the config seed's), and, as a check, the 90 % central-interval coverage and width of its draws per parameter. The candidate with
the lowest validation NLL wins. The test and calibration splits are not touched: they stay for the
one report of the chosen posterior (``train_posterior``). With ~20 validation families the NLL
differences below ~0.1 nat per family are noise; the table says so by listing them all.
"""

from __future__ import annotations

from dataclasses import dataclass

import time

import numpy as np

from ..config import defaults
from ..core import io
from ..core.errors import DatasetError
from ..core.streams import stream_rng, stream_seed
from .calibration import calibration_metrics
from .posterior import PosteriorFit, _float32, fit_posterior, posterior_settings
from .splits import assign_splits

CANDIDATES: tuple[dict, ...] = (
    {"summary": "features", "transforms": 3},
    {"summary": "features", "transforms": 5},
    {"summary": "crossfit", "transforms": 3},
    {"summary": "joint", "transforms": 3},
    {"summary": "features", "transforms": 3, "hidden": 32},
    {"summary": "features", "transforms": 3, "dropout": 0.2},
)
"""The architectures compared by default (each over the config's posterior settings)."""


@dataclass(frozen=True)
class TuningPlan:
    """What the tuning compares: ``candidates`` (partial posterior-settings mappings, each over the
    config's ``posterior`` section), ``draws`` (posterior draws per validation family for the coverage
    check) and ``weight_seeds`` (offsets added to the config seed: one fit per candidate and offset,
    the NLL averaged over them)."""

    candidates: tuple = CANDIDATES
    draws: int = 500
    weight_seeds: tuple = (0,)


@_float32
def tune_posterior(data, settings: dict | None, learning: dict | None, seed: int, plan: TuningPlan = TuningPlan(), *,
                   out=None, log=print) -> dict:
    """Fit every candidate of ``plan`` on train, score it on validation; returns (and writes to ``out``)
    the table and the chosen candidate's settings."""
    candidates, draws, weight_seeds = plan.candidates, plan.draws, plan.weight_seeds
    base = posterior_settings(settings)
    learning = {**defaults("learning"), **(learning or {})}
    names = tuple(base["parameters"])
    splits = assign_splits(data.sample_id, seed, learning["split"], learning["protocol"])
    train, val = splits["train"], splits["validation"]
    if len(train) < 2 or len(val) < 2:
        raise DatasetError(f"tuning needs train and validation splits (got {len(train)} and {len(val)} families)")
    u = np.stack([data.target(name) for name in names], axis=1)
    rows = []
    for k, candidate in enumerate(candidates):
        trial = posterior_settings({**(settings or {}), **candidate}, source=f"candidate {k}")
        nlls, calibs, epochs, fit_s = [], [], [], 0.0
        for w in weight_seeds:
            started = time.perf_counter()
            est = fit_posterior(data.images, data.ms_norm, u, train, val,
                                PosteriorFit(names=names, settings=trial, seed=seed + w, embedding="cnn",
                                             bounds=data.bounds), log=None)
            fit_s += time.perf_counter() - started
            nlls.append(-float(np.mean(est.log_prob(u[val], data.images[val], data.ms_norm[val]))))
            epochs.append(int(est.best_epoch))
            samples = est.sample(data.images[val], data.ms_norm[val], draws,
                                 seed=stream_seed(seed, "posterior", "tune", k, w))
            calibs.append(calibration_metrics(samples, u[val], names,
                                              stream_rng(seed, "posterior", "tune_calibration", k, w), (0.9,)))
        mean_of = lambda key, n: float(np.mean([c["per_parameter"][n][key] for c in calibs]))  # noqa: E731
        row = {"candidate": candidate, "validation_nll": float(np.mean(nlls)), "validation_nll_per_seed": nlls,
               "best_epoch": epochs[0], "best_epochs": epochs, "fit_s": fit_s,
               "validation_coverage_90": {n: mean_of("coverage_90", n) for n in names},
               "validation_width_90": {n: mean_of("width_90", n) for n in names},
               "validation_mae_median": {n: mean_of("mae_median", n) for n in names}}
        rows.append(row)
        log(f"candidate {k + 1}/{len(candidates)} {candidate}: validation NLL {row['validation_nll']:.3f}, "
            f"mean 90 % coverage {np.mean(list(row['validation_coverage_90'].values())):.2f}, {fit_s:.0f} s")
    best = min(range(len(rows)), key=lambda i: rows[i]["validation_nll"])
    result = {"criterion": "lowest validation negative log-likelihood of u (train split fitted, validation scored; "
                           "test and calibration splits untouched)", "weight_seeds": [int(w) for w in weight_seeds],
              "n_train": int(len(train)), "n_validation": int(len(val)), "parameters": list(names),
              "rows": rows, "chosen": rows[best]["candidate"], "chosen_index": int(best)}
    if out is not None:
        io.write_json(out, result)
    return result


def tuning_lines(result: dict) -> list[str]:
    """The table: one line per candidate, the chosen one marked."""
    lines = [f"{'':2s}{'candidate':55s} {'val NLL':>8s} {'cov90 mean':>10s} {'fit s':>6s}"]
    for i, row in enumerate(result["rows"]):
        mark = "* " if i == result["chosen_index"] else "  "
        cov = np.mean(list(row["validation_coverage_90"].values()))
        lines.append(f"{mark}{str(row['candidate']):55s} {row['validation_nll']:8.3f} {cov:10.2f} {row['fit_s']:6.0f}")
    return lines


__all__ = ["CANDIDATES", "TuningPlan", "tune_posterior", "tuning_lines"]
