"""Posterior-predictive closed loop on the simulated test set: re-simulate K posterior draws, not one point.

For each chosen test family y (true Hamiltonian θ*, its own disorder), K draws θ_k ~ q(θ | y, M_s)
of the neural posterior (M_s true) are re-simulated, draw k on disorder realisation k (stream
``closed_loop_disorder``, keys (sample id, k): the realisations the point closed loop uses), and
so is θ* on the same realisation k (the floor: what a new disorder alone costs, common random
numbers). Per family: the observation RMS of each draw's family against y (every FORC point with
H ≥ H_r), its median and 90 % range over the draws, the floor's mean, and the posterior median
θ̃ re-simulated on realisation 0. Summary: medians over families of rms_draws/rms_floor with a
bootstrap interval, and the fraction of draws whose RMS lies within the floor's range — a calibrated
posterior whose draws are as plausible as the truth has draws at the floor; an overconfident or biased
one has them above it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..config import defaults
from ..core.errors import DatasetError, SimulationError
from ..core.io import atomic_path, read_config, write_json, write_parquet
from ..core.parameters import denormalize
from ..core.streams import stream_rng, stream_seed
from ..learn.data import load_dataset
from ..learn.scoring import median_with_interval
from ..learn.splits import assign_splits
from .resimulate import observation_error, run_tasks


def draws_as_hamiltonians(draws_u, names, Ms: float, bounds: dict) -> list[dict]:
    """Posterior draws in u (K, n_params) → Hamiltonians (SI), true M_s, N_pin rounded to a count."""
    out = []
    for row in np.atleast_2d(draws_u):
        params = {"Ms": float(Ms)}
        for j, name in enumerate(names):
            params[name] = float(denormalize(name, row[j], bounds))
        if "N_pin" in params:
            params["N_pin"] = int(round(params["N_pin"]))
        out.append(params)
    return out


@dataclass(frozen=True)
class PosteriorLoopRun:
    """How the posterior-predictive closed loop runs: ``draws`` posterior draws re-simulated per family (≥ 1), at
    most ``max_samples`` test families (a random subset beyond), ``seed`` of its streams (``core.streams``),
    ``workers`` processes."""

    draws: int = 4
    max_samples: int = 8
    seed: int = 0
    workers: int = 1


def posterior_closed_loop(cfg: dict, estimator, data, test_index, curves_by_id: dict,
                          run: PosteriorLoopRun | None = None, *, progress=None,
                          **options) -> tuple[pd.DataFrame, dict]:
    """Per-sample table and summary of the posterior-predictive closed loop (see module docstring).
    ``estimator``: a ``learn.posterior.PosteriorEstimator``; ``data``: ``LearningData``; ``test_index``:
    positions of the test families in ``data``; ``curves_by_id``: their input families; ``run``: a
    ``PosteriorLoopRun`` (its defaults where None; keyword ``options`` set single fields);
    ``progress(done, total)``: per re-simulation."""
    run = replace(run or PosteriorLoopRun(), **options)
    draws, max_samples, seed, workers = run.draws, run.max_samples, run.seed, run.workers
    if draws < 1:
        raise ValueError("draws must be >= 1")
    test_index = np.asarray(test_index, dtype=int)
    if test_index.size == 0:
        raise DatasetError("no test family to re-simulate")
    rng = stream_rng(seed, "closed_loop_subset", "posterior")
    chosen = np.sort(rng.choice(test_index, min(max_samples, test_index.size), replace=False))
    names = tuple(estimator.names)
    samples = estimator.sample(data.images[chosen], data.ms_norm[chosen], draws,
                               seed=stream_seed(seed, "posterior", "closed_loop_draws"))
    medians = estimator.sample(data.images[chosen], data.ms_norm[chosen], 400,
                               seed=stream_seed(seed, "posterior", "closed_loop_median"))
    tasks, index, rows = [], [], []
    for k, position in enumerate(chosen):
        sid = int(data.sample_id[position])
        if sid not in curves_by_id:
            raise DatasetError(f"no input family for test sample {sid}")
        Ms = float(data.values["Ms"][position])
        truth = {"Ms": Ms, **{n: float(data.values[n][position]) for n in names}}
        if "N_pin" in truth:
            truth["N_pin"] = int(round(truth["N_pin"]))
        median = draws_as_hamiltonians(np.median(medians[k], axis=0), names, Ms, data.bounds)[0]
        for r, params in enumerate(draws_as_hamiltonians(samples[k], names, Ms, data.bounds)):
            tasks += [(params, sid, r), (truth, sid, r)]
            index += [(sid, "draw", r), (sid, "floor", r)]
        tasks.append((median, sid, 0))
        index.append((sid, "median", 0))
        rows.append({"sample_id": sid, "truth": truth, "posterior_median": median})
    outcomes = run_tasks(cfg, tasks, workers, progress)
    rms, failures = {}, {}
    for (sid, role, r), (curves, reason) in zip(index, outcomes):
        if curves is None:
            failures.setdefault(sid, []).append(f"{role} r={r}: {reason}")
            continue
        rms[(sid, role, r)] = observation_error(curves_by_id[sid], curves)["rms"]
    if not rms:
        raise SimulationError(f"every re-simulation failed, e.g. {next(iter(failures.values()))[0]}")
    table = []
    for row in rows:
        sid = row["sample_id"]
        d = np.array([rms.get((sid, "draw", r), np.nan) for r in range(draws)])
        f = np.array([rms.get((sid, "floor", r), np.nan) for r in range(draws)])
        paired = np.isfinite(d) & np.isfinite(f)
        record = {"sample_id": sid, "rms_draws": d.tolist(), "rms_floor_per_realisation": f.tolist(),
                  "rms_draws_median": float(np.nanmedian(d)) if np.isfinite(d).any() else np.nan,
                  "rms_draws_q05": float(np.nanquantile(d, 0.05)) if np.isfinite(d).any() else np.nan,
                  "rms_draws_q95": float(np.nanquantile(d, 0.95)) if np.isfinite(d).any() else np.nan,
                  "rms_floor": float(np.mean(f[paired])) if paired.any() else np.nan,
                  "rms_posterior_median": rms.get((sid, "median", 0), np.nan),
                  "fraction_draws_within_floor": (float(np.mean(d[paired] <= np.max(f[paired])))
                                                  if paired.any() else np.nan),
                  "failures": "; ".join(failures.get(sid, []))}
        record["ratio_draws_floor"] = (float(np.mean(d[paired]) / record["rms_floor"])
                                       if paired.any() and record["rms_floor"] > 0 else np.nan)
        record["ratio_median_floor"] = record["rms_posterior_median"] / record["rms_floor"]
        for name, value in row["posterior_median"].items():
            record[f"median_{name}"] = value
        for name, value in row["truth"].items():
            record[f"true_{name}"] = value
        table.append(record)
    table = pd.DataFrame(table)
    boot = stream_rng(seed, "bootstrap", "posterior_closed_loop")
    draws_ratio, draws_ci = median_with_interval(table["ratio_draws_floor"], boot)
    median_ratio, median_ci = median_with_interval(table["ratio_median_floor"], boot)
    summary = {"n_samples": int(len(table)), "draws_per_sample": int(draws),
               "median_rms_draws_over_floor": draws_ratio, "median_rms_draws_over_floor_ci90": draws_ci,
               "median_rms_posterior_median_over_floor": median_ratio,
               "median_rms_posterior_median_over_floor_ci90": median_ci,
               "fraction_draws_within_floor": float(np.nanmean(table["fraction_draws_within_floor"])),
               "rms_floor_median": float(table["rms_floor"].median()),
               "rms_draws_median": float(table["rms_draws_median"].median()),
               "definition": ("draw k re-simulated on disorder realisation k, the truth (floor) on the same "
                              "realisation; rms: RMS of <m_z> differences over all FORC points (H >= H_r) against the "
                              "input family; within floor: a draw's rms at most the largest floor rms of its sample")}
    return table, summary


@dataclass(frozen=True)
class StageOutputs:
    """Where the posterior-predictive stage writes: the summary JSON ``out``, the per-sample Parquet ``table``
    and the figure (PNG; None: none)."""

    out: object
    table: object
    figure: object = None


def run_stage(config_path, learning_path, dataset_path, model_path, outputs: StageOutputs,
              run: PosteriorLoopRun = PosteriorLoopRun(), *, log=None) -> dict:
    """Read config, learning.json (seed, split), dataset.h5 and the posterior model; run the loop on the
    test split (``run``: draws, test families, workers; the seed is the config's); write the per-sample Parquet
    table, the summary JSON and a figure (``outputs``)."""
    import h5py

    from ..learn.posterior import PosteriorEstimator  # local: the posterior imports torch

    out, table, figure = outputs.out, outputs.table, outputs.figure
    draws, max_samples, workers = run.draws, run.max_samples, run.workers
    started = time.perf_counter()
    cfg = read_config(config_path)
    stage = read_config(learning_path)
    learning = {**defaults("learning"), **stage.get("learning", {})}
    data = load_dataset(dataset_path)
    estimator = PosteriorEstimator.load(model_path)
    if estimator.metadata.get("config_hash") not in (None, data.config_hash):
        raise DatasetError(f"the posterior {model_path} was trained on another dataset "
                           f"(config hash {estimator.metadata.get('config_hash')} vs {data.config_hash})")
    splits = assign_splits(data.sample_id, cfg["seed"], learning["split"], learning["protocol"])
    test = splits["test"]
    with h5py.File(dataset_path, "r") as h5:
        curves = {int(data.sample_id[k]): h5["curves_mz"][k].astype(float) for k in test}
    if log is not None:
        log(f"posterior-predictive closed loop: {min(max_samples, len(test))} test families x {draws} draws "
            f"(+ floor, + posterior median), {workers} worker(s)")

    def progress(k, n):
        if log is not None:
            log(f"re-simulated {k}/{n} families")

    result, summary = posterior_closed_loop(cfg, estimator, data, test, curves, replace(run, seed=cfg["seed"]),
                                            progress=progress)
    write_parquet(table, result)
    summary["wall_s"] = time.perf_counter() - started
    write_json(out, summary)
    if figure is not None:
        _figure(figure, result, summary)
    return summary


def _figure(path, table: pd.DataFrame, summary: dict) -> None:
    """Per test family: each draw's RMS (dots), the floor realisations (crosses), the posterior median (bar)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    fig, ax = plt.subplots(figsize=(7, 3.5))
    for i, row in enumerate(table.itertuples()):
        ax.scatter(np.full(len(row.rms_draws), i) - 0.1, row.rms_draws, s=12, color="C0",
                   label="posterior draws" if i == 0 else None)
        ax.scatter(np.full(len(row.rms_floor_per_realisation), i) + 0.1, row.rms_floor_per_realisation, marker="x",
                   color="C3", label="truth, new disorder (floor)" if i == 0 else None)
        ax.hlines(row.rms_posterior_median, i - 0.3, i + 0.3, color="k", label="posterior median" if i == 0 else None)
    ax.set_xticks(range(len(table)), [str(s) for s in table["sample_id"]], rotation=60, fontsize=7)
    ax.set_xlabel("test family (sample id)")
    ax.set_ylabel("observation RMS of ⟨m_z⟩")
    ax.set_title(f"posterior-predictive closed loop: median draws/floor {summary['median_rms_draws_over_floor']:.2f}",
                 fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


__all__ = ["PosteriorLoopRun", "StageOutputs", "draws_as_hamiltonians", "posterior_closed_loop", "run_stage"]
