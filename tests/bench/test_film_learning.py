"""Learning curves against simulation core-hours (bench/film_learning.py) on two synthetic runs
whose answer is known: the costlier film learns better per sample but not per core-hour."""

import json

import numpy as np
import pandas as pd
import pytest

from forcdecode.bench.film_learning import compare_films, figure, run_curves, summary_lines
from forcdecode.core.errors import InputFileError


def write_run(folder, n_draws, n_ok, screen_cpu, family_cpu, sizes, mae, prior=0.2, ms_only=0.25, nx=64, ci=0.05,
              validation=None):
    """A finished run's files. ``validation``: (MAE sizes × seeds, prior MAE, M_s-only MAE) of the curve
    scored on validation; the validation predictions are made to give the full-set skill it implies."""
    folder.mkdir(parents=True)
    ok = np.arange(n_draws) < n_ok
    pd.DataFrame({"sample_id": np.arange(n_draws), "in_dataset": ok, "screen_s": 99.0, "screen_cpu_s": screen_cpu,
                  "family_s": np.where(ok, 99.0, np.nan), "family_cpu_s": np.where(ok, family_cpu, np.nan)}
                 ).to_parquet(folder / "samples.parquet")
    entry = {"sizes": sizes, "mae": mae, "baselines": {"prior": prior, "ms_only": ms_only}}
    if validation is not None:
        val_mae, val_prior, val_ms = validation
        entry |= {"mae_validation": val_mae, "baselines_validation": {"prior": val_prior, "ms_only": val_ms}}
        # 40 validation samples around a train median of 0.5: |prior error| = val_prior for each,
        # the M_s-only predictor off by val_ms, the network off by the full set's mean validation MAE
        truth = 0.5 + val_prior * np.where(np.arange(40) % 2 == 0, 1.0, -1.0)
        err = float(np.mean(val_mae[-1]))
        pd.DataFrame({"split": ["train"] * 3 + ["validation"] * 40,
                      "target": np.r_[0.4, 0.5, 0.6, truth], "prediction": np.r_[0.5, 0.5, 0.5, truth + err],
                      "ms_only_prediction": np.r_[0.5, 0.5, 0.5, truth - val_ms]}
                     ).to_parquet(_mkdir(folder / "learn") / "K_u_predictions.parquet")
    (folder / "learning_curve.json").write_text(json.dumps({"parameters": {"K_u": entry}}))
    (folder / "config.json").write_text(json.dumps({"mesh": {"nx": nx, "ny": nx, "nz": 1}, "n_grains": 16, "seed": 7}))
    skill = 1 - np.mean(mae[-1]) / min(prior, ms_only)
    (folder / "metrics.json").write_text(json.dumps({"parameters": {"K_u": {
        "n_test": 30, "skill_vs_prior": skill, "skill_vs_prior_ci90": [skill - ci, skill + ci],
        "skill_vs_ms_only": 0.0, "skill_vs_ms_only_ci90": [-0.1, 0.1]}}}))


def _mkdir(path):
    path.mkdir(parents=True, exist_ok=True)
    return path


def test_cost_per_sample_and_skill_over_best_trivial(tmp_path):
    # 10 draws at 1 CPU-s screening, 4 in the dataset at 8 CPU-s each: (10 + 32) / 4 = 10.5 core-s per sample
    write_run(tmp_path / "a", 10, 4, 1.0, 8.0, [2, 4], [[0.1, 0.12], [0.05, 0.07]])
    run = run_curves(tmp_path / "a")
    assert run["clock"] == "cpu"
    assert run["core_s_per_sample"] == pytest.approx(10.5)
    k = run["parameters"]["K_u"]
    assert k["core_hours"] == pytest.approx([2 * 10.5 / 3600, 4 * 10.5 / 3600])
    assert k["trivial_mae"] == 0.2  # the better of the two trivial predictors
    assert k["skill_mean"] == pytest.approx([1 - 0.11 / 0.2, 1 - 0.06 / 0.2])
    assert k["skill_min"] == pytest.approx([1 - 0.12 / 0.2, 1 - 0.07 / 0.2])


def test_equal_budget_favours_the_cheaper_film_when_it_learns_faster_per_core_hour(tmp_path):
    # cheap: 1 core-s per sample; skill 0.5 at 100 samples and 0.75 at 400
    write_run(tmp_path / "cheap", 4, 4, 0.0, 1.0, [100, 400], [[0.1, 0.1], [0.05, 0.05]])
    # costly: 4 core-s per sample; better per sample (0.6 at 100) but at 400 core-s it has only 100 samples
    write_run(tmp_path / "costly", 4, 4, 0.0, 4.0, [25, 100], [[0.12, 0.12], [0.08, 0.08]], nx=128)
    result = compare_films({"cheap": tmp_path / "cheap", "costly": tmp_path / "costly"})
    row = result["at_common_budget"]["K_u"]
    assert row["budget_core_hours"] == pytest.approx(400 / 3600)
    assert row["films"]["cheap"]["mean"] == pytest.approx(0.75)
    assert row["films"]["costly"]["mean"] == pytest.approx(0.6)
    assert row["best"] == "cheap"
    assert any("-> cheap" in line for line in summary_lines(result))
    assert result["films"]["costly"]["parameters"]["K_u"]["full_set_skill"] == pytest.approx(0.6)
    # a wide bootstrap interval on the full set makes the same curves a tie
    write_run(tmp_path / "cheap_few_tests", 4, 4, 0.0, 1.0, [100, 400], [[0.1, 0.1], [0.05, 0.05]], ci=0.3)
    wide = compare_films({"cheap": tmp_path / "cheap_few_tests", "costly": tmp_path / "costly"})
    assert wide["at_common_budget"]["K_u"]["best"] == "tie"
    # curves below the trivial predictors: nothing to choose by
    write_run(tmp_path / "bad1", 4, 4, 0.0, 1.0, [100, 400], [[0.3, 0.3], [0.25, 0.25]])
    write_run(tmp_path / "bad2", 4, 4, 0.0, 1.0, [100, 400], [[0.35, 0.35], [0.3, 0.3]])
    assert compare_films({"a": tmp_path / "bad1", "b": tmp_path / "bad2"})["at_common_budget"]["K_u"]["best"] == "none learned"
    figure(result, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0


def test_an_unfinished_run_is_named(tmp_path):
    (tmp_path / "run").mkdir()
    with pytest.raises(InputFileError, match="not a finished run"):
        run_curves(tmp_path / "run")


def test_curves_scored_on_validation_decide_and_test_is_only_carried(tmp_path):
    # on test the costly film looks better; on validation (where the choice is made) the cheap one is
    write_run(tmp_path / "cheap", 4, 4, 0.0, 1.0, [100, 400], [[0.12, 0.12], [0.1, 0.1]],
              validation=([[0.1, 0.1], [0.05, 0.05]], 0.2, 0.25))
    write_run(tmp_path / "costly", 4, 4, 0.0, 4.0, [25, 100], [[0.08, 0.08], [0.04, 0.04]], nx=128,
              validation=([[0.12, 0.12], [0.08, 0.08]], 0.2, 0.25))
    result = compare_films({"cheap": tmp_path / "cheap", "costly": tmp_path / "costly"})
    cheap = result["films"]["cheap"]
    assert cheap["scored_on"] == "validation"
    k = cheap["parameters"]["K_u"]
    assert k["trivial"] == "prior" and k["trivial_mae"] == 0.2
    assert k["skill_mean"] == pytest.approx([0.5, 0.75])
    # the full set on validation: 1 - 0.05 / 0.2, its bootstrap interval over 40 identical errors is a point
    assert k["full_set_skill"] == pytest.approx(0.75)
    assert k["full_set_skill_ci90"] == pytest.approx([0.75, 0.75])
    assert k["test_full_set_skill"] == pytest.approx(1 - 0.1 / 0.2)  # carried, not used
    row = result["at_common_budget"]["K_u"]
    assert row["films"]["costly"]["mean"] == pytest.approx(0.6) and row["best"] == "cheap"
    lines = summary_lines(result)
    assert any("curves scored on validation" in line for line in lines)
    assert any("test, reported only" in line for line in lines)
    # a run whose curves were scored on test cannot be ranked beside them
    write_run(tmp_path / "old", 4, 4, 0.0, 1.0, [100, 400], [[0.1, 0.1], [0.05, 0.05]])
    assert run_curves(tmp_path / "old")["scored_on"] == "test"
    with pytest.raises(InputFileError, match="different splits"):
        compare_films({"cheap": tmp_path / "cheap", "old": tmp_path / "old"})
