"""``forcdecode learn train|evaluate`` (workflow stages) and ``forcdecode predict`` (the user command).

    learn train     --config C --dataset dataset.h5 --parameter P --model M.pt --predictions X.parquet --metrics J.json
    learn evaluate  --metrics J.json... --predictions X.parquet... --out metrics.json --figures DIR
    predict INPUT --Ms-kA-m 800 --models results/models [--json]
        INPUT: a FORC file (any format `forcdecode read` knows), a 64×64 image (.npy, uint8 or m in [−1, 1]),
        or dataset.h5 with --sample-id.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="step", required=True)
    p = sub.add_parser("train", help="fit Alice and Bob for one parameter")
    p.add_argument("--config", required=True, help="resolved config.json")
    p.add_argument("--dataset", required=True)
    p.add_argument("--parameter", required=True)
    p.add_argument("--model", required=True, help="output model file (.pt)")
    p.add_argument("--predictions", required=True, help="output per-sample predictions (.parquet)")
    p.add_argument("--metrics", required=True, help="output metrics (.json)")
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("evaluate", help="metrics.json and the learning figures")
    p.add_argument("--metrics", nargs="+", required=True)
    p.add_argument("--predictions", nargs="+", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--figures", required=True)


def run(args) -> int:
    import torch

    from ..dataset.io import read_config, write_json

    if args.step == "train":
        from .data import TARGETS, load_dataset
        from .pipeline import train_parameter

        torch.set_num_threads(max(1, args.threads))
        cfg = read_config(args.config)
        if args.parameter not in TARGETS:
            raise SystemExit(f"error: unknown parameter {args.parameter!r} (one of {', '.join(TARGETS)})")
        data = load_dataset(args.dataset)
        metrics = train_parameter(data, args.parameter, cfg.get("learning", {}), cfg["seed"], args.model,
                                  args.predictions, log=_log)
        write_json(args.metrics, json.loads(json.dumps(metrics, default=float)))
        return 0
    if args.step == "evaluate":
        from .report import evaluate, markdown

        metrics = evaluate(args.metrics, args.predictions, args.out, args.figures)
        print(markdown(metrics))
        return 0
    raise SystemExit(f"unknown step {args.step}")


# ---------------------------------------------------------------- predict
def add_predict_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="FORC file, 64×64 image (.npy) or dataset.h5 (with --sample-id)")
    parser.add_argument("--Ms-kA-m", dest="ms_kA_m", type=float, required=True, help="saturation magnetization M_s (kA/m)")
    parser.add_argument("--models", default="results/models", help="directory with <parameter>.pt files")
    parser.add_argument("--sample-id", type=int, help="sample of dataset.h5 to read")
    parser.add_argument("--B-max-T", type=float, default=1.0, help="field window of the training grid (FORC files)")
    parser.add_argument("--force", action="store_true", help="predict even when the FORC file is out of the training domain")
    parser.add_argument("--json", action="store_true", help="machine-readable output")


def image_from_input(path: str, size: int, sample_id=None, B_max_T: float = 1.0, force: bool = False):
    """(uint8 image, note) from a .npy image, dataset.h5 sample or FORC file."""
    from ..forc.raster import quantize

    p = Path(path)
    if not p.exists():
        raise SystemExit(f"error: {path} does not exist")
    if p.suffix == ".npy":
        image = np.load(p)
        if image.shape != (size, size):
            raise SystemExit(f"error: {path}: image has shape {image.shape}, the models expect ({size}, {size})")
        if image.dtype != np.uint8:
            if np.nanmin(image) < -1.001 or np.nanmax(image) > 1.001:
                raise SystemExit(f"error: {path}: a float image must hold m in [-1, 1] (found {np.nanmin(image):.3g}..{np.nanmax(image):.3g})")
            image = quantize(image)
        return image, None
    if p.suffix in (".h5", ".hdf5"):
        import h5py

        if sample_id is None:
            raise SystemExit("error: a dataset input needs --sample-id")
        with h5py.File(p, "r") as h5:
            ids = list(h5["sample_id"][:])
            if sample_id not in ids:
                raise SystemExit(f"error: sample {sample_id} is not in {path}")
            return h5["images"][ids.index(sample_id)], None
    from ..forc.raster import measurement_on_grid
    from ..measured import ForcFormatError, read_forc

    try:
        data = read_forc(p)
    except ForcFormatError as error:
        raise SystemExit(f"error: {error}") from None
    image, _, note, _ = measurement_on_grid(data, B_max_T, size)
    if note is not None and not force:
        raise SystemExit(f"error: {path} is out of the training domain: {note} (use --force to predict anyway)")
    return image, note


def run_predict(args) -> int:
    from .data import UNITS
    from .predictor import load_models, predict_parameters

    models = load_models(args.models)
    size = next(iter(models.values())).image_size
    image, note = image_from_input(args.input, size, args.sample_id, args.B_max_T, args.force)
    result = predict_parameters(models, image, args.ms_kA_m * 1e3)
    if note:
        result["out_of_domain"] = note
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"{args.input}  (M_s = {args.ms_kA_m:g} kA/m given)")
    print(f"{'parameter':<16}{'value':>12}  {'68 % interval':>26}  {'90 % interval':>26}  {'Bob |err| (norm.)':>18}  unit")
    for name, entry in result.items():
        if not isinstance(entry, dict):
            continue
        i68, i90 = entry.get("interval_68", [np.nan] * 2), entry.get("interval_90", [np.nan] * 2)
        print(f"{name:<16}{entry['value']:>12.4g}  [{i68[0]:>11.4g}, {i68[1]:>11.4g}]  [{i90[0]:>11.4g}, {i90[1]:>11.4g}]"
              f"  {entry['bob_error_normalized']:>18.3f}  {UNITS.get(name, '')}")
    if note:
        print(f"warning: out of the training domain: {note}")
    return 0
