"""`realisations: R`: a training sample's family is the mean over R disorder realisations.

R = 1 is the dataset of before, bit for bit (config.json, config hash, family); for R = 2 the mean is
the average of the two families simulated directly from the two named streams; the spread stored is
0 for R = 1 and positive for R = 2; a failed realisation fails the sample, recorded. The tiny film of
config/test.yaml: well under a second per family."""

import hashlib
import json
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
import yaml

from forcdecode.config import dataset_config, defaults, load_config, realisations, shipped_config, validate_config
from forcdecode.core.errors import ConfigError, DatasetError
from forcdecode.core.streams import STREAMS, stream_rng
from forcdecode.dataset import simulate as simulate_module
from forcdecode.dataset import stages as stages_module
from forcdecode.dataset.merge import config_hash, merge, physics_config
from forcdecode.dataset.params import draw_parameters
from forcdecode.dataset.simulate import realisation_rng, simulate
from forcdecode.dataset.stages import draw_stage, screen_stage, simulate_stage
from forcdecode.forc.protocol import quasistatic_family
from forcdecode.forc.raster import rasterize_grid_family
from forcdecode.micromag.build import build_film, sweep_options
from snakemake_runs import snakemake_process

ROOT = Path(__file__).resolve().parents[2]
# config/test.yaml's and config/config.yaml's resolved config.json (sha256 of its bytes) and config
# hash, made by the workflow before the key `realisations` existed (commit 8355f54): a dataset and
# the models made then must keep them
CONFIG_JSON_SHA256_BEFORE = {"test": "5543862dd69a12641288a7bc95099a7fc73761a66dcd86be8d42b83f95aa3198",
                             "config": "25775332b2f4613e9f071213ca58c7305965d7e1218871da06f520bcb1aee649"}
CONFIG_HASH_BEFORE = {"test": "80ff68272e9a2d53", "config": "ba146b7d72ea6130"}
# the prior class each config resolved to then: config.yaml had no `prior` key (the schema's `paper`);
# it states `perpendicular` since 2026-11-29 (a new dataset by design), so it is resolved with the old class
PRIOR_BEFORE = {"test": "paper", "config": "paper"}
# a passing sample of config/test.yaml (seed 7; sample 3, the only one of screening chunk 0, passes too)
SAMPLE = 9


@pytest.fixture(scope="module")
def cfg():
    return load_config(shipped_config("test"))


@pytest.fixture(scope="module")
def params(cfg):
    return draw_parameters(cfg["seed"], SAMPLE, cfg["bounds"])


def family_from(cfg, params, rng=None, sample_id=SAMPLE):
    """One family simulated directly, as the dataset did before `realisations` (film from the
    sample's `disorder` stream unless ``rng``)."""
    film, m0, _ = build_film(cfg, params, sample_id, rng=rng)
    return quasistatic_family(film, m0, n_fields=cfg["field"]["n_fields"], B_max_T=cfg["field"]["B_max_T"],
                              **sweep_options(cfg))


# ------------------------------------------------------------------ configuration and hash
def test_schema_key():
    assert defaults()["realisations"] == 1
    assert validate_config({"n_samples": 1, "realisations": 4})["realisations"] == 4
    for bad in (0, 1.5, "2"):
        with pytest.raises(ConfigError, match="realisations"):
            validate_config({"n_samples": 1, "realisations": bad})
    assert "disorder_realisation" in STREAMS


def test_dataset_config_leaves_one_realisation_out(cfg):
    assert "realisations" in cfg and cfg["realisations"] == 1  # the schema's default, filled in
    assert "realisations" not in dataset_config(cfg) and dataset_config({**cfg, "realisations": 3})["realisations"] == 3
    assert realisations({}) == 1 and realisations({"realisations": 3}) == 3
    absent = {k: v for k, v in cfg.items() if k != "realisations"}
    assert config_hash(physics_config(cfg)) == config_hash(physics_config(absent))
    assert config_hash(physics_config({**cfg, "realisations": 2})) != config_hash(physics_config(absent))


def resolve(tmp_path, name, *extra):
    """results/config.json as the workflow writes it (snakemake's resolve_config) for config/NAME.yaml."""
    run = snakemake_process(tmp_path, "--configfile", ROOT / "config" / f"{name}.yaml", *extra, "--",
                            "results/config.json")
    assert run.returncode == 0, run.stderr[-3000:]
    return (tmp_path / "results" / "config.json").read_bytes()


def test_resolved_config_and_hash_as_before(tmp_path):
    """config/test.yaml with `realisations: 1` (what the schema fills in when the key is absent, too):
    config.json byte for byte and its hash as the workflow wrote them before the key existed."""
    one = resolve(tmp_path, "test", "--config", "realisations=1")
    assert hashlib.sha256(one).hexdigest() == CONFIG_JSON_SHA256_BEFORE["test"]
    assert config_hash(physics_config(json.loads(one))) == CONFIG_HASH_BEFORE["test"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["test", "config"])
def test_resolved_config_absent_one_two(tmp_path, name):
    """The key absent, 1 and 2, on the tiny and the laptop configs (six Snakemake runs: ~30 s each on a
    busy machine)."""
    prior = f"prior={PRIOR_BEFORE[name]}"
    absent = resolve(tmp_path / "absent", name, "--config", prior)
    one = resolve(tmp_path / "one", name, "--config", prior, "realisations=1")
    two = resolve(tmp_path / "two", name, "--config", prior, "realisations=2")
    assert one == absent and hashlib.sha256(absent).hexdigest() == CONFIG_JSON_SHA256_BEFORE[name]
    cfg = json.loads(absent)
    assert "realisations" not in cfg and config_hash(physics_config(cfg)) == CONFIG_HASH_BEFORE[name]
    cfg2 = json.loads(two)
    assert cfg2["realisations"] == 2 and config_hash(physics_config(cfg2)) != CONFIG_HASH_BEFORE[name]
    assert {k: v for k, v in cfg2.items() if k != "realisations"} == cfg


# ------------------------------------------------------------------ families
def test_one_realisation_is_the_family_of_before(cfg, params):
    direct = family_from(cfg, params)
    for config in (cfg, {k: v for k, v in cfg.items() if k != "realisations"}):
        out = simulate(config, params, SAMPLE)
        assert out["status"] == "ok" and out["realisations"] == 1
        assert out["curves_mz"].dtype == direct.curves_mz.dtype
        assert np.array_equal(out["curves_mz"], direct.curves_mz, equal_nan=True)  # bit for bit
        assert np.array_equal(out["descending_mz"], direct.descending_mz)
        assert np.array_equal(out["image"], rasterize_grid_family(direct.curves_mz))
        # the spread is 0 where the family is defined, NaN where it is not (H < H_r)
        assert np.array_equal(np.isnan(out["curves_std_mz"]), np.isnan(direct.curves_mz))
        assert np.nanmax(np.abs(out["curves_std_mz"])) == 0.0


def test_two_realisations_are_the_mean_of_the_two_streams(cfg, params):
    first = family_from(cfg, params)  # realisation 0: the sample's `disorder` stream
    second = family_from(cfg, params, rng=stream_rng(cfg["seed"], "disorder_realisation", SAMPLE, 1))
    out = simulate({**cfg, "realisations": 2}, params, SAMPLE)
    assert out["status"] == "ok" and out["reason"] == "" and out["realisations"] == 2
    mean = (first.curves_mz + second.curves_mz) / 2
    assert np.allclose(out["curves_mz"], mean, rtol=0, atol=1e-15, equal_nan=True)
    assert np.allclose(out["descending_mz"], (first.descending_mz + second.descending_mz) / 2, rtol=0, atol=1e-15)
    assert np.array_equal(out["image"], rasterize_grid_family(out["curves_mz"]))
    # the mean is not either family: the two realisations differ on this film
    assert not np.allclose(mean, first.curves_mz, equal_nan=True)
    # spread: the std (ddof 0) of two values is half their distance; positive on a disordered film
    assert np.allclose(out["curves_std_mz"], np.abs(first.curves_mz - second.curves_mz) / 2, atol=1e-15,
                       equal_nan=True)
    assert np.nanmax(out["curves_std_mz"]) > 0.01
    assert out["relaxations"] == first.stats["relaxations"] + second.stats["relaxations"]


def test_realisation_streams_are_distinct(cfg, params):
    assert realisation_rng(cfg, SAMPLE, 0) is None  # build_film's own `disorder` stream
    films = {}
    for sid, r in [(SAMPLE, 0), (SAMPLE, 1), (SAMPLE, 2), (SAMPLE + 1, 1)]:
        _, _, disorder = build_film(cfg, params, sid, rng=realisation_rng(cfg, sid, r))
        films[sid, r] = disorder.easy_axis
    keys = list(films)
    for a in range(len(keys)):
        for b in range(a + 1, len(keys)):
            assert not np.allclose(films[keys[a]], films[keys[b]]), (keys[a], keys[b])
    # a stream of its own: realisation 1 is not the `disorder` stream of another sample id
    assert not np.array_equal(stream_rng(7, "disorder_realisation", 3, 1).random(4),
                              stream_rng(7, "disorder", 3).random(4))


def test_a_failed_realisation_fails_the_sample(cfg, params, monkeypatch):
    real = simulate_module.simulate_realisation

    def second_diverges(config, p, sample_id, realisation=0):
        fam = real(config, p, sample_id, realisation)
        if realisation == 1:
            fam.curves_mz[3, 5] = np.nan  # a missing value above the diagonal
        return fam

    monkeypatch.setattr(simulate_module, "simulate_realisation", second_diverges)
    out = simulate({**cfg, "realisations": 3}, params, SAMPLE)
    assert out["status"] == "failed" and out["reason"].startswith("realisation 1 of 3: ValueError")

    def unconverged(config, p, sample_id, realisation=0):
        fam = real(config, p, sample_id, realisation)
        fam.stats["unconverged"] = realisation  # 0, 1, 2
        return fam

    monkeypatch.setattr(simulate_module, "simulate_realisation", unconverged)
    out = simulate({**cfg, "realisations": 3}, params, SAMPLE)
    assert out["status"] == "ok" and out["unconverged"] == 3
    assert out["reason"] == "3 relaxations hit max_iterations (realisation 1: 1, realisation 2: 2)"


# ------------------------------------------------------------------ the stages and dataset.h5
def run_chunk(cfg, tmp_path):
    """Draw, screen and simulate screening chunk 0 of ``cfg`` and merge it; returns dataset.h5's path."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    draw_stage(cfg, tmp_path / "params.parquet", chunk=0)
    screen_stage(cfg, tmp_path / "params.parquet", 0, tmp_path / "screen.parquet")
    simulate_stage(cfg, tmp_path / "params.parquet", tmp_path / "screen.parquet", 0, tmp_path / "family.h5",
                   part=0)
    merge(cfg, tmp_path / "params.parquet", [tmp_path / "screen.parquet"], [tmp_path / "family.h5"],
          tmp_path / "dataset.h5", tmp_path / "samples.parquet")
    return tmp_path / "dataset.h5"


def test_stages_and_merge_store_the_spread(cfg, tmp_path):
    small = {**cfg, "family_chunk_size": 8}  # chunk 0 (ids 0-7): sample 3 passes
    one, two = run_chunk(small, tmp_path / "one"), run_chunk({**small, "realisations": 2}, tmp_path / "two")
    with h5py.File(one, "r") as a, h5py.File(two, "r") as b:
        assert a.attrs["realisations"] == 1 and b.attrs["realisations"] == 2
        assert list(a["sample_id"][:]) == list(b["sample_id"][:]) == [3]
        assert "realisations" not in json.loads(a.attrs["config_json"])
        assert json.loads(b.attrs["config_json"])["realisations"] == 2
        assert a.attrs["config_hash"] == config_hash(physics_config({k: v for k, v in small.items()
                                                                    if k != "realisations"}))
        assert a.attrs["config_hash"] != b.attrs["config_hash"]
        for h5 in (a, b):
            spread = h5["curves_std_mz"][:]
            assert spread.dtype == np.float16 and spread.shape == h5["curves_mz"].shape
            assert np.array_equal(np.isnan(spread), np.isnan(h5["curves_mz"][:]))
        assert np.nanmax(a["curves_std_mz"][:]) == 0 and np.nanmax(b["curves_std_mz"][:]) > 0.01
        # R = 2's first sample: the mean family of simulate, stored as a single family is
        direct = simulate({**small, "realisations": 2}, draw_parameters(cfg["seed"], 3, cfg["bounds"]), 3)
        assert np.array_equal(b["images"][0], direct["image"])
        assert np.array_equal(b["curves_mz"][0], direct["curves_mz"].astype(np.float32), equal_nan=True)
    samples = pd.read_parquet(tmp_path / "two" / "samples.parquet")
    assert samples.loc[samples["in_dataset"], "family_cpu_s"].gt(0).all()  # the cost of both realisations
    # a family file of R = 2 under a config of R = 1: refused, naming the file
    d = tmp_path / "two"
    with pytest.raises(DatasetError, match="2 disorder realisations"):
        merge(small, d / "params.parquet", [d / "screen.parquet"], [d / "family.h5"], d / "other.h5",
              d / "other.parquet")


def test_llg_raw_curves_are_kept_per_realisation(cfg, tmp_path, monkeypatch):
    """The stage writes each realisation's raw (LLG) curves under raw/<sample>/<r> (simulate faked: an
    LLG family costs minutes)."""
    def fake(config, p, sample_id):
        n = config["field"]["n_fields"]
        curves = np.triu(np.ones((n, n)))
        curves[curves == 0] = np.nan
        raw = [[(np.array([0.0, 1.0]), np.array([r, 1.0]))] for r in range(2)]
        return {"sample_id": sample_id, "status": "ok", "reason": "", "image": rasterize_grid_family(curves),
                "curves_mz": curves, "descending_mz": np.ones(n), "curves_std_mz": 0 * curves, "realisations": 2,
                "family_s": 1.0, "family_cpu_s": 1.0, "relaxations": 0, "unconverged": 0, "raw_realisations": raw}

    small = {**cfg, "family_chunk_size": 8, "realisations": 2}
    draw_stage(small, tmp_path / "params.parquet", chunk=0)
    pd.DataFrame({"sample_id": [3], "screen_status": ["passed"]}).to_parquet(tmp_path / "screen.parquet")
    monkeypatch.setattr(stages_module, "simulate", fake)  # where the stage looks it up
    simulate_stage(small, tmp_path / "params.parquet", tmp_path / "screen.parquet", 0, tmp_path / "f.h5", part=0)
    with h5py.File(tmp_path / "f.h5", "r") as h5:
        assert h5.attrs["realisations"] == 2 and sorted(h5["raw/3"]) == ["0", "1"]
        assert list(h5["raw/3/1/mz"][:]) == [1.0, 1.0] and list(h5["raw/3/0/offsets"][:]) == [0, 2]


def test_slurm_runtime_scales_with_realisations(tmp_path, evaluate_slurm_resource):
    """profiles/slurm's simulate_family runtime, evaluated as Snakemake does (a Python expression with
    the job's input, built as Snakemake builds it): 240 min times the R of the job's config.json."""
    expression = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())[
        "set-resources"]["simulate_family"]["runtime"]
    path = tmp_path / "config.json"
    for cfg, minutes in (({"seed": 1}, 240), ({"seed": 1, "realisations": 4}, 960)):
        path.write_text(json.dumps(cfg))
        assert evaluate_slurm_resource(expression, path) == minutes


@pytest.mark.slow
def test_workflow_builds_a_two_realisation_dataset(tmp_path):
    """`snakemake --config realisations=2 -- results/dataset.h5` on the tiny configuration."""
    run = snakemake_process(tmp_path, "--configfile", ROOT / "config" / "test.yaml", "--config", "realisations=2",
                            "--", "results/dataset.h5", cores=2, timeout=900)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert json.loads((tmp_path / "results" / "config.json").read_text())["realisations"] == 2
    with h5py.File(tmp_path / "results" / "dataset.h5", "r") as h5:
        assert h5.attrs["realisations"] == 2 and len(h5["sample_id"]) > 0
        assert np.nanmax(h5["curves_std_mz"][:]) > 0
