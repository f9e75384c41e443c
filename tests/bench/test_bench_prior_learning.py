"""Paper against perpendicular prior class on K_eff > 0 validation families (bench/prior_learning.py),
on synthetic runs whose answer is known."""

import json

import h5py
import numpy as np
import pandas as pd
import pytest

from forcdecode.bench.prior_learning import compare_classes, load_class_run, summary_lines
from forcdecode.core.errors import InputFileError

MU0 = 4e-7 * np.pi


def write_run(folder, prior, k_eff_sign, error, n=120, seed=0, family_cpu=2.0, half_error=None):
    """A finished learning stage of ``n`` families: ``k_eff_sign[i]`` the sign of family i's K_eff;
    splits cycle train/validation; the full set's networks are off by ``error`` (alternating sign)
    everywhere, the half set's (the learning curve's first point) by ``half_error`` (default: the same)."""
    rng = np.random.default_rng(seed)
    (folder / "learn").mkdir(parents=True)
    ids = np.arange(n) + 1000 * seed
    ms = np.full(n, 1.0e6)
    k_u = MU0 * ms**2 / 2 * np.where(k_eff_sign > 0, 1.5, 0.5)
    with h5py.File(folder / "dataset.h5", "w") as h5:
        columns = ["Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K"]
        table = np.zeros((n, len(columns)))
        table[:, 0], table[:, 2] = ms, k_u
        h5["parameters"] = table
        h5["parameters"].attrs["columns"] = columns
        h5["sample_id"] = ids
        h5.attrs["config_json"] = json.dumps({"prior": prior} if prior != "paper" else {})
    pd.DataFrame({"sample_id": ids, "in_dataset": True, "screen_cpu_s": 1.0, "family_cpu_s": family_cpu}
                 ).to_parquet(folder / "samples.parquet")
    split = np.where(np.arange(n) % 2 == 0, "train", "validation")
    truth = rng.uniform(0.2, 0.8, n)
    sign = np.where(np.arange(n) % 4 < 2, 1.0, -1.0)
    for name in ("K_u", "D"):
        pd.DataFrame({"sample_id": ids, "split": split, "target": truth, "prediction": truth + sign * error,
                      "ms_only_prediction": np.full(n, 0.5)}).to_parquet(folder / "learn" / f"{name}_predictions.parquet")
        val = split == "validation"
        half = error if half_error is None else half_error
        curve = {"sizes": [n // 4, n // 2], "validation_sample_ids": ids[val].tolist(),
                 "validation_truth": truth[val].tolist(),
                 "validation_predictions": [[(truth[val] + sign[val] * e).tolist()] * 3 for e in (half, error)]}
        (folder / "learn" / f"{name}_metrics.json").write_text(json.dumps({"learning_curve": curve}))


def test_scored_on_k_eff_positive_validation_families_and_the_rule(tmp_path):
    n = 120
    mixed = np.where(np.arange(n) % 3 == 0, 1.0, -1.0)  # paper: a third perpendicular
    write_run(tmp_path / "a", "paper", mixed, 0.10)
    write_run(tmp_path / "c", "perpendicular", np.ones(n), 0.05, seed=1)
    run = load_class_run(tmp_path / "a")
    assert run["prior_class"] == "paper" and run["fraction_k_eff_positive"] == pytest.approx(40 / 120)
    # validation = odd positions; K_eff > 0 at multiples of 3: odd multiples of 3 below 120 -> 20
    assert run["parameters"]["K_u"]["ids"].size == 20
    result = compare_classes(tmp_path / "a", tmp_path / "c")
    assert result["mean_mae"]["A"] == pytest.approx(0.10) and result["mean_mae"]["C"] == pytest.approx(0.05)
    assert result["mean_mae_difference_ci90"][1] < 0
    assert result["decision"].startswith("C (perpendicular)")
    assert result["per_parameter"]["K_u"]["C"]["n"] == 60
    assert any(line.startswith("decision") for line in summary_lines(result))
    # the paper-class networks much better on perpendicular films: the paper class stays
    write_run(tmp_path / "c2", "perpendicular", np.ones(n), 0.30, seed=2)
    result = compare_classes(tmp_path / "a", tmp_path / "c2")
    assert result["mean_mae_difference_ci90"][0] > 0 and result["decision"].startswith("A (paper) stays")


def test_c_is_scored_against_a_at_matched_simulation_cost(tmp_path):
    n = 120
    mixed = np.where(np.arange(n) % 3 == 0, 1.0, -1.0)
    # A: 120 x (1 + 2) = 360 CPU-s, its half set 180; C: 120 x (1 + 0.5) = 180 CPU-s -> A's half set
    write_run(tmp_path / "a", "paper", mixed, 0.05, half_error=0.20)
    write_run(tmp_path / "c", "perpendicular", np.ones(n), 0.10, seed=1, family_cpu=0.5)
    result = compare_classes(tmp_path / "a", tmp_path / "c")
    assert result["runs"]["A"]["point"] == 0 and result["runs"]["A"]["train_size"] == 30
    assert result["cost_ratio_c_over_a"] == pytest.approx(1.0)
    assert result["mean_mae"]["A"] == pytest.approx(0.20) and result["decision"].startswith("C")
    # C dearer than any point of A by more than 10 %: refused, not scored against a cheaper A
    write_run(tmp_path / "c2", "perpendicular", np.ones(n), 0.10, seed=2, family_cpu=4.0)
    with pytest.raises(InputFileError, match="no point of run A"):
        compare_classes(tmp_path / "a", tmp_path / "c2")


def test_a_run_without_perpendicular_training_families_is_refused(tmp_path):
    write_run(tmp_path / "a", "paper", -np.ones(40), 0.1, n=40)
    with pytest.raises(InputFileError, match="no training family with K_eff > 0"):
        load_class_run(tmp_path / "a")
