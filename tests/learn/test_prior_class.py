"""The prior class travels with every model and is checked against the measured loop: a model records the
class of its training data (old files read as paper), ``predict`` says which class and refuses, with a
typed error giving the measured numbers, a file whose loop contradicts a perpendicular model's class
(``--force`` decodes it anyway), and ``learn evaluate`` reports the test families per regime of K_eff."""

import json
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
import torch

from forcdecode.cli import main
from forcdecode.core.errors import ModelFileError, OutOfDomainError, PriorClassError
from forcdecode.core.parameters import DEFAULT_BOUNDS, k_eff, normalize
from forcdecode.dataset.params import draw_prior_cdf
from forcdecode.forc.raster import quantize
from forcdecode.learn.prior_class import (PERPENDICULAR_MAX_EXIT_FIELD_T, PERPENDICULAR_MIN_REMANENCE,
                                         ascending_remanence, check_prior_class, descending_remanence, loop_remanence,
                                         saturation_exit_field)

SIDE = 16
FIXTURE = Path(__file__).parent / "data" / "laptop_forc_32px.npz"


def loop_image(descending, ascending, side=SIDE) -> np.ndarray:
    """A FORC image (uint8) whose diagonal is ``descending`` and whose first row is ``ascending`` (both
    functions of H on the symmetric grid); the other cells hold the descending branch's value."""
    h = np.linspace(-1.0, 1.0, side)
    m = np.tile(descending(h)[:, None], (1, side))  # row i: m(H_r = h_i) everywhere
    m[0] = ascending(h)
    np.fill_diagonal(m, descending(h))
    return quantize(m)


def square(h):  # perpendicular film: saturated down to the coercive field (0.3 T)
    return np.where(h > -0.3, 1.0, -1.0)


def square_up(h):
    return np.where(h > 0.3, 1.0, -1.0)


def hard_axis(h):  # in-plane film along its hard axis: m = H/H_k
    return np.clip(h / 0.6, -1.0, 1.0)


def test_the_remanence_is_read_off_both_branches():
    image = loop_image(square, square_up)
    assert descending_remanence(image) == pytest.approx(1.0) and ascending_remanence(image) == pytest.approx(1.0)
    assert loop_remanence(loop_image(hard_axis, hard_axis)) == pytest.approx(0.0, abs=0.01)
    # one square branch suffices (pinning and DMI break the ±H symmetry)
    assert loop_remanence(loop_image(hard_axis, square_up)) == pytest.approx(1.0)
    assert loop_remanence(np.full((SIDE, SIDE), 128, np.uint8)) == pytest.approx(0.0, abs=0.01)  # demagnetized


def test_a_perpendicular_model_refuses_an_in_plane_loop_with_the_numbers():
    in_plane = loop_image(hard_axis, hard_axis)
    with pytest.raises(PriorClassError) as caught:
        check_prior_class("perpendicular", in_plane, source="film.txt")
    message = str(caught.value)
    assert isinstance(caught.value, OutOfDomainError)
    assert "film.txt" in message and "m_r = M_r/M_s = 0.0" in message and "perpendicular" in message
    assert f"below {PERPENDICULAR_MIN_REMANENCE:g}" in message and "--force" in message
    assert caught.value.check["consistent"] is False and caught.value.check["m_r"] < 0.05
    forced = check_prior_class("perpendicular", in_plane, force=True)
    assert forced["forced"] and not forced["consistent"] and forced["reason"]
    ok = check_prior_class("perpendicular", loop_image(square, square_up))
    assert ok["consistent"] and ok["threshold"] == PERPENDICULAR_MIN_REMANENCE and ok["m_r"] > 0.99
    paper = check_prior_class("paper", in_plane)  # paper covers both regimes: nothing to contradict
    assert paper["consistent"] and paper["threshold"] is None and paper["m_r"] < 0.05
    assert check_prior_class(None, in_plane)["prior_class"] == "paper"


def test_a_spiral_loop_is_not_refused_an_in_plane_one_is():
    """Both unsaturated at remanence; the spiral film (|D| > D_c) leaves saturation only at low field."""
    spiral = loop_image(lambda h: np.clip(h / 0.1, -1, 1), lambda h: np.clip(h / 0.1, -1, 1), side=64)
    assert loop_remanence(spiral) < 0.05 and saturation_exit_field(spiral) < PERPENDICULAR_MAX_EXIT_FIELD_T
    assert check_prior_class("perpendicular", spiral)["consistent"]
    in_plane = loop_image(hard_axis, hard_axis, side=64)
    assert saturation_exit_field(in_plane) == pytest.approx(0.54, abs=0.01)
    assert saturation_exit_field(in_plane, B_max_T=2.0) == pytest.approx(1.08, abs=0.02)  # the grid's field scale
    with pytest.raises(PriorClassError, match="H_n = 0.539 T > 0.15 T"):
        check_prior_class("perpendicular", in_plane)
    assert -0.31 < saturation_exit_field(loop_image(square, square_up)) < -0.15  # a step at -0.3 T on the 16-field grid


def test_the_rule_on_simulated_laptop_families():
    """148 simulated families of an earlier laptop film (32 × 32 images averaged from 64 × 64; not used
    for any choice of the rule): no K_eff > 0 family refused, 88 of 97 K_eff < 0 ones caught (m_r alone:
    2 and 96). docs/inference.md has the rates on the current laptop film (forcdecode bench prior-class)."""
    from forcdecode.bench.prior_class import family_observables, rule_rates
    from forcdecode.learn.prior_class import contradicts_perpendicular

    data = np.load(FIXTURE)
    m_r, h_n = family_observables(data["images"])
    rates = rule_rates(contradicts_perpendicular(m_r, h_n), k_eff({"K_u": data["K_u"], "Ms": data["Ms"]}))
    assert rates["n_keff_positive"] == 51 and rates["n_keff_negative"] == 97
    assert rates["false_refusal_rate"] <= 0.05 and rates["catch_rate"] >= 0.85, rates


# ---------------------------------------------------------------- model files
def save_alice(path, name="K_u", prior_class="perpendicular", side=SIDE):
    """An (untrained) Alice–Bob model file as the pipeline writes it."""
    from types import SimpleNamespace

    from forcdecode.learn.models import build_network
    from forcdecode.learn.pipeline import ErrorModel, save_model
    from forcdecode.learn.uncertainty import ConformalIntervals

    torch.manual_seed(0)
    nets = [SimpleNamespace(net=build_network("small", width=4, image_size=side)) for _ in range(2)]
    data = SimpleNamespace(images=np.zeros((1, side, side), np.uint8), bounds=dict(DEFAULT_BOUNDS),
                           config_hash="test", prior_class=prior_class)
    errors = ErrorModel(bob=nets[1], validation_errors=[0.1, 0.2],
                        conformal=ConformalIntervals((0.68, 0.9), {0.68: 1.0, 0.9: 2.0}, 1e-4))
    save_model(path, name=name, alice=nets[0], error_model=errors,
               settings={"model": "small", "width": 4, "readout": "parabola"}, data=data, metrics={})


def test_a_model_file_records_its_class_and_an_old_one_reads_as_paper(tmp_path):
    from forcdecode.learn.predictor import ParameterModel, load_models, models_prior_class

    save_alice(tmp_path / "K_u.pt")
    assert ParameterModel.load(tmp_path / "K_u.pt").prior_class == "perpendicular"
    payload = torch.load(tmp_path / "K_u.pt", weights_only=True)
    del payload["prior_class"]  # a file written before the key
    payload["parameter"] = "D"
    torch.save(payload, tmp_path / "D.pt")
    assert ParameterModel.load(tmp_path / "D.pt").prior_class == "paper"
    with pytest.raises(ModelFileError, match="different prior classes"):
        models_prior_class(load_models(tmp_path))
    assert models_prior_class(load_models(tmp_path, ["K_u"])) == "perpendicular"


def test_predict_says_the_class_and_refuses_a_contradicting_file(tmp_path, capsys):
    models = tmp_path / "models"
    models.mkdir()
    save_alice(models / "K_u.pt")
    in_plane, square_loop = tmp_path / "in_plane.npy", tmp_path / "square.npy"
    np.save(in_plane, loop_image(hard_axis, hard_axis))
    np.save(square_loop, loop_image(square, square_up))
    assert main(["predict", str(in_plane), "--Ms-kA-m", "800", "--models", str(models)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "m_r = M_r/M_s = 0.0" in err and "'perpendicular'" in err
    assert "Traceback" not in err
    assert main(["predict", str(in_plane), "--Ms-kA-m", "800", "--models", str(models), "--force"]) == 0
    out = capsys.readouterr().out
    assert "model trained on prior class: perpendicular" in out and "WARNING (decoded with --force)" in out
    assert main(["predict", str(square_loop), "--Ms-kA-m", "800", "--models", str(models), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["prior_class"] == "perpendicular" and result["prior_check"]["consistent"]
    assert result["prior_check"]["m_r"] > 0.99 and "K_u" in result


def test_the_posterior_file_records_its_class_and_uses_its_draw_prior(tmp_path):
    from forcdecode.learn.posterior import PosteriorEstimator, posterior_settings
    from forcdecode.learn.posterior.flow import PosteriorNet

    settings = posterior_settings({"width": 8, "hidden": 8, "transforms": 1})
    architecture = {"embedding": "mlp", "features": 3, "summary": settings["summary"], "coordinates": "prior",
                    "dim": 2, "width": 8, "dropout": 0.0, "transforms": 1, "hidden": 8, "bins": int(settings["bins"])}
    est = PosteriorEstimator(PosteriorNet(architecture), architecture, ("K_u", "D"), dict(DEFAULT_BOUNDS),
                             prior_class="perpendicular")
    est.save(tmp_path / "model.pt")
    loaded = PosteriorEstimator.load(tmp_path / "model.pt")
    assert loaded.prior_class == "perpendicular"
    ms = np.array([6e5, 1.3e6])
    u = np.array([[0.97, 0.3], [0.99, 0.6]])
    v = loaded.to_coordinates(u, normalize("Ms", ms))
    assert np.allclose(v[:, 0], draw_prior_cdf("K_u", u[:, 0], ms, prior="perpendicular"))
    assert np.allclose(loaded.from_coordinates(v, normalize("Ms", ms)), u)
    payload = torch.load(tmp_path / "model.pt", weights_only=True)
    del payload["prior_class"]
    torch.save(payload, tmp_path / "old.pt")
    assert PosteriorEstimator.load(tmp_path / "old.pt").prior_class == "paper"


# ---------------------------------------------------------------- metrics per regime
def test_evaluate_reports_the_test_families_per_regime(tmp_path):
    from forcdecode.learn.report import regime_markdown, regime_metrics

    rng = np.random.default_rng(0)
    n = 40
    ms = rng.uniform(2e5, 1.4e6, n)
    ku = np.where(np.arange(n) % 2 == 0, 1.2 * 4e-7 * np.pi * ms**2 / 2, 2e3)  # even ids perpendicular
    path = tmp_path / "dataset.h5"
    columns = ["Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K"]
    table = np.zeros((n, len(columns)))
    table[:, 0], table[:, 2] = ms, ku
    with h5py.File(path, "w") as h5:
        dset = h5.create_dataset("parameters", data=table)
        dset.attrs["columns"] = columns
        h5["sample_id"] = np.arange(n)
        h5.attrs["config_json"] = json.dumps({"seed": 1, "prior": "paper"})
    split = np.where(np.arange(n) < 20, "train", "test")
    target = rng.random(n)
    error = np.where(np.arange(n) % 2 == 0, 0.05, 0.2)  # perpendicular test families predicted better
    frame = pd.DataFrame({"sample_id": np.arange(n), "split": split, "target": target, "prediction": target + error,
                          "ms_only_prediction": np.full(n, 0.5)})
    result = regime_metrics({"K_u": frame}, path)
    assert result["prior_class"] == "paper" and result["counts"] == {"K_eff>0": 10, "K_eff<0": 10}
    pos, neg = result["parameters"]["K_u"]["K_eff>0"], result["parameters"]["K_u"]["K_eff<0"]
    assert pos["n"] == 10 and pos["mae"] == pytest.approx(0.05) and neg["mae"] == pytest.approx(0.2)
    prior = np.median(target[:20])
    assert pos["mae_prior"] == pytest.approx(np.mean(np.abs(prior - target[20:][::2])))
    assert pos["skill_vs_prior"] == pytest.approx(1 - 0.05 / pos["mae_prior"])
    assert neg["skill_vs_ms_only"] == pytest.approx(1 - 0.2 / np.mean(np.abs(0.5 - target[21::2])))
    assert "| K_u | K_eff>0 | 10 | 0.050 |" in regime_markdown(result)


# ---------------------------------------------------------------- the loop
def test_the_loop_refuses_an_in_plane_file_for_a_perpendicular_model_and_writes_why(tmp_path, capsys):
    """A measured in-plane film (hard-axis loop of 0.1 T hysteresis, saturated at 0.65 T inside the ±1 T
    window: in the domain) given to a perpendicular-class model: `forcdecode loop` stops before any
    decoding, writes the report (status and the check) and exits 2 with the reason; nothing is
    re-simulated."""
    from forcdecode.measured.writers import write_micromag_0015

    root = Path(__file__).resolve().parents[2]
    models = tmp_path / "models"
    models.mkdir()
    save_alice(models / "K_u.pt", side=16)  # config/test.yaml: 16 fields
    fields = np.linspace(-1.0, 1.0, 41)
    rng = np.random.default_rng(0)
    descending, ascending = (lambda h: hard_axis(h + 0.05)), (lambda h: hard_axis(h - 0.05))
    # a FORC from H_r: the ascending branch moved to start on the descending one, up to it
    curves = [(fields[i:], (np.minimum(descending(fields[i:]), ascending(fields[i:]) + descending(h_r) - ascending(h_r))
                            + 1e-3 * rng.normal(size=fields.size - i)) * 1e-8) for i, h_r in enumerate(fields)]
    path = write_micromag_0015(tmp_path / "in_plane.frc", fields, curves)
    out = tmp_path / "loop"
    code = main(["loop", str(path), "--out", str(out), "--models", str(models), "--Ms-kA-m", "800",
                 "--config", str(root / "config" / "test.yaml")])
    err = capsys.readouterr().err
    assert code == 2 and "m_r = M_r/M_s = 0.09" in err and "'perpendicular'" in err, err
    report = json.loads((out / "report.json").read_text())
    assert report["in_domain"] and report["status"] == "contradicts the prior class"
    assert report["prior_class"] == "perpendicular" and report["prior_check"]["consistent"] is False
    assert "Not decoded" in (out / "report.md").read_text() and "prior class" in (out / "report.md").read_text()
