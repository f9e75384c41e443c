"""``forcdecode dataset <step>``: the workflow's per-stage commands (each writes its output atomically).

    draw      --config C --out params.parquet
    screen    --config C --params P --chunk K --out screen_K.parquet
    select    --config C --screens S... --out selection.json
    simulate  --config C --params P --selection SEL --chunk K --out family_K.h5
    merge     --config C --params P --screens S... --families F... --h5 dataset.h5 --parquet samples.parquet
    figure1   --dataset dataset.h5 --out figure1.png
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="step", required=True)
    p = sub.add_parser("draw")
    p.add_argument("--config", required=True)
    p.add_argument("--out", required=True)
    p = sub.add_parser("screen")
    p.add_argument("--config", required=True)
    p.add_argument("--params", required=True)
    p.add_argument("--chunk", type=int, required=True)
    p.add_argument("--out", required=True)
    p = sub.add_parser("select")
    p.add_argument("--config", required=True)
    p.add_argument("--screens", nargs="+", required=True)
    p.add_argument("--out", required=True)
    p = sub.add_parser("simulate")
    p.add_argument("--config", required=True)
    p.add_argument("--params", required=True)
    p.add_argument("--selection", required=True)
    p.add_argument("--chunk", type=int, required=True)
    p.add_argument("--out", required=True)
    p = sub.add_parser("merge", help="the workflow's chunks into dataset.h5, or (--runs) several runs' "
                                     "dataset.h5 files into one, with provenance per sample")
    p.add_argument("--config")
    p.add_argument("--params")
    p.add_argument("--screens", nargs="+")
    p.add_argument("--families", nargs="*", default=[])
    p.add_argument("--runs", nargs="+", help="dataset.h5 files of runs of one physics config (samples.parquet beside "
                                             "each is merged too)")
    p.add_argument("--h5", required=True)
    p.add_argument("--parquet", required=True)
    p = sub.add_parser("figure1")
    p.add_argument("--dataset", required=True)
    p.add_argument("--out", required=True)


def _log(text: str) -> None:
    from ..core.progress import say

    say(text)  # timestamped on stderr; on a terminal, above the progress bar


def run(args) -> int:
    from ..core.errors import ConfigError
    from ..core.io import read_config
    from . import stages

    if args.step == "figure1":
        from .figures import figure1

        figure1(args.dataset, args.out)
        return 0
    if args.step == "merge" and args.runs:
        from .merge import merge_runs

        merge_runs(args.runs, args.h5, args.parquet, log=_log)
        return 0
    if args.step == "merge" and not (args.config and args.params and args.screens):
        raise ConfigError("dataset merge needs --config, --params and --screens (the workflow's chunks), or --runs")
    cfg = read_config(args.config)
    if args.step == "draw":
        stages.draw_stage(cfg, args.out, log=_log)
    elif args.step == "screen":
        stages.screen_stage(cfg, args.params, args.chunk, args.out, log=_log)
    elif args.step == "select":
        stages.select_stage(cfg, args.screens, args.out, log=_log)
    elif args.step == "simulate":
        stages.simulate_stage(cfg, args.params, args.selection, args.chunk, args.out, log=_log)
    elif args.step == "merge":
        from .merge import merge

        merge(cfg, args.params, args.screens, args.families, args.h5, args.parquet)
    return 0
