"""Effects judged against the Hamiltonian refitted without them (loop.refit), and the physics-side
library (field tilt) on a film that is a different disorder realisation than the re-simulation.

The film (16×16×1 cells, 32 grains, 32 fields over ±1 T, weak disorder) has a nearly square loop:
its switching field, 2K_u/M_s − μ0M_s reduced by nucleation, moves by about one field step
(0.065 T, ≈ 6 % of K_u) when K_u changes by 6 %, so that is the resolution of a K_u refit here."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from forcdecode.bench.effects_user import _answer_of_report, score_answer
from forcdecode.loop.effects import HAMILTONIAN_CHANGE
from forcdecode.loop.physics_effects import analyse_residual, physics_candidate_families
from forcdecode.loop.refit import EffectOnTop, RefitSearch, analyse_with_refit, refit_hamiltonian
from forcdecode.infer.resimulate import resimulate

ROOT = Path(__file__).resolve().parents[2]
PREDICTION = {"Ms": 6e5, "A_ex": 5e-12, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 5.0, "sigma_K": 0.05}
NOISE = 0.002
GRIDS = dict(K_2_ratios=(-0.1, 0.15, 0.3), bias_fields_T=(-0.02, 0.02), soft_K_u_ratios=(0.1, 0.3), tilts_deg=(3.0, 6.0, 10.0))


@pytest.fixture(scope="module")
def protocol():
    """The test film's configuration and grid, and its measurement (no re-simulation made yet)."""
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = 32
    cfg["n_grains"] = 32

    def sample(noise=NOISE, **change):
        """The measured film: its own disorder realisation (key "sample"), instrument noise ``noise``."""
        family = resimulate(cfg, {**PREDICTION, **change}, key="sample")
        return family + noise * np.random.default_rng(0).normal(size=family.shape)

    return SimpleNamespace(cfg=cfg, fields=np.linspace(-1, 1, 32), sample=sample)


@pytest.fixture(scope="module")
def film(protocol):
    cfg = protocol.cfg
    return SimpleNamespace(**vars(protocol), base=resimulate(cfg, PREDICTION, n_profiles=2),
                           candidates=physics_candidate_families(cfg, PREDICTION, n_profiles=2, **GRIDS))


@pytest.fixture(scope="module")
def wrong_K_u(film):
    """A film whose K_u is 10 % above the prediction."""
    return film.sample(K_u=1.1 * PREDICTION["K_u"])


def test_refit_recovers_K_u_and_the_selection_prefers_none(film, wrong_K_u):
    result = analyse_with_refit(film.cfg, PREDICTION, wrong_K_u, film.fields, names=("K_u",), n_profiles=2, budget=16,
                                physics_grids=GRIDS, noise_sigma=NOISE, seed=1)
    K_u = result["hamiltonian"]["refit_without_effect"]["K_u"]
    # 10 % off before, within 5 % after (measured 4.24e5 against 4.4e5: one field step of resolution)
    assert K_u == pytest.approx(1.1 * PREDICTION["K_u"], rel=0.05) and K_u > 1.03 * PREDICTION["K_u"]
    assert result["refit"]["training_mse_refit"] < 0.01 * result["refit"]["training_mse_prediction"]
    assert result["refit"]["evaluations"] <= 16
    # the refitted Hamiltonian explains the difference: no effect, no field offset, nothing left
    assert result["chosen"] == "none" and result["verdict"] == "none", result["verdict_text"]
    assert not result["candidates"]["field_offset"]["accepted"]
    assert 0.1 < result["refit"]["heldout_rms_prediction"]
    # what is left is the noise and the model's own disorder: a curve reversed where the refit's two
    # profiles disagree (one switched, one not) may follow either (measured on an AMD Zen 3: the held-out
    # curve at H_r = -0.61 T, delta m = 1 along it, held-out RMS 0.30;
    # on the Intel CPU of earlier sessions below 2 x noise)
    assert result["structure"]["chi2_ratio"] < 2, result["structure"]
    assert result["hamiltonian"]["refit_with_effect"] is None
    assert set(result["split"]["held"]).isdisjoint(result["split"]["train"])


def test_without_the_refit_the_hamiltonian_error_is_not_forced_onto_an_effect(film, wrong_K_u):
    result = analyse_residual(wrong_K_u, film.base, film.fields, seed=1, noise_sigma=NOISE, n_profiles=2, **film.candidates)
    assert result["chosen"] == "none"
    assert result["verdict"] == "unexplained structured residual"
    assert result["structure"]["chi2_ratio"] > 100


def test_refit_with_a_measured_side_effect_fits_both(film):
    measured = film.sample(K_u=1.1 * PREDICTION["K_u"]) + 0.1 * film.fields[None, :]
    from forcdecode.loop.effects import EFFECTS, heldout_folds

    train, _ = heldout_folds(measured, 4, cross_fit=False)[0]
    joint = refit_hamiltonian(film.cfg, PREDICTION, measured, train, RefitSearch(n_profiles=2, budget=14),
                              on_top=EffectOnTop(EFFECTS["background"], film.fields))
    assert joint["params"]["K_u"] == pytest.approx(1.1 * PREDICTION["K_u"], rel=0.05)
    assert joint["effect_parameters"]["chi_per_T"] == pytest.approx(0.1, abs=0.01)


def test_a_misaligned_field_is_named_by_the_tilt_candidate(film):
    result = analyse_residual(film.sample(field_tilt_deg=8.0), film.base, film.fields, seed=2, noise_sigma=NOISE,
                              n_profiles=2, **film.candidates)
    assert result["chosen"] == "field_tilt" and result["kind"] == "physics"
    # the nearest grid node or the next (the sample's own disorder moves its switching field too)
    assert result["parameters"]["tilt_deg"] in (6.0, 10.0)
    assert result["heldout_rms_after"] < 0.1 * result["heldout_rms_before"]
    control = analyse_residual(film.sample(), film.base, film.fields, seed=2, noise_sigma=NOISE, n_profiles=2,
                               **film.candidates)
    assert control["chosen"] == "none"


def test_refitted_null_is_a_lower_floor_than_the_unrefitted_one(film):
    """The refit fits part of a film's own disorder realisation: the same effect-free films, refitted
    from the same start, leave candidates less to gain than unrefitted ones (``null_refit``)."""
    measured = film.sample()
    start = {**PREDICTION, "K_u": 1.1 * PREDICTION["K_u"]}
    gains = {}
    for refit_null in (False, True):
        result = analyse_with_refit(film.cfg, start, measured, film.fields, names=("K_u",), budget=10, physics=False,
                                    null_realisations=1, null_refit=refit_null, noise_sigma=NOISE, thermal=False)
        gains[refit_null] = result["refit"]["null_gain"]
    best = {r: max(g["mse"] for g in gains[r].values()) for r in gains}
    assert best[True] < 0.5 * best[False], best  # measured: field_offset 0.026 unrefitted, ~0 refitted


def test_the_null_films_are_the_structure_tests_disorder_floor(film):
    """A strongly disordered film of the predicted Hamiltonian on its own disorder (no effect): against
    the noise alone its residual is structured (another realisation moves switching fields), against
    the floor the null films measure it is not, and the verdict is "none", not an "unexplained
    structured residual"."""
    disordered = {**PREDICTION, "sigma_theta_deg": 15.0, "sigma_K": 0.3}
    measured = resimulate(film.cfg, disordered, key="sample") + NOISE * np.random.default_rng(0).normal(size=(32, 32))
    options = dict(names=("K_u",), budget=8, physics=False, null_realisations=4, noise_sigma=NOISE, thermal=False)
    with_floor = analyse_with_refit(film.cfg, disordered, measured, film.fields, **options)
    noise_only = analyse_with_refit(film.cfg, disordered, measured, film.fields, floor_variance=None, **options)
    assert with_floor["chosen"] == noise_only["chosen"] == "none"
    assert with_floor["structure"]["chi2_ratio"] < noise_only["structure"]["chi2_ratio"]
    # against the noise alone the residual is structured; where a candidate the realisation floor withheld
    # would have been named, the verdict says so (ambiguous with realisation noise) instead
    assert noise_only["structure"]["structured"]
    assert (noise_only["verdict"] == "unexplained structured residual"
            or (noise_only["verdict"] == "ambiguous" and "realisation noise" in noise_only["ambiguous"])), \
        noise_only["verdict_text"]
    assert with_floor["verdict"] == "none", with_floor["verdict_text"]


def test_the_error_after_is_also_scored_with_hamiltonian_and_effect_refitted_together(film):
    """A background on a film whose K_u is 10 % off: once the background is chosen, Hamiltonian and
    background are refitted together on the training curves and scored on the held-out ones; that
    model is at least as good there as the background on the Hamiltonian refitted without it."""
    measured = film.sample(K_u=1.1 * PREDICTION["K_u"]) + 0.1 * film.fields[None, :]
    result = analyse_with_refit(film.cfg, PREDICTION, measured, film.fields, names=("K_u",), n_profiles=2, budget=14,
                                physics=False, noise_sigma=NOISE, seed=1, thermal=False)
    assert result["chosen"] == "background", result["verdict_text"]
    joint = result["hamiltonian"]["refit_with_effect"]
    assert result["heldout_rms_after_joint"] == joint["heldout_rms"] and joint["generalises"]
    assert joint["heldout_rms"] < 0.2 * result["heldout_rms_before"]
    assert joint["heldout_rms"] <= 1.05 * result["heldout_rms_after"]
    assert joint["params"]["K_u"] == pytest.approx(1.1 * PREDICTION["K_u"], rel=0.05)
    # where nothing measured-side is chosen there is no joint refit, and "after" is the chosen model's
    plain = analyse_with_refit(film.cfg, PREDICTION, film.sample(K_u=1.1 * PREDICTION["K_u"]), film.fields,
                               names=("K_u",), n_profiles=2, budget=14, physics=False, noise_sigma=NOISE, seed=1,
                               thermal=False)
    assert plain["hamiltonian"]["refit_with_effect"] is None
    assert plain["heldout_rms_after_joint"] == plain["heldout_rms_after"]


def test_a_refitted_K_u_and_thermal_activation_that_explain_equally_are_ambiguous(protocol):
    """K_u 10 % below the prediction, 1 % noise: the refit lowers K_u (× 0.89), and thermal activation
    on the unrefitted prediction (every coercivity lowered by the Sharrock factor) fits the curves held
    out in turn as well (held-out RMS 0.0102 against the refit's 0.0101; the refit's 5 % bootstrap bound
    over it 0.003, the rule's 0.05; 0.001–0.011 over four noise seeds). The refit path answers
    "ambiguous" with both, in the default path's keys, and the bench reads the set as partial."""
    measured = protocol.sample(noise=0.01, K_u=0.9 * PREDICTION["K_u"])
    result = analyse_with_refit(protocol.cfg, PREDICTION, measured, protocol.fields, names=("K_u",), n_profiles=2,
                                budget=12, physics=False, noise_sigma=0.01, seed=1)
    assert result["chosen"] == "none" and result["verdict"] == "ambiguous", result["verdict_text"]
    assert result["ambiguous"] == [HAMILTONIAN_CHANGE, "thermal_activation"]
    separating = result["separating_measurements"]
    assert "sweep rates" in separating["thermal_activation"] and "hard-axis" in separating[HAMILTONIAN_CHANGE]
    record = result["refit_ambiguity"]
    assert record["explains"] and record["hamiltonian_change"]["names"] == ["K_u"]
    assert record["hamiltonian_change"]["multipliers"]["K_u"] < 0.95 and "K_u × 0.89" in result["verdict_text"]
    report = {"status": "analysed", "verdict": result["verdict"], "effect": result["chosen"],
              "analysis": {"ambiguous": result["ambiguous"]}}
    answer = _answer_of_report(report)
    assert answer["named"] == ["thermal_activation"] and answer["ambiguous"] and answer["hedged"]
    assert score_answer("library", "thermal_activation", answer) == "partial"


def test_where_the_refitted_K_u_clearly_wins_the_answer_is_not_ambiguous(protocol):
    """K_u 10 % above the prediction, the same noise: thermal activation can only lower coercivities and
    a field offset moves both branches one way, so on the unrefitted prediction neither explains what
    the refit does (held-out RMS 0.35 and 0.43 against 0.010): the refitted Hamiltonian stands alone."""
    measured = protocol.sample(noise=0.01, K_u=1.1 * PREDICTION["K_u"])
    result = analyse_with_refit(protocol.cfg, PREDICTION, measured, protocol.fields, names=("K_u",), n_profiles=2,
                                budget=12, physics=False, noise_sigma=0.01, seed=1)
    assert result["verdict"] == "none", result["verdict_text"]
    assert result["ambiguous"] == [] and result["separating_measurements"] == {}
    record = result["refit_ambiguity"]
    assert record["explains"] and record["members"] == []
    assert {"thermal_activation", "field_offset"} <= set(record["offered_on_prediction"])
    rms = record["heldout_rms"]
    assert rms[HAMILTONIAN_CHANGE] < 0.05 * min(rms["thermal_activation"], rms["field_offset"])


def test_a_joint_refit_worse_on_held_out_curves_is_not_used():
    from forcdecode.loop.refit import JOINT_TOLERANCE, joint_generalises

    assert joint_generalises(0.0027, 0.0034) and joint_generalises(0.0034 * (1 + JOINT_TOLERANCE), 0.0034)
    # the validation 24 mT offset film: offset 43 mT, K_u 8 % low, held-out 0.086 against 0.018
    assert not joint_generalises(0.0858, 0.0178)
    assert not joint_generalises(float("nan"), 0.0178)
