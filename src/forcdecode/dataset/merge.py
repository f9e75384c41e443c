"""Merge the per-chunk outputs into ``dataset.h5`` (HDF5) and ``samples.parquet`` (one row per drawn
sample, with its screening and simulation outcome)."""

from __future__ import annotations

import hashlib
import json
import time

import h5py
import numpy as np
import pandas as pd

from .. import __version__
from ..core import io
from ..core.parameters import NAMES as PARAMETERS


def config_hash(cfg: dict) -> str:
    return hashlib.sha256(json.dumps(cfg, sort_keys=True).encode()).hexdigest()[:16]


def merge(cfg, params_path, screen_paths, family_paths, h5_path, parquet_path) -> None:
    params = pd.read_parquet(params_path)
    screens = pd.concat([pd.read_parquet(p) for p in screen_paths], ignore_index=True)
    table = params.merge(screens.drop(columns=[c for c in ("traceback",) if c in screens]), on="sample_id", how="left")
    family_rows, images, curves, descending, ok_ids, raw_sources = [], [], [], [], [], []
    for path in family_paths:
        with h5py.File(path, "r") as h5:
            ids = h5["sample_id"][:]
            status = h5["status"].asstr()[:]
            reason = h5["reason"].asstr()[:]
            seconds = h5["family_s"][:]
            for k, sample_id in enumerate(ids):
                family_rows.append({"sample_id": int(sample_id), "family_status": status[k],
                                    "family_reason": reason[k], "family_s": float(seconds[k])})
                if status[k] == "ok":
                    ok_ids.append(int(sample_id))
                    if f"raw/{int(sample_id)}" in h5:
                        raw_sources.append((path, int(sample_id)))
                    images.append(h5["images"][k])
                    curves.append(h5["curves_mz"][k])
                    descending.append(h5["descending_mz"][k])
    families = pd.DataFrame(family_rows, columns=["sample_id", "family_status", "family_reason", "family_s"])
    table = table.merge(families, on="sample_id", how="left")
    table["in_dataset"] = table["sample_id"].isin(ok_ids)
    table["config_hash"] = config_hash(cfg)
    order = np.argsort(ok_ids)
    ok_ids = np.asarray(ok_ids, dtype=np.int64)[order]
    n_fields = cfg["field"]["n_fields"]
    stack = lambda arrays, shape, dtype: (np.stack(arrays)[order] if arrays else np.zeros((0,) + shape, dtype))  # noqa: E731
    indexed = params.set_index("sample_id")
    with io.atomic_path(h5_path) as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.create_dataset("images", data=stack(images, (n_fields, n_fields), np.uint8), compression="gzip")
            h5.create_dataset("curves_mz", data=stack(curves, (n_fields, n_fields), np.float32), compression="gzip")
            h5.create_dataset("descending_mz", data=stack(descending, (n_fields,), np.float32), compression="gzip")
            h5["sample_id"] = ok_ids
            h5["fields_T"] = np.linspace(-cfg["field"]["B_max_T"], cfg["field"]["B_max_T"], n_fields)
            values = indexed.loc[ok_ids, list(PARAMETERS)].to_numpy(dtype=float) if len(ok_ids) else np.zeros((0, len(PARAMETERS)))
            dset = h5.create_dataset("parameters", data=values)
            dset.attrs["columns"] = list(PARAMETERS)
            dset.attrs["units"] = ["A/m", "J/m", "J/m^3", "J/m^2", "count (256x256x2 grid)", "deg", "fraction"]
            for path, sample_id in raw_sources:
                with h5py.File(path, "r") as source:
                    source.copy(source[f"raw/{sample_id}"], h5, name=f"raw_curves/{sample_id}")
            h5.attrs["config_hash"] = config_hash(cfg)
            h5.attrs["config_json"] = json.dumps(cfg, sort_keys=True)
            h5.attrs["seed"] = cfg["seed"]
            h5.attrs["package_version"] = __version__
            h5.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            h5.attrs["image_rule"] = "rows: reversal field ascending; columns: field ascending; H<H_r filled with m(H_r,H_r); uint8=round(127.5(m+1))"
    io.write_parquet(parquet_path, table)
    passed = int((table["screen_status"] == "passed").sum())
    print(f"merged {len(ok_ids)} families; {passed}/{len(table)} samples passed screening", flush=True)
