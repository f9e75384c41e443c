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
import json
import sys
import time

import numpy as np


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
    p = sub.add_parser("merge")
    p.add_argument("--config", required=True)
    p.add_argument("--params", required=True)
    p.add_argument("--screens", nargs="+", required=True)
    p.add_argument("--families", nargs="*", default=[])
    p.add_argument("--h5", required=True)
    p.add_argument("--parquet", required=True)
    p = sub.add_parser("figure1")
    p.add_argument("--dataset", required=True)
    p.add_argument("--out", required=True)


def _log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def chunk_ids(cfg: dict, chunk: int) -> list[int]:
    size = cfg["chunk_size"]
    return list(range(chunk * size, min((chunk + 1) * size, cfg["n_samples"])))


def run(args) -> int:
    import pandas as pd

    from . import io
    from .params import draw_parameters

    if args.step == "figure1":
        from .figures import figure1

        figure1(args.dataset, args.out)
        return 0
    cfg = io.read_config(args.config)
    if args.step == "draw":
        rows = [{"sample_id": i, **draw_parameters(cfg["seed"], i, cfg.get("bounds"))} for i in range(cfg["n_samples"])]
        io.write_parquet(args.out, pd.DataFrame(rows))
        _log(f"drew {len(rows)} samples (seed {cfg['seed']})")
        return 0
    params = pd.read_parquet(args.params).set_index("sample_id") if hasattr(args, "params") else None
    if args.step == "screen":
        from .simulate import screen

        ids = chunk_ids(cfg, args.chunk)
        rows = []
        for n, sample_id in enumerate(ids, 1):
            row = screen(cfg, params.loc[sample_id].to_dict(), sample_id)
            rows.append(row)
            _log(f"screen chunk {args.chunk}: sample {sample_id} ({n}/{len(ids)}) {row['screen_status']}"
                 f" {row['screen_reason']} [{row['screen_s']:.1f} s]")
        io.write_parquet(args.out, pd.DataFrame(rows))
        return 0
    if args.step == "select":
        table = pd.concat([pd.read_parquet(path) for path in args.screens], ignore_index=True)
        passed = sorted(int(i) for i in table.loc[table["screen_status"] == "passed", "sample_id"])
        size = cfg["family_chunk_size"]
        chunks = {str(k): passed[k * size:(k + 1) * size] for k in range((len(passed) + size - 1) // size)}
        counts = table["screen_status"].value_counts().to_dict()
        io.write_json(args.out, {"chunks": chunks, "n_passed": len(passed), "n_screened": int(len(table)),
                                 "pass_rate": len(passed) / max(1, len(table)), "counts": counts})
        _log(f"screening: {len(passed)}/{len(table)} passed ({counts}); {len(chunks)} family chunks")
        return 0
    if args.step == "simulate":
        return _simulate_chunk(cfg, params, args)
    if args.step == "merge":
        from .merge import merge

        merge(cfg, args.params, args.screens, args.families, args.h5, args.parquet)
        return 0
    raise AssertionError(args.step)


def _simulate_chunk(cfg, params, args) -> int:
    import h5py

    from . import io
    from .simulate import simulate

    selection = json.loads(open(args.selection).read())
    ids = selection["chunks"].get(str(args.chunk))
    if ids is None:
        raise SystemExit(f"error: chunk {args.chunk} is not in {args.selection}")
    n_fields = cfg["field"]["n_fields"]
    results = []
    for n, sample_id in enumerate(ids, 1):
        result = simulate(cfg, params.loc[sample_id].to_dict(), sample_id)
        results.append(result)
        _log(f"family chunk {args.chunk}: sample {sample_id} ({n}/{len(ids)}) {result['status']} "
             f"{result['reason']} [{result['family_s']:.1f} s, {result['relaxations']} relaxations]")
    with io.atomic_path(args.out) as tmp:
        with h5py.File(tmp, "w") as h5:
            count = len(results)
            h5["sample_id"] = np.array([r["sample_id"] for r in results], dtype=np.int64)
            h5["status"] = np.array([r["status"] for r in results], dtype=h5py.string_dtype())
            h5["reason"] = np.array([r["reason"] for r in results], dtype=h5py.string_dtype())
            h5["family_s"] = np.array([r["family_s"] for r in results])
            images = np.zeros((count, n_fields, n_fields), dtype=np.uint8)
            curves = np.full((count, n_fields, n_fields), np.nan, dtype=np.float32)
            descending = np.full((count, n_fields), np.nan, dtype=np.float32)
            for k, r in enumerate(results):
                if r["status"] == "ok":
                    images[k], curves[k], descending[k] = r["image"], r["curves_mz"], r["descending_mz"]
            h5.create_dataset("images", data=images, compression="gzip")
            h5.create_dataset("curves_mz", data=curves, compression="gzip")
            h5.create_dataset("descending_mz", data=descending, compression="gzip")
            # raw recorded points of the LLG protocol (not on the grid), per sample: the closed loop uses them
            for r in results:
                if r["status"] == "ok" and r.get("raw_curves") is not None:
                    group = h5.create_group(f"raw/{r['sample_id']}")
                    write_raw_curves(group, r["raw_curves"])
    return 0


def write_raw_curves(group, raw_curves) -> None:
    """Ragged curves as one flat array each for fields and m_z, plus offsets (curve k is
    [offsets[k], offsets[k+1]))."""
    lengths = [len(f) for f, _ in raw_curves]
    group["offsets"] = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    group["field_T"] = np.concatenate([f for f, _ in raw_curves]).astype(np.float64)
    group["mz"] = np.concatenate([m for _, m in raw_curves]).astype(np.float64)
