"""The dataset stages of the workflow as library functions (``forcdecode dataset <step>`` calls them):
draw the parameters, screen a chunk, select the passing samples, simulate a chunk's FORC families.
Every output is written atomically; fields in T, m normalized, parameters SI (``core.parameters``).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from ..core.errors import InputFileError
from ..core.io import atomic_path, write_json, write_parquet
from ..core.progress import progress
from .params import draw_parameters


def _quiet(text: str) -> None:
    pass


def chunk_ids(cfg: dict, chunk: int) -> list[int]:
    """Sample ids of screening chunk ``chunk`` (``chunk_size`` consecutive ids)."""
    size = cfg["chunk_size"]
    return list(range(chunk * size, min((chunk + 1) * size, cfg["n_samples"])))


def draw_stage(cfg: dict, out, log=_quiet) -> pd.DataFrame:
    """Draw the parameters of every sample (``n_samples``) and write them (Parquet, one row each)."""
    rows = [{"sample_id": i, **draw_parameters(cfg["seed"], i, cfg.get("bounds"))} for i in range(cfg["n_samples"])]
    table = pd.DataFrame(rows)
    write_parquet(out, table)
    log(f"drew {len(rows)} samples (seed {cfg['seed']})")
    return table


def _parameters(params_path) -> pd.DataFrame:
    return pd.read_parquet(params_path).set_index("sample_id")


def screen_stage(cfg: dict, params_path, chunk: int, out, log=_quiet) -> pd.DataFrame:
    """Screen the samples of one chunk (``simulate.screen``) and write one row per sample."""
    from .simulate import screen

    params = _parameters(params_path)
    ids = chunk_ids(cfg, chunk)
    rows = []
    for n, sample_id in enumerate(progress(ids, desc=f"screen chunk {chunk}", unit="samples"), 1):
        row = screen(cfg, params.loc[sample_id].to_dict(), sample_id)
        rows.append(row)
        log(f"screen chunk {chunk}: sample {sample_id} ({n}/{len(ids)}) {row['screen_status']}"
            f" {row['screen_reason']} [{row['screen_s']:.1f} s]")
    table = pd.DataFrame(rows)
    write_parquet(out, table)
    return table


def select_stage(cfg: dict, screens, out, log=_quiet) -> dict:
    """The passing samples of every screening chunk, grouped in chunks of ``family_chunk_size``."""
    table = pd.concat([pd.read_parquet(path) for path in screens], ignore_index=True)
    passed = sorted(int(i) for i in table.loc[table["screen_status"] == "passed", "sample_id"])
    size = cfg["family_chunk_size"]
    chunks = {str(k): passed[k * size:(k + 1) * size] for k in range((len(passed) + size - 1) // size)}
    counts = table["screen_status"].value_counts().to_dict()
    selection = {"chunks": chunks, "n_passed": len(passed), "n_screened": int(len(table)),
                 "pass_rate": len(passed) / max(1, len(table)), "counts": counts}
    write_json(out, selection)
    log(f"screening: {len(passed)}/{len(table)} passed ({counts}); {len(chunks)} family chunks")
    return selection


def simulate_stage(cfg: dict, params_path, selection_path, chunk: int, out, log=_quiet) -> list[dict]:
    """Simulate the FORC families of one family chunk (``simulate.simulate``) and write them (HDF5).
    InputFileError if the chunk is not in the selection."""
    import h5py

    from .simulate import simulate

    params = _parameters(params_path)
    with open(selection_path) as handle:
        selection = json.load(handle)
    ids = selection["chunks"].get(str(chunk))
    if ids is None:
        raise InputFileError(f"chunk {chunk} is not in {selection_path}")
    n_fields = cfg["field"]["n_fields"]
    results = []
    for n, sample_id in enumerate(progress(ids, desc=f"family chunk {chunk}", unit="families"), 1):
        result = simulate(cfg, params.loc[sample_id].to_dict(), sample_id)
        results.append(result)
        log(f"family chunk {chunk}: sample {sample_id} ({n}/{len(ids)}) {result['status']} "
            f"{result['reason']} [{result['family_s']:.1f} s, {result['relaxations']} relaxations]")
    with atomic_path(out) as tmp:
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
    return results


def write_raw_curves(group, raw_curves) -> None:
    """Ragged curves as one flat array each for fields and m_z, plus offsets (curve k is
    [offsets[k], offsets[k+1]))."""
    lengths = [len(f) for f, _ in raw_curves]
    group["offsets"] = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    group["field_T"] = np.concatenate([f for f, _ in raw_curves]).astype(np.float64)
    group["mz"] = np.concatenate([m for _, m in raw_curves]).astype(np.float64)
