"""``forcdecode posterior-loop``: the posterior-predictive closed loop on the simulated test set
(``infer.posterior_predictive``): K posterior draws per test family re-simulated against the floor.

    posterior-loop --config config.json --learning learning.json --dataset dataset.h5
                   --posterior model.pt --out summary.json --table table.parquet [--figure F.png]
                   [--draws 4] [--max-samples 8] [--workers N]
"""

from __future__ import annotations

import argparse
import sys
import time
from ..core.errors import ConfigError
from .posterior_predictive import PosteriorLoopRun, StageOutputs, run_stage


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="resolved dataset config.json")
    parser.add_argument("--learning", required=True, help="resolved learning.json (seed, split)")
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--posterior", required=True, help="posterior model (.pt) of `learn posterior`")
    parser.add_argument("--out", required=True, help="summary JSON")
    parser.add_argument("--table", required=True, help="per-family Parquet table")
    parser.add_argument("--figure", help="figure: draws' and floor's observation RMS per family")
    parser.add_argument("--draws", type=int, default=4, help="posterior draws re-simulated per family (default 4)")
    parser.add_argument("--max-samples", type=int, default=8, help="test families (random subset; default 8)")
    parser.add_argument("--workers", type=int, default=1, help="processes re-simulating in parallel")


def run(args) -> int:
    if args.draws < 1 or args.max_samples < 1 or args.workers < 1:
        raise ConfigError("--draws, --max-samples and --workers must be >= 1")
    summary = run_stage(args.config, args.learning, args.dataset, args.posterior,
                        StageOutputs(out=args.out, table=args.table, figure=args.figure),
                        PosteriorLoopRun(draws=args.draws, max_samples=args.max_samples, workers=args.workers),
                        log=lambda m: print(f"[{time.strftime('%H:%M:%S')}] {m}", file=sys.stderr, flush=True))
    print(f"posterior-predictive closed loop on {summary['n_samples']} test families x {summary['draws_per_sample']} "
          f"draws: median rms(draws)/rms(floor) {summary['median_rms_draws_over_floor']:.2f} "
          f"{summary['median_rms_draws_over_floor_ci90']}; posterior median/floor "
          f"{summary['median_rms_posterior_median_over_floor']:.2f}; draws within the floor's range "
          f"{summary['fraction_draws_within_floor']:.2f}")
    return 0
