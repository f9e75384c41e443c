"""Training on families averaged over R disorder realisations against R = 1, at equal core-hours.

A measured film is millimetres wide: its FORC family is the mean over very many patches of the
simulated box. With ``realisations: R`` each training sample is the mean family of R films that differ
only in their disorder, at R times the cost of a family, so at a fixed simulation budget R = 4 buys a
quarter of the samples, each less noisy. This bench reads two finished learning stages of the workflow
(run A, run B: ``learn/NAME_metrics.json`` with the learning curve's validation predictions,
``samples.parquet``, ``config.json``) and compares them sample by sample:

- cost of a curve point: size / n_train × the simulation CPU of the whole dataset (every draw's
  screening, rejected ones included, and every family, all R realisations);
- per validation id the two runs share (the split is a hash of the sample id, so an id is in
  validation in both), the absolute error in the normalized units of the MAE tables, averaged over the
  weight seeds; each run's networks read their own dataset's image of that id (A's one realisation, B's
  mean of R);
- each of B's curve points against A's point of nearest cost (matched when B costs 0.5–1.1× A's): the
  paired difference B − A of the mean
  absolute error with a 90 % bootstrap interval over the shared ids (the same resamples for every
  parameter, so the mean over parameters gets one too).

Decision rule (docs/results/2026-11-29-realisations.md, fixed before the runs): at the largest matched
point, B replaces A when the 90 % interval of the mean over parameters of B − A lies below 0.
Validation also stops the training (early stopping), which biases both runs' figures the same way.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.errors import InputFileError
from ..core.streams import stream_rng
from ..learn.data import load_dataset

N_BOOT = 2000

MATCH_RATIO = (0.5, 1.1)
"""A point of B is matched to A's nearest when its cost is 0.5-1.1 times A's: B is never given more
simulation than A (beyond 10 %), so a win of B is not bought with budget."""


def simulation_cpu_s(samples: pd.DataFrame) -> float:
    """CPU seconds of every screening and every family of a run (``samples.parquet``)."""
    for column in ("screen_cpu_s", "family_cpu_s"):
        if column not in samples or not samples[column].notna().any():
            raise InputFileError(f"samples.parquet has no {column}: the run predates CPU accounting")
    return float(samples["screen_cpu_s"].fillna(0.0).sum() + samples["family_cpu_s"].fillna(0.0).sum())


def validation_curves(results_dir) -> dict:
    """Parameter name → (path, learning curve) of every ``learn/NAME_metrics.json`` of a run, each
    curve holding its fits' validation predictions (runs from 2026-11-29 on)."""
    curves = {}
    for path in sorted((Path(results_dir) / "learn").glob("*_metrics.json")):
        curve = json.loads(path.read_text()).get("learning_curve", {})
        if "validation_predictions" not in curve:
            raise InputFileError(f"{path}: its learning curve has no validation predictions (a run before "
                                 "2026-11-29); rerun its train_parameter jobs")
        curves[path.name[: -len("_metrics.json")]] = (path, curve)
    if not curves:
        raise InputFileError(f"{results_dir}/learn: no *_metrics.json (the learning stage has not run)")
    return curves


def load_run(results_dir) -> dict:
    """One run's learning curves with their validation predictions, and what its points cost."""
    results_dir = Path(results_dir)
    try:
        samples = pd.read_parquet(results_dir / "samples.parquet")
        config = json.loads((results_dir / "config.json").read_text())
    except FileNotFoundError as error:
        raise InputFileError(f"{results_dir}: not a finished dataset ({error.filename} missing)") from None
    curves = validation_curves(results_dir)
    total_s = simulation_cpu_s(samples)
    out = {"results": str(results_dir), "realisations": int(config.get("realisations", 1)),
           "n_draws": int(len(samples)), "n_dataset": int(samples["in_dataset"].sum()),
           "simulation_core_s": total_s, "parameters": {}}
    for name, (_, curve) in curves.items():
        sizes = np.asarray(curve["sizes"], dtype=float)
        n_train = sizes.max()
        out["parameters"][name] = {
            "sizes": sizes.astype(int).tolist(),
            "core_hours": (sizes / n_train * total_s / 3600.0).tolist(),
            "ids": np.asarray(curve["validation_sample_ids"], dtype=np.int64),
            "truth": np.asarray(curve["validation_truth"], dtype=float),
            "predictions": np.asarray(curve["validation_predictions"], dtype=float),  # sizes × seeds × ids
            "mae_validation": np.nanmean(np.asarray(curve["mae_validation"], dtype=float), axis=1).tolist(),
            "baselines_validation": curve["baselines_validation"],
        }
    return out


def _shared(a: dict, b: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shared validation ids and their positions in each run; the truths must agree."""
    shared, ia, ib = np.intersect1d(a["ids"], b["ids"], return_indices=True)
    if shared.size < 2:
        raise InputFileError(f"the runs share {shared.size} validation ids: nothing to pair")
    if not np.allclose(a["truth"][ia], b["truth"][ib], atol=1e-9):
        raise InputFileError("the runs' normalized truths differ on shared ids: not the same Hamiltonians")
    return shared, ia, ib


def _seed_mean_abs_error(entry: dict, point: int, index: np.ndarray) -> np.ndarray:
    return np.nanmean(np.abs(entry["predictions"][point][:, index] - entry["truth"][index]), axis=0)


def _interval(values: np.ndarray, resamples: np.ndarray) -> list[float]:
    means = values[resamples].mean(axis=1)
    return [float(np.quantile(means, 0.05)), float(np.quantile(means, 0.95))]


def compare(run_a, run_b, seed: int = 0) -> dict:
    """Paired comparison of run B against run A at matched core-hours (see the module docstring)."""
    a, b = load_run(run_a), load_run(run_b)
    parameters = sorted(set(a["parameters"]) & set(b["parameters"]))
    if not parameters:
        raise InputFileError("the runs have no learned parameter in common")
    shared, _, _ = _shared(a["parameters"][parameters[0]], b["parameters"][parameters[0]])
    rng = stream_rng(seed, "bootstrap", "realisations")
    resamples = rng.integers(0, shared.size, size=(N_BOOT, shared.size))
    points = []
    for j, cost_b in enumerate(b["parameters"][parameters[0]]["core_hours"]):
        costs_a = np.asarray(a["parameters"][parameters[0]]["core_hours"])
        i = int(np.argmin(np.abs(np.log(costs_a) - np.log(cost_b))))
        row = {"b_point": j, "a_point": i, "b_size": b["parameters"][parameters[0]]["sizes"][j],
               "a_size": a["parameters"][parameters[0]]["sizes"][i], "b_core_hours": cost_b,
               "a_core_hours": float(costs_a[i]), "cost_ratio_b_over_a": float(cost_b / costs_a[i]),
               "n_shared": int(shared.size), "parameters": {}}
        differences = []
        for p in parameters:
            ea, eb = a["parameters"][p], b["parameters"][p]
            _, ia, ib = _shared(ea, eb)
            err_a, err_b = _seed_mean_abs_error(ea, i, ia), _seed_mean_abs_error(eb, j, ib)
            diff = err_b - err_a
            differences.append(diff)
            row["parameters"][p] = {"mae_a": float(err_a.mean()), "mae_b": float(err_b.mean()),
                                    "difference_b_minus_a": float(diff.mean()),
                                    "difference_ci90": _interval(diff, resamples)}
        mean_diff = np.mean(differences, axis=0)
        row["mean_difference_b_minus_a"] = float(mean_diff.mean())
        row["mean_difference_ci90"] = _interval(mean_diff, resamples)
        points.append(row)
    matched = [r for r in points if MATCH_RATIO[0] <= r["cost_ratio_b_over_a"] <= MATCH_RATIO[1]]
    decisive = max(matched, key=lambda r: r["b_core_hours"]) if matched else None
    if decisive is None:
        decision = f"no matched point (cost ratio B/A within {MATCH_RATIO[0]}-{MATCH_RATIO[1]})"
    elif decisive["mean_difference_ci90"][1] < 0:
        decision = f"B (R = {b['realisations']})"
    else:
        decision = f"A (R = {a['realisations']}) stays"
    strip = {"ids", "truth", "predictions"}
    runs = {key: {**run, "parameters": {p: {k: v for k, v in e.items() if k not in strip}
                                        for p, e in run["parameters"].items()}}
            for key, run in (("A", a), ("B", b))}
    return {"runs": runs, "parameters": parameters, "points": points,
            "decisive_point": None if decisive is None else decisive["b_point"], "decision": decision,
            "rule": f"at the largest matched point (cost ratio B/A within {MATCH_RATIO[0]}-{MATCH_RATIO[1]}: B never "
                    "gets more than 10 % more simulation than A), B when the 90 % bootstrap interval of the mean over "
                    "parameters of the paired validation MAE difference B - A lies below 0"}


def cross_reading(run_a, run_b, seed: int = 0) -> dict:
    """Each run's full-set network (member 0, ``models/NAME.pt``, the one ``predict`` uses) on both
    runs' images of the shared validation ids: A's single-realisation images and B's R-realisation
    means. A measured film is an average over very many patches, so "A's network on B's images" is the
    situation of a user whose decoder was trained on single realisations. Reported only (not part of
    the decision). Per parameter: the four MAEs and, for A's network, the paired difference (mean
    images − own images) with a 90 % bootstrap interval over the shared ids."""
    # loads torch: imported only when this runs
    from ..learn.predictor import ParameterModel

    runs = {"A": Path(run_a), "B": Path(run_b)}
    runs_loaded = {k: load_run(r) for k, r in runs.items()}
    data = {k: load_dataset(r / "dataset.h5") for k, r in runs.items()}
    parameters = sorted(set(runs_loaded["A"]["parameters"]) & set(runs_loaded["B"]["parameters"]))
    rng = stream_rng(seed, "bootstrap", "realisations", "cross_reading")
    out = {}
    for p in parameters:
        shared, _, _ = _shared(runs_loaded["A"]["parameters"][p], runs_loaded["B"]["parameters"][p])
        position = {k: np.array([int(np.flatnonzero(d.sample_id == i)[0]) for i in shared]) for k, d in data.items()}
        truth = data["A"].target(p)[position["A"]]
        if not np.allclose(truth, data["B"].target(p)[position["B"]], atol=1e-9):
            raise InputFileError(f"{p}: the runs' datasets disagree on the truth of shared ids")
        ms = data["A"].values["Ms"][position["A"]]
        errors = {}
        for net in runs:
            model = ParameterModel.load(runs[net] / "models" / f"{p}.pt")
            for images in runs:
                predicted = model.predict(data[images].images[position[images]], ms)["normalized"]
                errors[f"{net}_net_on_{images}_images"] = np.abs(predicted - truth)
        shift = errors["A_net_on_B_images"] - errors["A_net_on_A_images"]
        resamples = rng.integers(0, shared.size, size=(N_BOOT, shared.size))
        out[p] = {**{k: float(v.mean()) for k, v in errors.items()}, "n_shared": int(shared.size),
                  "a_net_mean_images_minus_own": float(shift.mean()),
                  "a_net_mean_images_minus_own_ci90": _interval(shift, resamples)}
    return out


def summary_lines(result: dict) -> list[str]:
    lines = []
    for key, run in result["runs"].items():
        lines.append(f"{key}: R = {run['realisations']}, {run['n_dataset']} of {run['n_draws']} draws in the dataset, "
                     f"{run['simulation_core_s'] / 3600:.2f} core-h of simulation ({run['results']})")
    for row in result["points"]:
        lines.append(f"B {row['b_size']} train ({row['b_core_hours']:.3f} core-h) vs A {row['a_size']} train "
                     f"({row['a_core_hours']:.3f} core-h, ratio {row['cost_ratio_b_over_a']:.2f}), "
                     f"{row['n_shared']} shared validation ids:")
        for p, v in row["parameters"].items():
            lines.append(f"    {p:>6}: MAE A {v['mae_a']:.3f}, B {v['mae_b']:.3f}, B - A {v['difference_b_minus_a']:+.3f} "
                         f"[{v['difference_ci90'][0]:+.3f}, {v['difference_ci90'][1]:+.3f}]")
        lines.append(f"    mean over parameters: B - A {row['mean_difference_b_minus_a']:+.3f} "
                     f"[{row['mean_difference_ci90'][0]:+.3f}, {row['mean_difference_ci90'][1]:+.3f}]")
    lines.append(f"decision: {result['decision']} ({result['rule']})")
    for p, v in result.get("cross_reading", {}).items():
        lines.append(f"cross-reading {p:>6} ({v['n_shared']} ids, full-set networks, member 0): A's net on A's images "
                     f"{v['A_net_on_A_images']:.3f}, on B's mean images {v['A_net_on_B_images']:.3f} "
                     f"({v['a_net_mean_images_minus_own']:+.3f} [{v['a_net_mean_images_minus_own_ci90'][0]:+.3f}, "
                     f"{v['a_net_mean_images_minus_own_ci90'][1]:+.3f}]); B's net on A's {v['B_net_on_A_images']:.3f}, "
                     f"on B's {v['B_net_on_B_images']:.3f}")
    return lines


def figure(result: dict, out_path) -> None:
    """Validation MAE (mean over seeds, each run's whole validation split) against core-hours."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parameters = result["parameters"]
    fig, axes = plt.subplots(1, len(parameters), figsize=(3.6 * len(parameters), 3.2), squeeze=False)
    for ax, p in zip(axes.flat, parameters):
        for key, run in result["runs"].items():
            entry = run["parameters"][p]
            ax.plot(entry["core_hours"], entry["mae_validation"], marker="o", label=f"{key}: R = {run['realisations']}")
        trivial = min(result["runs"]["A"]["parameters"][p]["baselines_validation"].values())
        ax.axhline(trivial, color="grey", ls=":", lw=0.8, label="best trivial (A)")
        ax.set_xscale("log")
        ax.set_title(p)
        ax.set_xlabel("simulation core-hours")
        ax.set_ylabel("validation MAE (normalized)")
    axes.flat[0].legend(fontsize=8)
    fig.tight_layout()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=120)
    plt.close(fig)


__all__ = ["simulation_cpu_s", "validation_curves", "load_run", "compare", "cross_reading", "summary_lines", "figure"]
