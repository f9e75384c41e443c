"""Every shipped configuration passes the workflow's schema; the paper scale trains the paper's network."""

import json
from pathlib import Path

import pytest
import yaml
from snakemake.exceptions import WorkflowError
from snakemake.utils import validate
from snakemake_runs import snakemake_process

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = str(ROOT / "workflow" / "schemas" / "config.schema.yaml")


def resolved_config(workdir, *args, target="results/config.json") -> dict:
    """Snakemake with ``args`` (config files, overrides) up to ``target`` in a new ``workdir``; the
    resolved results/config.json. The jobs run this checkout's package."""
    workdir.mkdir()
    done = snakemake_process(workdir, *args, "--", target)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads((workdir / "results" / "config.json").read_text())


@pytest.mark.parametrize("name", ["config.yaml", "cluster.yaml", "paper.yaml", "test.yaml"])
def test_shipped_config_validates(name):
    config = yaml.safe_load((ROOT / "config" / name).read_text())
    validate(config, SCHEMA, set_default=True)
    assert config["learning"]["readout"] == "parabola"  # defaults filled in (no config sets it)


def test_paper_config_is_the_papers_training():
    learning = yaml.safe_load((ROOT / "config" / "paper.yaml").read_text())["learning"]
    assert (learning["model"], learning["lr"], learning["batch_size"]) == ("paper", 0.01, 500)


def test_the_cluster_default_is_the_information_maps_film_with_the_laptop_physics():
    """config/cluster.yaml is the film `box128_8nm` of `bench information` (mesh, cell, grains, protocol),
    and apart from the film and the run's size it is the laptop default: the map's bounds are its bounds."""
    from forcdecode.bench.information_films import FILMS

    cluster = yaml.safe_load((ROOT / "config" / "cluster.yaml").read_text())
    laptop = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    film = FILMS["box128_8nm"]
    assert (cluster["mesh"]["nx"], cluster["mesh"]["ny"], cluster["mesh"]["nz"]) == (film["nx"], film["ny"], film["nz"])
    assert cluster["n_grains"] == film["n_grains"] and cluster["protocol"]["name"] == film["protocol"]
    assert {k: cluster["mesh"][k] for k in ("dx_nm", "dy_nm", "dz_nm")} == \
        {k: laptop["mesh"][k] for k in ("dx_nm", "dy_nm", "dz_nm")}
    run_size = {"mesh", "n_grains", "n_samples", "family_chunk_size", "sealed"}
    assert {k: v for k, v in cluster.items() if k not in run_size} == \
        {k: v for k, v in laptop.items() if k not in run_size}
    assert cluster["sealed"]["first_sample_id"] >= cluster["n_samples"]


def test_a_wrong_learning_value_is_refused():
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["learning"]["model"] = "resnet"
    with pytest.raises(WorkflowError, match="resnet"):
        validate(config, SCHEMA)


@pytest.mark.slow  # two Snakemake runs: 62 s on the 2-core machine while a main job runs
def test_the_prior_class_reaches_the_draw_and_the_default_stays_out_of_config_json(tmp_path):
    """`prior: paper` (the default) is left out of results/config.json, so a dataset made before the key
    keeps its config.json (nothing reruns) and its config hash; `prior: perpendicular` is written there
    and the draw follows it (every K_eff > 0)."""
    import pandas as pd

    from forcdecode.core.parameters import k_eff

    def run(workdir, *config):
        chunk = "results/params/chunk_0000.parquet"
        cfg = resolved_config(workdir, "--configfile", str(ROOT / "config" / "test.yaml"),
                              *(("--config", *config) if config else ()), target=chunk)
        return cfg, pd.read_parquet(workdir / chunk)

    cfg, paper = run(tmp_path / "paper")
    assert "prior" not in cfg
    cfg, perpendicular = run(tmp_path / "perpendicular", "prior=perpendicular")
    assert cfg["prior"] == "perpendicular"
    assert (k_eff({"K_u": perpendicular["K_u"].to_numpy(), "Ms": perpendicular["Ms"].to_numpy()}) > 0).all()
    assert perpendicular["Ms"].equals(paper["Ms"]) and not perpendicular["K_u"].equals(paper["K_u"])


def test_a_configfile_on_the_command_line_replaces_the_laptop_default(tmp_path):
    """`--configfile paper.yaml` alone gives the paper's config with the schema's defaults for what it
    leaves out (255 grains, the paper's prior class), not the laptop default's keys: Snakemake extends
    a Snakefile's `configfile:` by the command line's files, so the Snakefile reads config.yaml only
    when none is given (paper runs had the laptop's 16 grains before). Without --configfile the laptop
    default is read."""
    laptop = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    paper = resolved_config(tmp_path / "paper", "--configfile", str(ROOT / "config" / "paper.yaml"))
    assert paper["n_grains"] == 255 != laptop["n_grains"] and paper["mesh"]["nx"] == 256
    assert "prior" not in paper  # the paper class, left out of config.json
    default = resolved_config(tmp_path / "default")
    assert default["n_grains"] == laptop["n_grains"] and default.get("prior", "paper") == laptop.get("prior", "paper")
    assert default["mesh"] == laptop["mesh"]
