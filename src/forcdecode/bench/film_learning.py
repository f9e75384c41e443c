"""Accuracy per core-hour of candidate laptop films: learning curves at equal simulation budget.

Each candidate film (``config/config.yaml``, ``config/films/*.yaml``) is run through the workflow up to
``results/metrics.json``; its learning stage fits Alice on nested subsets of its train split (the
``learning_curve`` fractions, several seeds) and scores each on the film's own validation split (the
choice of a film is made there; the test split's figures are carried along, reported only). Here the
x axis becomes what those training samples cost to simulate: the CPU seconds of every draw's screening
and every family (rejected draws included), per sample that entered the dataset, times the training-
set size (``screen_cpu_s``, ``family_cpu_s`` of ``samples.parquet``; wall seconds where a run predates
them). The y axis is skill over the best trivial predictor of that validation split, 1 − MAE /
min(MAE of the train median, MAE of the M_s-only k-NN), per seed; the full training set's skill also
gets a 90 % bootstrap interval over validation samples. A film is the better laptop default for a
parameter when its curve lies above the others' at the same core-hours. Validation also stops Alice's
training (early stopping), which biases its figures up by the same mechanism for every film.
Runs made before the pipeline scored its curves on validation fall back to test, flagged
(``scored_on``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.errors import InputFileError
from ..core.streams import stream_rng
from ..learn.scoring import skill, skill_interval


def _validation_full_set(results_dir, name: str, which: str, seed: int, n_boot: int = 2000) -> tuple[float, list]:
    """Skill of the full-training-set Alice over the ``which`` trivial predictor on the validation split,
    with its paired 90 % bootstrap interval over validation samples (``learn/NAME_predictions.parquet``)."""
    path = Path(results_dir) / "learn" / f"{name}_predictions.parquet"
    try:
        table = pd.read_parquet(path, columns=["split", "target", "prediction", "ms_only_prediction"])
    except FileNotFoundError:
        raise InputFileError(f"{path}: missing; the run's learning stage did not finish") from None
    val = table[table["split"] == "validation"]
    truth, prediction = val["target"].to_numpy(float), val["prediction"].to_numpy(float)
    if which == "ms_only":
        baseline = val["ms_only_prediction"].to_numpy(float)
    else:  # the train median
        baseline = np.full(len(val), float(np.median(table.loc[table["split"] == "train", "target"])))
    value = skill(float(np.mean(np.abs(prediction - truth))), float(np.mean(np.abs(baseline - truth))))
    return value, skill_interval(truth, prediction, baseline, stream_rng(seed, "bootstrap", "film_learning", name), n_boot)


def _best_trivial(baselines: dict) -> str:
    """The trivial predictor with the lower MAE: ``ms_only`` (ties included) or ``prior``."""
    return "ms_only" if baselines.get("ms_only", np.inf) <= baselines.get("prior", np.inf) else "prior"


def _cost_per_sample_s(samples: pd.DataFrame) -> tuple[float, str]:
    """CPU (or, for older runs, wall) seconds of simulation per sample in the dataset."""
    n_ok = int(samples["in_dataset"].sum())
    if n_ok == 0:
        raise InputFileError("the run has no sample in its dataset")
    # one clock for both stages: CPU where the run recorded it, else wall
    use_cpu = all(c in samples and samples[c].notna().any() for c in ("screen_cpu_s", "family_cpu_s"))
    screen = samples["screen_cpu_s" if use_cpu else "screen_s"].fillna(0.0).sum()
    family = samples["family_cpu_s" if use_cpu else "family_s"].fillna(0.0).sum()
    return float((screen + family) / n_ok), "cpu" if use_cpu else "wall"


def run_curves(results_dir) -> dict:
    """Learning curves of one workflow run (its ``results/`` folder) against simulation core-hours."""
    results_dir = Path(results_dir)
    try:
        samples = pd.read_parquet(results_dir / "samples.parquet")
        curves = json.loads((results_dir / "learning_curve.json").read_text())
        config = json.loads((results_dir / "config.json").read_text())
        metrics = json.loads((results_dir / "metrics.json").read_text())["parameters"]
    except FileNotFoundError as error:
        raise InputFileError(f"{results_dir}: not a finished run up to metrics.json ({error.filename} missing)") from None
    per_sample_s, clock = _cost_per_sample_s(samples)
    validated = all(e.get("mae_validation") is not None and e.get("baselines_validation")
                    for e in curves["parameters"].values())
    out = {"results": str(results_dir), "mesh": config["mesh"], "n_grains": config.get("n_grains"),
           "n_draws": int(len(samples)), "n_dataset": int(samples["in_dataset"].sum()),
           "core_s_per_sample": per_sample_s, "clock": clock,
           "scored_on": "validation" if validated else "test", "parameters": {}}
    for name, entry in curves["parameters"].items():
        baselines = (entry["baselines_validation"] if validated else entry.get("baselines")) or {}
        trivial_name = _best_trivial(baselines)
        trivial = float(baselines[trivial_name])
        mae = np.asarray(entry["mae_validation"] if validated else entry["mae"], dtype=float)  # sizes × seeds
        curve_skill = 1.0 - mae / trivial
        sizes = np.asarray(entry["sizes"], dtype=float)
        # the full training set: skill over the same best trivial predictor with its bootstrap interval
        # over the scored split's samples (the learning-curve points carry only the seeds' spread)
        full = metrics.get(name, {})
        test_which = _best_trivial(entry.get("baselines") or {})
        test_skill, test_ci = full.get(f"skill_vs_{test_which}"), full.get(f"skill_vs_{test_which}_ci90")
        if validated:
            full_skill, full_ci = _validation_full_set(results_dir, name, trivial_name, int(config["seed"]))
        else:
            full_skill, full_ci = test_skill, test_ci
        out["parameters"][name] = {
            "sizes": sizes.tolist(), "core_hours": (sizes * per_sample_s / 3600.0).tolist(),
            "trivial": trivial_name, "trivial_mae": trivial, "skill_mean": np.nanmean(curve_skill, axis=1).tolist(),
            "skill_min": np.nanmin(curve_skill, axis=1).tolist(), "skill_max": np.nanmax(curve_skill, axis=1).tolist(),
            "n_seeds": int(mae.shape[1]), "n_test": full.get("n_test"), "n_validation": full.get("n_validation"),
            "full_set_skill": full_skill, "full_set_skill_ci90": full_ci,
            # reported only: the test split's figures (no choice is made on them)
            "test_full_set_skill": test_skill, "test_full_set_skill_ci90": test_ci,
        }
    return out


def _at(core_hours, skill, budget) -> float:
    """Skill at ``budget`` core-hours, linear in log(core-hours) between measured sizes (NaN outside)."""
    x, y = np.log(np.asarray(core_hours)), np.asarray(skill)
    if not (x[0] - 1e-9 <= np.log(budget) <= x[-1] + 1e-9):
        return float("nan")
    return float(np.interp(np.log(budget), x, y))


def compare_films(runs: dict) -> dict:
    """``runs``: film name → results folder. Per parameter, each film's skill at the largest budget
    every film reached (the common budget) and the film that is best there: best when its seeds'
    range lies above the runner-up's and its full-set bootstrap interval (90 %, over the scored split's
    samples: validation) above the runner-up's full-set skill; else "tie"; "none learned" when the
    leader's skill there, or the lower end of its full-set interval, is not above zero."""
    films = {name: run_curves(path) for name, path in runs.items()}
    splits = {f["scored_on"] for f in films.values()}
    if len(splits) > 1:
        raise InputFileError("the runs' learning curves are scored on different splits ("
                             + ", ".join(f"{n}: {f['scored_on']}" for n, f in films.items())
                             + "); rerun the learning stage of the older runs")
    parameters = sorted(set.intersection(*(set(f["parameters"]) for f in films.values())))
    common = {}
    for p in parameters:
        budget = min(f["parameters"][p]["core_hours"][-1] for f in films.values())
        row = {"budget_core_hours": budget, "films": {}}
        for name, f in films.items():
            c = f["parameters"][p]
            row["films"][name] = {k: _at(c["core_hours"], c[f"skill_{k}"], budget) for k in ("mean", "min", "max")}
        ranked = sorted(row["films"], key=lambda n: -np.nan_to_num(row["films"][n]["mean"], nan=-np.inf))
        best, second = ranked[0], ranked[1] if len(ranked) > 1 else None
        separated = second is None or row["films"][best]["min"] > row["films"][second]["max"]
        if second is not None:
            ci = films[best]["parameters"][p]["full_set_skill_ci90"]
            other = films[second]["parameters"][p]["full_set_skill"]
            separated = separated and ci is not None and other is not None and ci[0] > other
        ci_best = films[best]["parameters"][p]["full_set_skill_ci90"]
        if not row["films"][best]["mean"] > 0 or (ci_best is not None and not ci_best[0] > 0):
            row["best"] = "none learned"  # no film beats the trivial predictors there: nothing to choose by
        else:
            row["best"] = best if separated else "tie"
        common[p] = row
    return {"films": films, "at_common_budget": common}


def summary_lines(result: dict) -> list[str]:
    lines = []
    for name, f in result["films"].items():
        lines.append(f"{name}: {f['mesh']['nx']}x{f['mesh']['ny']}x{f['mesh']['nz']} cells, {f['n_grains']} grains, "
                     f"{f['n_dataset']} of {f['n_draws']} draws in the dataset, "
                     f"{f['core_s_per_sample']:.1f} core-s ({f['clock']}) of simulation per sample; "
                     f"curves scored on {f['scored_on']}")
    for p, row in result["at_common_budget"].items():
        cells = ", ".join(f"{n} {v['mean']:+.2f} [{v['min']:+.2f}, {v['max']:+.2f}]" for n, v in row["films"].items())
        lines.append(f"{p}: skill at {row['budget_core_hours']:.3f} core-hours (seeds' range): {cells} -> {row['best']}")
        for split, key in (("scored split", "full_set_skill"), ("test, reported only", "test_full_set_skill")):
            full = []
            for n, f in result["films"].items():
                c = f["parameters"][p]
                if c.get(key) is not None and c.get(f"{key}_ci90"):
                    full.append(f"{n} {c[key]:+.2f} [{c[key + '_ci90'][0]:+.2f}, {c[key + '_ci90'][1]:+.2f}] "
                                f"at {c['core_hours'][-1]:.3f} core-h")
            if full:
                lines.append(f"    full training set, 90 % bootstrap ({split}): {', '.join(full)}")
            if split == "scored split" and all(f["scored_on"] == "test" for f in result["films"].values()):
                break  # the same figures
    return lines


def figure(result: dict, out_path) -> None:
    """Skill (seeds: line = mean, band = range) against simulation core-hours, one panel per parameter."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parameters = list(result["at_common_budget"])
    cols = min(3, max(1, len(parameters)))
    rows = int(np.ceil(len(parameters) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.0 * cols, 3.2 * rows), squeeze=False)
    for ax, p in zip(axes.flat, parameters):
        for name, f in result["films"].items():
            c = f["parameters"][p]
            line, = ax.plot(c["core_hours"], c["skill_mean"], marker="o", label=name)
            ax.fill_between(c["core_hours"], c["skill_min"], c["skill_max"], color=line.get_color(), alpha=0.2)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.axvline(result["at_common_budget"][p]["budget_core_hours"], color="grey", ls=":", lw=0.8)
        ax.set_xscale("log")
        ax.set_title(p)
        ax.set_xlabel("simulation core-hours of the training set")
        ax.set_ylabel(f"skill over best trivial ({result['films'][next(iter(result['films']))]['scored_on']})")
    for ax in list(axes.flat)[len(parameters):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8)
    fig.tight_layout()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=120)
    plt.close(fig)


__all__ = ["run_curves", "compare_films", "summary_lines", "figure"]
