"""``forcdecode dataset <step>``: the workflow's per-stage commands (each writes its output atomically).

    draw      --config C [--chunk K] --out params_K.parquet      (one screening chunk's ids, or all)
    screen    --config C --params P... --chunk K --out screen_K.parquet
    select    --config C --screens S... --out selection.json     (the screening summary)
    simulate  --config C --params P... --screen screen_K.parquet --chunk K --part J --out family_K_J.h5
              (or the old layout: --selection selection.json --chunk K)
    merge     --config C --params P... --screens S... --families F... --h5 dataset.h5 --parquet samples.parquet
    merge     --runs RUN/dataset.h5... --h5 dataset.h5 --parquet samples.parquet   (several runs into one)
    figure1   --dataset dataset.h5 --out figure1.png
"""

from __future__ import annotations

import argparse
from ..core.errors import ConfigError
from ..core.io import read_config, read_json
from ..core.progress import say
from . import stages
from .figures import figure1
from .merge import merge, merge_runs


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="step", required=True)
    p = sub.add_parser("draw")
    p.add_argument("--config", required=True)
    p.add_argument("--chunk", type=int, help="draw only this screening chunk's samples")
    p.add_argument("--out", required=True)
    p = sub.add_parser("screen")
    p.add_argument("--config", required=True)
    p.add_argument("--params", nargs="+", required=True)
    p.add_argument("--chunk", type=int, required=True)
    p.add_argument("--out", required=True)
    p = sub.add_parser("select")
    p.add_argument("--config", required=True)
    p.add_argument("--screens", nargs="+", required=True)
    p.add_argument("--out", required=True)
    p = sub.add_parser("simulate")
    p.add_argument("--config", required=True)
    p.add_argument("--params", nargs="+", required=True)
    p.add_argument("--screen", required=True, help="the screening chunk's parquet")
    p.add_argument("--chunk", type=int, required=True, help="the screening chunk's number")
    p.add_argument("--part", type=int, required=True, help="family part of that chunk (family_chunk_size samples each)")
    p.add_argument("--out", required=True)
    p = sub.add_parser("merge", help="the workflow's chunks into dataset.h5, or (--runs) several runs' "
                                     "dataset.h5 files into one, with provenance per sample")
    p.add_argument("--config")
    p.add_argument("--params", nargs="+")
    p.add_argument("--screens", nargs="+")
    p.add_argument("--families", nargs="*", default=[])
    p.add_argument("--family-lists", nargs="*", default=[],
                   help="JSON lists of family files, one per screening chunk (the workflow's families/chunk_K.json)")
    p.add_argument("--runs", nargs="+", help="dataset.h5 files of runs of one physics config (samples.parquet beside "
                                             "each is merged too)")
    p.add_argument("--h5", required=True)
    p.add_argument("--parquet", required=True)
    p = sub.add_parser("figure1")
    p.add_argument("--dataset", required=True)
    p.add_argument("--out", required=True)


def _log(text: str) -> None:
    say(text)  # timestamped on stderr; on a terminal, above the progress bar


def run(args) -> int:
    if args.step == "figure1":
        figure1(args.dataset, args.out)
        return 0
    if args.step == "merge" and args.runs:
        merge_runs(args.runs, args.h5, args.parquet, log=_log)
        return 0
    if args.step == "merge" and not (args.config and args.params and args.screens):
        raise ConfigError("dataset merge needs --config, --params and --screens (the workflow's chunks), or --runs")
    cfg = read_config(args.config)
    if args.step == "draw":
        stages.draw_stage(cfg, args.out, log=_log, chunk=args.chunk)
    elif args.step == "screen":
        stages.screen_stage(cfg, args.params, args.chunk, args.out, log=_log)
    elif args.step == "select":
        stages.select_stage(cfg, args.screens, args.out, log=_log)
    elif args.step == "simulate":
        stages.simulate_stage(cfg, args.params, args.screen, args.chunk, args.out, log=_log, part=args.part)
    elif args.step == "merge":
        families = list(args.families)
        for listing in args.family_lists:
            families += read_json(listing, what="family list")["families"]
        merge(cfg, args.params, args.screens, families, args.h5, args.parquet)
    return 0
