"""Shipping trained models (``learn.shipped``, issue 60 item 1) without a main job: half-precision weights
answer as the float32 ones do (to a tolerance that could fail: 2e-3 in normalized units) at half the size,
a fresh run's sealed figures are compared with a manifest's by their 90 % intervals, and `--models`
resolves to the shipped set, the user's directory, or results/models where nothing is shipped."""

import json

import numpy as np
import pytest
import torch

from forcdecode.core.errors import ModelFileError
from forcdecode.learn.pipeline import train_parameter
from forcdecode.learn.predictor import load_models
from forcdecode.learn.shipped import FORMAT, MANIFEST, _copy_model, compare, resolve_models

from test_answer import NAMES, TINY, bar_films


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("ship")
    data = bar_films()
    for name in NAMES:
        train_parameter(data, name, TINY, seed=3, model_path=out / "models" / f"{name}.pt",
                        predictions_path=out / f"{name}_predictions.parquet", log=lambda *_: None)
    return data, out


def test_half_precision_weights_answer_as_the_full_ones_at_half_the_size(trained):
    data, out = trained
    half = out / "half"
    half.mkdir()
    for path in (out / "models").glob("*.pt"):
        _copy_model(path, half / path.name, half=True)
    full, small = load_models(out / "models"), load_models(half)
    images, ms = data.images[:40], data.values["Ms"][:40]
    for name in NAMES:
        a, b = full[name].predict(images, ms), small[name].predict(images, ms)
        assert np.max(np.abs(a["normalized"] - b["normalized"])) < 2e-3, name
        assert np.max(np.abs(a["normalized_90"][1] - b["normalized_90"][1])) < 5e-3, name
        assert (half / f"{name}.pt").stat().st_size < 0.7 * (out / "models" / f"{name}.pt").stat().st_size


def test_a_fresh_run_is_compared_with_the_manifest_by_its_intervals(tmp_path):
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    manifest = {"format": FORMAT, "code_commit": "abc", "config_hash": "h",
                "sealed": {"K_u": {"skill": 0.52, "ci90": [0.47, 0.56]}, "D": {"skill": 0.39, "ci90": [0.34, 0.44]}}}
    (shipped / MANIFEST).write_text(json.dumps(manifest))
    fresh = tmp_path / "results"
    fresh.mkdir()

    def metrics(k_u, d):
        (fresh / "metrics.json").write_text(json.dumps({"sealed": {"parameters": {
            "K_u": {"skill_vs_best_trivial": k_u[0], "skill_vs_best_trivial_ci90": k_u[1:]},
            "D": {"skill_vs_best_trivial": d[0], "skill_vs_best_trivial_ci90": d[1:]}}}}))

    metrics((0.50, 0.45, 0.55), (0.41, 0.36, 0.46))
    assert compare(fresh, shipped)["agree"]
    metrics((0.50, 0.45, 0.55), (0.20, 0.15, 0.25))  # D's skill fell outside the shipped interval
    result = compare(fresh, shipped)
    assert not result["agree"] and result["rows"]["K_u"]["agree"] and not result["rows"]["D"]["agree"]


def test_models_resolve_to_the_users_the_shipped_or_the_workflows(tmp_path):
    assert resolve_models("mine", tmp_path)[0].name == "mine"
    directory, line = resolve_models(None, tmp_path / "nothing-shipped")
    assert str(directory) == "results/models" and "no shipped models" in line
    (tmp_path / MANIFEST).write_text(json.dumps({"format": "other"}))
    with pytest.raises(ModelFileError, match="not a shipped-models manifest"):
        resolve_models(None, tmp_path)


def test_the_users_thickness_is_checked_against_the_models_thickness_study(tmp_path):
    import json

    import pytest

    from forcdecode.core.errors import ConfigError
    from forcdecode.learn.shipped import THICKNESS_FILE, check_thickness, models_thickness_nm

    models = tmp_path / "models"
    models.mkdir()
    assert "4 nm assumed" in check_thickness(models, None, 4.0)
    assert "the models' own" in check_thickness(models, 4.0, 4.0)
    with pytest.raises(ConfigError, match="no thickness study"):  # nothing measured: refused, with the reason
        check_thickness(models, 6.0, 4.0)
    (tmp_path / THICKNESS_FILE).write_text(json.dumps({"reference_nm": 4.0, "safe_nm": [3.0, 5.0],
                                                       "safe_mae_increase": 0.02}))
    assert models_thickness_nm(models) == 4.0
    assert "inside the models' safe range" in check_thickness(models, 3.5, 4.0)
    with pytest.raises(ConfigError, match="accepts 3-5 nm"):
        check_thickness(models, 8.0, 4.0)
    assert "OUTSIDE" in check_thickness(models, 8.0, 4.0, force=True)


def test_a_config_at_another_thickness_is_one_layer_of_that_thickness():
    import pytest

    from forcdecode.config import film_thickness_nm, load_config, shipped_config, with_thickness
    from forcdecode.core.errors import ConfigError

    cfg = load_config(shipped_config("config"))
    assert film_thickness_nm(cfg) == 4.0
    thick = with_thickness(cfg, 8.0)
    assert film_thickness_nm(thick) == 8.0 and thick["mesh"]["nx"] == cfg["mesh"]["nx"] and cfg["mesh"]["dz_nm"] == 4.0
    for bad in (0.0, -1.0, float("nan"), "x"):
        with pytest.raises(ConfigError):
            with_thickness(cfg, bad)
