"""The shipped models (issue 60 item 1): present in the package, loadable, and their manifest true to the
code and to the files beside it."""

import json

import pytest

from forcdecode.config import film_thickness_nm, load_config, shipped_config
from forcdecode.core.parameters import TARGETS
from forcdecode.dataset.merge import config_hash, physics_config
from forcdecode.learn.predictor import load_models, models_prior_class
from forcdecode.learn.shipped import FORMAT, SHIPPED, read_manifest, resolve_models, sha256

MAX_WHEEL_MODELS_MB = 40.0
"""The shipped set's size budget: the wheel must stay under 50 MB with the code and configs beside it."""


@pytest.fixture(scope="module")
def manifest():
    return read_manifest(SHIPPED)


def test_the_manifest_describes_the_laptop_default_the_code_trains(manifest):
    cfg = load_config(shipped_config("config"))
    assert manifest["format"] == FORMAT
    physics = manifest["physics_config"]
    assert manifest["config_hash"] == config_hash(physics_config(physics)) == manifest["model_config_hashes"][0]
    changed = {k: (v, cfg.get(k)) for k, v in physics.items() if k not in ("kernel_cache_dir", "results_dir")
               and (cfg.get(k) != v if not isinstance(v, dict) else any(cfg.get(k, {}).get(a) != b for a, b in v.items()))}
    assert not changed, f"the laptop config changed since shipping (re-train and ship): {changed}"
    assert manifest["prior_class"] == cfg["prior"]
    assert manifest["film"]["thickness_nm"] == film_thickness_nm(cfg) and manifest["film"]["mesh"] == cfg["mesh"]
    assert len(manifest["code_commit"]) == 40 and len(manifest["dataset_sha256"]) == 64
    assert sorted(manifest["parameters"]) == sorted(TARGETS)
    for name in ("K_u", "D", "sigma_w"):  # the sealed figures the models scored, with their intervals
        row = manifest["sealed"][name]
        assert row["ci90"][0] <= row["skill"] <= row["ci90"][1]


def test_every_file_is_the_one_the_manifest_names(manifest):
    on_disk = {str(p.relative_to(SHIPPED)) for p in SHIPPED.rglob("*") if p.is_file()
               and p.name != "manifest.json"}
    assert on_disk == set(manifest["files"])
    total = 0
    for name, row in manifest["files"].items():
        assert sha256(SHIPPED / name) == row["sha256"], name
        total += row["bytes"]
    assert total / 1e6 < MAX_WHEEL_MODELS_MB


def test_the_shipped_models_load_and_answer(manifest):
    models_dir, line = resolve_models(None)
    assert models_dir == SHIPPED / "models" and "shipped" in line
    models = load_models(models_dir)
    assert sorted(models) == sorted(TARGETS) and models_prior_class(models) == manifest["prior_class"]
    image = (json.loads((SHIPPED / "models" / "ood_image_reference.json").read_text())["key"])
    assert image["shipped"] is True
    # half precision measured, not assumed: on average the stored weights move a prediction by < 0.1 % of a prior
    # width and no MAE by 0.2 % (the largest single move, σ_K on one family of 300, is 1.8 %)
    effect = manifest["half_precision_effect"]
    assert effect["n"] >= 100
    for name in TARGETS:
        assert effect[name]["mean_abs_du"] < 0.001 and abs(effect[name]["mae_change"]) < 0.002, name


def test_the_readmes_headline_figures_are_the_manifests(manifest):
    """The README's sealed-set table and posterior line quote the shipped manifest, digit for digit."""
    import re
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    rows = {m.group(1): m for m in re.finditer(
        r"^\| [^|]+ \| `(\w+)` \| ([\d.]+) \| \**([+-][\d.]+)\** \[([+-][\d.]+), ([+-][\d.]+)\] \|", readme, re.M)}
    assert set(rows) >= {"K_u", "D", "A_ex", "N_pin", "sigma_w", "delta_w", "D_over_Dc", "Q"}, sorted(rows)
    for name, m in rows.items():
        figure = manifest["sealed"][name]
        assert m.group(2) == f"{figure['mae']:.3f}", name
        shown = [float(m.group(k)) for k in (3, 4, 5)]
        assert shown == pytest.approx([figure["skill"], *figure["ci90"]], abs=0.0051), name
    coverage = manifest["posterior_sealed"]["coverage_90"].values()
    line = re.search(r"90 % intervals cover ([\d.]+)–([\d.]+) of the sealed families.*?TARP ([\d.]+)", readme, re.S)
    assert line, "the README's posterior coverage line"
    assert float(line.group(1)) == pytest.approx(min(coverage), abs=0.0051)
    assert float(line.group(2)) == pytest.approx(max(coverage), abs=0.0051)
    assert float(line.group(3)) == pytest.approx(manifest["posterior_sealed"]["tarp_coverage_90"], abs=0.0051)
