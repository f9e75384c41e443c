"""The closed loop on the simulated test set: prediction, floor (true Hamiltonian) and null
(training-median Hamiltonian) on shared new disorder realisations, on the tiny 16x16 test films."""

import copy
import importlib
import json
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
import yaml

from forcdecode.core.errors import ConfigError, DatasetError, SimulationError
from forcdecode.core.parameters import TARGETS, normalize
from forcdecode.core.streams import stream_rng
from forcdecode.dataset.params import draw_parameters
from forcdecode.loop import simulated
from forcdecode.micromag.build import mesh_from_config
from forcdecode.micromag.disorder import periodic_voronoi_labels

ROOT = Path(__file__).resolve().parents[2]
resim = importlib.import_module("forcdecode.infer.resimulate")  # the module (the package exports the function)
route = importlib.import_module("forcdecode.forc.simulate")  # the module: the one route from a Hamiltonian to a family
SAMPLE = 5
# a square-loop film whose FORCs hardly depend on the disorder realisation on 16x16 cells
TRUTH = dict(Ms=8e5, A_ex=1.2e-11, K_u=1.5e6, D=1e-3, N_pin=2, sigma_theta_deg=5.0, sigma_K=0.1)


@pytest.fixture(scope="module")
def cfg():
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["pinning"].setdefault("treatment", "full")
    return cfg


@pytest.fixture(scope="module")
def medians(cfg):
    """Medians of 40 draws of the test config: the null of a dataset drawn like it."""
    draws = pd.DataFrame([draw_parameters(cfg["seed"], i, cfg["bounds"]) for i in range(40)])
    out = {name: float(draws[name].median()) for name in draws if name != "Ms"}
    out["N_pin"] = int(round(out["N_pin"]))
    return out


@pytest.fixture(scope="module")
def input_family(cfg):
    """The sample's family on its own dataset disorder stream (what the dataset holds)."""
    return resim.simulate_family(cfg, TRUTH, stream_rng(cfg["seed"], "disorder", SAMPLE))


def _table(predicted: dict) -> pd.DataFrame:
    return pd.DataFrame([{"sample_id": SAMPLE, **predicted, "bob_error_mean": 0.1, "abs_error_mean": 0.0}])


@pytest.fixture(scope="module")
def exact(cfg, medians, input_family):
    """Closed loop of a prediction equal to the truth; the film builder records every disorder drawn."""
    drawn = []
    real = route.build_film

    def spy(cfg_, params, sample_id=None, pinning=None, rng=None):
        film, m0, disorder = real(cfg_, params, sample_id, pinning=pinning, rng=rng)
        drawn.append((dict(params), disorder))
        return film, m0, disorder

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(route, "build_film", spy)  # the one route into the engine (forc.simulate)
        result, families = simulated.closed_loop(cfg, _table(TRUTH), {SAMPLE: input_family},
                                                 pd.DataFrame([TRUTH], index=[SAMPLE]), medians, max_samples=5,
                                                 realisations=3)
    return result.iloc[0], families, drawn


def test_prediction_equal_to_truth_gives_the_floor_exactly_and_the_floor_is_below_the_null(exact):
    row, families, _ = exact
    assert row["rms"] == row["rms_floor"] and row["ratio_floor"] == 1.0
    assert list(row["rms_per_realisation"]) == list(row["rms_floor_per_realisation"])
    np.testing.assert_array_equal(families[SAMPLE]["prediction"], families[SAMPLE]["floor"])
    floor, null = np.asarray(row["rms_floor_per_realisation"]), np.asarray(row["rms_null_per_realisation"])
    # new disorder, never the sample's own stream (which would reproduce the input exactly: RMS 0)
    assert np.all(floor > 0)
    assert row["rms"] == pytest.approx(floor.mean(), rel=1e-12)
    assert row["rms_null"] == pytest.approx(null.mean(), rel=1e-12)
    # measured: floor ~0.01, null ~0.7 (the median K_u of the draw gives a sheared, lower loop)
    assert row["rms_floor"] < 0.1 < 0.3 < row["rms_null"]
    assert np.all(floor < null)
    assert row["ratio_null"] == pytest.approx(row["rms"] / row["rms_null"])
    assert row["failures"] == ""


def test_common_random_numbers_share_each_realisation_across_the_three_hamiltonians(exact, cfg, medians):
    _, _, drawn = exact
    assert len(drawn) == 3 * 3  # realisation-major, roles prediction, floor, null
    by_realisation = [drawn[3 * r: 3 * r + 3] for r in range(3)]
    for r, (prediction, floor, null) in enumerate(by_realisation):
        assert prediction[0] == floor[0] == TRUTH and null[0]["K_u"] == medians["K_u"] and null[0]["Ms"] == TRUTH["Ms"]
        # identical Hamiltonians: identical disorder, cell by cell
        for field in ("K_u", "easy_axis", "grain_labels", "pinning_mask", "pinning_initial"):
            np.testing.assert_array_equal(getattr(prediction[1], field), getattr(floor[1], field))
        # the null draws from the same stream: same grains (the first draw), its own K_u scale
        np.testing.assert_array_equal(null[1].grain_labels, floor[1].grain_labels)
        # it is stream closed_loop_disorder with keys (sample, realisation): the grains are its first draw
        grains = periodic_voronoi_labels(mesh_from_config(cfg), cfg["n_grains"],
                                         stream_rng(cfg["seed"], "closed_loop_disorder", SAMPLE, r))
        np.testing.assert_array_equal(prediction[1].grain_labels, grains)
    # realisations differ from each other and from the dataset's own disorder
    assert not np.array_equal(by_realisation[0][0][1].grain_labels, by_realisation[1][0][1].grain_labels)
    own = resim.build_film(cfg, TRUTH, SAMPLE)[2]
    assert not np.array_equal(own.grain_labels, by_realisation[0][0][1].grain_labels)


def test_llg_protocol_runs_the_adaptive_family_with_slaved_pinning(cfg, monkeypatch):
    small = copy.deepcopy(cfg)
    small["mesh"].update(nx=8, ny=8)
    small["field"]["n_fields"] = 4
    # fast settings (heavy damping, high slew rates) that still reverse the film
    small["protocol"] = {"name": "llg", "alpha": 1.0, "safety": 0.2, "rate_min_T_per_s": 1e8, "rate_max_T_per_s": 1e10}
    calls = {"adaptive": 0, "pinning": []}
    real_adaptive, real_build = route.adaptive_family, route.build_film

    def adaptive(*args, **kwargs):
        calls["adaptive"] += 1
        return real_adaptive(*args, **kwargs)

    def build(*args, **kwargs):
        calls["pinning"].append(kwargs.get("pinning"))
        return real_build(*args, **kwargs)

    def quasistatic(*args, **kwargs):
        raise AssertionError("the llg protocol must not run the quasi-static family")

    monkeypatch.setattr(route, "adaptive_family", adaptive)
    monkeypatch.setattr(route, "build_film", build)
    monkeypatch.setattr(route, "quasistatic_family", quasistatic)
    soft = {**TRUTH, "K_u": 3e5, "N_pin": 0}
    curves = resim.simulate_family(small, soft, stream_rng(cfg["seed"], "closed_loop_disorder", 0, 0))
    assert calls == {"adaptive": 1, "pinning": ["slaved"]}
    # the descending branch (diagonal) reverses from +B_max to -B_max (measured -0.999 ... 0.998)
    assert curves.shape == (4, 4) and curves[0, 0] < -0.9 and curves[-1, -1] > 0.9
    assert np.all(np.isnan(curves[np.tril_indices(4, -1)]))
    with pytest.raises(ConfigError, match="protocol"):
        resim.simulate_family({**small, "protocol": {"name": "euler"}}, TRUTH, np.random.default_rng(0))


def test_bad_input_raises_typed_errors(cfg, medians, input_family, tmp_path):
    truths = pd.DataFrame([TRUTH], index=[SAMPLE])
    with pytest.raises(DatasetError, match="no test sample"):
        simulated.closed_loop(cfg, _table(TRUTH).iloc[:0], {SAMPLE: input_family}, truths, medians, max_samples=5)
    with pytest.raises(DatasetError, match="shape"):
        simulated.closed_loop(cfg, _table(TRUTH), {SAMPLE: input_family[:-1]}, truths, medians, max_samples=5)
    with pytest.raises(DatasetError, match="no input family"):
        simulated.closed_loop(cfg, _table(TRUTH), {}, truths, medians, max_samples=5)
    values = pd.DataFrame([TRUTH, TRUTH], index=[1, 2])
    path = tmp_path / "K_u_predictions.parquet"
    pd.DataFrame({"sample_id": [1, 2], "split": ["train", "validation"], "prediction": [0.5, 0.5],
                  "bob_error": [0.1, 0.1], "abs_error": [0.0, 0.0]}).to_parquet(path)
    with pytest.raises(DatasetError, match="no test sample"):
        simulated.predicted_hamiltonians({"K_u": path}, values, {})
    pd.DataFrame({"sample_id": [1, 2], "split": ["test", "validation"], "prediction": [0.5, 0.5],
                  "bob_error": [0.1, 0.1], "abs_error": [0.0, 0.0]}).to_parquet(path)
    with pytest.raises(DatasetError, match="no train sample"):
        simulated.training_medians({"K_u": path}, values)


def test_a_failed_resimulation_drops_its_realisation_from_all_three_means(cfg, medians, input_family, monkeypatch):
    offsets = {"prediction": 0.1, "floor": 0.0, "null": 0.3}

    def fake(cfg_, params, sample_id, realisation):
        role = "null" if params["K_u"] == medians["K_u"] else "prediction" if params["D"] != TRUTH["D"] else "floor"
        if role == "null" and realisation == 1:
            return None, "SimulationError: diverged"
        return input_family + offsets[role] + 0.01 * realisation, ""

    monkeypatch.setattr(resim, "_simulate_task", fake)
    truths = pd.DataFrame([TRUTH], index=[SAMPLE])
    result, _ = simulated.closed_loop(cfg, _table({**TRUTH, "D": 2e-3}), {SAMPLE: input_family}, truths, medians,
                                      max_samples=5)
    row = result.iloc[0]
    assert row["realisations_used"] == 2 and row["failures"] == "null r=1: SimulationError: diverged"
    assert np.isnan(row["rms_null_per_realisation"][1])
    assert row["rms_floor"] == pytest.approx((0.00 + 0.02) / 2) and row["rms"] == pytest.approx((0.10 + 0.12) / 2)
    assert row["rms_null"] == pytest.approx((0.30 + 0.32) / 2)
    monkeypatch.setattr(resim, "_simulate_task", lambda *args: (None, "ValueError: bad"))
    with pytest.raises(SimulationError, match="every re-simulation failed"):
        simulated.closed_loop(cfg, _table(TRUTH), {SAMPLE: input_family}, truths, medians, max_samples=5)


def test_summary_medians_of_the_ratios_with_bootstrap_intervals(cfg):
    ratios_null = np.array([0.2, 0.5, 0.6, 0.9, 3.0, 0.4, 0.7])
    table = pd.DataFrame({"rms": ratios_null * 2.0, "rms_null": 2.0, "rms_floor": ratios_null,
                          "ratio_null": ratios_null, "ratio_floor": 2.0, "failures": ["", "", "", "", "", "", "x"]})
    table.loc[6, ["rms", "ratio_null", "ratio_floor"]] = np.nan  # a failed sample is left out
    summary = simulated.summarize(cfg, table, realisations=3, n_boot=500)
    assert summary["median_rms_over_null"] == pytest.approx(np.median(ratios_null[:6])) == 0.55
    low, high = summary["median_rms_over_null_ci90"]
    assert 0.2 <= low < 0.55 < high <= 3.0
    assert summary["median_rms_over_floor"] == 2.0 and summary["median_rms_over_floor_ci90"] == [2.0, 2.0]
    assert summary["n_samples"] == 7 and summary["n_ratios"] == 6 and summary["n_failed_samples"] == 1
    assert summary["fraction_rms_below_null"] == pytest.approx(5 / 6)  # rms < rms_null where ratio < 1
    assert simulated.summarize(cfg, table, 3, 500) == summary  # the bootstrap stream is seeded
    one = simulated.summarize(cfg, table.iloc[:1], realisations=3, n_boot=500)
    assert one["median_rms_over_null"] == 0.2 and all(np.isnan(one["median_rms_over_null_ci90"]))


def _write_stage_inputs(tmp_path, cfg, input_family):
    """dataset.h5 (merge layout; the test sample's family in float64) and six predictions files:
    three train samples, one test sample (SAMPLE, predicted exactly)."""
    train = [dict(TRUTH, K_u=k, A_ex=a, N_pin=n) for k, a, n in ((1e5, 1e-11, 1), (2e5, 2e-11, 3), (3e5, 3e-11, 4))]
    rows = {10: train[0], 11: train[1], 12: train[2], SAMPLE: TRUTH}
    ids = np.array(sorted(rows))
    columns = list(TRUTH)
    n = cfg["field"]["n_fields"]
    dataset = tmp_path / "dataset.h5"
    with h5py.File(dataset, "w") as h5:
        h5["images"] = np.zeros((len(ids), n, n), np.uint8)
        h5["curves_mz"] = np.stack([input_family] * len(ids))
        h5["sample_id"] = ids
        h5["fields_T"] = np.linspace(-cfg["field"]["B_max_T"], cfg["field"]["B_max_T"], n)
        h5.create_dataset("parameters", data=np.array([[rows[i][c] for c in columns] for i in ids], dtype=float))
        h5["parameters"].attrs["columns"] = columns
        h5.attrs["config_hash"] = "0" * 16
        h5.attrs["config_json"] = json.dumps(cfg)
    paths = []
    bounds = {"N_pin": cfg["bounds"]["N_pin"]}
    for name in TARGETS:
        frame = pd.DataFrame({"sample_id": ids, "split": ["test" if i == SAMPLE else "train" for i in ids],
                              "prediction": [float(normalize(name, rows[i][name], bounds)) for i in ids],
                              "bob_error": 0.1, "abs_error": 0.0})
        paths.append(tmp_path / f"{name}_predictions.parquet")
        frame.to_parquet(paths[-1])
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    (tmp_path / "learning.json").write_text(json.dumps({"seed": cfg["seed"], "learning": {"bootstrap": 200},
                                                        "loop": {"max_test_samples": 2, "n_figure_samples": 2}}))
    return dataset, paths


def test_stage_with_two_workers_writes_the_summary_and_matches_the_inline_run(cfg, input_family, exact, tmp_path):
    from forcdecode.cli import main

    dataset, predictions = _write_stage_inputs(tmp_path, cfg, input_family)
    out, figures = tmp_path / "closed_loop.json", tmp_path / "figures"
    code = main(["closed-loop", "--config", str(tmp_path / "config.json"),
                 "--learning", str(tmp_path / "learning.json"), "--dataset", str(dataset),
                 "--predictions", *map(str, predictions), "--out", str(out),
                 "--table", str(tmp_path / "closed_loop.parquet"), "--figures", str(figures), "--workers", "2"])
    assert code == 0
    summary = json.loads(out.read_text())
    assert summary["n_samples"] == 1 and summary["realisations"] == 3 and summary["workers"] == 2
    assert summary["protocol"] == "quasistatic" and summary["bootstrap_resamples"] == 200
    # the null: medians over the three train samples, the middle one
    assert summary["training_medians"]["K_u"] == 2e5 and summary["training_medians"]["N_pin"] == 3
    table = pd.read_parquet(tmp_path / "closed_loop.parquet").iloc[0]
    inline = exact[0]
    # same disorder streams, same input family: the floor does not depend on the worker count
    assert list(table["rms_floor_per_realisation"]) == list(inline["rms_floor_per_realisation"])
    assert table["null_K_u"] == 2e5 and table["null_Ms"] == TRUTH["Ms"]
    assert summary["median_rms_over_null"] == pytest.approx(table["rms"] / table["rms_null"])
    assert all(np.isnan(summary["median_rms_over_null_ci90"]))  # no interval from one sample
    assert summary["rms_null_median"] > summary["rms_floor_median"]
    for name in ("figure4", "closed_loop_vs_bob", "closed_loop_floor_null"):
        assert (figures / f"{name}.png").stat().st_size > 5_000, name
