"""The Snakemake DAG on the tiny CI configuration, run for real (local executor)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def snakemake(*args, timeout=600):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run([*SNAKEMAKE, "--cores", "2", "--configfile", "config/test.yaml", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)


def test_tiny_config_builds_the_dataset(tmp_path):
    out = tmp_path / "results"
    run = snakemake("--config", f"results_dir={out}")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    samples = pd.read_parquet(out / "samples.parquet")
    assert len(samples) == 6  # one row per drawn sample, rejected ones included
    assert set(samples["screen_status"]) <= {"passed", "rejected", "failed"}
    assert (samples["screen_status"] != "passed").all() or samples["screen_reason"].notna().all()
    assert samples.loc[samples["screen_status"] == "rejected", "screen_reason"].str.len().min() > 0
    selection = json.loads((out / "screen" / "selection.json").read_text())
    with h5py.File(out / "dataset.h5", "r") as h5:
        n = h5["images"].shape[0]
        assert h5["images"].dtype == "uint8" and h5["images"].shape[1:] == (16, 16)
        assert n == selection["n_passed"] - int((samples["family_status"] == "failed").sum())
        assert h5["parameters"].shape == (n, 7)
        assert len(h5.attrs["config_hash"]) == 16 and h5.attrs["seed"] == 7
    assert (out / "figures" / "figure1.png").stat().st_size > 10_000
    # a finished run has nothing left to do
    again = snakemake("--config", f"results_dir={out}", "-n")
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr


def test_bad_config_stops_before_any_job_naming_the_key(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text((ROOT / "config" / "test.yaml").read_text() + "\nmesh: {nx: 16, ny: 16, nz: 1, dx_nm: -2.0}\n")
    run = subprocess.run([*SNAKEMAKE, "--cores", "1", "--configfile", str(bad), "--config",
                          f"results_dir={tmp_path / 'r'}"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode != 0
    text = run.stdout + run.stderr
    assert "dx_nm" in text and "exclusiveMinimum" in text or "-2.0" in text
    assert not (tmp_path / "r").exists()
