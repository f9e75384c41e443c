"""``forcdecode closed-loop``: the closed loop on the simulated test set (workflow stage).

    closed-loop --config config.json --learning learning.json --dataset dataset.h5
                --predictions P1.parquet ... --out closed_loop.json --table closed_loop.parquet --figures DIR
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="resolved dataset config.json")
    parser.add_argument("--learning", required=True, help="resolved learning.json (loop section)")
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--predictions", nargs="+", required=True, help="<parameter>_predictions.parquet files")
    parser.add_argument("--out", required=True, help="summary JSON")
    parser.add_argument("--table", required=True, help="per-sample Parquet table")
    parser.add_argument("--figures", required=True, help="directory for figure4.png and closed_loop_vs_bob.png")


def run(args) -> int:
    import h5py
    import pandas as pd

    from ..dataset.io import read_config, write_json, write_parquet
    from ..learn.data import load_dataset
    from ..learn.uncertainty import spearman
    from .simulated import closed_loop, correlation_figure, figure4, predicted_hamiltonians

    cfg = read_config(args.config)
    loop_cfg = read_config(args.learning).get("loop", {})
    data = load_dataset(args.dataset)
    values = pd.DataFrame({k: v for k, v in data.values.items()}, index=data.sample_id)
    paths = {Path(p).stem.replace("_predictions", ""): p for p in args.predictions}
    table = predicted_hamiltonians(paths, values, data.bounds)
    if table.empty:
        raise SystemExit("error: the predictions hold no test sample")
    with h5py.File(args.dataset, "r") as h5:
        ids = list(h5["sample_id"][:])
        curves = {int(s): h5["curves_mz"][ids.index(s)].astype(float) for s in table["sample_id"]}
    # disorder widths for a run whose learning config trains no network for them (mid-range of the draw)
    defaults = {"sigma_theta_deg": 5.0, "sigma_K": 0.1}
    started = time.perf_counter()
    result, families = closed_loop(cfg, table, curves, defaults, loop_cfg.get("max_test_samples", 40), cfg["seed"],
                                   progress=lambda k, n: print(f"[{time.strftime('%H:%M:%S')}] re-simulated {k}/{n}",
                                                               file=sys.stderr, flush=True))
    write_parquet(args.table, result)
    rng = np.random.default_rng(cfg["seed"] + 6_000_006)
    n_fig = min(loop_cfg.get("n_figure_samples", 10), len(result))
    shown = sorted(rng.choice(result["sample_id"].to_numpy(), n_fig, replace=False).tolist())
    figures = Path(args.figures)
    figures.mkdir(parents=True, exist_ok=True)
    figure4(figures / "figure4.png", data.fields_T, curves, families, shown)
    correlation_figure(figures / "closed_loop_vs_bob.png", result)
    summary = {"n_resimulated": int(len(result)), "observation_rms_mean": float(result["observation_rms"].mean()),
               "observation_rms_median": float(result["observation_rms"].median()),
               "spearman_observation_rms_vs_bob_error": spearman(result["bob_error_mean"], result["observation_rms"]),
               "spearman_observation_rms_vs_true_parameter_error": spearman(result["abs_error_mean"], result["observation_rms"]),
               "figure4_samples": shown, "wall_s": time.perf_counter() - started}
    write_json(args.out, summary)
    print(f"closed loop on {len(result)} test samples: observation RMS mean {summary['observation_rms_mean']:.4f}; "
          f"Spearman vs Bob {summary['spearman_observation_rms_vs_bob_error']:.2f}")
    return 0
