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
from ..config import dataset_config, realisations
from ..core import io
from ..core.errors import DatasetError
from ..core.parameters import NAMES as PARAMETERS


def config_hash(cfg: dict) -> str:
    return hashlib.sha256(json.dumps(cfg, sort_keys=True).encode()).hexdigest()[:16]


def merge(cfg, params_path, screen_paths, family_paths, h5_path, parquet_path) -> None:
    """The workflow's chunks (parameter draws, screens, family files) into ``dataset.h5`` (families
    ordered by sample id, parameters SI, fields in T) and ``samples.parquet`` (every drawn sample).
    ``config_hash`` is the hash of the physics config (``physics_config``): a grown run keeps it.
    With ``realisations: R`` the families are means over R disorder realisations: ``curves_std_mz``
    (float16, NaN below the diagonal) holds their spread, 0 for R = 1 (and for family files written
    before the spread was recorded, all R = 1), and the attribute ``realisations`` says R. A family
    file simulated with another R than ``cfg`` says raises DatasetError."""

    paths = [params_path] if isinstance(params_path, (str, bytes)) or not hasattr(params_path, "__iter__") else list(params_path)
    params = pd.concat([pd.read_parquet(p) for p in paths], ignore_index=True)
    # the workflow's config.json leaves out how many samples were drawn (so that growing a dataset
    # reruns nothing): the dataset records the ids actually drawn, whole chunks
    cfg = dataset_config(cfg)  # `realisations: 1` left out, as resolve_config does: the hash of before
    count = realisations(cfg)
    if len(params):
        cfg.setdefault("n_samples", int(len(params)))
        cfg.setdefault("first_sample_id", int(params["sample_id"].min()))
    screens = pd.concat([pd.read_parquet(p) for p in screen_paths], ignore_index=True)
    table = params.merge(screens.drop(columns=[c for c in ("traceback",) if c in screens]), on="sample_id", how="left")
    family_rows, images, curves, descending, spread, ok_ids, raw_sources = [], [], [], [], [], [], []
    for path in family_paths:
        with h5py.File(path, "r") as h5:
            found = int(h5.attrs.get("realisations", 1))  # files written before R existed: 1
            if found != count:
                raise DatasetError(f"{path} holds families of {found} disorder realisations, the config says {count}")
            ids = h5["sample_id"][:]
            status = h5["status"].asstr()[:]
            reason = h5["reason"].asstr()[:]
            seconds = h5["family_s"][:]
            # CPU time of the family (s); chunks written before it was recorded have none
            cpu_seconds = h5["family_cpu_s"][:] if "family_cpu_s" in h5 else np.full(len(ids), np.nan)
            for k, sample_id in enumerate(ids):
                family_rows.append({"sample_id": int(sample_id), "family_status": status[k],
                                    "family_reason": reason[k], "family_s": float(seconds[k]),
                                    "family_cpu_s": float(cpu_seconds[k])})
                if status[k] == "ok":
                    ok_ids.append(int(sample_id))
                    if f"raw/{int(sample_id)}" in h5:
                        raw_sources.append((path, int(sample_id)))
                    images.append(h5["images"][k])
                    curves.append(h5["curves_mz"][k])
                    descending.append(h5["descending_mz"][k])
                    spread.append(h5["curves_std_mz"][k] if "curves_std_mz" in h5
                                  else np.where(np.isnan(curves[-1]), np.nan, 0.0))
    families = pd.DataFrame(family_rows, columns=["sample_id", "family_status", "family_reason", "family_s",
                                                  "family_cpu_s"])
    table = table.merge(families, on="sample_id", how="left")
    table["in_dataset"] = table["sample_id"].isin(ok_ids)
    table["config_hash"] = config_hash(physics_config(cfg))
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
            h5.create_dataset("curves_std_mz", data=stack(spread, (n_fields, n_fields), np.float16).astype(np.float16),
                              compression="gzip")
            h5["sample_id"] = ok_ids
            h5["fields_T"] = np.linspace(-cfg["field"]["B_max_T"], cfg["field"]["B_max_T"], n_fields)
            values = indexed.loc[ok_ids, list(PARAMETERS)].to_numpy(dtype=float) if len(ok_ids) else np.zeros((0, len(PARAMETERS)))
            dset = h5.create_dataset("parameters", data=values)
            dset.attrs["columns"] = list(PARAMETERS)
            dset.attrs["units"] = ["A/m", "J/m", "J/m^3", "J/m^2", "count (256x256x2 grid)", "deg", "fraction"]
            for path, sample_id in raw_sources:
                with h5py.File(path, "r") as source:
                    source.copy(source[f"raw/{sample_id}"], h5, name=f"raw_curves/{sample_id}")
            h5.attrs["config_hash"] = config_hash(physics_config(cfg))  # the same for a grown run
            h5.attrs["config_json"] = json.dumps(cfg, sort_keys=True)
            h5.attrs["seed"] = cfg["seed"]
            h5.attrs["realisations"] = count
            h5.attrs["package_version"] = __version__
            h5.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            h5.attrs["image_rule"] = "rows: reversal field ascending; columns: field ascending; H<H_r filled with m(H_r,H_r); uint8=round(127.5(m+1))"
    io.write_parquet(parquet_path, table)
    passed = int((table["screen_status"] == "passed").sum())
    print(f"merged {len(ok_ids)} families; {passed}/{len(table)} samples passed screening", flush=True)


# ---------------------------------------------------------------- several runs into one dataset
SIZE_KEYS = ("n_samples", "chunk_size", "family_chunk_size", "results_dir", "first_sample_id", "kernel_cache_dir")
"""Config keys that say how much was run and where, not what was simulated: runs may differ in them."""


def physics_config(cfg: dict) -> dict:
    """The part of a dataset config that decides what a family is (mesh, field grid, minimizer,
    protocol, pinning, grains, screening, bounds, prior class, seed, realisations): runs merged into one
    dataset must agree on it. ``realisations: 1`` and ``prior: paper`` are left out
    (``config.dataset_config``), so the hash of a config that says them is the hash of the same config
    from before the keys existed."""
    return {k: v for k, v in dataset_config(cfg).items() if k not in SIZE_KEYS}


def merge_runs(dataset_paths, h5_path, parquet_path=None, log=print) -> dict:
    """Merge the dataset.h5 files of several runs (and the samples.parquet beside each, when present)
    into one, with per-sample provenance (``provenance/run`` indexes the ``runs`` attribute: path,
    config hash, seed, package version, creation time). Runs must share the physics config (and so
    the seed: the split is a function of (seed, sample id), and a sample keeps its split in the merged
    dataset); a sample id present in several runs must carry the same parameters (it is then taken
    once, from the first run). Raises DatasetError naming the runs and the difference."""

    paths = [str(p) for p in dataset_paths]
    if len(paths) < 1:
        raise DatasetError("no run to merge")
    runs, reference = [], None
    images, curves, descending, spread, params, ids, run_of = [], [], [], [], [], [], []
    seen: dict[int, np.ndarray] = {}
    fields = columns = None
    for r, path in enumerate(paths):
        try:
            h5 = h5py.File(path, "r")
        except OSError as error:
            raise DatasetError(f"cannot open run {path}: {error}") from None
        with h5:
            try:
                cfg = json.loads(h5.attrs["config_json"])
            except KeyError:
                raise DatasetError(f"{path} has no config provenance (not written by `forcdecode dataset merge`)") from None
            physics = physics_config(cfg)
            if reference is None:
                reference, reference_path = physics, path
                fields, columns = h5["fields_T"][:], list(h5["parameters"].attrs["columns"])
            elif physics != reference:
                keys = sorted(k for k in set(physics) | set(reference) if physics.get(k) != reference.get(k))
                raise DatasetError(f"run {path} simulated other films than {reference_path}: they differ in "
                                   f"{', '.join(keys)}; only runs of one physics config can share a dataset")
            runs.append({"path": path, "config_hash": str(h5.attrs.get("config_hash", "")),
                         "seed": int(h5.attrs.get("seed", cfg.get("seed", -1))),
                         "package_version": str(h5.attrs.get("package_version", "")),
                         "created": str(h5.attrs.get("created", "")), "n_samples": int(cfg.get("n_samples", -1)),
                         "first_sample_id": int(cfg.get("first_sample_id", 0))})
            sample_ids = h5["sample_id"][:]
            values = h5["parameters"][:]
            for k, sid in enumerate(sample_ids):
                sid = int(sid)
                if sid in seen:
                    if not np.allclose(seen[sid], values[k], rtol=1e-12, atol=0.0, equal_nan=True):
                        raise DatasetError(f"sample {sid} of {path} has other parameters than in an earlier run: "
                                           "two runs drew different samples under one id")
                    continue
                seen[sid] = values[k]
                images.append(h5["images"][k])
                curves.append(h5["curves_mz"][k])
                descending.append(h5["descending_mz"][k])
                # runs merged before the spread was recorded were all one realisation: spread 0
                spread.append(h5["curves_std_mz"][k] if "curves_std_mz" in h5
                              else np.where(np.isnan(curves[-1]), np.nan, 0.0).astype(np.float16))
                params.append(values[k])
                ids.append(sid)
                run_of.append(r)
        log(f"run {r}: {path}: {len(sample_ids)} families")
    order = np.argsort(ids)
    with io.atomic_path(h5_path) as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.create_dataset("images", data=np.stack(images)[order], compression="gzip")
            h5.create_dataset("curves_mz", data=np.stack(curves)[order], compression="gzip")
            h5.create_dataset("descending_mz", data=np.stack(descending)[order], compression="gzip")
            h5.create_dataset("curves_std_mz", data=np.stack(spread)[order].astype(np.float16), compression="gzip")
            h5["sample_id"] = np.asarray(ids, dtype=np.int64)[order]
            h5["fields_T"] = fields
            dset = h5.create_dataset("parameters", data=np.stack(params)[order])
            dset.attrs["columns"] = columns
            dset.attrs["units"] = ["A/m", "J/m", "J/m^3", "J/m^2", "count (256x256x2 grid)", "deg", "fraction"]
            h5.create_dataset("provenance/run", data=np.asarray(run_of, dtype=np.int32)[order])
            h5.attrs["runs"] = json.dumps(runs)
            # samples drawn by all runs together: the union of their id ranges [first, first + n)
            drawn = set().union(*(range(r["first_sample_id"], r["first_sample_id"] + max(r["n_samples"], 0)) for r in runs))
            merged_cfg = {**reference, "n_samples": len(drawn), "first_sample_id": min(drawn, default=0)}
            h5.attrs["config_json"] = json.dumps(merged_cfg, sort_keys=True)
            h5.attrs["config_hash"] = config_hash(physics_config(merged_cfg))
            h5.attrs["seed"] = int(reference.get("seed", -1))
            h5.attrs["realisations"] = realisations(reference)
            h5.attrs["package_version"] = __version__
            h5.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            h5.attrs["image_rule"] = "rows: reversal field ascending; columns: field ascending; H<H_r filled with m(H_r,H_r); uint8=round(127.5(m+1))"
    if parquet_path is not None:
        from pathlib import Path

        tables = []
        for r, path in enumerate(paths):
            beside = Path(path).with_name("samples.parquet")
            if beside.exists():
                t = pd.read_parquet(beside)
                t["run"] = r
                tables.append(t)
        if tables:
            table = pd.concat(tables, ignore_index=True).drop_duplicates("sample_id", keep="first")
            io.write_parquet(parquet_path, table.sort_values("sample_id").reset_index(drop=True))
    log(f"merged {len(ids)} families from {len(paths)} runs into {h5_path}")
    return {"n_families": len(ids), "runs": runs}
