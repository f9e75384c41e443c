"""``forcdecode closed-loop``: the closed loop on the simulated test set (workflow stage).

    closed-loop --config config.json --learning learning.json --dataset dataset.h5
                --predictions P1.parquet ... --out closed_loop.json --table closed_loop.parquet --figures DIR
                [--workers N]

Writes figure4.png, closed_loop_vs_bob.png and closed_loop_floor_null.png into DIR.
"""

from __future__ import annotations

import argparse
import sys
import time
from .simulated import StageOutputs, run_stage


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="resolved dataset config.json")
    parser.add_argument("--learning", required=True, help="resolved learning.json (loop section)")
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--predictions", nargs="+", required=True, help="<parameter>_predictions.parquet files")
    parser.add_argument("--out", required=True, help="summary JSON")
    parser.add_argument("--table", required=True, help="per-sample Parquet table")
    parser.add_argument("--figures", required=True,
                        help="directory for figure4.png, closed_loop_vs_bob.png and closed_loop_floor_null.png")
    parser.add_argument("--workers", type=_positive_int, default=1,
                        help="processes re-simulating samples x realisations in parallel (one numba thread each)")


def _log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def run(args) -> int:
    summary = run_stage(args.config, args.learning, args.dataset, args.predictions,
                        StageOutputs(out=args.out, table=args.table, figures=args.figures), workers=args.workers,
                        log=_log)
    print(f"closed loop on {summary['n_samples']} test samples x {summary['realisations']} realisations: "
          f"median rms/rms_floor {summary['median_rms_over_floor']:.2f} {summary['median_rms_over_floor_ci90']}, "
          f"median rms/rms_null {summary['median_rms_over_null']:.2f} {summary['median_rms_over_null_ci90']}; "
          f"Spearman vs Bob {summary['spearman_observation_rms_vs_bob_error']:.2f}")
    return 0
