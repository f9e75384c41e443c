"""Undeclared effects in a real instrument file are traced by the whole residual analysis.

Each "measurement" is a simulated film (16×16×1 cells, 32 grains, 32 fields over ±1 T) with one
effect switched on, recorded by a simulated instrument (noise 0.2 % of the film moment), written as
a PMC MicroMag 0015 file, read back by ``read_forc``, put on the grid by ``measured_image`` and
analysed against the clean re-simulation by ``analyse_residual`` with every candidate (measured-side
singles and combinations, K_2, bias field, second phase), never told which effect is there.

Moments are normalized by the film's nominal saturation moment M_s·V (known sample volume): a
normalization by the measured saturation moment (as ``forcdecode loop`` does) would absorb a scale
error by construction.
"""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from forcdecode.micromag.build import mesh_from_config
from forcdecode.forc.raster import measured_image
from forcdecode.infer.resimulate import resimulate
from forcdecode.loop.instrument import simulated_instrument_curves
from forcdecode.loop.physics_effects import analyse_residual, physics_candidate_families
from forcdecode.measured import read_forc
from forcdecode.measured.writers import write_micromag_0015

ROOT = Path(__file__).resolve().parents[2]
PARAMS = {"Ms": 6e5, "A_ex": 2e-12, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 15.0, "sigma_K": 0.3}
K_U = PARAMS["K_u"]
NOISE = 0.002


@pytest.fixture(scope="module")
def film():
    """The film, its clean re-simulation (the 'predicted Hamiltonian' is the true one) and every
    physics-side candidate family, simulated once for the module."""
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = 32
    cfg["n_grains"] = 32  # small weakly coupled grains: a family with many switching events
    mesh = mesh_from_config(cfg)
    candidates = physics_candidate_families(cfg, PARAMS, K_2_ratios=(-0.2, -0.1, 0.1, 0.2, 0.3),
                                            bias_fields_T=(-0.03, -0.02, -0.01, 0.01, 0.02, 0.03),
                                            soft_K_u_ratios=(0.05, 0.1, 0.2, 0.3))
    return SimpleNamespace(cfg=cfg, fields=np.linspace(-1, 1, 32), base=resimulate(cfg, PARAMS),
                           candidates=candidates, moment_Am2=PARAMS["Ms"] * mesh.n_cells * mesh.cell_volume)


def measured_family(film, tmp_path, truth, seed, **instrument):
    """``truth`` through a simulated instrument, a MicroMag file and the reader, onto the grid."""
    reversal, curves = simulated_instrument_curves(truth, film.fields, film.moment_Am2, noise=NOISE,
                                                   rng=np.random.default_rng(seed), **instrument)
    path = write_micromag_0015(tmp_path / f"film_{seed}.frc", reversal, curves)
    data = read_forc(path)
    assert data.format == "micromag-0015" and len(data.curves) == 32
    _, family, _ = measured_image([c.reversal_field_T for c in data.curves],
                                  [(c.field_T, c.moment_Am2) for c in data.curves], film.moment_Am2, 1.0, 32)
    return family


def physics_truth(film, effect, size, fraction=None):
    """The true family of a physics-side effect: a re-simulation with it switched on."""
    if effect == "K_2":
        return resimulate(film.cfg, {**PARAMS, "K_2": size})
    if effect == "bias_field":
        return resimulate(film.cfg, {**PARAMS, "B_bias_T": size})
    soft = resimulate(film.cfg, {**PARAMS, "K_u": size})
    return (1 - fraction) * film.base + fraction * soft


# effect, instrument settings, true parameters (name: (value, tolerance))
MEASURED_CASES = [
    ("background", {"background_chi_per_T": 0.10}, {"chi_per_T": (0.10, 0.005), "scale": (1.0, 0.01)}),
    ("field_offset", {"field_offset_T": 0.004}, {"offset_T": (0.004, 0.0005)}),
    ("additive_drift", {"additive_drift": 0.03}, {"additive_drift": (0.03, 0.003)}),
    ("multiplicative_drift", {"multiplicative_drift": 0.04}, {"multiplicative_drift": (0.04, 0.004)}),
    ("scale", {"scale": 0.9}, {"scale": (0.9, 0.005)}),
    ("background+additive_drift", {"background_chi_per_T": 0.08, "additive_drift": 0.03},
     {"chi_per_T": (0.08, 0.005), "additive_drift": (0.03, 0.003)}),
    ("background+field_offset", {"background_chi_per_T": 0.10, "field_offset_T": -0.004},
     {"chi_per_T": (0.10, 0.005), "offset_T": (-0.004, 0.0005)}),
    ("field_offset+scale", {"field_offset_T": 0.004, "scale": 0.92}, {"offset_T": (0.004, 0.0005), "scale": (0.92, 0.005)}),
]


def assert_named_with_a_clear_cut(result, effect):
    alternatives = {k: round(v["heldout_rms"], 4) for k, v in result["candidates"].items()}
    assert result["chosen"] == effect, alternatives
    assert result["heldout_reduction_ci90"][0] > 0.3, (result["heldout_reduction"], result["heldout_reduction_ci90"])
    assert result["heldout_rms_after"] < 0.7 * result["heldout_rms_before"]
    assert result["residual_rms_after"] < result["residual_rms_before"]
    assert result["heldout_rms_after"] < 1.5 * NOISE  # what is left is the instrument noise


@pytest.mark.parametrize("effect,instrument,truth", MEASURED_CASES, ids=[c[0] for c in MEASURED_CASES])
def test_undeclared_measured_side_effect_is_named_and_sized(film, tmp_path, effect, instrument, truth):
    measured = measured_family(film, tmp_path, film.base, seed=3, **instrument)
    result = analyse_residual(measured, film.base, film.fields, seed=3, **film.candidates)
    assert_named_with_a_clear_cut(result, effect)
    assert result["kind"] == "measured"
    for name, (value, tolerance) in truth.items():
        assert result["parameters"][name] == pytest.approx(value, abs=tolerance), result["parameters"]
        # the reported 1σ uncertainty is honest: the truth lies within 4σ
        assert abs(result["parameters"][name] - value) < 4 * result["uncertainties"][name] + 1e-4
    # 11 measured-side (singles and pairs) + none + 5 physics (K_2, bias, second phase, field tilt, thermal)
    assert len(result["candidates"]) == 17


@pytest.mark.parametrize("effect,size,fraction,expected", [
    ("K_2", 0.2 * K_U, None, {"K_2_J_per_m3": (0.2 * K_U, 0.01 * K_U)}),
    # between grid nodes (0.1, 0.2) and between the base (size 0) and the node −0.1: the family is
    # interpolated between nodes, so the size is read off the grid, not snapped to the nearest node
    ("K_2", 0.15 * K_U, None, {"K_2_J_per_m3": (0.15 * K_U, 0.025 * K_U)}),
    ("K_2", -0.05 * K_U, None, {"K_2_J_per_m3": (-0.05 * K_U, 0.025 * K_U)}),
    ("bias_field", 0.02, None, {"B_bias_T": (0.02, 0.001)}),
    ("bias_field", 0.025, None, {"B_bias_T": (0.025, 0.0051)}),  # between grid values (0.02, 0.03)
    ("second_phase", 0.1 * K_U, 0.3, {"K_u_soft_J_per_m3": (0.1 * K_U, 1.0), "fraction": (0.3, 0.01)}),
    ("second_phase", 0.15 * K_U, 0.2, {"K_u_soft_J_per_m3": (0.15 * K_U, 0.051 * K_U)}),  # between grid values
], ids=["K_2", "K_2_between_nodes", "K_2_between_base_and_node", "bias_on_grid", "bias_off_grid",
        "second_phase_on_grid", "second_phase_off_grid"])
def test_undeclared_physics_effect_is_found_by_resimulation(film, tmp_path, effect, size, fraction, expected):
    truth = physics_truth(film, effect, size, fraction)
    measured = measured_family(film, tmp_path, truth, seed=5)
    result = analyse_residual(measured, film.base, film.fields, seed=5, **film.candidates)
    alternatives = {k: round(v["heldout_rms"], 4) for k, v in result["candidates"].items()}
    if size == -0.05 * K_U:
        # a small negative K_2 looks much like a K_u 6 % lower: its 41 % lower held-out error than that
        # neighbourhood is not significant on 32 curves, so nothing is named (never another effect),
        # but the candidate's own size is read right
        assert result["chosen"] in ("K_2", "none"), alternatives
        record = result["candidates"]["K_2"]
        assert record["parameters"]["K_2_J_per_m3"] == pytest.approx(size, abs=0.025 * K_U)
        assert result["hamiltonian_neighbourhood"]["K_u_change"] < 0
        return
    assert result["chosen"] == effect, alternatives
    assert result["kind"] == "physics"
    # between nodes a linear interpolation of two families with avalanches leaves part of the
    # residual, and which held-out curves keep it moves with the last bits of the simulation
    # (measured: held-out cuts 0.28 and 0.38 there, against > 0.5 on the nodes; the bias between its
    # nodes cut 0.61 with a 90 % interval from 0.27 on an AMD Zen 3, above 0.3 on an Intel CPU)
    between_nodes = {("K_2", 0.15 * K_U), ("K_2", -0.05 * K_U), ("bias_field", 0.025), ("second_phase", 0.15 * K_U)}
    least = 0.1 if (effect, size) in between_nodes else 0.3
    assert result["heldout_reduction_ci90"][0] > least, (result["heldout_reduction"], result["heldout_reduction_ci90"])
    for name, (value, tolerance) in expected.items():
        assert result["parameters"][name] == pytest.approx(value, abs=tolerance), result["parameters"]
        assert abs(result["parameters"][name] - value) <= result["uncertainties"][name] + tolerance
    if effect == "bias_field":
        # a bias field on the film and an offset of the reported field are one observable
        assert result["same_observable_as"] == ["field_offset"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_control_file_without_effect_is_left_alone(film, tmp_path, seed):
    measured = measured_family(film, tmp_path, film.base, seed=seed)
    result = analyse_residual(measured, film.base, film.fields, seed=seed, **film.candidates)
    accepted = [k for k, v in result["candidates"].items() if v["accepted"]]
    assert result["chosen"] == "none", accepted
    assert result["heldout_reduction"] == 0.0 and result["heldout_rms_after"] == result["heldout_rms_before"]
    assert result["parameters"] == {} and result["kind"] == "none"
    assert result["heldout_rms_before"] == pytest.approx(NOISE, rel=0.35)


def test_report_is_complete_and_select_effect_keys_still_hold(film, tmp_path):
    """The report carries what the loop's report needs; ``select_effect`` still answers the keys
    ``forcdecode loop`` reads, now with the combinations among its candidates."""
    from forcdecode.loop.effects import COMBINATIONS, select_effect

    measured = measured_family(film, tmp_path, film.base, seed=7, background_chi_per_T=0.08, additive_drift=0.03)
    result = analyse_residual(measured, film.base, film.fields, seed=7, **film.candidates)
    n = len(film.fields)
    assert result["arrays"]["model"].shape == (n, n) and len(result["per_curve_rms_after"]) == n
    assert set(result["candidates"]["second_phase"]["parameters"]) == {"K_u_soft_J_per_m3", "fraction"}
    for candidate in result["candidates"].values():
        assert {"kind", "n_parameters", "parameters", "uncertainties", "heldout_rms", "gain_ci90", "accepted"} <= set(candidate)
    low, high = result["heldout_reduction_ci90"]
    assert low <= result["heldout_reduction"] <= high
    selection = select_effect(measured, film.base, film.fields, np.linspace(1.0, 0.0, n))
    assert {"chosen", "candidates", "heldout_rms_before", "heldout_rms_after"} <= set(selection)
    assert set(COMBINATIONS) <= set(selection["candidates"])
    assert selection["chosen"] == "background+additive_drift"  # per-curve clock, as `forcdecode loop` gives
