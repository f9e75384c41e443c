"""The answer a user reads (issue 44 item 5, ``learn.answer``): each parameter and derived combination is
flagged read from the image only when its validation skill over the best trivial predictor has a 90 %
bootstrap interval above 0; the flag is saved with the model at training time (Alice and the
posterior), `predict` prints "not read from the image: prior only" instead of the number, `--json`
carries {read_from_image, basis}, Alice's combinations come with Monte-Carlo intervals, and a model
file saved before the flag gives null with the reason.

The data: 16×16 images whose bright rows tell K_u (a bar, as in the posterior tests); A_ex and D are
drawn independently of the image, i.e. networks trained on them learn targets shuffled against their
images. Tiny networks: the three Alice fits take a few seconds."""

import json
import shutil

import numpy as np
import pytest
import torch

from forcdecode.cli import main
from forcdecode.core.parameters import DEFAULT_BOUNDS, denormalize, normalize, quality_factor
from forcdecode.core.streams import stream_rng
from forcdecode.learn.answer import (PREDATES, PRIOR_ONLY, RULE, alice_answer, identification_record,
                                     quantile_draws)
from forcdecode.learn.data import LearningData
from forcdecode.learn.pipeline import train_parameter
from forcdecode.learn.predictor import load_models, predict_parameters

SIDE = 16
NAMES = ("A_ex", "K_u", "D")
TINY = {"width": 16, "epochs": 15, "patience": 5, "batch_size": 8, "lr": 1.0, "folds": 2, "mc_passes": 2,
        "learning_curve": [1.0], "seeds": 1, "bootstrap": 500}


def bar_films(n=200, seed=0) -> LearningData:
    """Rows 0..round(u_K (SIDE − 1)) bright; A_ex and D independent of the image; M_s random."""
    rng = np.random.default_rng(seed)
    u = {name: rng.random(n) for name in NAMES}
    images = np.zeros((n, SIDE, SIDE))
    for k, row in enumerate(np.rint(u["K_u"] * (SIDE - 1)).astype(int)):
        images[k, :row + 1] = 235
    images = (images + rng.integers(0, 20, images.shape)).astype(np.uint8)
    ms = rng.uniform(*DEFAULT_BOUNDS["Ms"], n)
    values = {"Ms": ms, **{name: denormalize(name, u[name]) for name in NAMES}}
    return LearningData(images=images, ms_norm=normalize("Ms", ms), values=values, sample_id=np.arange(n) * 5 + 1,
                        bounds=dict(DEFAULT_BOUNDS), config_hash="bar-films", fields_T=np.linspace(-1, 1, SIDE))


@pytest.fixture(scope="module")
def alice(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("answer")
    data = bar_films()
    metrics = {name: train_parameter(data, name, TINY, seed=3, model_path=out / "models" / f"{name}.pt",
                                     predictions_path=out / f"{name}_predictions.parquet", log=lambda *_: None)
               for name in NAMES}
    return data, metrics, out


# ---------------------------------------------------------------- the rule
def test_the_flag_follows_the_validation_skill_over_the_best_trivial_predictor():
    rng = np.random.default_rng(0)
    n, train, val = 300, np.arange(200), np.arange(200, 260)
    ms, u = rng.random(n), rng.random(n)
    good = np.clip(u + rng.normal(0, 0.05, n), 0, 1)
    constant = np.full(n, np.median(u[train]))          # a model that outputs the prior whatever the image
    shuffled = rng.permutation(u)                       # a model whose answers belong to other families

    def record(estimate):
        return identification_record(u[val], estimate[val], u[train], ms[train], ms[val],
                                     stream_rng(1, "bootstrap", "identification", "x"), 500)

    read = record(good)
    assert read["read_from_image"] is True and read["skill_ci90"][0] > 0.5, read
    assert read["split"] == "validation" and read["n"] == 60
    assert read["basis"] == (f"validation skill over the best trivial predictor {read['skill']:+.2f}, 90 % bootstrap "
                             f"interval [{read['skill_ci90'][0]:+.2f}, {read['skill_ci90'][1]:+.2f}] (n = 60 validation "
                             "families)")
    for estimate in (constant, shuffled):
        row = record(estimate)
        assert row["read_from_image"] is False and row["skill_ci90"][0] < 0, row
    assert record(good) == read                          # the named stream: the same flag on every run
    # the better trivial predictor on each resample: a model that beats only the weaker one is not read
    ms_tied = u + rng.normal(0, 0.02, n)                 # M_s tells u: the M_s-only k-NN is the one to beat
    halfway = np.clip(u + rng.normal(0, 0.15, n), 0, 1)
    row = identification_record(u[val], halfway[val], u[train], ms_tied[train], ms_tied[val],
                                stream_rng(1, "bootstrap", "identification", "y"), 500)
    assert row["best_trivial"] == "ms_only" and row["mae"] < row["mae_prior"] and row["read_from_image"] is False, row
    too_few = identification_record(u[:1], good[:1], u[train], ms[train], ms[:1], rng, 100)
    assert too_few["read_from_image"] is None and "needs 2" in too_few["basis"]


def test_quantile_draws_pass_through_the_intervals_and_stay_in_the_box():
    rng = np.random.default_rng(0)
    draws = quantile_draws(0.3, {0.68: (0.2, 0.4), 0.9: (0.1, 0.5)}, rng, 200_000)
    np.testing.assert_allclose(np.quantile(draws, [0.05, 0.16, 0.5, 0.84, 0.95]), [0.1, 0.2, 0.3, 0.4, 0.5], atol=0.005)
    assert draws.min() >= 0.1 - 0.05 / 0.11 * 0.1 - 1e-9 and draws.max() <= 1.0
    edge = quantile_draws(0.02, {0.68: (0.0, 0.1), 0.9: (0.0, 0.2)}, rng, 10_000)   # clipped at the bound
    assert edge.min() == 0.0 and np.all(np.diff(np.sort(edge)) >= 0)


# ---------------------------------------------------------------- Alice: training and predict
def test_training_saves_the_validation_flag_with_the_model(alice):
    import pandas as pd

    data, metrics, out = alice
    flags = {name: m["validation_identification"]["read_from_image"] for name, m in metrics.items()}
    assert flags == {"K_u": True, "A_ex": False, "D": False}, {n: m["validation_identification"]["basis"]
                                                               for n, m in metrics.items()}
    for name in NAMES:
        payload = torch.load(out / "models" / f"{name}.pt", weights_only=True)
        block = payload["identification"]
        assert block["parameter"] == json.loads(json.dumps(metrics[name]["validation_identification"]))
        # the record is the validation rows' figures (never test): recomputed from the predictions file
        frame = pd.read_parquet(out / f"{name}_predictions.parquet")
        val, train = frame[frame["split"] == "validation"], frame[frame["split"] == "train"]
        ms = dict(zip(data.sample_id, data.ms_norm))
        again = identification_record(val["target"], val["prediction"], train["target"],
                                      [ms[s] for s in train["sample_id"]], [ms[s] for s in val["sample_id"]],
                                      stream_rng(3, "bootstrap", "identification", name), TINY["bootstrap"])
        assert json.loads(json.dumps(again)) == block["parameter"], name
        assert block["records"]["validation"]["sample_id"] == val["sample_id"].tolist()
        assert block["seed"] == 3 and block["rule"] == RULE
    # results/metrics.json carries the validation flag beside the test split's image_adds_information
    from forcdecode.learn.report import aggregate

    paths = []
    for name in NAMES:
        paths.append(out / f"{name}_metrics.json")
        paths[-1].write_text(json.dumps(metrics[name], default=float))
    table = aggregate(paths, out / "metrics.json")["parameters"]
    assert {n: table[n]["validation_identification"]["read_from_image"] for n in NAMES} == flags


def _image_and_ms(data, k=0):
    return data.images[k], float(data.values["Ms"][k])


def test_predict_json_flags_each_parameter_and_combination(alice, tmp_path, capsys):
    data, _, out = alice
    k = int(np.argmax(data.target("K_u")))           # a film with a large K_u: K_eff > 0 at most M_s
    np.save(tmp_path / "image.npy", data.images[k])
    ms_kA_m = float(data.values["Ms"][k]) / 1e3
    args = ["predict", str(tmp_path / "image.npy"), "--Ms-kA-m", f"{ms_kA_m!r}", "--models", str(out / "models")]
    assert main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for name in NAMES:
        assert set(result[name]) >= {"read_from_image", "basis", "value", "interval_68", "interval_90"}
        assert result[name]["basis"].startswith("validation skill over the best trivial predictor")
    assert result["K_u"]["read_from_image"] is True and "prior_range" not in result["K_u"]
    assert result["A_ex"]["read_from_image"] is False and result["D"]["read_from_image"] is False
    assert result["A_ex"]["prior_range"] == pytest.approx(list(DEFAULT_BOUNDS["A_ex"]))
    combos = result["combinations"]
    assert set(combos) == {"sigma_w", "delta_w", "D_over_Dc", "Q"}
    for row in combos.values():
        assert {"read_from_image", "basis", "defined_fraction", "unit", "formula"} <= set(row)
        assert row["read_from_image"] in (True, False, None)
    assert "independently" in result["combinations_method"] and "correlations" in result["combinations_method"]
    # Q depends on K_u alone (M_s given) and grows with it: its Monte-Carlo quantiles are Q at K_u's interval ends
    q, k_u = combos["Q"], result["K_u"]
    assert q["read_from_image"] is True, q["basis"]          # K_u is read, and the plug-in Q with it
    assert q["value"] == pytest.approx(float(quality_factor({"K_u": k_u["value"], "Ms": ms_kA_m * 1e3})), rel=1e-6)
    per_k_u = float(quality_factor({"K_u": 1.0, "Ms": ms_kA_m * 1e3}))
    for tag in ("68", "90"):   # compared in u (K_u's log scale), to the Monte-Carlo error of 4000 draws
        u_ends = normalize("K_u", np.array(q[f"interval_{tag}"]) / per_k_u)
        assert u_ends == pytest.approx(k_u[f"interval_{tag}_normalized"], abs=0.03), tag
    assert main([*args, "--json"]) == 0 and json.loads(capsys.readouterr().out) == result   # same seed, same draws


def test_predict_text_says_prior_only_instead_of_a_number(alice, tmp_path, capsys):
    data, _, out = alice
    np.save(tmp_path / "image.npy", data.images[0])
    assert main(["predict", str(tmp_path / "image.npy"), "--Ms-kA-m", "800", "--models", str(out / "models")]) == 0
    text = capsys.readouterr().out
    rows = {line.split()[0]: line for line in text.splitlines() if line.split()}
    value = predict_parameters(load_models(out / "models"), data.images[0], 8e5)["A_ex"]["value"]
    assert PRIOR_ONLY in rows["A_ex"] and f"{value:.4g}" not in rows["A_ex"] and rows["A_ex"].rstrip().endswith("no")
    assert PRIOR_ONLY in rows["D"] and PRIOR_ONLY not in rows["K_u"] and rows["K_u"].rstrip().endswith("yes")
    assert "derived combinations" in text and "ignores the correlations" in text and "Q" in rows
    assert "K_u: validation skill over the best trivial predictor" in text and RULE in text


def test_an_old_model_file_gives_null_with_the_reason(alice, tmp_path, capsys):
    data, _, out = alice
    models = tmp_path / "models"
    shutil.copytree(out / "models", models)
    payload = torch.load(models / "D.pt", weights_only=True)
    del payload["identification"]                      # a model file saved before the flag existed
    torch.save(payload, models / "D.pt")
    loaded = load_models(models)
    image, ms = _image_and_ms(data)
    result = alice_answer(loaded, predict_parameters(loaded, image, ms), n_draws=500)
    assert result["D"]["read_from_image"] is None and result["D"]["basis"] == PREDATES
    for name in ("sigma_w", "D_over_Dc"):             # they need D
        assert result["combinations"][name]["read_from_image"] is None
        assert result["combinations"][name]["basis"] == PREDATES
    assert result["combinations"]["Q"]["read_from_image"] is True     # K_u alone: still decided
    assert result["K_u"]["read_from_image"] is True
    np.save(tmp_path / "image.npy", image)
    assert main(["predict", str(tmp_path / "image.npy"), "--Ms-kA-m", f"{ms / 1e3!r}", "--models", str(models)]) == 0
    text = capsys.readouterr().out
    assert f"D: {PREDATES}" in text and "retrain the models" in text
    assert main(["predict", str(tmp_path / "image.npy"), "--Ms-kA-m", "800", "--models", str(models),
                 "--draws", "0"]) == 2
    assert "must be positive" in capsys.readouterr().err


# ---------------------------------------------------------------- the posterior
@pytest.fixture(scope="module")
def posterior(tmp_path_factory):
    from forcdecode.learn.posterior import train_posterior

    from test_posterior import LEARNING, SEED, SETTINGS, bar_dataset

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("posterior_answer")
    data = bar_dataset()
    metrics = train_posterior(data, {**SETTINGS, "ensemble": 1}, LEARNING, SEED, out / "model.pt", out / "metrics.json",
                              out / "figures" / "posterior_calibration.png", log=lambda *_: None)
    return data, metrics, out


def test_the_posterior_saves_its_validation_flags_and_predict_carries_them(posterior, tmp_path, capsys):
    from forcdecode.learn.posterior import PosteriorEstimator

    data, metrics, out = posterior
    block = metrics["identification"]
    assert block["split"] == "validation" and block["rule"] == RULE
    parameters = block["parameters"]
    assert parameters["K_u"]["read_from_image"] is True and parameters["D"]["read_from_image"] is False, parameters
    assert set(block["combinations"]) == {"Q"}          # the only combination of K_u and D (M_s given)
    est = PosteriorEstimator.load(out / "model.pt")
    assert est.metadata["identification"] == json.loads(json.dumps(block))
    np.save(tmp_path / "image.npy", data.images[0])
    args = ["predict", str(tmp_path / "image.npy"), "--Ms-kA-m", "800", "--estimator", "posterior",
            "--posterior", str(out / "model.pt"), "--draws", "300"]
    assert main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["K_u"]["read_from_image"] is True and result["D"]["read_from_image"] is False
    assert result["D"]["basis"] == parameters["D"]["basis"] and result["D"]["prior_range"] == list(DEFAULT_BOUNDS["D"])
    assert result["combinations"]["Q"]["read_from_image"] == block["combinations"]["Q"]["read_from_image"]
    assert main(args) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.split()}
    assert PRIOR_ONLY in rows["D"] and PRIOR_ONLY not in rows["K_u"]
    # a posterior saved before the flag: null with the reason
    est.metadata.pop("identification")
    est.save(tmp_path / "old.pt", **est.metadata)
    assert main([*args[:-4], "--posterior", str(tmp_path / "old.pt"), "--draws", "300", "--json"]) == 0
    old = json.loads(capsys.readouterr().out)
    assert old["K_u"]["read_from_image"] is None and old["K_u"]["basis"] == PREDATES
    assert old["combinations"]["Q"]["basis"] == PREDATES


def test_a_quantity_whose_interval_spans_most_of_its_prior_is_not_read_for_this_file():
    """Per-file honesty (issue 59 item 5): the global flag says D is read from the image on average, but
    for this file D's 90 % interval spans 90 % of its prior range, so it is printed as not read for this
    file with the reason; K_u, narrow here, is; a prior-only parameter stays prior only; a combination
    whose interval covers its whole prior range at this M_s is not read for this file either."""
    from forcdecode.learn.answer import NOT_FOR_THIS_FILE, per_file_identification
    from forcdecode.learn.predictor import prediction_lines

    bounds = dict(DEFAULT_BOUNDS)
    ms = 8e5

    def entry(name, lo, hi, read=True):
        mid = (lo + hi) / 2
        return {"value": float(denormalize(name, mid, bounds)), "normalized": mid,
                "interval_68": [float(denormalize(name, mid - 0.01, bounds)), float(denormalize(name, mid + 0.01, bounds))],
                "interval_90": [float(denormalize(name, lo, bounds)), float(denormalize(name, hi, bounds))],
                "interval_90_normalized": [lo, hi], "read_from_image": read, "basis": "validation skill …"}

    result = {"Ms": ms, "K_u": entry("K_u", 0.45, 0.52), "D": entry("D", 0.05, 0.95),
              "N_pin": entry("N_pin", 0.1, 0.9, read=False),
              "combinations": {"Q": {"value": 2.0, "interval_68": [1.9, 2.1], "interval_90": [1e-3, 1e3], "unit": "",
                                     "defined_fraction": 1.0, "read_from_image": True, "basis": "…"}}}
    out = per_file_identification(result, bounds)
    assert out["K_u"]["read_for_this_file"] and out["K_u"]["interval_90_prior_share"] == pytest.approx(0.07)
    assert out["D"]["read_for_this_file"] is False and NOT_FOR_THIS_FILE in out["D"]["per_file_basis"]
    assert out["N_pin"]["read_for_this_file"] is False and "per_file_basis" not in out["N_pin"]
    assert out["combinations"]["Q"]["read_for_this_file"] is False
    assert out["identified_for_this_file"] == ["K_u"]
    text = "\n".join(prediction_lines(out, "file", ms / 1e3))
    assert "no: not for this file" in text and "this file identifies: K_u" in text
