"""Posterior architecture choice on validation only: a crippled candidate loses to a sound one, and
the test and calibration splits do not influence anything (their targets scrambled: same table)."""

import dataclasses

import numpy as np
import pytest
import torch

from forcdecode.learn.posterior_tune import TuningPlan, tune_posterior, tuning_lines
from forcdecode.learn.splits import assign_splits

from test_posterior import LEARNING, SEED, SETTINGS, bar_dataset

QUICK = {**SETTINGS, "epochs": 30, "patience": 8, "ensemble": 1}
CANDIDATES = ({"transforms": 2, "width": 16}, {"transforms": 1, "width": 1, "hidden": 2, "epochs": 1})


@pytest.fixture(scope="module")
def tuned():
    torch.set_num_threads(1)
    data = bar_dataset(n=200)
    return data, tune_posterior(data, QUICK, LEARNING, SEED, TuningPlan(candidates=CANDIDATES, draws=200), log=lambda *_: None)


def test_the_sound_candidate_wins_on_validation(tuned):
    _, result = tuned
    print("\n".join(tuning_lines(result)))
    assert result["chosen_index"] == 0
    assert result["rows"][0]["validation_nll"] < result["rows"][1]["validation_nll"]
    assert result["rows"][0]["validation_mae_median"]["K_u"] < 0.1


def test_test_and_calibration_targets_do_not_matter(tuned):
    data, result = tuned
    splits = assign_splits(data.sample_id, SEED, LEARNING["split"], LEARNING["protocol"])
    hidden = np.concatenate([splits["test"], splits["calibration"]])
    rng = np.random.default_rng(5)
    values = {k: v.copy() for k, v in data.values.items()}
    for name in ("K_u", "D"):
        values[name][hidden] = rng.permutation(values[name][hidden])
        values[name][hidden[:3]] = values[name][hidden[3:6]] * 1.01
    scrambled = dataclasses.replace(data, values=values)
    again = tune_posterior(scrambled, QUICK, LEARNING, SEED, TuningPlan(candidates=CANDIDATES, draws=200),
                           log=lambda *_: None)
    for a, b in zip(result["rows"], again["rows"]):
        assert a["validation_nll"] == b["validation_nll"]
        assert a["validation_coverage_90"] == b["validation_coverage_90"]
