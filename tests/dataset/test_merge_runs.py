"""`forcdecode dataset merge --runs`: several runs' dataset.h5 into one, with provenance per sample;
overlapping identical samples taken once; runs of other films or clashing samples refused; the
split of every sample unchanged by the merge."""

import json

import h5py
import numpy as np
import pandas as pd
import pytest

from forcdecode.cli import main
from forcdecode.core.errors import DatasetError
from forcdecode.core.parameters import NAMES
from forcdecode.dataset.merge import merge_runs
from forcdecode.learn.data import load_dataset
from forcdecode.learn.splits import assign_splits

CFG = {"seed": 7, "n_samples": 10, "chunk_size": 5, "mesh": {"nx": 16, "ny": 16, "nz": 1, "dx_nm": 2.0, "dy_nm": 2.0,
                                                                "dz_nm": 4.0}, "field": {"B_max_T": 1.0, "n_fields": 8}}


def fake_run(path, ids, cfg=CFG, shift=0.0):
    rng = np.random.default_rng(0)
    ids = np.asarray(ids)
    params = np.stack([np.full(len(NAMES), 1.0) * (sid + 1) + shift for sid in ids])
    params[:, 0] = 5e5 + 1e4 * ids  # M_s
    with h5py.File(path, "w") as h5:
        h5["images"] = rng.integers(0, 255, (len(ids), 8, 8)).astype(np.uint8)
        h5["curves_mz"] = rng.random((len(ids), 8, 8)).astype(np.float32)
        h5["descending_mz"] = rng.random((len(ids), 8)).astype(np.float32)
        h5["sample_id"] = ids
        h5["fields_T"] = np.linspace(-1, 1, 8)
        d = h5.create_dataset("parameters", data=params)
        d.attrs["columns"] = list(NAMES)
        h5.attrs["config_json"] = json.dumps(cfg)
        h5.attrs["config_hash"] = "h" + str(cfg["n_samples"])
        h5.attrs["seed"] = cfg["seed"]
    pd.DataFrame({"sample_id": ids, "screen_status": "passed"}).to_parquet(path.with_name("samples.parquet"))
    return path


def test_two_runs_merge_with_provenance(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = fake_run(tmp_path / "a" / "dataset.h5", [0, 2, 3])
    b = fake_run(tmp_path / "b" / "dataset.h5", [3, 11, 14], cfg={**CFG, "n_samples": 20})  # grown run: 3 again
    out = tmp_path / "merged.h5"
    assert main(["dataset", "merge", "--runs", str(a), str(b), "--h5", str(out), "--parquet",
                 str(tmp_path / "samples.parquet")]) == 0
    with h5py.File(out, "r") as h5:
        assert list(h5["sample_id"][:]) == [0, 2, 3, 11, 14]
        assert list(h5["provenance/run"][:]) == [0, 0, 0, 1, 1]
        runs = json.loads(h5.attrs["runs"])
        assert [r["path"] for r in runs] == [str(a), str(b)] and runs[1]["n_samples"] == 20
        assert json.loads(h5.attrs["config_json"])["n_samples"] == 20
        with h5py.File(b, "r") as src:
            assert np.array_equal(h5["images"][3], src["images"][1])
    table = pd.read_parquet(tmp_path / "samples.parquet")
    assert list(table["sample_id"]) == [0, 2, 3, 11, 14] and list(table["run"]) == [0, 0, 0, 1, 1]
    # every sample keeps its split: the split is a function of (seed, sample id) only
    merged = load_dataset(out)
    split = [0.5, 0.2, 0.1, 0.2]
    whole = assign_splits(merged.sample_id, 7, split, "holdout")
    part = assign_splits(np.array([0, 2, 3]), 7, split, "holdout")
    for name in whole:
        assert set(merged.sample_id[whole[name]]) & {0, 2, 3} == set(np.array([0, 2, 3])[part[name]])


def test_runs_of_other_films_or_clashing_samples_refuse(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    a = fake_run(tmp_path / "a" / "dataset.h5", [0, 1])
    other = fake_run(tmp_path / "b" / "dataset.h5", [5], cfg={**CFG, "mesh": {**CFG["mesh"], "nx": 32}})
    with pytest.raises(DatasetError, match="differ in mesh"):
        merge_runs([a, other], tmp_path / "m.h5", log=lambda *_: None)
    clash = fake_run(tmp_path / "c" / "dataset.h5", [1], shift=0.5)
    with pytest.raises(DatasetError, match="sample 1 .* other parameters"):
        merge_runs([a, clash], tmp_path / "m.h5", log=lambda *_: None)
    assert not (tmp_path / "m.h5").exists()
    assert main(["dataset", "merge", "--h5", str(tmp_path / "m.h5"), "--parquet", str(tmp_path / "s.parquet")]) == 2
