"""The closed loop on the simulated test set: F_sim(F_CNN(y)) against y, with a floor and a null.

Each chosen test sample's input family y (its own disorder) is compared with three re-simulations,
each on the same R new disorder realisations (common random numbers: realisation r of a sample draws
its disorder from stream ``closed_loop_disorder`` with keys (sample id, r) for all three):

- ``rms``: the *predicted* Hamiltonian (Alice's outputs, the true M_s; a parameter without a network
  takes its training median);
- ``rms_floor``: the *true* Hamiltonian — what a new disorder realisation alone costs;
- ``rms_null``: the *training-median* Hamiltonian (median of each parameter over the train split,
  the sample's own true M_s) — what a decoder that ignores the image would get.

Each is the mean over the R realisations of the observation RMS: the root mean square, over every
FORC point the two families share (H ≥ H_r), of ⟨m_z⟩(re-simulated, realisation r) − ⟨m_z⟩(input).
Errors are averaged, not families (averaging families first would smooth the re-simulation's own
disorder noise and flatter all three). rms/rms_floor = 1 is as good as knowing the truth;
rms/rms_null < 1 is better than the prior. The summary gives their medians over samples with a
bootstrap 90 % interval, Spearman's ρ of rms against Bob's predicted error, and Figure 4 of the seed
paper (ten test samples, input vs re-simulated from the prediction, realisation 0).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..config import defaults
from ..core.errors import DatasetError, SimulationError
from ..core.io import atomic_path, read_config, write_json, write_parquet
from ..core.parameters import NAMES as PARAMETERS, denormalize
from ..core.streams import stream_rng
from ..forc.simulate import protocol_name
from ..infer.resimulate import observation_error, run_tasks
from ..learn.data import load_dataset
from ..learn.scoring import median_with_interval

ROLES = ("prediction", "floor", "null")
"""The three re-simulated Hamiltonians of a sample: predicted, true (floor), training median (null)."""

_RMS_COLUMN = {"prediction": "rms", "floor": "rms_floor", "null": "rms_null"}


def _read_predictions(prediction_paths: dict) -> dict:
    if not prediction_paths:
        raise DatasetError("no prediction file given")
    return {name: pd.read_parquet(path).set_index("sample_id") for name, path in prediction_paths.items()}


def _split_ids(frames: dict, split: str) -> list:
    """Sample ids in ``split`` in every predictions frame (the split is shared by the parameters)."""
    ids = None
    for frame in frames.values():
        these = set(frame.index[frame["split"] == split])
        ids = these if ids is None else ids & these
    return sorted(int(i) for i in ids or [])


def predicted_hamiltonians(prediction_paths: dict, values: pd.DataFrame, bounds: dict) -> pd.DataFrame:
    """Per test sample: the predicted parameters (SI), the true M_s, Bob's mean normalized error.
    Raises DatasetError when the predictions share no test sample."""
    frames = _read_predictions(prediction_paths)
    ids = _split_ids(frames, "test")
    if not ids:
        raise DatasetError(f"the predictions ({', '.join(prediction_paths)}) share no test sample")
    out = pd.DataFrame({"sample_id": ids}).set_index("sample_id")
    out["Ms"] = values.loc[ids, "Ms"].to_numpy()
    for name, frame in frames.items():
        out[name] = denormalize(name, frame.loc[ids, "prediction"].to_numpy(), bounds)
        out[f"{name}_bob_error"] = frame.loc[ids, "bob_error"].to_numpy()
        out[f"{name}_abs_error"] = frame.loc[ids, "abs_error"].to_numpy()
    out["bob_error_mean"] = out[[f"{n}_bob_error" for n in frames]].mean(axis=1)
    out["abs_error_mean"] = out[[f"{n}_abs_error" for n in frames]].mean(axis=1)
    if "N_pin" in out:
        out["N_pin"] = np.rint(out["N_pin"]).astype(int)
    return out.reset_index()


def training_medians(prediction_paths: dict, values: pd.DataFrame) -> dict:
    """Median of each Hamiltonian parameter but M_s (SI) over the train split; N_pin rounded.
    Raises DatasetError when the predictions share no train sample."""
    ids = _split_ids(_read_predictions(prediction_paths), "train")
    if not ids:
        raise DatasetError("the predictions share no train sample: no training median for the null")
    medians = {name: float(values.loc[ids, name].median()) for name in PARAMETERS if name != "Ms"}
    medians["N_pin"] = int(round(medians["N_pin"]))
    return medians


def hamiltonians(row: dict, truth: dict, medians: dict) -> dict:
    """The three Hamiltonians (SI) of one sample: role -> parameters. ``row`` holds the predicted
    parameters (those with a network), ``truth`` every true parameter, ``medians`` the training medians."""
    missing = [name for name in PARAMETERS if name not in truth]
    if missing:
        raise DatasetError(f"true parameters missing: {', '.join(missing)}")
    true = {name: float(truth[name]) for name in PARAMETERS}
    null = {**medians, "Ms": true["Ms"]}
    predicted = {**null, **{name: float(row[name]) for name in PARAMETERS if name != "Ms" and name in row}}
    out = {"prediction": predicted, "floor": true, "null": null}
    for params in out.values():
        params["N_pin"] = int(round(params["N_pin"]))
    return out


def choose_samples(table: pd.DataFrame, max_samples: int, seed: int) -> pd.DataFrame:
    """Up to ``max_samples`` rows (a random subset from stream ``closed_loop_subset``), in table order."""
    if len(table) <= max_samples:
        return table
    rng = stream_rng(seed, "closed_loop_subset")
    return table.iloc[np.sort(rng.choice(len(table), max_samples, replace=False))]


@dataclass(frozen=True)
class ClosedLoopRun:
    """How many test samples the simulated closed loop re-simulates and how: up to ``max_samples`` samples
    (a random subset beyond), ``realisations`` shared disorder realisations each (≥ 1), on ``workers``
    processes."""

    max_samples: int
    realisations: int = 3
    workers: int = 1


def closed_loop(cfg: dict, table: pd.DataFrame, curves_by_id: dict, truths: pd.DataFrame, medians: dict,
                run: ClosedLoopRun | None = None, *, progress=None, **options) -> tuple[pd.DataFrame, dict]:
    """Re-simulate up to ``max_samples`` test samples (prediction, floor, null; ``realisations`` shared
    disorder realisations each): the fields of ``run`` (a ``ClosedLoopRun``; keyword ``options`` set single
    ones, or make it where None). ``table``: ``predicted_hamiltonians``; ``curves_by_id``: input
    families (n_fields × n_fields); ``truths``: true parameters (SI) indexed by sample id; ``medians``: the
    training medians (the null Hamiltonian); ``progress(done, total)``: per re-simulation.

    Returns the per-sample table (``rms``, ``rms_floor``, ``rms_null``, their per-realisation lists,
    ``ratio_floor`` = rms/rms_floor, ``ratio_null`` = rms/rms_null, failures) and, per sample id, the
    families of realisation 0 by role. A failed re-simulation is recorded (``failures``) and its
    realisation left out of all three means. Raises DatasetError on no test sample or a family whose
    shape is not the config's field grid, SimulationError when every re-simulation failed."""
    run = ClosedLoopRun(**options) if run is None else replace(run, **options)
    max_samples, realisations, workers = run.max_samples, run.realisations, run.workers
    if realisations < 1:
        raise ValueError("realisations must be >= 1")
    if table.empty:
        raise DatasetError("no test sample to re-simulate")
    n_fields = cfg["field"]["n_fields"]
    chosen = choose_samples(table, max_samples, cfg["seed"])
    rows, tasks, index = [], [], []
    for row in chosen.to_dict("records"):
        sid = int(row["sample_id"])
        if sid not in curves_by_id:
            raise DatasetError(f"no input family for test sample {sid}")
        shape = np.shape(curves_by_id[sid])
        if shape != (n_fields, n_fields):
            raise DatasetError(f"input family of sample {sid} has shape {shape}, the config's grid is "
                               f"{n_fields} × {n_fields}")
        if sid not in truths.index:
            raise DatasetError(f"no true parameters for test sample {sid}")
        sets = hamiltonians(row, truths.loc[sid].to_dict(), medians)
        rows.append({**row, **{f"{role}_params": sets[role] for role in ROLES}})
        for r in range(realisations):
            for role in ROLES:
                tasks.append((sets[role], sid, r))
                index.append((sid, role, r))
    outcomes = run_tasks(cfg, tasks, workers, progress)
    rms = {key: np.nan for key in index}
    families, failures = {}, {}
    for (sid, role, r), (curves, reason) in zip(index, outcomes):
        if curves is None:
            failures.setdefault(sid, []).append(f"{role} r={r}: {reason}")
            continue
        rms[(sid, role, r)] = observation_error(curves_by_id[sid], curves)["rms"]
        if r == 0:
            families.setdefault(sid, {})[role] = curves
    if len(failures) == len(rows) and all(len(f) == len(ROLES) * realisations for f in failures.values()):
        raise SimulationError(f"every re-simulation failed, e.g. {next(iter(failures.values()))[0]}")
    out = []
    for row in rows:
        sid = int(row["sample_id"])
        record = {k: v for k, v in row.items() if not k.endswith("_params")}
        # means over the realisations where all three re-simulations succeeded (keeps the pairing)
        complete = [r for r in range(realisations) if all(np.isfinite(rms[(sid, role, r)]) for role in ROLES)]
        for role in ROLES:
            values = [rms[(sid, role, r)] for r in range(realisations)]
            record[_RMS_COLUMN[role]] = float(np.mean([values[r] for r in complete])) if complete else np.nan
            record[f"{_RMS_COLUMN[role]}_per_realisation"] = [float(v) for v in values]
        record["realisations_used"] = len(complete)
        for role in ("floor", "null"):
            for name, value in row[f"{role}_params"].items():
                record[f"{role}_{name}"] = value
        record["ratio_floor"] = record["rms"] / record["rms_floor"]
        record["ratio_null"] = record["rms"] / record["rms_null"]
        record["observation_rms"] = record["rms"]
        record["failures"] = "; ".join(failures.get(sid, []))
        out.append(record)
    return pd.DataFrame(out), families


def summarize(cfg: dict, result: pd.DataFrame, realisations: int, n_boot: int = 2000) -> dict:
    """The closed-loop summary: medians (over samples) of rms/rms_floor and rms/rms_null with bootstrap
    90 % intervals (stream ``bootstrap``, key "closed_loop"), medians of the three RMS, counts."""
    rng = stream_rng(cfg["seed"], "bootstrap", "closed_loop")
    floor, floor_ci = median_with_interval(result["ratio_floor"], rng, n_boot)
    null, null_ci = median_with_interval(result["ratio_null"], rng, n_boot)
    paired = result[["rms", "rms_null"]].dropna()
    return {
        "protocol": protocol_name(cfg), "n_samples": int(len(result)), "realisations": int(realisations),
        "n_failed_samples": int((result["failures"] != "").sum()),
        "rms_median": float(result["rms"].median()), "rms_floor_median": float(result["rms_floor"].median()),
        "rms_null_median": float(result["rms_null"].median()),
        "median_rms_over_floor": floor, "median_rms_over_floor_ci90": floor_ci,
        "median_rms_over_null": null, "median_rms_over_null_ci90": null_ci,
        "n_ratios": int(np.isfinite(result["ratio_null"].to_numpy(dtype=float)).sum()),
        "fraction_rms_below_null": float((paired["rms"] < paired["rms_null"]).mean()) if len(paired) else float("nan"),
        "bootstrap_resamples": int(n_boot),
        "definition": ("rms: mean over the shared disorder realisations of the RMS of <m_z> differences over all "
                       "FORC points (H >= H_r) between the re-simulated family and the input family; floor: true "
                       "Hamiltonian; null: training-median Hamiltonian with the true M_s"),
    }


def _save(fig, out_path) -> None:
    """Write a figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(out_path) as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)


def figure4(out_path, fields, truths: dict, resims: dict, sample_ids) -> None:
    """Ten test samples: input FORCs (red) and the re-simulated ones (dark), every 4th curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sample_ids = list(sample_ids)
    cols = 5
    rows = max(1, int(np.ceil(len(sample_ids) / cols)))
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 2.6 * rows), squeeze=False, sharex=True, sharey=True)
    for ax in axes.flat[len(sample_ids):]:
        ax.axis("off")
    for ax, sid in zip(axes.flat, sample_ids):
        truth, resim = truths[sid], resims[sid]
        for i in range(0, fields.size, 4):
            ax.plot(fields[i:], truth[i, i:], color="tab:red", lw=0.7)
            ax.plot(fields[i:], resim[i, i:], color="0.15", lw=0.7, ls="--")
        rms = observation_error(truth, resim)["rms"]
        ax.set_title(f"ID {sid}: RMS {rms:.3f}", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel(r"$\mu_0H$ (T)")
    for ax in axes[:, 0]:
        ax.set_ylabel(r"$m_z$")
    fig.suptitle("closed loop: input FORCs (red) vs re-simulated from the predicted Hamiltonian (dashed)", fontsize=9)
    fig.tight_layout()
    _save(fig, out_path)


def correlation_figure(out_path, table: pd.DataFrame) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 3.6))
    ax.scatter(table["bob_error_mean"], table["rms"], s=16)
    ax.set(xlabel="Bob's predicted error (mean over parameters)", ylabel="observation-space RMS of m",
           title="closed loop vs Bob")
    fig.tight_layout()
    _save(fig, out_path)


def floor_null_figure(out_path, table: pd.DataFrame, summary: dict | None = None) -> None:
    """Per sample: rms (prediction) against rms_floor (left) and rms_null (right), the y = x line,
    bars spanning the realisations' range of the prediction's RMS."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.9))
    per = np.array([np.asarray(v, dtype=float) for v in table["rms_per_realisation"]])
    low = table["rms"].to_numpy() - np.nanmin(per, axis=1)
    high = np.nanmax(per, axis=1) - table["rms"].to_numpy()
    finite = np.concatenate([table[c].to_numpy(dtype=float) for c in ("rms", "rms_floor", "rms_null")])
    finite = finite[np.isfinite(finite)]
    top = 1.08 * float(finite.max()) if finite.size else 1.0
    for ax, column, label, key in ((axes[0], "rms_floor", "floor: true Hamiltonian re-simulated", "floor"),
                                   (axes[1], "rms_null", "null: training-median Hamiltonian", "null")):
        ax.plot([0, top], [0, top], color="0.5", lw=0.8, ls=":")
        ax.errorbar(table[column], table["rms"], yerr=[low, high], fmt="o", ms=4, lw=0.7, capsize=2)
        title = f"rms vs {key}"
        if summary is not None:
            median, (lo, hi) = summary[f"median_rms_over_{key}"], summary[f"median_rms_over_{key}_ci90"]
            title += f": median ratio {median:.2f} [{lo:.2f}, {hi:.2f}]"
        ax.set(xlim=(0, top), ylim=(0, top), xlabel=f"RMS of m, {label}", ylabel="RMS of m, predicted Hamiltonian",
               title=title)
        ax.title.set_fontsize(8)
        ax.set_aspect("equal")
    fig.suptitle("closed loop on the simulated test set (mean over shared disorder realisations; bars: their range)",
                 fontsize=8)
    fig.tight_layout()
    _save(fig, out_path)


def _spearman(a, b) -> float:
    """Spearman's ρ (NaN below three finite pairs or for a constant input)."""
    from scipy.stats import spearmanr

    pairs = pd.DataFrame({"a": a, "b": b}).dropna()
    if len(pairs) < 3:
        return float("nan")
    value = spearmanr(pairs["a"], pairs["b"]).statistic
    return float(value) if np.isfinite(value) else float("nan")


@dataclass(frozen=True)
class StageOutputs:
    """Where the closed-loop stage writes: the summary JSON ``out``, the per-sample Parquet ``table`` and the
    directory ``figures`` (figure4.png, closed_loop_vs_bob.png, closed_loop_floor_null.png)."""

    out: object
    table: object
    figures: object


def run_stage(config_path, learning_path, dataset_path, prediction_paths, outputs: StageOutputs, *,
              workers: int = 1, log=None) -> dict:
    """The workflow stage: read the dataset config, the loop section of learning.json, dataset.h5 and
    the predictions; re-simulate (``closed_loop``, on ``workers`` processes); write the per-sample Parquet
    table, the summary JSON and three figures (``outputs``). Returns the summary."""
    import h5py

    out, table, figures = outputs.out, outputs.table, outputs.figures

    started = time.perf_counter()
    cfg = read_config(config_path)
    stage_cfg = read_config(learning_path)
    loop_cfg = {**defaults("loop"), **stage_cfg.get("loop", {})}
    realisations, max_samples = int(loop_cfg["realisations"]), int(loop_cfg["max_test_samples"])
    n_boot = int({**defaults("learning"), **stage_cfg.get("learning", {})}.get("bootstrap", 2000))
    data = load_dataset(dataset_path)
    values = pd.DataFrame({k: v for k, v in data.values.items()}, index=data.sample_id.astype(int))
    paths = {Path(p).stem.replace("_predictions", ""): p for p in prediction_paths}
    predictions = predicted_hamiltonians(paths, values, data.bounds)
    medians = training_medians(paths, values)
    with h5py.File(dataset_path, "r") as h5:
        position = {int(s): k for k, s in enumerate(h5["sample_id"][:])}
        missing = [int(s) for s in predictions["sample_id"] if int(s) not in position]
        if missing:
            raise DatasetError(f"test samples {missing[:5]} are not in {dataset_path}")
        curves = {int(s): h5["curves_mz"][position[int(s)]].astype(float) for s in predictions["sample_id"]}

    def progress(k, n):
        if log is not None:
            log(f"re-simulated {k}/{n} families")

    if log is not None:
        log(f"closed loop: {min(len(predictions), max_samples)} samples x {realisations} "
            f"realisations x {len(ROLES)} Hamiltonians, protocol {protocol_name(cfg)}, {workers} worker(s)")
    result, families = closed_loop(cfg, predictions, curves, values, medians,
                                   ClosedLoopRun(max_samples, realisations=realisations, workers=workers),
                                   progress=progress)
    write_parquet(table, result)
    summary = summarize(cfg, result, realisations, n_boot)
    shown_pool = [sid for sid in result["sample_id"] if "prediction" in families.get(int(sid), {})]
    rng = stream_rng(cfg["seed"], "figure_samples", "figure4")
    n_fig = min(int(loop_cfg["n_figure_samples"]), len(shown_pool))
    shown = sorted(int(s) for s in rng.choice(np.asarray(shown_pool, dtype=int), n_fig, replace=False)) if n_fig else []
    figures = Path(figures)
    figures.mkdir(parents=True, exist_ok=True)
    figure4(figures / "figure4.png", data.fields_T, curves, {s: families[s]["prediction"] for s in shown}, shown)
    correlation_figure(figures / "closed_loop_vs_bob.png", result)
    floor_null_figure(figures / "closed_loop_floor_null.png", result, summary)
    summary.update({
        "n_resimulated": int(len(result)), "observation_rms_mean": float(result["rms"].mean()),
        "observation_rms_median": float(result["rms"].median()),
        "spearman_observation_rms_vs_bob_error": _spearman(result["bob_error_mean"], result["rms"]),
        "spearman_observation_rms_vs_true_parameter_error": _spearman(result["abs_error_mean"], result["rms"]),
        "training_medians": medians, "workers": int(workers), "figure4_samples": shown,
        "wall_s": time.perf_counter() - started,
    })
    write_json(out, summary)
    return summary
