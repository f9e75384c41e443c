"""The FORC posterior stage end to end on images whose content is known: the image tells K_u (a bar
whose height is u_K) and nothing about D (pure noise). The posterior must be narrow and accurate
for K_u, prior-wide for D, calibrated on the workflow's test split (the hash split Alice uses),
reproduce its draws after a save and a reload, and refuse bad inputs with typed errors."""

import json

import h5py
import numpy as np
import pytest
import torch

from forcdecode.cli import main
from forcdecode.core.errors import ConfigError, DatasetError, ModelFileError, OutOfDomainError
from forcdecode.core.parameters import DEFAULT_BOUNDS, denormalize, normalize
from forcdecode.learn.data import LearningData
from forcdecode.learn.posterior import (PosteriorEstimator, PosteriorFit, fit_posterior, from_latent, posterior_settings,
                                        summarize, posterior_prediction, to_latent, train_posterior)
from forcdecode.learn.scoring import binomial_band
from forcdecode.learn.splits import assign_splits

SIDE = 16
SETTINGS = {"parameters": ["K_u", "D"], "width": 16, "dropout": 0.0, "epochs": 60, "patience": 10, "batch_size": 16,
            "lr": 1e-3, "transforms": 2, "hidden": 32, "draws": 300}
LEARNING = {"split": [0.55, 0.15, 0.15, 0.15], "protocol": "holdout"}
SEED = 11


def bar_dataset(n=320, seed=0) -> LearningData:
    """Rows 0..round(u_K (SIDE − 1)) bright, noise of 20 grey levels; D drawn independently of the image."""
    rng = np.random.default_rng(seed)
    u_k, u_d = rng.random(n), rng.random(n)
    images = np.zeros((n, SIDE, SIDE))
    for k, row in enumerate(np.rint(u_k * (SIDE - 1)).astype(int)):
        images[k, :row + 1] = 235
    images = (images + rng.integers(0, 20, images.shape)).astype(np.uint8)
    ms = rng.uniform(*DEFAULT_BOUNDS["Ms"], n)
    values = {"Ms": ms, "K_u": denormalize("K_u", u_k), "D": denormalize("D", u_d)}
    return LearningData(images=images, ms_norm=normalize("Ms", ms), values=values, sample_id=np.arange(n) * 7 + 3,
                        bounds=dict(DEFAULT_BOUNDS), config_hash="bars", fields_T=np.linspace(-1, 1, SIDE))


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("posterior")
    data = bar_dataset()
    # every fitted map applied (gate 1): the stage's maps are near the identity, and the tests below check
    # how a map is fitted, saved and applied; the gate's own rule is tested in test_posterior_calibration.py
    metrics = train_posterior(data, {**SETTINGS, "recalibration_gate_alpha": 1.0}, LEARNING, SEED, out / "model.pt",
                              out / "metrics.json",
                              out / "figures" / "posterior_calibration.png", log=lambda *_: None)
    return data, metrics, out


def test_accurate_where_the_image_tells_prior_wide_where_it_does_not(stage):
    _, metrics, _ = stage
    k, d = metrics["per_parameter"]["K_u"], metrics["per_parameter"]["D"]
    assert k["mae_median"] < 0.06 and k["mae_mean"] < 0.06, k          # a bar of 16 rows: ±1/32 at best
    assert d["mae_median"] > 0.17, d                                     # the prior's MAE is 0.25
    assert k["width_90"] < 0.3 and d["width_90"] > 0.7, (k, d)           # the prior's 90 % width is 0.9
    band = binomial_band(metrics["n_test"], 0.9, level=0.99)
    for row in (k, d):
        assert band[0] <= row["coverage_90"] <= band[1], row
        assert row["sbc_ks_p"] > 0.001, row
        assert set(row) >= {"mae_mean", "mae_median", "sbc_ks_p", "coverage_50", "coverage_68", "coverage_90", "width_90"}


def test_calibrated_on_alices_test_split_and_files_written(stage):
    data, metrics, out = stage
    splits = assign_splits(data.sample_id, SEED, LEARNING["split"], "holdout")
    assert metrics["sample_id_test"] == data.sample_id[splits["test"]].tolist()
    assert metrics["n_train"] + metrics["n_recalibration_holdout"] == len(splits["train"])
    assert metrics["n_validation"] == len(splits["validation"])
    # a quarter of train held out from the flow for its recalibration (binomial, 178 families: 99.9 % band)
    assert 0.12 < metrics["n_recalibration_holdout"] / len(splits["train"]) < 0.38
    on_disk = json.loads((out / "metrics.json").read_text())
    assert on_disk["per_parameter"] == json.loads(json.dumps(metrics["per_parameter"]))
    assert (out / "figures" / "posterior_calibration.png").read_bytes()[:4] == b"\x89PNG"
    assert 0 <= metrics["best_epoch"] < metrics["epochs_run"] <= SETTINGS["epochs"]
    regression = metrics["summary_regression"]
    assert regression["best_epoch"] >= 0 and regression["validation_mse"] < 1.0 and metrics["summary"] == "features"


def test_a_reloaded_model_reproduces_its_draws(stage):
    data, _, out = stage
    est = PosteriorEstimator.load(out / "model.pt")
    again = PosteriorEstimator.load(out / "model.pt")
    first = est.sample(data.images[:5], data.ms_norm[:5], 50, seed=4)
    np.testing.assert_array_equal(first, again.sample(data.images[:5], data.ms_norm[:5], 50, seed=4))
    assert not np.array_equal(first, est.sample(data.images[:5], data.ms_norm[:5], 50, seed=5))
    assert first.shape == (5, 50, 2) and est.names == ("K_u", "D") and est.metadata["config_hash"] == "bars"
    # the summary in SI: the K_u median maps back through the log-scale bounds
    summary = summarize(first[0], est.names, est.bounds)
    assert summary["parameters"]["K_u"]["median_value"] == pytest.approx(
        denormalize("K_u", np.median(first[0, :, 0])), rel=1e-9)
    assert np.asarray(summary["correlation"]["matrix"]).shape == (2, 2)


def test_the_recalibration_is_fitted_on_held_out_splits_saved_and_reported_beside_the_flow(stage):
    """train_posterior fits the Beta recalibration on the calibration split and the part of train held out
    from the flow (families that chose nothing; validation stopped the training),
    saves it with the model, reports the flow's own test calibration beside the recalibrated one, and
    ``recalibrated=False`` gives the flow's draws (the law ``log_prob`` is the density of)."""
    data, metrics, out = stage
    est = PosteriorEstimator.load(out / "model.pt")
    splits = assign_splits(data.sample_id, SEED, LEARNING["split"], "holdout")
    recal = metrics["recalibration"]
    assert recal["n"] == len(splits["calibration"]) + metrics["n_recalibration_holdout"]
    assert recal["fitted_on"] == "calibration split + train held out from the flow"
    assert est.recalibration == recal["beta"] and set(recal["beta_fitted"]) == {"K_u", "D"}
    # applied exactly where the likelihood-ratio test supports the map at the schema's level
    assert set(recal["beta"]) == {n for n, p in recal["likelihood_ratio_p"].items() if p < recal["gate_alpha"]}
    assert recal["gate_alpha"] == 1.0 and set(recal["beta"]) == {"K_u", "D"}
    assert posterior_settings()["recalibration_gate_alpha"] == 0.05 and posterior_settings()["recalibration_holdout"] == 0.25
    for a, b in recal["beta_fitted"].values():
        assert 0.3 < a < 3.0 and 0.3 < b < 3.0
    assert set(metrics["flow_without_recalibration"]["per_parameter"]) == {"K_u", "D"}
    flow = est.sample(data.images[:3], data.ms_norm[:3], 200, seed=4, recalibrated=False)
    mapped = est.sample(data.images[:3], data.ms_norm[:3], 200, seed=4)
    # the same flow draws, each coordinate mapped monotonically: the rank order is kept (ordered by the
    # flow's draws, the mapped ones never decrease beyond float rounding; near-equal draws may tie)
    in_flow_order = np.take_along_axis(mapped, np.argsort(flow, axis=1, kind="stable"), axis=1)
    assert np.diff(in_flow_order, axis=1).min() >= -1e-6
    assert not np.array_equal(flow, mapped)
    # a few draws are mapped through reference draws: reproducible, inside [0, 1]
    few = est.sample(data.images[:3], data.ms_norm[:3], 3, seed=8)
    np.testing.assert_array_equal(few, est.sample(data.images[:3], data.ms_norm[:3], 3, seed=8))
    assert few.shape == (3, 3, 2) and np.all((few >= 0) & (few <= 1))


def test_the_crossfit_and_joint_summaries_learn_too(tmp_path):
    """The two other conditioning modes on a smaller set and budget: K_u well below the prior's 0.25."""
    data = bar_dataset(n=160, seed=1)
    for summary in ("crossfit", "joint"):
        metrics = train_posterior(data, {**SETTINGS, "summary": summary, "folds": 2, "epochs": 40}, LEARNING, SEED,
                                  tmp_path / f"{summary}.pt", tmp_path / f"{summary}.json", tmp_path / f"{summary}.png",
                                  log=lambda *_: None)
        assert metrics["summary"] == summary and metrics["per_parameter"]["K_u"]["mae_median"] < 0.1, metrics
        assert PosteriorEstimator.load(tmp_path / f"{summary}.pt").architecture["summary"] == summary


def test_the_latent_map_is_a_bijection_onto_the_bounds():
    u = np.array([0.0, 1e-4, 0.3, 0.999, 1.0])
    np.testing.assert_allclose(from_latent(to_latent(u)), u, atol=1e-12)
    assert np.isfinite(to_latent(u)).all() and from_latent(np.array([-50.0, 50.0])).tolist() == [0.0, 1.0]


def test_bad_inputs_raise_typed_errors(stage, tmp_path):
    data, _, out = stage
    est = PosteriorEstimator.load(out / "model.pt")
    with pytest.raises(OutOfDomainError, match="16×16"):
        est.sample(np.zeros((2, 32, 32), np.uint8), [0.5, 0.5], 10, seed=0)
    with pytest.raises(OutOfDomainError, match="not finite"):
        est.sample(data.images[:2], [np.nan, 0.5], 10, seed=0)
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(ModelFileError):
        PosteriorEstimator.load(tmp_path / "junk.pt")
    torch.save({"format": "forcdecode-alice-bob/1"}, tmp_path / "alice.pt")
    with pytest.raises(ModelFileError, match="not a forcdecode posterior"):
        PosteriorEstimator.load(tmp_path / "alice.pt")
    with pytest.raises(ModelFileError):
        PosteriorEstimator.load(tmp_path / "missing.pt")
    with pytest.raises(ConfigError, match="posterior.width"):
        posterior_settings({"width": 0})
    with pytest.raises(ConfigError, match="posterior"):
        posterior_settings({"bogus": 1})
    u = np.stack([data.target("K_u"), data.target("D")], axis=1)
    with pytest.raises(DatasetError, match="inside"):
        fit_posterior(data.images, data.ms_norm, u + 0.5, np.arange(10), np.arange(10, 20),
                      PosteriorFit(names=("K_u", "D")))
    with pytest.raises(DatasetError, match="at least"):
        train_posterior(bar_dataset(n=5), SETTINGS, LEARNING, SEED, tmp_path / "m.pt", tmp_path / "m.json",
                        tmp_path / "f.png", log=lambda *_: None)


def write_dataset_h5(path, data: LearningData) -> None:
    """The fields of dataset.h5 that ``load_dataset`` reads."""
    columns = ["Ms", "K_u", "D"]
    with h5py.File(path, "w") as h5:
        h5["images"] = data.images
        h5["sample_id"] = data.sample_id
        h5["fields_T"] = data.fields_T
        h5["parameters"] = np.stack([data.values[c] for c in columns], axis=1)
        h5["parameters"].attrs["columns"] = columns
        h5.attrs["config_json"] = json.dumps({"seed": SEED})
        h5.attrs["config_hash"] = "bars"


def test_the_command_line_stage(tmp_path, capsys):
    data = bar_dataset(n=120)
    write_dataset_h5(tmp_path / "dataset.h5", data)
    (tmp_path / "learning.json").write_text(json.dumps({"seed": SEED, "learning": LEARNING}))
    quick = json.dumps({**SETTINGS, "epochs": 3, "draws": 20})
    args = ["learn", "posterior", "--config", str(tmp_path / "learning.json"), "--dataset", str(tmp_path / "dataset.h5"),
            "--model", str(tmp_path / "posterior" / "model.pt"), "--metrics", str(tmp_path / "posterior" / "metrics.json"),
            "--figures", str(tmp_path / "posterior" / "figures")]
    assert main([*args, "--settings", quick]) == 0
    metrics = json.loads((tmp_path / "posterior" / "metrics.json").read_text())
    assert set(metrics["per_parameter"]) == {"K_u", "D"} and metrics["n_draws"] == 20
    assert (tmp_path / "posterior" / "figures" / "posterior_calibration.png").exists()
    assert PosteriorEstimator.load(tmp_path / "posterior" / "model.pt").names == ("K_u", "D")
    capsys.readouterr()
    assert main([*args, "--settings", json.dumps({"draws": 1})]) == 2
    assert capsys.readouterr().err.startswith("error: posterior settings: invalid value at posterior.draws")
    assert main([*args, "--settings", "{not json"]) == 2


def test_predict_with_the_posterior_estimator(stage, tmp_path, capsys):
    data, metrics, out = stage
    index = int(np.flatnonzero(np.isin(data.sample_id, metrics["sample_id_test"]))[0])
    np.save(tmp_path / "image.npy", data.images[index])
    ms_kA_m = float(data.values["Ms"][index]) / 1e3
    args = ["predict", str(tmp_path / "image.npy"), "--Ms-kA-m", f"{ms_kA_m!r}", "--estimator", "posterior",
            "--posterior", str(out / "model.pt"), "--draws", "500"]
    assert main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    truth = float(data.values["K_u"][index])
    k = result["K_u"]
    assert k["interval_90"][0] <= k["interval_68"][0] <= k["value"] <= k["interval_68"][1] <= k["interval_90"][1]
    assert abs(normalize("K_u", k["value"]) - data.target("K_u")[index]) < 0.1, (k, truth)
    assert k["normalized"] == pytest.approx(normalize("K_u", k["value"]), abs=1e-9)
    assert result["posterior_correlation"]["names"] == ["K_u", "D"] and result["estimator"] == "posterior"
    assert main([*args, "--json"]) == 0 and json.loads(capsys.readouterr().out) == result  # same seed, same draws
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "K_u" in table and "J/m^3" in table
    assert main([*args[:-4], "--posterior", str(tmp_path / "none.pt")]) == 2
    assert "cannot load posterior model" in capsys.readouterr().err


def test_intervals_conformalized_on_the_calibration_split(stage):
    """The calibration split (held out from the flow) widens the reported intervals; the widening is
    saved with the model, measured on test, and carried into a prediction."""
    data, metrics, out = stage
    splits = assign_splits(data.sample_id, SEED, LEARNING["split"], "holdout")
    conformal = metrics["conformal"]
    assert conformal["n_calibration"] == len(splits["calibration"])
    for tag in ("50", "68", "90"):
        assert set(conformal["widening"][tag]) == set(metrics["parameters"])
    for row in metrics["per_parameter"].values():
        assert 0.0 <= row["coverage_90_conformal"] <= 1.0 and 0.0 < row["width_90_conformal"] <= 1.0
    est = PosteriorEstimator.load(out / "model.pt")
    assert est.metadata["conformal"] == conformal
    k = int(splits["test"][0])
    result = posterior_prediction(est, data.images[k], float(denormalize("Ms", data.ms_norm[k], data.bounds)), n_draws=500)
    row = result["K_u"]
    q = conformal["widening"]["90"]["K_u"]
    lo, hi = row["interval_90_normalized"]
    assert row["interval_90_conformal_normalized"] == pytest.approx([max(0.0, lo - q), min(1.0, hi + q)])
    assert row["interval_90_conformal"] == pytest.approx(
        [denormalize("K_u", v, est.bounds) for v in row["interval_90_conformal_normalized"]])


def test_split_diagnostics_tell_a_training_marginal_unlike_the_held_out_one(stage):
    """The image tells nothing of D, so the posterior of D is the training families' marginal. A
    'training split' of the families with the highest D must show up twice: its D marginal differs
    from the rest (two-sample KS), and its truths sit above the posterior draws (PIT piled at the top
    fifth); K_u, which the image tells, stays calibrated on both."""
    from forcdecode.learn.posterior import split_diagnostics

    data, metrics, out = stage
    est = PosteriorEstimator.load(out / "model.pt")
    u = np.stack([data.target(n) for n in est.names], axis=1)
    d = list(est.names).index("D")
    order = np.argsort(u[:, d])
    splits = {"train": order[-60:], "validation": order[:60], "calibration": order[60:120], "test": order[120:180]}
    diag = split_diagnostics(est, data, u, splits, draws=200, seed=1)
    assert diag["train_vs_held_out_ks_p"]["D"] < 1e-6 and diag["train_vs_held_out_ks_p"]["K_u"] > 0.01, diag
    assert diag["pit"]["train"]["D"]["ks_p"] < 1e-4 and diag["pit"]["train"]["D"]["per_fifth"][-1] > 30, diag["pit"]
    assert diag["pit"]["train"]["K_u"]["ks_p"] > 0.01, diag["pit"]
    # the workflow's own split: iid families, nothing to tell apart
    reported = metrics["split_diagnostics"]
    assert set(reported["pit"]) == {"train", "validation", "calibration", "test"}
    assert min(reported["train_vs_held_out_ks_p"].values()) > 0.001, reported["train_vs_held_out_ks_p"]


def _fresh(n=400, seed=5, first_id=100_000):
    """A fresh draw of the same generator: other random numbers, ids outside the training dataset's."""
    import dataclasses

    data = bar_dataset(n=n, seed=seed)
    return dataclasses.replace(data, sample_id=np.arange(n) + first_id)


class ExactBarPosterior:
    """The exact posterior of ``bar_dataset``: the bar's height r = round(u_K · 15) leaves u_K uniform on
    [(r − ½)/15, (r + ½)/15] ∩ [0, 1] (the noise never hides a row), and D uniform on [0, 1]."""

    names = ("K_u", "D")

    recalibration = None

    def __init__(self, shift=0.0):
        self.metadata, self.shift = {"config_hash": "bars", "sample_ids_fitted": [3]}, shift

    def sample(self, images, ms_norm, n_draws, seed, recalibrated=True):
        rng = np.random.default_rng(seed)
        rows = (np.asarray(images) > 200).all(axis=2).sum(axis=1) - 1
        low, high = np.clip((rows - 0.5) / (SIDE - 1), 0, 1), np.clip((rows + 0.5) / (SIDE - 1), 0, 1)
        k = low[:, None] + (high - low)[:, None] * rng.random((len(rows), n_draws))
        return np.stack([np.clip(k + self.shift, 0, 1), rng.random((len(rows), n_draws))], axis=2)


def test_a_fresh_draw_scores_the_exact_posterior_calibrated_and_a_biased_one_not():
    from forcdecode.learn.posterior_check import check_lines, fresh_calibration

    fresh = _fresh(n=600)
    metrics = fresh_calibration(ExactBarPosterior(), fresh, seed=SEED, draws=400, levels=(0.5, 0.9))
    band = binomial_band(len(fresh), 0.9, level=0.99)
    for name in ("K_u", "D"):
        row = metrics["per_parameter"][name]
        assert band[0] <= row["coverage_90"] <= band[1] and row["sbc_ks_p"] > 0.001, (name, row)
        assert sum(metrics["pit_histogram"][name]) == len(fresh)
    assert metrics["n_fresh"] == 600 and metrics["sample_id_range"] == [100_000, 100_599]
    assert metrics["ood_false_alarm_fraction"] is None          # no OOD reference in this posterior
    assert any("fresh families" in line for line in check_lines(metrics))
    # the exact posterior moved up by 0.1 in K_u (1.5 cells): SBC and coverage must both see it
    biased = fresh_calibration(ExactBarPosterior(shift=0.1), fresh, seed=SEED, draws=400, levels=(0.5, 0.9))
    assert biased["per_parameter"]["K_u"]["sbc_ks_p"] < 1e-3 and biased["per_parameter"]["K_u"]["coverage_90"] < 0.2
    assert biased["per_parameter"]["D"] == metrics["per_parameter"]["D"]


def test_the_trained_posterior_on_a_fresh_draw(stage):
    """The toy flow on 400 fresh families: accurate where the image tells, and the OOD check's false
    alarms on in-distribution families near its α."""
    from forcdecode.learn.posterior_check import fresh_calibration

    _, _, out = stage
    metrics = fresh_calibration(PosteriorEstimator.load(out / "model.pt"), _fresh(), seed=SEED, draws=300)
    assert metrics["per_parameter"]["K_u"]["mae_median"] < 0.04 and metrics["per_parameter"]["D"]["mae_median"] > 0.17
    assert 0.0 <= metrics["ood_false_alarm_fraction"] <= 0.15


def test_a_fresh_draw_must_be_fresh_and_of_the_same_physics(stage):
    import dataclasses

    from forcdecode.learn.posterior_check import fitted_sample_ids, fresh_calibration

    data, _, out = stage
    est = PosteriorEstimator.load(out / "model.pt")
    splits = assign_splits(data.sample_id, SEED, LEARNING["split"])
    # saved with the model: the calibration split too, since the recalibration was fitted on it
    fitted = np.sort(data.sample_id[np.union1d(np.union1d(splits["train"], splits["validation"]), splits["calibration"])])
    assert np.array_equal(fitted_sample_ids(est), fitted)
    with pytest.raises(DatasetError, match="used to fit the posterior"):
        fresh_calibration(est, data, seed=SEED, draws=20)
    # families of the test split were not fitted on: allowed
    test_only = dataclasses.replace(data, images=data.images[splits["test"]], ms_norm=data.ms_norm[splits["test"]],
                                    values={k: v[splits["test"]] for k, v in data.values.items()},
                                    sample_id=data.sample_id[splits["test"]])
    assert fresh_calibration(est, test_only, seed=SEED, draws=20)["n_fresh"] == len(splits["test"])
    with pytest.raises(DatasetError, match="another configuration"):
        fresh_calibration(est, dataclasses.replace(_fresh(n=30), config_hash="other"), seed=SEED, draws=20)
    older = PosteriorEstimator.load(out / "model.pt")
    older.metadata.pop("sample_ids_fitted")
    with pytest.raises(DatasetError, match="--training-dataset"):
        fresh_calibration(older, _fresh(n=30), seed=SEED, draws=20)
    with pytest.raises(DatasetError, match="used to fit"):       # an older model: every training id excluded
        fresh_calibration(older, test_only, seed=SEED, draws=20, training_data=data)
    with pytest.raises(ConfigError, match="at least 2 draws"):
        fresh_calibration(est, test_only, seed=SEED, draws=1)


def test_the_fresh_check_command(stage, tmp_path, capsys):
    _, _, out = stage
    write_dataset_h5(tmp_path / "fresh.h5", _fresh(n=60))
    args = ["learn", "posterior-check", "--posterior", str(out / "model.pt"), "--dataset", str(tmp_path / "fresh.h5"),
            "--out", str(tmp_path / "fresh.json"), "--figure", str(tmp_path / "fresh.png"), "--draws", "50"]
    assert main(args) == 0
    metrics = json.loads((tmp_path / "fresh.json").read_text())
    assert metrics["n_fresh"] == 60 and set(metrics["per_parameter"]) == {"K_u", "D"}
    assert (tmp_path / "fresh.png").exists() and "fresh families" in capsys.readouterr().out
    assert main([*args[:4], "--dataset", str(tmp_path / "missing.h5"), *args[6:]]) != 0


class WideBarPosterior(ExactBarPosterior):
    """The exact posterior with its K_u draws spread twice as wide about each family's centre (clipped
    to [0, 1]): PITs bunched in the middle, a Beta map with a, b > 1 corrects it."""

    def sample(self, images, ms_norm, n_draws, seed, recalibrated=True):
        draws = super().sample(images, ms_norm, n_draws, seed, recalibrated)
        centre = draws[:, :, :1].mean(axis=1, keepdims=True)
        draws[:, :, :1] = np.clip(centre + 4.0 * (draws[:, :, :1] - centre), 0, 1)
        return draws


def test_a_recalibration_fitted_on_a_fresh_draw_sharpens_only_what_is_miscalibrated():
    """On 400 fresh families the 4× too wide K_u gets a Beta map with a, b > 1 whose likelihood ratio
    against the identity is overwhelming; the exact D gets a map near (1, 1) the test does not support.
    The record keeps the map it replaces, and the families it was fitted on join the fitted ids."""
    from forcdecode.learn.posterior_check import apply_recalibration, fresh_recalibration, recalibration_lines

    est = WideBarPosterior()
    est.metadata["recalibration"] = {"beta": {"K_u": [1.1, 1.0], "D": [1.0, 1.0]}}
    fresh = _fresh(n=400)
    record = fresh_recalibration(est, fresh, seed=SEED, draws=300)
    (a, b), (a_d, b_d) = record["beta_fitted"]["K_u"], record["beta_fitted"]["D"]
    assert a > 1.5 and b > 1.5 and record["likelihood_ratio_p"]["K_u"] < 1e-6, record
    assert abs(a_d - 1) < 0.2 and abs(b_d - 1) < 0.2 and record["likelihood_ratio_p"]["D"] > 0.05, record
    # only the supported map is applied: D's marginal stays the (exact) flow's own
    assert record["beta"] == {"K_u": [a, b]} and record["gate_alpha"] == 0.05
    assert set(fresh_recalibration(est, fresh, seed=SEED, draws=300, gate_alpha=1.0)["beta"]) == {"K_u", "D"}
    assert record["n"] == 400 and record["sample_id_range"] == [100_000, 100_399]
    assert record["previous"] == {"beta": {"K_u": [1.1, 1.0], "D": [1.0, 1.0]}}
    assert any("1.100, 1.000" in line for line in recalibration_lines(record))
    metadata = apply_recalibration(est, record, fresh.sample_id)
    assert metadata["recalibration"] is record and set(metadata["sample_ids_fitted"]) == {3, *range(100_000, 100_400)}
    with pytest.raises(DatasetError, match="used to fit the posterior"):
        fresh_recalibration(ExactBarPosterior(), _fresh(n=30, first_id=3), seed=SEED, draws=20)


def test_the_recalibrate_command_saves_a_model_that_refuses_its_own_draw(stage, tmp_path, capsys):
    """``learn posterior-recalibrate``: the new model answers with the fresh draw's map, is scored on the
    training run's test split when asked, and a later check refuses the families it was fitted on but
    takes another fresh draw."""
    data, _, out = stage
    write_dataset_h5(tmp_path / "cal.h5", _fresh(n=200))
    write_dataset_h5(tmp_path / "other.h5", _fresh(n=60, seed=6, first_id=200_000))
    write_dataset_h5(tmp_path / "training.h5", data)
    (tmp_path / "learning.json").write_text(json.dumps({"seed": SEED, "learning": LEARNING}))
    model = tmp_path / "recal" / "model.pt"
    args = ["learn", "posterior-recalibrate", "--posterior", str(out / "model.pt"), "--dataset", str(tmp_path / "cal.h5"),
            "--out", str(model), "--report", str(tmp_path / "recal" / "report.json"), "--draws", "100",
            "--training-dataset", str(tmp_path / "training.h5"), "--config", str(tmp_path / "learning.json")]
    assert main(args) == 0
    report = json.loads((tmp_path / "recal" / "report.json").read_text())
    assert report["recalibration"]["n"] == 200 and set(report["recalibration"]["beta_fitted"]) == {"K_u", "D"}
    splits = assign_splits(data.sample_id, SEED, LEARNING["split"], "holdout")
    assert report["test_split"]["n_fresh"] == len(splits["test"])
    assert "recalibrated on 200 families" in capsys.readouterr().out
    est = PosteriorEstimator.load(model)
    assert est.recalibration == report["recalibration"]["beta"]
    check = ["learn", "posterior-check", "--posterior", str(model), "--out", str(tmp_path / "check.json"), "--draws", "30"]
    assert main([*check, "--dataset", str(tmp_path / "cal.h5")]) != 0
    assert main([*check, "--dataset", str(tmp_path / "other.h5")]) == 0
    # --config scores the training run's test split, which needs that run's dataset
    assert main([*args[:-4], "--config", str(tmp_path / "learning.json")]) != 0


def test_split_coverage_per_held_out_split_sees_a_bias_and_passes_the_exact_posterior():
    """`learn posterior-splits`: the exact posterior covers within each split's binomial band, a biased one
    does not, and the splits are train_posterior's (hash of seed and sample id)."""
    from forcdecode.config import defaults
    from forcdecode.learn.posterior_check import split_coverage, split_coverage_lines
    from forcdecode.learn.splits import assign_splits

    data = bar_dataset(n=600, seed=3)
    learning = defaults("learning")
    table = split_coverage(ExactBarPosterior(), data, seed=SEED, split_seed=SEED, learning=learning, draws=400,
                           levels=(0.9,))
    splits = assign_splits(data.sample_id, SEED, learning["split"], learning["protocol"])
    assert set(table) == {"validation", "calibration", "test"}
    for split, row in table.items():
        assert row["n"] == len(splits[split])
        wide = binomial_band(row["n"], 0.9, level=0.99)
        assert all(wide[0] <= c <= wide[1] for c in row["coverage_90"].values()), (split, row)
        assert row["pooled_90"] == pytest.approx(np.mean(list(row["coverage_90"].values())))
    biased = split_coverage(ExactBarPosterior(shift=0.1), data, seed=SEED, split_seed=SEED, learning=learning,
                            draws=400, levels=(0.9,))
    assert all(row["coverage_90"]["K_u"] < 0.2 for row in biased.values()), biased
    assert len(split_coverage_lines(table)) == 8 and "pooled" in split_coverage_lines(table)[0]
    for row in table.values():  # the exact posterior's K_u median is within half a bar of the truth
        assert row["mae_median"]["K_u"] < 0.5 / (SIDE - 1) and 0.15 < row["mae_median"]["D"] < 0.35
        low, high = row["mae_median_ci90"]["D"]
        assert low < row["mae_median"]["D"] < high
    with pytest.raises(ConfigError, match="at least 2 draws"):
        split_coverage(ExactBarPosterior(), data, seed=SEED, split_seed=SEED, learning=learning, draws=1)


def test_the_recalibration_holdout_depends_only_on_seed_and_id():
    """A family's side (flow or recalibration) is a uniform of (seed, its id): a grown dataset moves no
    family, the fraction is binomial, 0 holds out nothing and the recalibration then falls back to
    validation + calibration."""
    from forcdecode.learn.posterior import recalibration_families, recalibration_holdout

    ids = np.arange(1000, 3000)
    train = np.arange(0, 2000, 2)
    flow, held = recalibration_holdout(ids, train, SEED, 0.25)
    assert np.array_equal(np.sort(np.concatenate([flow, held])), train) and not np.intersect1d(flow, held).size
    assert abs(len(held) / len(train) - 0.25) < 3.3 * np.sqrt(0.25 * 0.75 / len(train))
    grown_ids = np.concatenate([ids, np.arange(5000, 5400)])
    _, held_grown = recalibration_holdout(grown_ids, np.concatenate([train, np.arange(2000, 2400)]), SEED, 0.25)
    assert set(ids[held]) == set(grown_ids[held_grown]) & set(ids)
    assert not np.array_equal(recalibration_holdout(ids, train, SEED + 1, 0.25)[1], held)
    none_flow, none_held = recalibration_holdout(ids, train, SEED, 0.0)
    assert np.array_equal(none_flow, train) and none_held.size == 0
    splits = {"validation": np.array([1, 3]), "calibration": np.array([5, 7])}
    assert recalibration_families(splits, np.array([0, 2]))[0].tolist() == [0, 2, 5, 7]
    families, fitted_on = recalibration_families(splits, none_held)
    assert families.tolist() == [1, 3, 5, 7] and fitted_on == "validation + calibration splits"

