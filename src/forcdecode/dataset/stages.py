"""The dataset stages of the workflow as library functions (``forcdecode dataset <step>`` calls them):
draw the parameters, screen a chunk, select the passing samples, simulate a chunk's FORC families.
Every output is written atomically; fields in T, m normalized, parameters SI (``core.parameters``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..config import realisations
from ..core.errors import InputFileError
from ..core.io import atomic_path, write_json, write_parquet
from ..core.parameters import prior_class
from ..core.progress import progress
from .params import draw_parameters
from .simulate import screen, simulate


def _quiet(text: str) -> None:
    pass


def chunk_ids(cfg: dict, chunk: int) -> list[int]:
    """Sample ids of screening chunk ``chunk``: ``chunk_size`` consecutive ids from chunk · chunk_size
    (chunk numbers are absolute: a run from ``first_sample_id`` starts at chunk first_sample_id /
    chunk_size). A chunk does not depend on ``n_samples`` (the workflow's config.json leaves it out
    and runs whole chunks, n_samples rounded up), so a grown dataset keeps every chunk it had, bit for
    bit; a config that has ``n_samples`` (called by hand) clamps the last chunk to
    [first_sample_id, first_sample_id + n_samples)."""
    size = cfg["chunk_size"]
    start, end = chunk * size, (chunk + 1) * size
    if "n_samples" in cfg:
        first = cfg.get("first_sample_id", 0)
        start, end = max(start, first), min(end, first + cfg["n_samples"])
    return list(range(start, end))


def draw_stage(cfg: dict, out, log=_quiet, chunk: int | None = None) -> pd.DataFrame:
    """Draw the parameters of the samples of screening chunk ``chunk`` (or of all ``n_samples``) and
    write them (Parquet, one row each). Draws come from (seed, sample id) and the prior class
    (``cfg["prior"]``, absent: paper) alone: chunk by chunk or all at once, a sample's parameters are
    the same."""
    first = cfg.get("first_sample_id", 0)
    ids = chunk_ids(cfg, chunk) if chunk is not None else range(first, first + cfg["n_samples"])
    prior = prior_class(cfg)  # absent (every config.json of the paper class): paper
    rows = [{"sample_id": i, **draw_parameters(cfg["seed"], i, cfg.get("bounds"), prior=prior)} for i in ids]
    table = pd.DataFrame(rows)
    write_parquet(out, table)
    log(f"drew {len(rows)} samples (seed {cfg['seed']}, prior {prior})")
    return table


def _parameters(params_paths) -> pd.DataFrame:
    paths = [params_paths] if isinstance(params_paths, (str, bytes)) or not hasattr(params_paths, "__iter__") else list(params_paths)
    return pd.concat([pd.read_parquet(p) for p in paths], ignore_index=True).set_index("sample_id")


def family_parts(cfg: dict, screen_path) -> list[list[int]]:
    """The passing samples of one screening chunk (ascending ids), in parts of ``family_chunk_size``:
    the family jobs of that chunk. Depends on that chunk's screening alone."""
    table = pd.read_parquet(screen_path)
    passed = sorted(int(i) for i in table.loc[table["screen_status"] == "passed", "sample_id"])
    size = cfg["family_chunk_size"]
    return [passed[k * size:(k + 1) * size] for k in range((len(passed) + size - 1) // size)]


def screen_stage(cfg: dict, params_path, chunk: int, out, log=_quiet) -> pd.DataFrame:
    """Screen the samples of one chunk (``simulate.screen``) and write one row per sample."""

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
    """The screening summary: counts by outcome, the pass rate, and each screening chunk's family
    parts (``family_parts``: the jobs its passing samples make)."""
    from pathlib import Path

    table = pd.concat([pd.read_parquet(path) for path in screens], ignore_index=True)
    passed = int((table["screen_status"] == "passed").sum())
    parts = {Path(path).stem: family_parts(cfg, path) for path in screens}
    counts = table["screen_status"].value_counts().to_dict()
    selection = {"parts": parts, "n_passed": passed, "n_screened": int(len(table)),
                 "pass_rate": passed / max(1, len(table)), "counts": counts,
                 "n_family_jobs": int(sum(len(p) for p in parts.values()))}
    write_json(out, selection)
    log(f"screening: {passed}/{len(table)} passed ({counts}); {selection['n_family_jobs']} family jobs")
    return selection


def simulate_stage(cfg: dict, params_path, screen_path, chunk: int, out, log=_quiet, part: int = 0) -> list[dict]:
    """Simulate the FORC families of one family job (``simulate.simulate``) and write them (HDF5): part
    ``part`` of screening chunk ``chunk`` (its screen parquet ``screen_path``, ``family_parts``).
    With ``realisations: R`` each family is the mean of R disorder realisations (R times the cost;
    ``family_s``/``family_cpu_s`` cover all R) and ``curves_std_mz`` their spread.
    InputFileError if that chunk has no such part."""
    import h5py


    params = _parameters(params_path)
    parts = family_parts(cfg, screen_path)
    if not 0 <= part < len(parts):
        raise InputFileError(f"part {part} is not among the {len(parts)} family parts of {screen_path}")
    ids = parts[part]
    chunk = f"{chunk}.{part}"
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
            h5["family_cpu_s"] = np.array([r.get("family_cpu_s", np.nan) for r in results])
            images = np.zeros((count, n_fields, n_fields), dtype=np.uint8)
            curves = np.full((count, n_fields, n_fields), np.nan, dtype=np.float32)
            spread = np.full((count, n_fields, n_fields), np.nan, dtype=np.float32)
            descending = np.full((count, n_fields), np.nan, dtype=np.float32)
            for k, r in enumerate(results):
                if r["status"] == "ok":
                    images[k], curves[k], descending[k] = r["image"], r["curves_mz"], r["descending_mz"]
                    spread[k] = r["curves_std_mz"]
            h5.create_dataset("images", data=images, compression="gzip")
            h5.create_dataset("curves_mz", data=curves, compression="gzip")
            h5.create_dataset("descending_mz", data=descending, compression="gzip")
            # the realisation spread (std of the R realisations' curves; 0 for R = 1) and R itself
            h5.create_dataset("curves_std_mz", data=spread, compression="gzip")
            h5.attrs["realisations"] = realisations(cfg)
            # raw recorded points of the LLG protocol (not on the grid), per sample: the closed loop uses them
            # (with R > 1 realisations, one subgroup per realisation: raw/<sample>/<r>)
            for r in results:
                if r["status"] == "ok" and r.get("raw_curves") is not None:
                    group = h5.create_group(f"raw/{r['sample_id']}")
                    write_raw_curves(group, r["raw_curves"])
                elif r["status"] == "ok" and r.get("raw_realisations") is not None:
                    for k, raw in enumerate(r["raw_realisations"]):
                        write_raw_curves(h5.create_group(f"raw/{r['sample_id']}/{k}"), raw)
    return results


def write_raw_curves(group, raw_curves) -> None:
    """Ragged curves as one flat array each for fields and m_z, plus offsets (curve k is
    [offsets[k], offsets[k+1]))."""
    lengths = [len(f) for f, _ in raw_curves]
    group["offsets"] = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    group["field_T"] = np.concatenate([f for f, _ in raw_curves]).astype(np.float64)
    group["mz"] = np.concatenate([m for _, m in raw_curves]).astype(np.float64)
