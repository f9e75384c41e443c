"""--estimator auto (learn/estimator_choice.py): the estimator validation shows better answers; Alice
where the records are missing or on a tie; the loop's own overrides (--refine, --params)."""

import argparse
from types import SimpleNamespace

import pytest

from forcdecode.core.errors import ModelFileError
from forcdecode.learn.estimator_choice import (alice_validation_mae, choose, choose_estimator,
                                               default_posterior_path, posterior_validation_mae)
from forcdecode.learn.predictor import load_models
from forcdecode.loop.command import resolve_estimator


def test_the_lower_mean_validation_mae_answers():
    alice = {"K_u": 0.05, "A_ex": 0.12, "D": 0.20}
    better = choose(alice, {"K_u": 0.04, "A_ex": 0.12, "D": 0.19})
    assert better["estimator"] == "posterior" and better["parameters"] == ["A_ex", "D", "K_u"]
    assert "posterior 0.117, Alice 0.123" in better["basis"]
    assert choose(alice, {"K_u": 0.06, "A_ex": 0.12, "D": 0.20})["estimator"] == "alice"
    assert choose(alice, dict(alice))["estimator"] == "alice"  # a tie: Alice
    # only the parameters both estimate count: the posterior's extra N_pin does not
    assert choose(alice, {"K_u": 0.049, "A_ex": 0.12, "D": 0.20, "N_pin": 0.9})["estimator"] == "posterior"
    assert choose(alice, None)["basis"] == "no posterior model"
    assert choose(alice, {"N_pin": 0.1})["estimator"] == "alice"


def test_the_records_come_from_the_identification_blocks():
    models = {"K_u": SimpleNamespace(payload={"identification": {"parameter": {"mae": 0.05}}}),
              "D": SimpleNamespace(payload={"format": "forcdecode-alice-bob/1"})}  # saved before the records
    assert alice_validation_mae(models) == {"K_u": 0.05}
    assert posterior_validation_mae({"identification": {"parameters": {"K_u": {"mae": 0.04}}}}) == {"K_u": 0.04}
    assert posterior_validation_mae({}) == {}


def test_without_any_model_alice_says_what_is_missing_and_a_posterior_alone_answers(tmp_path):
    nothing = choose_estimator(tmp_path / "models", tmp_path / "posterior" / "model.pt")
    assert nothing["estimator"] == "alice" and "no model files" in nothing["basis"]
    with pytest.raises(ModelFileError, match="no trained model"):  # where Alice is then needed
        load_models(tmp_path / "models")
    (tmp_path / "posterior").mkdir()
    (tmp_path / "posterior" / "model.pt").write_bytes(b"")
    assert choose_estimator(tmp_path / "models", tmp_path / "posterior" / "model.pt")["estimator"] == "posterior"
    assert default_posterior_path("results/models") == "results/posterior/model.pt"


def test_the_loop_resolves_auto_before_anything_is_read(tmp_path):
    args = argparse.Namespace(estimator="auto", refine=50, params=None, models=str(tmp_path / "m"), posterior=None)
    assert resolve_estimator(args)["estimator"] == "posterior" and args.estimator == "posterior"
    assert args.posterior == str(tmp_path / "posterior" / "model.pt")
    args = argparse.Namespace(estimator="auto", refine=0, params="h.json", models=str(tmp_path / "m"), posterior=None)
    assert resolve_estimator(args)["estimator"] == "alice"
    args = argparse.Namespace(estimator="alice", refine=0, params=None, models="m", posterior="p.pt")
    assert resolve_estimator(args) is None and args.posterior == "p.pt"
