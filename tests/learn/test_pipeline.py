"""Alice + Bob end to end on a synthetic dataset whose difficulty is visible in the image.

The target sets the row up to which the image is bright (as in test_train.py). A quarter of the
images are "featureless": their bar sits at a random row unrelated to the target, and a grey band
marks them. Alice cannot do better than a guess there; Bob, which sees the same image, must rank
those errors higher — while the conformal intervals keep their coverage and the saved model
predicts exactly what the pipeline recorded. 32×32 images keep the test fast."""

import json

import numpy as np
import pandas as pd
import pytest

from forcdecode.core.errors import DatasetError
from forcdecode.core.parameters import DEFAULT_BOUNDS, denormalize
from forcdecode.learn.data import LearningData
from forcdecode.learn.pipeline import DEFAULT_SETTINGS, train_parameter
from forcdecode.learn.predictor import ParameterModel, hamiltonian, load_models, predict_parameters
from forcdecode.learn.report import evaluate


def synthetic_dataset(n=200, seed=0, side=32) -> LearningData:
    rng = np.random.default_rng(seed)
    u = rng.random(n)
    hard = rng.random(n) < 0.25
    shown = np.where(hard, rng.random(n), u)  # featureless: the bar carries no information on u
    images = np.zeros((n, side, side), dtype=float)
    for k in range(n):
        images[k, : int(np.rint(shown[k] * (side - 1))) + 1, :] = 255
    images = np.clip(images + 10 * rng.standard_normal(images.shape), 0, 255)
    images[hard, :, -8:] = 128  # a visible marker of the featureless quarter: a grey band
    ms = rng.uniform(*DEFAULT_BOUNDS["Ms"], n)
    values = {"Ms": ms, "D": denormalize("D", u)}
    data = LearningData(images=images.astype(np.uint8), ms_norm=(ms - 2e5) / 1.2e6, values=values,
                        sample_id=np.arange(n) * 3, bounds=dict(DEFAULT_BOUNDS), config_hash="synthetic", fields_T=np.linspace(-1, 1, side))
    data.hard = hard
    return data


SETTINGS = {"width": 32, "epochs": 60, "patience": 10, "batch_size": 8, "lr": 1.0, "folds": 3, "mc_passes": 8,
            "learning_curve": [0.5, 1.0], "seeds": 2, "bootstrap": 300}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("learn")
    data = synthetic_dataset()
    metrics = train_parameter(data, "D", SETTINGS, seed=3, model_path=out / "D.pt",
                              predictions_path=out / "D_predictions.parquet", log=lambda *_: None)
    (out / "D_metrics.json").write_text(json.dumps(metrics))
    return data, metrics, out


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_alice_learns_and_reports_on_the_test_split_only(trained):
    data, metrics, out = trained
    frame = pd.read_parquet(out / "D_predictions.parquet")
    test = frame[frame["split"] == "test"]
    assert metrics["n_test"] == len(test) and 20 <= len(test) <= 40 and metrics["reported_on"] == "test"
    assert set(frame["split"]) == {"train", "validation", "calibration", "test"}
    assert metrics["mae"] == pytest.approx(np.abs(test["prediction"] - test["target"]).mean())
    assert metrics["skill"] > 0.4 and metrics["pearson_r"] > 0.7, metrics  # a quarter is unpredictable
    # out-of-fold errors exist for every training sample only
    train = frame[frame["split"] == "train"]
    assert train["oof_error"].notna().all() and frame.loc[frame["split"] != "train", "oof_error"].isna().all()
    assert metrics["bob"]["oof_mae"] == pytest.approx(train["oof_error"].mean())
    n_train = metrics["n_train"]
    assert metrics["learning_curve"]["sizes"] == [round(0.5 * n_train), n_train]
    assert np.asarray(metrics["learning_curve"]["mae"]).shape == (2, 2)  # sizes x seeds
    # the same fits scored on validation (choices are made there); the full-set point is the seed members'
    curve = metrics["learning_curve"]
    assert np.asarray(curve["mae_validation"]).shape == (2, 2)
    val = frame[frame["split"] == "validation"]
    assert curve["mae_validation"][-1][0] == pytest.approx(np.abs(val["prediction"] - val["target"]).mean())
    assert curve["mae"][-1][0] == pytest.approx(metrics["mae"])
    # each fit's validation predictions are kept (paired comparisons of runs): they give its MAE
    kept = np.asarray(curve["validation_predictions"])
    assert kept.shape == (2, 2, len(val)) and curve["validation_sample_ids"] == val["sample_id"].tolist()
    assert np.abs(kept - np.asarray(curve["validation_truth"])).mean(axis=2) == pytest.approx(
        np.asarray(curve["mae_validation"]))
    prior = np.median(frame.loc[frame["split"] == "train", "target"])
    assert curve["baselines_validation"]["prior"] == pytest.approx(np.abs(prior - val["target"]).mean())
    assert curve["baselines_validation"]["ms_only"] == pytest.approx(
        np.abs(val["ms_only_prediction"] - val["target"]).mean())


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_baselines_and_intervals(trained):
    """The image carries the target: the network beats the M_s-only baseline with an interval above 0,
    and shuffling the test images destroys the skill."""
    _, metrics, _ = trained
    base = metrics["baselines"]
    assert set(base) >= {"prior", "ms_only", "images_shuffled"}
    assert metrics["skill_vs_ms_only_ci90"][0] > 0.2, metrics["skill_vs_ms_only_ci90"]
    assert base["images_shuffled"] > 2 * metrics["mae"] and base["ms_only"] > 2 * metrics["mae"]
    low, high = metrics["mae_ci90"]
    assert low < metrics["mae"] < high and high - low < metrics["mae"]
    assert len(metrics["seeds"]["mae"]) == 2 and metrics["seeds"]["mae"][0] == pytest.approx(metrics["mae"])
    for method in ("bob", "vhat", "mc_dropout", "ensemble"):
        row = metrics["uncertainty_baselines"][method]
        assert 0 < row["width_90"] < 1 and np.isfinite(row["spearman"])


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_bob_ranks_the_hard_inputs(trained):
    data, metrics, out = trained
    frame = pd.read_parquet(out / "D_predictions.parquet")
    evaluation = frame["split"] != "train"
    hard = data.hard[evaluation.to_numpy()]
    bob = frame.loc[evaluation, "bob_error"].to_numpy()
    assert np.median(bob[hard]) > 1.1 * np.median(bob[~hard])
    assert metrics["bob"]["bob_spearman"] > 0.15
    assert metrics["bob"]["retention"]["area_bob"] < metrics["bob"]["retention"]["area_random"]


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_conformal_intervals_cover_two_sided_and_are_narrower_than_trivial(trained):
    """Coverage inside its binomial band on both sides (an interval that always covers, such as the
    trivial [0, 1], fails the width bound; one that is too narrow fails the lower side)."""
    from scipy.stats import binom

    _, metrics, _ = trained
    bob, n = metrics["bob"], metrics["n_test"]
    for level, key in ((0.9, "coverage_90"), (0.68, "coverage_68")):
        low, high = binom.ppf(0.01, n, level) / n, binom.ppf(0.99, n, level) / n
        assert low <= bob[key] <= high, (key, bob[key], low, high)
    assert 0 < bob["width_68"] < bob["width_90"] < 0.6  # the trivial interval [0, 1] has width 1
    assert metrics["coverage_90"] == bob["coverage_90"]
    assert metrics["coverage_90_ci90"][0] <= bob["coverage_90"] <= metrics["coverage_90_ci90"][1]


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_saved_model_predicts_what_the_pipeline_recorded(trained):
    data, _, out = trained
    frame = pd.read_parquet(out / "D_predictions.parquet")
    model = ParameterModel.load(out / "D.pt")
    result = model.predict(data.images[:5], data.values["Ms"][:5])
    np.testing.assert_allclose(result["normalized"], frame["prediction"][:5], atol=1e-6)
    np.testing.assert_allclose(result["bob_error"], frame["bob_error"][:5], atol=1e-6)
    assert np.all(result["normalized_90"][0] <= result["normalized"]) and np.all(result["normalized"] <= result["normalized_90"][1])
    models = load_models(out)
    prediction = predict_parameters(models, data.images[0], data.values["Ms"][0])
    assert prediction["D"]["value"] == pytest.approx(denormalize("D", frame["prediction"][0]), rel=1e-5)
    assert hamiltonian(prediction)["Ms"] == data.values["Ms"][0]


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_the_sealed_set_is_scored_by_the_frozen_model(trained):
    """A sealed draw of the same synthetic physics (other ids) scored by the saved model: the baselines are
    the pipeline's own (fitted on train, k on validation), the figures agree with the test split's."""
    from forcdecode.learn.sealed import alice_sealed_metrics

    data, metrics, out = trained
    sealed = synthetic_dataset(n=120, seed=5)
    sealed.sample_id = 100_000 + np.arange(120)
    result = alice_sealed_metrics(load_models(out), data, sealed, seed=3, settings={**DEFAULT_SETTINGS, **SETTINGS},
                                  n_boot=300)
    row = result["parameters"]["D"]
    assert row["n_sealed"] == 120 and row["baselines"]["ms_only_k"] == metrics["baselines"]["ms_only_k"]
    assert metrics["mae_ci90"][0] - 0.05 <= row["mae"] <= metrics["mae_ci90"][1] + 0.05
    assert row["skill_vs_best_trivial_ci90"][0] > 0 and row["mae"] < row["baselines"]["images_shuffled"]
    assert 0.75 <= row["coverage_90"] <= 1.0


@pytest.mark.slow  # the `trained` fixture: ~140 s of training on this 2-core machine
def test_evaluate_writes_metrics_and_figures(trained, tmp_path):
    _, _, out = trained
    metrics = evaluate([out / "D_metrics.json"], [out / "D_predictions.parquet"], tmp_path / "metrics.json", tmp_path / "fig")
    stored = json.loads((tmp_path / "metrics.json").read_text())["parameters"]["D"]
    for key in ("mae", "pearson_r", "skill", "n_test", "bob_spearman", "coverage_68", "coverage_90"):
        assert np.isfinite(stored[key]), key
    assert stored["paper"] == {"mae": 0.07, "pearson_r": 0.90}
    for name in ("figure3", "figure5bc", "learning_curve", "retention"):
        assert (tmp_path / "fig" / f"{name}.png").stat().st_size > 10_000
    assert "| D |" in (tmp_path / "metrics.md").read_text() and metrics["parameters"]["D"]["n_test"] == 30


def test_too_small_a_dataset_is_a_clear_error(tmp_path):
    data = synthetic_dataset(6)
    with pytest.raises(DatasetError, match="6 FORC families"):
        train_parameter(data, "D", SETTINGS, 0, tmp_path / "m.pt", tmp_path / "p.parquet", log=lambda *_: None)


def test_leakage_canary_test_targets_never_enter_the_fit(tmp_path):
    """Randomising the test split's targets leaves the weights, the conformal quantiles and every
    calibration-side output bit for bit unchanged (only the reported test figures move)."""
    import torch

    from forcdecode.learn.splits import assign_splits

    settings = {**SETTINGS, "epochs": 6, "patience": 3, "folds": 2, "mc_passes": 3, "learning_curve": [1.0],
                "bootstrap": 100}
    runs = []
    for randomise in (False, True):
        data = synthetic_dataset(n=120, seed=5)
        if randomise:
            test = assign_splits(data.sample_id, 9, DEFAULT_SETTINGS["split"])["test"]
            data.values["D"] = data.values["D"].copy()
            data.values["D"][test] = np.random.default_rng(1).permutation(data.values["D"][test])[::-1] * 0.5
        out = tmp_path / str(randomise)
        metrics = train_parameter(data, "D", settings, seed=9, model_path=out / "D.pt",
                                  predictions_path=out / "D_predictions.parquet", log=lambda *_: None)
        runs.append((torch.load(out / "D.pt", weights_only=False), pd.read_parquet(out / "D_predictions.parquet"), metrics))
    (a, frame_a, metrics_a), (b, frame_b, metrics_b) = runs
    for key in ("alice_state", "bob_state"):
        for name, tensor in a[key].items():
            assert torch.equal(tensor, b[key][name]), (key, name)
    assert a["conformal"] == b["conformal"] and a["validation_errors"] == b["validation_errors"]
    for column in ("prediction", "bob_error", "low_90", "high_90", "mc_std", "vhat_std", "ensemble_std", "ms_only_prediction"):
        np.testing.assert_array_equal(frame_a[column].to_numpy(), frame_b[column].to_numpy(), err_msg=column)
    assert metrics_a["mae"] != metrics_b["mae"]  # the canary did change what is reported
