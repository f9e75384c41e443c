"""Which prior class to train on, judged on the films of a user's class: K_eff > 0 validation families.

Two finished learning stages of the workflow (run A and run C, e.g. ``prior: paper`` and
``prior: perpendicular``; their ``dataset.h5``, ``samples.parquet``, ``learn/NAME_predictions.parquet``
and ``learn/NAME_metrics.json`` with the learning curve's validation predictions) are scored on the
validation families whose true K_eff = K_u − μ0 M_s²/2 is above 0 (a perpendicular film, what a thin-
film lab measures):

- C's full training set against A's learning-curve point of matched simulation cost (C costs 0.5–1.1×
  that point: never more simulation than A): per family and parameter the absolute error of those
  networks in the normalized units of the MAE tables, averaged over the weight seeds;
- per parameter the MAE and the skill over the best trivial predictor of that run on those families
  (the median of its K_eff > 0 training targets; its M_s-only k-NN's predictions), with the paired
  bootstrap interval of ``learn.scoring.skill_over_best_trivial``;
- the difference C − A of the mean absolute error over parameters (per family the mean over the
  parameters, then the mean over families), 90 % interval from independent bootstrap resamples of
  each run's families (the runs hold different Hamiltonians: no pairing).

Decision rule (docs/results/2026-11-29-prior-class.md, fixed before run C): C's class becomes the
default unless the 90 % interval of C − A lies above 0. Validation also stops the training (early
stopping), the same bias for both runs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..core.errors import InputFileError
from ..core.streams import stream_rng
from ..learn.report import dataset_truth
from ..learn.scoring import skill_over_best_trivial
from .realisations import simulation_cpu_s, validation_curves

N_BOOT = 2000


def load_class_run(results_dir) -> dict:
    """Per parameter, the K_eff > 0 validation families of one run: truth, the seed-mean prediction of
    every learning-curve point (points × families), the two trivial predictors; and the run's class,
    simulation CPU and the cost of every curve point (size / n_train × the CPU)."""
    results_dir = Path(results_dir)
    try:
        keff, prior_class = dataset_truth(results_dir / "dataset.h5")
        samples = pd.read_parquet(results_dir / "samples.parquet")
    except FileNotFoundError as error:
        raise InputFileError(f"{results_dir}: not a finished dataset ({error.filename} missing)") from None
    cpu = simulation_cpu_s(samples)
    out = {"results": str(results_dir), "prior_class": prior_class, "n_draws": int(len(samples)),
           "n_dataset": int(samples["in_dataset"].sum()), "simulation_core_s": cpu,
           "fraction_k_eff_positive": float(np.mean(np.array(list(keff.values())) > 0)), "parameters": {}}
    for name, (metrics_path, curve) in validation_curves(results_dir).items():
        frame = pd.read_parquet(results_dir / "learn" / f"{name}_predictions.parquet",
                                columns=["sample_id", "split", "target", "ms_only_prediction"])
        frame["k_eff"] = [keff.get(int(s), np.nan) for s in frame["sample_id"]]
        train = frame[(frame["split"] == "train") & (frame["k_eff"] > 0)]
        if train.empty:
            raise InputFileError(f"{results_dir}: no training family with K_eff > 0")
        ids = np.asarray(curve["validation_sample_ids"], dtype=np.int64)
        sizes = np.asarray(curve["sizes"], dtype=float)
        out["curve_core_s"] = (sizes / sizes.max() * cpu).tolist()
        out["curve_sizes"] = sizes.astype(int).tolist()
        val = frame.set_index("sample_id").loc[ids]
        keep = (val["k_eff"] > 0).to_numpy()
        truth = np.asarray(curve["validation_truth"], dtype=float)[keep]
        if not np.allclose(truth, val["target"].to_numpy(float)[keep], atol=1e-9):
            raise InputFileError(f"{metrics_path}: its validation truths disagree with the predictions file")
        seed_means = np.nanmean(np.asarray(curve["validation_predictions"], dtype=float), axis=1)  # points × ids
        out["parameters"][name] = {
            "ids": ids[keep], "truth": truth, "point_predictions": seed_means[:, keep],
            "prior": np.full(int(keep.sum()), float(np.median(train["target"]))),
            "ms_only": val["ms_only_prediction"].to_numpy(float)[keep]}
    return out


def at_point(run: dict, point: int = -1) -> dict:
    """``run`` scored at its learning curve's point ``point`` (-1: the full training set): each
    parameter's ``prediction`` is that point's seed mean; ``point`` and ``train_size`` are recorded."""
    point = int(point % len(run["curve_sizes"]))
    parameters = {p: {**e, "prediction": e["point_predictions"][point]} for p, e in run["parameters"].items()}
    return {**run, "parameters": parameters, "point": point, "train_size": run["curve_sizes"][point]}


def _mean_error_per_family(run: dict, parameters) -> np.ndarray:
    first = run["parameters"][parameters[0]]["ids"]
    for p in parameters[1:]:
        if not np.array_equal(run["parameters"][p]["ids"], first):
            raise InputFileError(f"{run['results']}: parameters scored on different validation families")
    return np.mean([np.abs(run["parameters"][p]["prediction"] - run["parameters"][p]["truth"]) for p in parameters],
                   axis=0)


MATCH_RATIO = (0.5, 1.1)
"""C's full set is scored against A's learning-curve point whose simulation cost is nearest, among
those C costs 0.5-1.1 times: C is never given more simulation than A (beyond 10 %)."""


def matched_point(costs_a, cost_c: float) -> int:
    """Index of A's curve point nearest (in log cost) to ``cost_c`` with cost_c / cost_a in MATCH_RATIO."""
    costs_a = np.asarray(costs_a, dtype=float)
    ratio = cost_c / costs_a
    allowed = np.flatnonzero((ratio >= MATCH_RATIO[0]) & (ratio <= MATCH_RATIO[1]))
    if allowed.size == 0:
        raise InputFileError(f"no point of run A's learning curve costs within {MATCH_RATIO} of run C's "
                             f"{cost_c:.0f} CPU-s (A's points: {np.round(costs_a).tolist()})")
    return int(allowed[np.argmin(np.abs(np.log(ratio[allowed])))])


def compare_classes(run_a, run_c, seed: int = 0) -> dict:
    """Run C's full training set against run A at the learning-curve point of matched simulation cost,
    on the K_eff > 0 validation families of each (see the module docstring)."""
    c = at_point(load_class_run(run_c))
    a = load_class_run(run_a)
    a = at_point(a, matched_point(a["curve_core_s"], c["simulation_core_s"]))
    parameters = sorted(set(a["parameters"]) & set(c["parameters"]))
    if not parameters:
        raise InputFileError("the runs have no learned parameter in common")
    table = {}
    for p in parameters:
        table[p] = {}
        for key, run in (("A", a), ("C", c)):
            e = run["parameters"][p]
            table[p][key] = skill_over_best_trivial(e["truth"], e["prediction"], e["prior"], e["ms_only"],
                                                    stream_rng(seed, "bootstrap", "prior_learning", key, p), N_BOOT)
    err_a, err_c = _mean_error_per_family(a, parameters), _mean_error_per_family(c, parameters)
    rng = stream_rng(seed, "bootstrap", "prior_learning", "difference")
    boot = (err_c[rng.integers(0, err_c.size, (N_BOOT, err_c.size))].mean(axis=1)
            - err_a[rng.integers(0, err_a.size, (N_BOOT, err_a.size))].mean(axis=1))
    difference = float(err_c.mean() - err_a.mean())
    interval = [float(np.quantile(boot, 0.05)), float(np.quantile(boot, 0.95))]
    decision = (f"A ({a['prior_class']}) stays" if interval[0] > 0 else f"C ({c['prior_class']})")
    runs = {key: {**run, "parameters": {p: {"n_validation_k_eff_positive": int(e["ids"].size)}
                                        for p, e in run["parameters"].items()}}
            for key, run in (("A", a), ("C", c))}
    return {"runs": runs, "parameters": parameters, "per_parameter": table,
            "cost_ratio_c_over_a": float(c["simulation_core_s"] / a["curve_core_s"][a["point"]]),
            "mean_mae": {"A": float(err_a.mean()), "C": float(err_c.mean())},
            "mean_mae_difference_c_minus_a": difference, "mean_mae_difference_ci90": interval,
            "decision": decision,
            "rule": "C's class unless the 90 % bootstrap interval of C - A (mean over parameters of the validation "
                    "MAE on K_eff > 0 families) lies above 0"}


def summary_lines(result: dict) -> list[str]:
    lines = []
    for key, run in result["runs"].items():
        n = next(iter(run["parameters"].values()))["n_validation_k_eff_positive"]
        lines.append(f"{key}: prior {run['prior_class']}, {run['n_dataset']} of {run['n_draws']} draws in the dataset "
                     f"({100 * run['fraction_k_eff_positive']:.0f} % with K_eff > 0), {run['simulation_core_s'] / 3600:.2f} "
                     f"core-h of simulation; scored: {run['train_size']} training families "
                     f"({run['curve_core_s'][run['point']] / 3600:.2f} core-h); {n} validation families with "
                     f"K_eff > 0 ({run['results']})")
    for p, row in result["per_parameter"].items():
        cells = ", ".join(f"{k} MAE {v['mae']:.3f} skill {v['skill']:+.2f} [{v['skill_ci90'][0]:+.2f}, "
                          f"{v['skill_ci90'][1]:+.2f}] over {v['best_trivial']}" for k, v in row.items())
        lines.append(f"    {p:>6}: {cells}")
    lo, hi = result["mean_mae_difference_ci90"]
    lines.append(f"mean over parameters: A {result['mean_mae']['A']:.3f}, C {result['mean_mae']['C']:.3f}, "
                 f"C - A {result['mean_mae_difference_c_minus_a']:+.3f} [{lo:+.3f}, {hi:+.3f}]")
    lines.append(f"decision: {result['decision']} ({result['rule']})")
    return lines


__all__ = ["load_class_run", "at_point", "matched_point", "compare_classes", "summary_lines"]
