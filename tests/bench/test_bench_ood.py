"""``bench ood``: the exact binomial interval, the films each case builds, and the flag rates it
reports from images whose status is known (families of the training generator vs another one)."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from forcdecode.bench.ood import CASES, HeldOutFamilies, bench_ood, carry_over, case_film, clopper_pearson, ood_lines
from forcdecode.core.errors import ConfigError
from forcdecode.learn.posterior import PosteriorEstimator, train_posterior
from forcdecode.learn.scoring import binomial_band

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "learn"))
from test_posterior import LEARNING, SEED, SETTINGS, bar_dataset  # noqa: E402


def test_clopper_pearson_matches_its_closed_forms():
    # k = 0: upper = 1 − (tail)^(1/n); k = n: lower = (tail)^(1/n) (tail = 0.05 at 90 %)
    assert clopper_pearson(0, 10) == pytest.approx((0.0, 1 - 0.05 ** 0.1), abs=1e-9)
    assert clopper_pearson(10, 10) == pytest.approx((0.05 ** 0.1, 1.0), abs=1e-9)
    low, high = clopper_pearson(5, 20)
    assert low < 0.25 < high and high - low < 0.4


def test_each_case_changes_only_what_it_names():
    cfg = {"n_grains": 16, "bounds": {"N_pin": [0, 255]}}
    params = {"Ms": 6e5, "A_ex": 1e-11, "K_u": 3e5, "D": 1e-3, "N_pin": 100, "sigma_theta_deg": 2.0, "sigma_K": 0.1}
    assert case_film(cfg, params, "control") == (cfg, params)
    assert case_film(cfg, params, "no_pinning")[1]["N_pin"] == 0
    c, p = case_film(cfg, params, "pinning_beyond_prior")
    assert p["N_pin"] == 765 and c == cfg
    c, p = case_film(cfg, params, "grains_8nm")
    assert c["n_grains"] == 255 and p == params and cfg["n_grains"] == 16
    with pytest.raises(ConfigError, match="unknown OOD case"):
        case_film(cfg, params, "magnumnp")


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("ood_bench")
    train_posterior(bar_dataset(n=400), {**SETTINGS, "epochs": 40}, LEARNING, SEED, out / "model.pt",
                    out / "metrics.json", out / "fig.png", log=lambda *_: None)
    return PosteriorEstimator.load(out / "model.pt")


def test_flag_rates_of_known_families_from_the_stored_images(model, tmp_path):
    fresh = bar_dataset(n=60, seed=42)               # the training generator: in distribution
    rng = np.random.default_rng(1)
    other = np.zeros((60, 16, 16), np.uint8)         # bars grown from the side: another generator
    for k in range(60):
        other[k, :, : rng.integers(2, 15)] = 235
    other = (other + rng.integers(0, 20, other.shape)).astype(np.uint8)
    np.savez_compressed(tmp_path / "control.npz", images=fresh.images)
    np.savez_compressed(tmp_path / "grains_8nm.npz", images=other)
    rows = [{"Ms": 8e5}] * 60
    # cfg None: a case without stored images would have to simulate, and fail
    families = HeldOutFamilies(rows, range(60), fresh.ms_norm, dataset_images=fresh.images)
    result = bench_ood(model, None, families, cases=("control", "grains_8nm"), out_dir=tmp_path,
                       say=lambda *_: None)
    control, other_row = result["cases"]["control"], result["cases"]["grains_8nm"]
    assert control["flagged_fraction"] <= binomial_band(60, 0.05)[1], control
    assert other_row["flagged_fraction"] >= 0.8, other_row
    assert control["interval_90"][0] <= control["flagged_fraction"] <= control["interval_90"][1]
    assert len(ood_lines(result)) == 4
    # distance to the dataset's family of the same Hamiltonian: none for the family itself, the bars'
    # whole area for the other generator (their columns vs its rows)
    assert control["median_grey_levels_from_dataset_family"] == 0.0
    assert other_row["median_grey_levels_from_dataset_family"] > 30
    with pytest.raises(ConfigError, match="holds 60 families, not the 10"):
        bench_ood(model, None, HeldOutFamilies(rows[:10], range(10), fresh.ms_norm[:10]), cases=("control",),
                  out_dir=tmp_path)


def test_unknown_cases_and_models_without_reference_are_refused(model, tmp_path):
    with pytest.raises(ConfigError, match="unknown OOD case"):
        bench_ood(model, None, HeldOutFamilies([], [], []), cases=("tilted",), out_dir=tmp_path)
    bare = PosteriorEstimator(model.net, model.architecture, model.names, model.bounds)
    with pytest.raises(ConfigError, match="no OOD reference"):
        bench_ood(bare, None, HeldOutFamilies([], [], []), cases=CASES[:1], out_dir=tmp_path)


def test_the_predictive_check_per_case_reads_saved_refinements(model, tmp_path):
    """With ``predictive`` settings each case's families are judged by ``infer.predictive_check``
    against the validation reference; saved fit results are reused (nothing is simulated here: cfg
    None would fail), and the table gains the check's rows."""
    import json

    from forcdecode.infer.predictive_check import make_reference

    fresh = bar_dataset(n=20, seed=43)
    curves = np.zeros((20, 16, 16), np.float32)
    np.savez_compressed(tmp_path / "pinning_beyond_prior.npz", images=fresh.images, curves=curves)
    statistics = [5.0] * 15 + [0.5] * 5  # 15 families no in-prior film reproduces, 5 it does
    for key, t in enumerate(statistics):
        path = tmp_path / "fits" / "pinning_beyond_prior" / f"sample_{key}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"prior": "draw", "observation_rms": {"best_over_floor_by_budget": {"25": t}}}))
    reference = make_reference(np.linspace(0.4, 1.2, 20), budget=25, round_size=25, prior="draw", sample_ids=range(20))
    settings = {"budget": 25, "round_size": 25, "workers": 1, "seed": 0, "prior": "draw",
                "fit_dir": str(tmp_path / "fits"), "reference": reference, "cases": ("pinning_beyond_prior",)}
    result = bench_ood(model, None, HeldOutFamilies([{"Ms": 8e5}] * 20, range(20), fresh.ms_norm),
                       cases=("pinning_beyond_prior",), out_dir=tmp_path, say=lambda *_: None, predictive=settings)
    row = result["cases"]["pinning_beyond_prior"]["predictive"]
    assert row["flagged"] == 15 and row["n"] == 20 and row["median_statistic"] == 5.0
    assert row["flagged_by_either"] >= 15 and row["p_values"][0] == pytest.approx(1 / 21)
    figure = tmp_path / "fits" / "pinning_beyond_prior" / "predictive_check.png"
    assert figure.read_bytes()[:4] == b"\x89PNG"
    result["predictive_reference"] = reference
    assert any("posterior-predictive check" in line for line in ood_lines(result))


def test_a_run_over_some_cases_adds_to_the_summary_instead_of_erasing_it():
    """An earlier run's rows (and its predictive rows, judged against the same reference) survive a
    run over other cases on the same families; another family set, or another reference, replaces them."""
    reference = {"budget": 50, "values": [1.0, 2.0]}
    same = {"split": "test", "sample_ids": [7, 13], "posterior": "p.pt"}
    earlier = {**same, "predictive_reference": reference,
               "cases": {"control": {"flagged": 1, "predictive": {"flagged": 2}}, "magnumnp": {"flagged": 0}}}
    now = {**same, "predictive_reference": reference,
           "cases": {"magnumnp": {"flagged": 1, "predictive": {"flagged": 1}}}}
    merged = carry_over(earlier, json_copy(now))
    assert merged["cases"]["control"] == {"flagged": 1, "predictive": {"flagged": 2}}
    assert merged["cases"]["magnumnp"] == now["cases"]["magnumnp"]  # this run's row wins
    # without a predictive reference now, the earlier one comes along with its rows
    merged = carry_over(earlier, {**same, "cases": {"magnumnp": {"flagged": 1}}})
    assert merged["predictive_reference"] == reference and merged["cases"]["control"]["predictive"] == {"flagged": 2}
    # another reference: earlier predictive rows are dropped, the rest kept
    other = carry_over(earlier, {**json_copy(now), "predictive_reference": {"budget": 200, "values": [1.0]}})
    assert other["cases"]["control"] == {"flagged": 1}
    # other families: nothing carried over
    assert "control" not in carry_over(earlier, {**json_copy(now), "sample_ids": [1, 2]})["cases"]


def json_copy(value):
    import json

    return json.loads(json.dumps(value))
