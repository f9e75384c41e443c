"""Identified combinations (issue 44 item 1): the table's formulas against a Néel wall computed by hand,
their undefined region, the transform of posterior draws, the ridge correlation, and the combinations
in the posterior's metrics.json (trained on a tiny synthetic dataset) and in Alice's plug-in metrics."""

import json
import math

import numpy as np
import pytest
import torch

from forcdecode.core.parameters import (COMBINATION_BY_NAME, COMBINATION_NAMES, DEFAULT_BOUNDS, critical_dmi,
                                        combination_reference, combination_values, denormalize, dmi_ratio, k_eff,
                                        normalize, normalize_combination, quality_factor, wall_energy, wall_width)
from forcdecode.learn.combinations import (alice_combination_metrics, available, combinations_of,
                                           condition_on_defined, ridge_correlations, ridge_summary)
from forcdecode.learn.data import LearningData

# a Néel wall by hand: μ0 M_s²/2 = 4π·1e-7 · (8e5)² / 2 = 0.32e5 · 4π = 402 123.86 J/m³
WALL = {"A_ex": 1e-11, "K_u": 1e6, "Ms": 8e5, "D": 1e-3}
K_EFF = 1e6 - 402123.8597                   # 597 876.14 J/m³
SQRT_AK = math.sqrt(1e-11 * K_EFF)           # 2.445151e-3 J/m²
BY_HAND = {"sigma_w": 4 * SQRT_AK - math.pi * 1e-3,      # 9.78060e-3 − 3.14159e-3 = 6.63901e-3 J/m²
           "delta_w": math.pi * math.sqrt(1e-11 / K_EFF),  # π · 4.08976e-9 = 1.28483e-8 m
           "D_over_Dc": 1e-3 / (4 * SQRT_AK / math.pi),    # 1e-3 / 3.11326e-3 = 0.321206
           "Q": 2e6 / 804247.7193}                         # 2.486796


def test_formulas_against_a_neel_wall_by_hand():
    assert k_eff(WALL) == pytest.approx(597876.14, rel=1e-7)
    assert BY_HAND["sigma_w"] == pytest.approx(6.63901e-3, rel=1e-5)
    assert BY_HAND["delta_w"] == pytest.approx(1.28483e-8, rel=1e-5)
    assert BY_HAND["D_over_Dc"] == pytest.approx(0.321206, rel=1e-5)
    assert BY_HAND["Q"] == pytest.approx(2.486796, rel=1e-6)
    assert critical_dmi(WALL) == pytest.approx(3.113262e-3, rel=1e-6)
    values = combination_values(WALL)
    assert set(values) == set(COMBINATION_NAMES) == set(BY_HAND)
    for name, expected in BY_HAND.items():
        assert float(values[name]) == pytest.approx(expected, rel=1e-9), name
        assert COMBINATION_BY_NAME[name].unit and COMBINATION_BY_NAME[name].formula


def test_the_wall_energy_vanishes_at_the_critical_dmi():
    rng = np.random.default_rng(0)
    p = {"A_ex": rng.uniform(2e-12, 3e-11, 20), "K_u": rng.uniform(6e5, 1.5e6, 20), "Ms": rng.uniform(2e5, 9e5, 20)}
    dc = critical_dmi(p)
    assert np.all(dc > 0)
    assert np.allclose(wall_energy({**p, "D": dc}), 0.0, atol=1e-15)
    assert np.allclose(wall_energy({**p, "D": -dc}), 0.0, atol=1e-15)         # |D|
    assert np.allclose(dmi_ratio({**p, "D": dc}), 1.0)
    assert np.all(wall_energy({**p, "D": 0.5 * dc}) > 0) and np.all(wall_energy({**p, "D": 1.5 * dc}) < 0)


def test_vectorized_and_broadcast_like_scalar_calls():
    rng = np.random.default_rng(1)
    p = {"A_ex": rng.uniform(2e-12, 3e-11, (3, 4)), "K_u": rng.uniform(1e4, 1.5e6, (3, 4)),
         "D": rng.uniform(0, 5e-3, (3, 4)), "Ms": rng.uniform(2e5, 1.4e6, (3, 1))}      # M_s per row
    for name in COMBINATION_NAMES:
        out = COMBINATION_BY_NAME[name](p)
        assert out.shape == (3, 4), name
        for i in range(3):
            for j in range(4):
                scalar = COMBINATION_BY_NAME[name]({k: v[i, j] if v.shape[1] > 1 else v[i, 0] for k, v in p.items()})
                np.testing.assert_equal(out[i, j], scalar)


def test_undefined_where_the_effective_anisotropy_is_not_positive():
    ms = 8e5
    k_shape = 4e-7 * math.pi * ms ** 2 / 2
    p = {"A_ex": np.full(3, 1e-11), "K_u": np.array([0.5, 1.0, 2.0]) * k_shape, "D": np.full(3, 1e-3), "Ms": ms}
    for fn in (wall_energy, wall_width, dmi_ratio, critical_dmi):
        out = fn(p)
        assert np.isnan(out[0]) and np.isnan(out[1]) and np.isfinite(out[2]), fn.__name__
    q = quality_factor(p)
    np.testing.assert_allclose(q, [0.5, 1.0, 2.0])                              # Q = 1 ⇔ K_eff = 0


def test_normalization_by_a_reference_range():
    values = np.geomspace(1e-9, 1e-7, 101)
    lo, hi = combination_reference("delta_w", np.append(values, [np.nan, -1.0]))  # NaN and ≤ 0 ignored (log)
    assert (lo, hi) == pytest.approx(tuple(np.percentile(values, [1, 99])))
    u = normalize_combination("delta_w", [lo, hi, math.sqrt(lo * hi), np.nan], [lo, hi])
    np.testing.assert_allclose(u[:3], [0.0, 1.0, 0.5])                          # log scale: the geometric mean
    assert np.isnan(u[3])
    u = normalize_combination("sigma_w", [1.0, 3.0, 2.0], [1.0, 3.0])
    np.testing.assert_allclose(u, [0.0, 1.0, 0.5])                              # linear
    assert COMBINATION_BY_NAME["Q"].scale == "log" and COMBINATION_BY_NAME["D_over_Dc"].scale == "linear"


def test_transform_of_draws_is_the_formula_per_draw():
    names = ("N_pin", "A_ex", "K_u", "D")
    rng = np.random.default_rng(2)
    u = rng.random((3, 7, len(names)))
    ms_norm = rng.random(3)
    out = combinations_of(u, names, ms_norm, DEFAULT_BOUNDS)
    assert out.shape == (3, 7, 4) and available(names) == COMBINATION_NAMES
    for i in range(3):
        for d in range(7):
            p = {n: float(denormalize(n, u[i, d, j])) for j, n in enumerate(names)}
            p["Ms"] = float(denormalize("Ms", ms_norm[i]))
            for k, name in enumerate(COMBINATION_NAMES):
                np.testing.assert_allclose(out[i, d, k], COMBINATION_BY_NAME[name](p), rtol=1e-12)
    assert np.isnan(out).any() and np.isfinite(out).any()     # the prior box holds K_eff ≤ 0 draws
    assert available(("K_u", "D")) == ("Q",)


def test_undefined_draws_are_replaced_by_the_familys_defined_ones():
    draws = np.array([[1.0, np.nan, 2.0, np.nan], [np.nan] * 4, [5.0, 6.0, 7.0, 8.0]])
    filled, fraction = condition_on_defined(draws, np.random.default_rng(0))
    np.testing.assert_allclose(fraction, [0.5, 0.0, 1.0])
    assert set(filled[0]) <= {1.0, 2.0} and filled[0, 0] == 1.0 and filled[0, 2] == 2.0
    assert np.isnan(filled[1]).all()
    np.testing.assert_array_equal(filled[2], draws[2])


def test_ridge_correlation_median_by_hand():
    # three families, draws of (N_pin, A_ex, D): A_ex and D r = +1, −1 and 0 (a 2 × 2 checkerboard)
    a = np.array([0.1, 0.2, 0.3, 0.4])
    samples = np.stack([np.stack([np.zeros(4), a, 2 * a + 0.1], -1),
                        np.stack([np.zeros(4), a, 1 - a], -1),
                        np.stack([np.zeros(4), [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]], -1)])
    r = ridge_correlations(samples, ("N_pin", "A_ex", "D"))
    np.testing.assert_allclose(r, [1.0, -1.0, 0.0], atol=1e-12)
    summary = ridge_summary(samples, ("N_pin", "A_ex", "D"), np.random.default_rng(0), n_boot=200)
    assert summary["A_ex_D_correlation_median"] == pytest.approx(0.0, abs=1e-12)
    samples[2, :, 2] = [0.0, 1.0, 0.0, 2.0]     # r = 0.9045 (hand: cov 0.375, sd 0.5 and √0.6875); median of (1, −1, 0.9045)
    assert ridge_summary(samples, ("N_pin", "A_ex", "D"), np.random.default_rng(0), 200)[
        "A_ex_D_correlation_median"] == pytest.approx(0.375 / (0.5 * math.sqrt(0.6875)), rel=1e-9)
    assert ridge_correlations(samples, ("K_u", "D", "N_pin")) is None


# ---------------------------------------------------------------- the posterior's metrics.json
SIDE = 16
SETTINGS = {"parameters": ["A_ex", "K_u", "D"], "width": 8, "dropout": 0.0, "epochs": 8, "patience": 3,
            "batch_size": 16, "lr": 2e-3, "transforms": 1, "hidden": 16, "draws": 120}
LEARNING = {"split": [0.55, 0.15, 0.15, 0.15], "protocol": "holdout", "bootstrap": 200, "min_samples": 20}
SEED = 5


def wall_dataset(n=140, seed=0) -> LearningData:
    """K_u as a bar (rows bright up to u_K), A_ex and D not in the image; M_s low enough that most
    families have K_eff > 0, a few not."""
    rng = np.random.default_rng(seed)
    u_a, u_k, u_d = rng.random(n), rng.uniform(0.45, 1.0, n), rng.random(n)
    images = np.zeros((n, SIDE, SIDE))
    for k, row in enumerate(np.rint(u_k * (SIDE - 1)).astype(int)):
        images[k, :row + 1] = 235
    images = (images + rng.integers(0, 20, images.shape)).astype(np.uint8)
    ms = rng.uniform(2e5, 6e5, n)
    values = {"Ms": ms, "A_ex": denormalize("A_ex", u_a), "K_u": denormalize("K_u", u_k), "D": denormalize("D", u_d)}
    return LearningData(images=images, ms_norm=normalize("Ms", ms), values=values, sample_id=np.arange(n) * 3 + 1,
                        bounds=dict(DEFAULT_BOUNDS), config_hash="walls", fields_T=np.linspace(-1, 1, SIDE))


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    from forcdecode.learn.posterior import train_posterior

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("posterior_combinations")
    data = wall_dataset()
    metrics = train_posterior(data, SETTINGS, LEARNING, SEED, out / "model.pt", out / "metrics.json",
                              out / "figures" / "posterior_calibration.png", log=lambda *_: None)
    return data, metrics, out


def test_posterior_metrics_hold_every_combination(stage):
    data, metrics, out = stage
    on_disk = json.loads((out / "metrics.json").read_text())
    assert set(on_disk["combinations"]) == set(COMBINATION_NAMES)
    truth = combination_values(data.values)
    assert np.isnan(truth["sigma_w"]).any()                     # some families have K_eff ≤ 0 …
    for name, row in on_disk["combinations"].items():
        assert row["n_scored"] >= 2, (name, row)
        for key in ("mae_median", "mae_mean", "sbc_ks_p", "coverage_90", "width_90", "coverage_50", "mae",
                    "skill_vs_prior", "skill_vs_ms_only", "skill_vs_images_shuffled"):
            assert np.isfinite(row[key]), (name, key, row[key])
        for key in ("skill_vs_prior_ci90", "skill_vs_ms_only_ci90", "skill_vs_images_shuffled_ci90", "mae_ci90"):
            assert len(row[key]) == 2 and np.all(np.isfinite(row[key])), (name, key)
        assert set(row["baselines"]) >= {"prior", "ms_only", "images_shuffled"}
        assert all(np.isfinite(row["baselines"][b]) for b in ("prior", "ms_only", "images_shuffled"))
        assert 0.0 <= row["coverage_90"] <= 1.0 and 0.0 <= row["undefined_draw_fraction"] <= 1.0
        assert row["n_scored"] + row["n_truth_undefined"] + row["n_too_few_defined_draws"] == metrics["n_test"]
    assert on_disk["combinations"]["Q"]["n_truth_undefined"] == 0            # … Q is always defined
    lo, hi = on_disk["combinations"]["Q"]["normalization"]["reference"]
    assert 0 < lo < hi


def test_posterior_q_is_accurate_where_the_image_tells_k_u(stage):
    # Q = 2K_u/(μ0 M_s²): the image tells K_u, M_s is given, so the posterior's Q beats the prior
    _, metrics, _ = stage
    q = metrics["combinations"]["Q"]
    assert q["mae_median"] < q["baselines"]["prior"], q


def test_posterior_ridge_correlation_and_figure(stage):
    _, metrics, out = stage
    median = metrics["A_ex_D_correlation_median"]
    per_family = np.asarray(metrics["A_ex_D_correlation_per_family"], dtype=float)
    assert len(per_family) == metrics["n_test"]
    assert -1.0 <= median <= 1.0
    assert median == pytest.approx(float(np.median(per_family[np.isfinite(per_family)])))
    assert metrics["ridge_figure"] == "posterior_ridge.png"
    assert (out / "figures" / "posterior_ridge.png").read_bytes()[:4] == b"\x89PNG"


# ---------------------------------------------------------------- Alice's plug-in
def test_alice_plug_in_combinations():
    data = wall_dataset(n=80, seed=3)
    names = ("A_ex", "K_u", "D")
    target = {n: data.target(n) for n in names}
    split = np.array(["train", "validation", "calibration", "test"])[np.arange(80) % 4]
    rng_of = lambda *keys: np.random.default_rng(0)  # noqa: E731
    perfect = alice_combination_metrics(target, target, data.ms_norm, data.bounds, split, rng_of, n_boot=200)
    assert set(perfect) == set(COMBINATION_NAMES)
    for name, row in perfect.items():
        assert row["mae"] == 0.0 and row["skill_vs_prior"] == 1.0, (name, row)
        assert set(row["baselines"]) == {"prior", "ms_only", "ms_only_k"}
    noisy = {n: np.clip(target[n] + np.random.default_rng(4).normal(0, 0.05, 80), 0, 1) for n in names}
    rows = alice_combination_metrics(noisy, target, data.ms_norm, data.bounds, split, rng_of, n_boot=200)
    # by hand for Q: the plug-in Q of the noisy K_u, normalized by the train truths' Q range
    test, train = split == "test", split == "train"
    ms = denormalize("Ms", data.ms_norm)
    q_true = quality_factor({"K_u": denormalize("K_u", target["K_u"]), "Ms": ms})
    q_hat = quality_factor({"K_u": denormalize("K_u", noisy["K_u"]), "Ms": ms})
    lo, hi = np.percentile(q_true[train], [1, 99])
    g = lambda q: (np.log(q) - np.log(lo)) / (np.log(hi) - np.log(lo))  # noqa: E731
    assert rows["Q"]["mae"] == pytest.approx(float(np.mean(np.abs(g(q_hat[test]) - g(q_true[test])))), rel=1e-12)
    assert rows["Q"]["baselines"]["prior"] == pytest.approx(
        float(np.mean(np.abs(np.median(g(q_true[train])) - g(q_true[test])))), rel=1e-12)


def test_alice_combinations_from_prediction_files_and_dataset(tmp_path):
    import h5py
    import pandas as pd

    from forcdecode.learn.report import alice_combinations

    data = wall_dataset(n=60, seed=6)
    columns = ["Ms", "A_ex", "K_u", "D"]
    with h5py.File(tmp_path / "dataset.h5", "w") as h5:
        h5["parameters"] = np.stack([data.values[c] for c in columns], axis=1)
        h5["parameters"].attrs["columns"] = columns
        h5["images"], h5["sample_id"], h5["fields_T"] = data.images, data.sample_id, data.fields_T
        h5.attrs["config_json"], h5.attrs["config_hash"] = json.dumps({"bounds": {}}), "walls"
    split = np.array(["train", "validation", "calibration", "test"])[np.arange(60) % 4]
    order = np.random.default_rng(0).permutation(60)       # the frames' rows in another order than the file's
    noise = np.random.default_rng(1)
    predictions = {n: pd.DataFrame({"sample_id": data.sample_id[order], "split": split[order],
                                    "target": data.target(n)[order],
                                    "prediction": np.clip(data.target(n)[order] + noise.normal(0, 0.05, 60), 0, 1)})
                   for n in ("A_ex", "K_u", "D")}
    rows = alice_combinations(predictions, tmp_path / "dataset.h5", seed=3, n_boot=200)
    expected = alice_combination_metrics({n: f["prediction"].to_numpy() for n, f in predictions.items()},
                                         {n: f["target"].to_numpy() for n, f in predictions.items()},
                                         data.ms_norm[order], data.bounds, split[order],
                                         lambda *k: np.random.default_rng(0), n_boot=200)
    assert set(rows) == set(COMBINATION_NAMES)
    for name in COMBINATION_NAMES:
        assert rows[name]["mae"] == pytest.approx(expected[name]["mae"], rel=1e-12), name
        assert rows[name]["baselines"] == pytest.approx(expected[name]["baselines"]), name
        assert np.all(np.isfinite(rows[name]["skill_vs_ms_only_ci90"]))


def test_alice_combinations_images_shuffled_baseline_from_the_model_files(tmp_path):
    import h5py
    import pandas as pd

    from forcdecode.learn.models import build_network
    from forcdecode.learn.predictor import ParameterModel
    from forcdecode.learn.report import alice_combinations

    data = wall_dataset(n=48, seed=7)
    columns = ["Ms", "A_ex", "K_u", "D"]
    with h5py.File(tmp_path / "dataset.h5", "w") as h5:
        h5["parameters"] = np.stack([data.values[c] for c in columns], axis=1)
        h5["parameters"].attrs["columns"] = columns
        h5["images"], h5["sample_id"], h5["fields_T"] = data.images, data.sample_id, data.fields_T
        h5.attrs["config_json"], h5.attrs["config_hash"] = json.dumps({"bounds": {}}), "walls"
    torch.manual_seed(0)
    models = tmp_path / "models"
    models.mkdir()
    for name in ("A_ex", "K_u", "D"):   # untrained networks: what matters is that the baseline runs them
        net = build_network("small", width=4, image_size=SIDE)
        torch.save({"format": "forcdecode-alice-bob/1", "parameter": name,
                    "architecture": {"model": "small", "width": 4, "image_size": SIDE}, "readout": "parabola",
                    "bounds": {k: list(v) for k, v in DEFAULT_BOUNDS.items()}, "alice_state": net.state_dict(),
                    "bob_state": net.state_dict(), "validation_errors": [0.1, 0.2],
                    "conformal": {"levels": [0.9], "quantiles": {"0.9": 1.0}, "sigma_floor": 1e-4}}, models / f"{name}.pt")
    split = np.array(["train", "validation", "calibration", "test"])[np.arange(48) % 4]
    # Alice's own predictions on the unshuffled test images: the same networks
    predictions = {n: pd.DataFrame({"sample_id": data.sample_id, "split": split, "target": data.target(n),
                                    "prediction": ParameterModel.load(models / f"{n}.pt").predict(
                                        data.images, data.values["Ms"])["normalized"]}) for n in ("A_ex", "K_u", "D")}
    without = alice_combinations(predictions, tmp_path / "dataset.h5", seed=1, n_boot=200)
    rows = alice_combinations(predictions, tmp_path / "dataset.h5", seed=1, n_boot=200, models=models)
    assert rows["Q"]["n_scored"] == 12                     # Q is defined for every test family
    for name in COMBINATION_NAMES:
        assert "images_shuffled" not in without[name]["baselines"]
        if rows[name]["n_scored"] < 2:
            continue
        base = rows[name]["baselines"]
        assert np.isfinite(base["images_shuffled"]) and base["images_shuffled_permutations"] == 5, name
        assert rows[name]["skill_vs_images_shuffled"] == pytest.approx(1 - rows[name]["mae"] / base["images_shuffled"])
        assert len(rows[name]["skill_vs_images_shuffled_ci90"]) == 2
        assert rows[name]["mae"] == without[name]["mae"]


def test_prediction_summarizes_the_combinations_of_the_draws(stage):
    from forcdecode.learn.combinations import summarize_draws
    from forcdecode.learn.posterior import PosteriorEstimator, posterior_prediction

    data, _, out = stage
    est = PosteriorEstimator.load(out / "model.pt")
    result = posterior_prediction(est, data.images[0], float(data.values["Ms"][0]), n_draws=200, seed=0)
    assert set(result["combinations"]) == set(COMBINATION_NAMES)
    q = result["combinations"]["Q"]
    assert q["defined_fraction"] == 1.0 and q["interval_90"][0] <= q["value"] <= q["interval_90"][1]
    # by hand on fixed draws: Q of the K_u draws, σ_w NaN (K_eff ≤ 0) for the draws with small K_u
    names = ("A_ex", "K_u", "D")
    draws = np.array([[0.5, 0.2, 0.5], [0.5, 0.9, 0.5], [0.5, 0.95, 0.5], [0.5, 1.0, 0.5]])
    ms_norm = float(normalize("Ms", 8e5))
    rows = summarize_draws(draws, names, ms_norm, DEFAULT_BOUNDS)
    k_u = denormalize("K_u", draws[:, 1])
    assert rows["Q"]["value"] == pytest.approx(float(np.median(quality_factor({"K_u": k_u, "Ms": 8e5}))))
    sigma = wall_energy({"A_ex": denormalize("A_ex", 0.5), "K_u": k_u, "D": denormalize("D", 0.5), "Ms": 8e5})
    assert np.isnan(sigma[0]) and rows["sigma_w"]["defined_fraction"] == 0.75
    assert rows["sigma_w"]["value"] == pytest.approx(float(np.median(sigma[1:])))
