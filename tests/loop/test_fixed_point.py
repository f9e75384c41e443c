"""Predict, correct, predict again (loop.fixed_point): a substrate background biases the prediction
as it biases a network reading the saturated branches; removing it and predicting again must reach
the Hamiltonian and name the background, never a field offset (issue 14, item 4).

The film is the bench's tiny film (``bench.effects.CONFIG``: 16×16 cells, 32 grains, 32 fields over
±1 T; ``PARAMS``' M_s, K_u, D) with the exchange and disorder of test_refit's film (A_ex 5e-12 J/m,
σ_θ 5°, σ_K 0.05). With ``PARAMS``' own disorder (A_ex 2e-12, σ_θ 15°, σ_K 0.3) two disorder
realisations of one Hamiltonian differ by a held-out RMS of about 0.1 (50 × the noise) and the K_u
refit lands anywhere between 0.7 and 1.04 × the truth depending on the realisation, so no method can
be held to 5 % there; on this film a realisation is reproduced to the noise and the refit to ±5 %."""

import numpy as np
import pytest

from forcdecode.bench.effects import CONFIG, PARAMS
from forcdecode.core.errors import ConfigError
from forcdecode.loop.fixed_point import image_of_family, predict_correct_iterate
from forcdecode.infer.resimulate import resimulate

FILM = {**PARAMS, "A_ex": 5e-12, "sigma_theta_deg": 5.0, "sigma_K": 0.05}
N = 32
NOISE = 0.002
CHI = 0.08
GRIDS = dict(K_2_ratios=(-0.1, 0.15, 0.3), bias_fields_T=(-0.02, 0.02), soft_K_u_ratios=(0.1, 0.3), tilts_deg=(3.0, 6.0))
CFG = {**CONFIG, "field": {**CONFIG["field"], "n_fields": N}}
FIELDS = np.linspace(-1, 1, N)


def saturated_slope(family) -> float:
    """dm/d(μ0H) of the top (saturated) branch: one line through every point with H, H_r > 0.6 T."""
    family = np.asarray(family, float)
    H = np.broadcast_to(FIELDS[None, :], family.shape)
    H_r = np.broadcast_to(FIELDS[:, None], family.shape)
    ok = np.isfinite(family) & (H > 0.6) & (H_r > 0.6)
    return float(np.polyfit(H[ok], family[ok], 1)[0])


def biased_predictor(calls=None):
    """Like a network, reads the saturated branches' slope as a harder film: K_u × (1 + 2·slope)."""
    def predict(family):
        if calls is not None:
            calls.append(np.array(family, copy=True))
        return {**FILM, "K_u": FILM["K_u"] * (1 + 2 * saturated_slope(family))}
    return predict


@pytest.fixture(scope="module")
def film():
    """The film's own disorder realisation (key "sample", not the refit's), instrument noise."""
    family = resimulate(CFG, FILM, key="sample")
    return family + NOISE * np.random.default_rng(0).normal(size=family.shape)


def _iterate(measured, **options):
    return predict_correct_iterate(CFG, biased_predictor(), measured, FIELDS, names=("K_u",), budget=16,
                                   max_iterations=4, null_realisations=2, noise_sigma=NOISE, seed=1,
                                   physics_grids=GRIDS, **options)


def test_a_background_is_removed_and_the_prediction_reaches_the_hamiltonian(film):
    """The refit searches ±10 % around a prediction; the background's bias (16 %) is beyond it, as
    in the reported case: only predicting again from the corrected family reaches K_u."""
    measured = film + CHI * FIELDS[None, :]
    result = _iterate(measured, relative_bounds=0.1)
    its = result["iterations"]
    truth = FILM["K_u"]
    assert abs(its[0]["prediction"]["K_u"] / truth - 1) > 0.10  # the background biased the first prediction
    assert result["converged"] and 2 <= result["n_iterations"] <= 4
    # every iteration names the background; once the prediction is corrected, an offset never comes
    # with it. The first iteration's K_u is off by 16 %, beyond the refit's ±10 %: its switching fields
    # are shifted and an offset mimics part of that (here background+field_offset 0.0022 against the
    # background's 0.0026 held-out; chosen on a CI machine without AVX-512, 2026-12-02, not here)
    for it in its:
        assert it["kind"] == "measured" and "background" in it["chosen"].split("+"), it["chosen"]
    for it in its[1:]:
        assert "field_offset" not in it["chosen"].split("+"), it["chosen"]
    assert result["chosen"] == its[-1]["chosen"] and result["kind"] == "measured"
    assert its[-1]["effect_parameters"]["chi_per_T"] == pytest.approx(CHI, abs=0.01)
    # the network's own prediction from the corrected family, and the refitted Hamiltonian
    assert its[-1]["prediction"]["K_u"] == pytest.approx(truth, rel=0.05)
    final = its[-1]["refitted"]["K_u"]
    assert final == pytest.approx(truth, rel=0.05)
    assert abs(final / truth - 1) < abs(its[0]["refitted"]["K_u"] / truth - 1)
    assert max(its[-1]["change"].values()) < result["tolerance"]
    # the corrected family is the film: its saturated branch is flat again
    assert abs(saturated_slope(result["corrected_family"])) < 0.01 < CHI - 0.01 < saturated_slope(measured)


def test_without_a_background_nothing_measured_side_is_named(film):
    result = _iterate(film)
    assert result["converged"]
    assert result["verdict"] in ("none", "unexplained structured residual"), result["verdict_text"]
    assert all(it["kind"] != "measured" and it["effect_parameters"] == {} for it in result["iterations"])
    assert result["iterations"][-1]["reused"]  # the input did not change: the same prediction, the same analysis
    assert np.array_equal(result["corrected_family"], film, equal_nan=True)
    assert result["hamiltonian"]["refit_without_effect"]["K_u"] == pytest.approx(FILM["K_u"], rel=0.05)


def _fake_analysis(chosen_per_call, K_u_per_call=None, chi_per_call=None):
    """A stand-in for refit.analyse_with_refit: the effect chosen on each call, in turn."""
    calls = []

    def analyse(cfg, params, measured, fields, **options):
        k = len(calls)
        calls.append(options)
        chosen = chosen_per_call[min(k, len(chosen_per_call) - 1)]
        kind = "none" if chosen == "none" else "measured"
        chi = (chi_per_call or {}).get(k, 0.1)
        parameters = {"scale": 1.0, "chi_per_T": chi} if chosen == "background" else \
            {"offset_T": 0.03} if chosen == "field_offset" else {}
        refit = {**params, "K_u": (K_u_per_call or {}).get(k, params["K_u"])}
        return {"chosen": chosen, "kind": kind, "verdict": chosen, "parameters": parameters,
                "hamiltonian": {"prediction": params, "refit_without_effect": refit,
                                "refit_with_effect": None if kind != "measured" else
                                {"params": refit, "effect_parameters": parameters, "objective": 0.0}}}
    return analyse, calls


def test_alternating_effects_are_never_reported_as_converged(monkeypatch):
    import forcdecode.loop.fixed_point as fixed_point  # where the iteration looks the analysis up

    analyse, calls = _fake_analysis(["background", "field_offset"] * 3)
    monkeypatch.setattr(fixed_point, "analyse_with_refit", analyse)
    seen = []
    measured = np.triu(np.ones((N, N))) + 0.1 * FIELDS[None, :]
    measured[np.tril_indices(N, -1)] = np.nan
    result = predict_correct_iterate(CFG, biased_predictor(seen), measured, FIELDS, max_iterations=3,
                                     null_realisations=2, noise_sigma=NOISE)
    assert result["converged"] is False and result["n_iterations"] == 3 and len(calls) == 3
    assert [it["chosen"] for it in result["iterations"]] == ["background", "field_offset", "background"]
    # the effect is judged on the original measurement; the prediction reads the corrected family
    assert calls[0]["null_realisations"] == 2 and calls[0]["noise_sigma"] == NOISE
    assert np.array_equal(seen[0], measured, equal_nan=True)
    assert saturated_slope(seen[1]) == pytest.approx(0.0, abs=1e-9)  # background 0.1 per tesla removed
    assert not np.array_equal(seen[2], measured, equal_nan=True)  # the offset corrected


def test_the_same_effect_with_a_moving_hamiltonian_is_not_a_fixed_point(monkeypatch):
    import forcdecode.loop.fixed_point as fixed_point  # where the iteration looks the analysis up

    # the fitted background moves a little each time, so each prediction differs and is analysed anew
    analyse, calls = _fake_analysis(["background"], K_u_per_call={0: 4.0e5, 1: 4.4e5, 2: 4.41e5},
                                    chi_per_call={0: 0.09, 1: 0.095, 2: 0.096})
    monkeypatch.setattr(fixed_point, "analyse_with_refit", analyse)
    measured = np.triu(np.ones((N, N))) + 0.1 * FIELDS[None, :]
    measured[np.tril_indices(N, -1)] = np.nan
    result = predict_correct_iterate(CFG, biased_predictor(), measured, FIELDS, max_iterations=4)
    # 10 % change from the first to the second: on; 0.2 % from the second to the third: converged
    assert result["converged"] and result["n_iterations"] == 3 and len(calls) == 3
    assert not any(it["reused"] for it in result["iterations"])
    assert result["iterations"][1]["change"]["K_u"] == pytest.approx(0.4 / 4.4)
    assert result["iterations"][2]["change"]["K_u"] == pytest.approx(0.01 / 4.41)
    # with a 0.1 % tolerance the same run is not a fixed point
    analyse, _ = _fake_analysis(["background"], K_u_per_call={0: 4.0e5, 1: 4.4e5, 2: 4.41e5, 3: 4.43e5},
                                chi_per_call={0: 0.09, 1: 0.095, 2: 0.096, 3: 0.097})
    monkeypatch.setattr(fixed_point, "analyse_with_refit", analyse)
    result = predict_correct_iterate(CFG, biased_predictor(), measured, FIELDS, max_iterations=4, tolerance=0.001)
    assert result["converged"] is False and result["n_iterations"] == 4


@pytest.mark.parametrize("options", [{"max_iterations": 0}, {"max_iterations": -2}, {"max_iterations": 1.5},
                                     {"tolerance": 0.0}, {"null_realisations": -1}])
def test_bad_options_raise_config_errors(options):
    measured = np.full((N, N), np.nan)
    with pytest.raises(ConfigError):
        predict_correct_iterate(CFG, biased_predictor(), measured, FIELDS, **options)
    with pytest.raises(ConfigError):
        predict_correct_iterate(CFG, None, measured, FIELDS)


def test_the_image_of_a_family_follows_the_raster_rules():
    from forcdecode.forc.raster import rasterize_grid_family

    family = np.triu(np.tile(np.linspace(-1, 1, N), (N, 1)))
    family[np.tril_indices(N, -1)] = np.nan
    assert np.array_equal(image_of_family(family), rasterize_grid_family(family))
    holed = family.copy()
    holed[3, -2:] = np.nan  # a correction that shifted the end of a curve out of the window
    image = image_of_family(holed)
    assert image[3, -1] == image[3, -3] and np.array_equal(np.delete(image, 3, 0), np.delete(image_of_family(family), 3, 0))


def test_the_loop_refuses_a_fixed_point_it_cannot_run(tmp_path):
    from forcdecode.loop.measured_loop import close_loop_on_file

    with pytest.raises(ConfigError, match="refit"):
        close_loop_on_file(tmp_path / "absent.frc", tmp_path / "out", CFG, fixed_point=True)
    with pytest.raises(ConfigError, match="params"):
        close_loop_on_file(tmp_path / "absent.frc", tmp_path / "out", CFG, params=FILM, refit=["K_u"], fixed_point=True)


def test_the_loop_reports_the_iterations(tmp_path, monkeypatch):
    """``close_loop_on_file(fixed_point=True)`` on a MicroMag file of the film with the background:
    a stand-in network (the biased rule above, read from the uint8 image it is given) is asked again
    on the image of the corrected family; report.json and report.md carry the iterations. (The file's
    normalization by its saturated branches leaves an offset M_0 ≠ 0 with the background, which an
    additive drift may take up next to the background; no field offset.)"""
    import json

    import forcdecode.learn.predictor as predictor
    from forcdecode.loop.measured_loop import close_loop_on_file
    from forcdecode.measured.writers import write_micromag_0015
    from forcdecode.micromag.build import mesh_from_config

    images = []

    def network(image, Ms):
        images.append(np.array(image))
        m = np.asarray(image, float) / 127.5 - 1
        m[np.tril_indices(N, -1)] = np.nan  # the image's H < H_r half is filled, not measured
        K_u = FILM["K_u"] * (1 + 2 * saturated_slope(m))
        return {"Ms": float(Ms), **{k: {"value": float(v), "interval_68": [float(v)] * 2, "interval_90": [float(v)] * 2}
                                    for k, v in {**FILM, "K_u": K_u}.items() if k != "Ms"}}

    monkeypatch.setattr(predictor, "load_models", lambda directory: network)
    # the stand-in has no prior class, no validation records and no intervals to propagate
    import forcdecode.loop.measured_loop as measured_loop  # where the loop looks alice_answer up

    monkeypatch.setattr(predictor, "models_prior_class", lambda models: "paper")
    monkeypatch.setattr(measured_loop, "alice_answer", lambda models, prediction, **kwargs: prediction)
    truth = resimulate(CFG, FILM, key="sample")
    mesh = mesh_from_config(CFG)
    moment = FILM["Ms"] * mesh.n_cells * mesh.cell_volume
    rng = np.random.default_rng(0)
    curves = [(FIELDS[i:], (truth[i, i:] + CHI * FIELDS[i:] + NOISE * rng.normal(size=N - i)) * moment)
              for i in range(N)]
    path = write_micromag_0015(tmp_path / "film.frc", FIELDS, curves)
    report = close_loop_on_file(path, tmp_path / "loop", CFG, ms_values_A_per_m=[FILM["Ms"]], profiles=1,
                                sweep_profiles=1, refit=["K_u"], refit_budget=12, physics=False,
                                measured_protocol=False, force=True, fixed_point=True, log=lambda text: None)
    fixed = report["fixed_point"]
    its = fixed["iterations"]
    assert len(its) == fixed["n_iterations"] >= 2 and len(images) >= 1 + len(its)
    # the image clips m at 1, so the stand-in sees less of the background than on the family (4.6 % off here)
    first, second = (abs(it["prediction"]["K_u"] / FILM["K_u"] - 1) for it in its[:2])
    assert first > 0.03 and second < first / 2  # the second prediction read the corrected image
    for it in its:
        assert "background" in it["chosen"].split("+") and "field_offset" not in it["chosen"].split("+")
    saved = json.loads((tmp_path / "loop" / "report.json").read_text())
    assert saved["fixed_point"]["converged"] == fixed["converged"] and len(saved["fixed_point"]["iterations"]) == len(its)
    assert "corrected_family" not in saved["analysis"] and "iterations" not in saved["analysis"]
    text = (tmp_path / "loop" / "report.md").read_text()
    assert "Fixed point of (Hamiltonian, measured-side effect)" in text
    assert ("converged after" if fixed["converged"] else "NOT converged after") in text


def test_a_joint_refit_that_misses_the_held_out_curves_is_not_used(monkeypatch):
    """The joint refit (Hamiltonian and offset together) lands on an offset that misplaces the held-out
    curves: the iteration reads the effect on the Hamiltonian refitted without it instead."""
    import forcdecode.loop.fixed_point as fixed_point  # where the iteration looks the analysis up

    def analyse(cfg, params, measured, fields, **options):
        without = {**params, "K_u": 4.2e5}
        joint = {"params": {**params, "K_u": 3.4e5}, "effect_parameters": {"offset_T": 0.043}, "objective": 0.0,
                 "heldout_rms": 0.086, "generalises": False}
        return {"chosen": "field_offset", "kind": "measured", "verdict": "field_offset",
                "parameters": {"offset_T": 0.01},
                "hamiltonian": {"prediction": params, "refit_without_effect": without, "refit_with_effect": joint}}

    monkeypatch.setattr(fixed_point, "analyse_with_refit", analyse)
    measured = np.triu(np.ones((N, N)))
    measured[np.tril_indices(N, -1)] = np.nan
    result = predict_correct_iterate(CFG, biased_predictor(), measured, FIELDS, max_iterations=2)
    first = result["iterations"][0]
    assert first["effect_parameters"] == {"offset_T": 0.01}
    assert first["refitted"]["K_u"] == 4.2e5
