"""A dataset that grows: the tiny workflow run to dataset.h5 with 16 samples, then with 24. The second
run draws, screens and simulates only the new chunk: every file of the first run is kept (same
mtime, same bytes), the old samples keep their parameters, families and split."""

import hashlib
from pathlib import Path

import h5py
import numpy as np
import pytest

from forcdecode.learn.data import load_dataset
from forcdecode.learn.splits import assign_splits
from snakemake_runs import snakemake_process

ROOT = Path(__file__).resolve().parents[2]


def snakemake(workdir, n_samples, *args, extra=()):
    """The tiny workflow up to dataset.h5 with ``n_samples`` (target first: --configfile takes several values)."""
    return snakemake_process(workdir, "results/dataset.h5", "--config", f"n_samples={n_samples}", *extra,
                             "--configfile", ROOT / "config" / "test.yaml", *args, cores=2, timeout=900)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow  # two tiny dataset runs: about a minute
def test_growing_n_samples_reuses_every_family(tmp_path):
    first = snakemake(tmp_path, 16)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    kept = {p: (p.stat().st_mtime_ns, digest(p)) for d in ("params", "screen", "families")
            for p in (tmp_path / "results" / d).glob("chunk_*")}
    assert any("families" in str(p) for p in kept)
    old = load_dataset(tmp_path / "results" / "dataset.h5")
    plan = snakemake(tmp_path, 24, "-n")
    assert plan.returncode == 0, plan.stderr[-3000:]
    planned = plan.stdout + plan.stderr
    # jobs only for the new chunk (merge lists every chunk as input, but no job of chunks 0 and 1 runs)
    assert "wildcards: chunk=0002" in planned
    assert "wildcards: chunk=0000" not in planned and "wildcards: chunk=0001" not in planned
    grown = snakemake(tmp_path, 24)
    assert grown.returncode == 0, grown.stdout[-3000:] + grown.stderr[-3000:]
    for path, (mtime, content) in kept.items():
        assert path.stat().st_mtime_ns == mtime and digest(path) == content, path
    new = load_dataset(tmp_path / "results" / "dataset.h5")
    assert set(old.sample_id) < set(new.sample_id)
    with h5py.File(tmp_path / "results" / "dataset.h5") as h5:
        position = {int(s): k for k, s in enumerate(h5["sample_id"][:])}
        for k, sid in enumerate(old.sample_id):
            assert np.array_equal(new.images[position[int(sid)]], old.images[k])
    split = [0.5, 0.15, 0.15, 0.2]
    before = assign_splits(old.sample_id, 7, split, "holdout")
    after = assign_splits(new.sample_id, 7, split, "holdout")
    for name in before:
        assert set(old.sample_id[before[name]]) == set(new.sample_id[after[name]]) & set(old.sample_id)


@pytest.mark.slow  # a tiny dataset run: about 20 s
def test_a_second_id_range_merges_with_the_first(tmp_path):
    from forcdecode.cli import main

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    assert snakemake(tmp_path / "a", 8).returncode == 0
    second = snakemake(tmp_path / "b", 8, extra=("first_sample_id=16",))
    assert second.returncode == 0, second.stderr[-3000:]
    assert sorted(p.name for p in (tmp_path / "b" / "results" / "params").glob("*.parquet")) == ["chunk_0002.parquet"]
    out = tmp_path / "merged.h5"
    assert main(["dataset", "merge", "--runs", str(tmp_path / "a" / "results" / "dataset.h5"),
                 str(tmp_path / "b" / "results" / "dataset.h5"), "--h5", str(out), "--parquet",
                 str(tmp_path / "samples.parquet")]) == 0
    with h5py.File(out) as h5:
        ids = h5["sample_id"][:]
        assert ids.min() < 8 and ids.max() >= 16 and not ((ids >= 8) & (ids < 16)).any()
        assert set(h5["provenance/run"][:]) <= {0, 1}
