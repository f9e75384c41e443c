"""``bench fit``'s scoring (``bench/fit.py``) on rows whose errors are known."""

import numpy as np
import pytest

from forcdecode.bench.fit import families_to_resolve, fit_summary, summary_lines


def row(truth, amortized, refined, lo_hi, Ms=8e5):
    summary = lambda m, iv: {"parameters": {"K_u": {"median": m, "interval_90": list(iv)}}, "ess": 10.0,  # noqa: E731
                             "wall_s": 5.0, "tempered": False}
    return {"names": ["K_u"], "Ms": Ms, "observation_rms": {"amortized_over_floor": 3.0, "refined_over_floor": 1.0}, "truth_normalized": {"K_u": truth},
            "amortized": summary(amortized, (0.0, 1.0)), "refined_by_budget": {"50": summary(refined, lo_hi)}}


def test_a_refinement_that_halves_every_error_is_scored_as_better():
    rng = np.random.default_rng(0)
    truths = rng.uniform(0.3, 0.9, 12)
    offsets = rng.choice([-1, 1], 12) * rng.uniform(0.05, 0.1, 12)
    rows = [row(t, t + o, t + o / 2, (t - 0.01, t + 0.2) if i < 9 else (t + 0.01, t + 0.2))
            for i, (t, o) in enumerate(zip(truths, offsets))]
    out = fit_summary(rows, [50], None, np.random.default_rng(1))
    assert out["mae_refined"]["50"]["K_u"] == pytest.approx(out["mae_amortized"]["K_u"] / 2)
    lo, hi = out["mae_difference_interval_90"]["50"]["K_u"]
    assert hi < 0 and lo < out["mae_difference"]["50"]["K_u"] < hi
    assert out["families_improved"]["50"]["K_u"] == 12
    assert out["coverage_refined"]["50"]["K_u"] == pytest.approx(0.75) and out["coverage_amortized"]["K_u"] == 1.0
    # the M_s-only predictor: K_u's draw prior p(u) = 2u has its median at 1/√2 whatever M_s
    assert out["mae_prior"]["K_u"] == pytest.approx(np.mean(np.abs(2**-0.5 - truths)), abs=1e-3)
    assert any("beta = 1 in 12 of 12" in line for line in summary_lines(out))
    assert out["observation_rms_over_floor"] == {"amortized": [3.0, 3.0, 3.0], "refined": [1.0, 1.0, 1.0]}
    # the mean 90 % widths: (0, 1) amortized; refined 0.21 in nine families, 0.19 in three
    assert out["width_90_amortized"]["K_u"] == pytest.approx(1.0)
    assert out["width_90_refined"]["50"]["K_u"] == pytest.approx(0.205)
    assert "image_reading_refused" not in out


def test_a_variant_of_the_same_simulations_is_scored_beside_the_refinement():
    """Rows with ``variants`` (the adjusted fit's proposal_as_prior): each variant's MAE and coverage,
    scored like the refinement, and a printed line."""
    truths = np.linspace(0.3, 0.8, 6)
    rows = []
    for t in truths:
        r = row(t, t + 0.1, t + 0.05, (t - 0.2, t + 0.2))
        r["variants"] = {"proposal_as_prior": {"50": {**r["refined_by_budget"]["50"], "parameters": {
            "K_u": {"median": t + 0.02, "interval_90": [t + 0.01, t + 0.03]}}}}}
        rows.append(r)
    out = fit_summary(rows, [50], None, np.random.default_rng(1))
    variant = out["variants"]["proposal_as_prior"]
    assert variant["mae_refined"]["50"]["K_u"] == pytest.approx(0.02)
    assert variant["coverage_refined"]["50"]["K_u"] == 0.0 and out["coverage_refined"]["50"]["K_u"] == 1.0
    assert variant["families_improved"]["50"]["K_u"] == 6
    assert out["mae_refined"]["50"]["K_u"] == pytest.approx(0.05)
    assert any(line.startswith("  variant proposal_as_prior, 50: MAE K_u 0.020") for line in summary_lines(out))
    for k, r in enumerate(rows):  # the adjusted fit's summary resolution: the median over families, printed
        r["refined_by_budget"]["50"]["summary_resolution"] = {"K_u": float(k)}
    out = fit_summary(rows, [50], None, np.random.default_rng(1))
    assert out["summary_resolution_median"] == {"50": {"K_u": 2.5}}
    assert any(line.startswith("summary resolution at 50") and "K_u 2.5" in line for line in summary_lines(out))
    for k, r in enumerate(rows):  # and the image summaries' resolution, where every row has them
        r["refined_by_budget"]["50"]["image_summaries"] = {"components": 5, "ridge": 1.0, "resolution": {"K_u": 2.0 * k}}
    out = fit_summary(rows, [50], None, np.random.default_rng(1))
    assert out["image_summary_resolution_median"] == {"50": {"K_u": 5.0}}
    assert any(line.startswith("image summary resolution at 50") and "K_u 5" in line for line in summary_lines(out))
    # the guard's refusals counted over the rows that have image summaries
    for k, r in enumerate(rows):
        r["refined_by_budget"]["50"]["image_summaries"]["outside_simulations"] = k in (1, 4)
    del rows[0]["refined_by_budget"]["50"]["image_summaries"]
    out = fit_summary(rows, [50], None, np.random.default_rng(1))
    assert out["image_reading_refused"] == {"50": {"refused": 2, "formed": 5}}
    assert "image reading at 50: refused in 2 of the 5 families that have image summaries" in "\n".join(summary_lines(out))
    rows[2]["refined_by_budget"]["50"].pop("image_summaries")
    assert "image_summary_resolution_median" not in fit_summary(rows, [50], None, np.random.default_rng(1))
    rows[1]["refined_by_budget"]["50"].pop("summary_resolution")  # not in every row: not reported
    assert "summary_resolution_median" not in fit_summary(rows, [50], None, np.random.default_rng(1))
    rows[0].pop("variants")  # a variant not in every row is not scored
    assert "variants" not in fit_summary(rows, [50], None, np.random.default_rng(1))


def test_the_families_a_bench_needs_follow_the_spread_of_the_paired_differences():
    """Differences −0.1, 0, −0.1, 0: mean −0.05, s = 0.0577, so ⌈(1.645 · 0.0577 / 0.05)²⌉ = ⌈3.6⌉ = 4 families; a
    spread ten times larger needs a hundred times more (⌈360.8⌉). In the scoring, per budget and parameter, and printed."""
    assert families_to_resolve([-0.1, 0.0, -0.1, 0.0]) == 4
    assert families_to_resolve([-0.55, 0.45, -0.55, 0.45]) == 361  # mean −0.05, s = 0.577
    assert families_to_resolve([0.1, 0.1, 0.1]) == 2 and families_to_resolve([0.0, 0.0]) is None
    assert families_to_resolve([0.3]) is None
    # mean −0.05 and s 0.2 need 44 families; normal samples of 44 families then exclude 0 from their 90 %
    # interval about half the time (the count is where the power is 0.5, not a guarantee)
    rng = np.random.default_rng(3)
    z = rng.normal(size=500)
    n = families_to_resolve(-0.05 + 0.2 * (z - z.mean()) / z.std(ddof=1))  # mean −0.05, s 0.2 exactly
    assert n == 44  # ⌈(1.645 · 0.2 / 0.05)²⌉ = ⌈43.3⌉
    excluded = [abs(d.mean()) > 1.645 * d.std(ddof=1) / np.sqrt(n) for d in rng.normal(-0.05, 0.2, (2000, n))]
    assert 0.45 < np.mean(excluded) < 0.55
    rows = [row(0.5, 0.5 + e, 0.5 + e - d, (0.0, 1.0)) for e, d in zip([0.2, 0.2, 0.2, 0.2], [0.1, 0.0, 0.1, 0.0])]
    out = fit_summary(rows, [50], None, np.random.default_rng(1))
    assert out["families_to_resolve"] == {"50": {"K_u": 4}}
    assert "families for the Δ interval at 50 to exclude 0 if the effect is as measured (now 4): K_u 4" in summary_lines(out)


@pytest.mark.parametrize("flags", [["--first-family", "-1"], ["--families", "0"]])
def test_a_family_range_that_cannot_exist_is_one_clear_error(flags, capsys):
    from forcdecode.cli import main

    assert main(["bench", "fit", *flags]) == 2
    assert "--first-family must be >= 0 and --families >= 1" in capsys.readouterr().err


def test_case_observations_take_the_stored_families_and_the_cases_truth(tmp_path):
    """``bench fit --case``: the families of a ``bench ood`` case, matched to the split's positions,
    with the case's Hamiltonian as the truth (magnumnp: no pinning; beyond the prior: 3× the bound)."""
    from types import SimpleNamespace

    from forcdecode.bench.cli import _case_observations
    from forcdecode.core.errors import ConfigError

    names = ["Ms", "N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K"]
    values = {n: np.arange(5, dtype=float) + 1 for n in names}
    data = SimpleNamespace(values=values)
    held_out = np.array([4, 2, 0])
    images = np.arange(3)[:, None, None] * np.ones((3, 4, 4), np.uint8)
    curves = np.arange(3)[:, None, None] * np.ones((3, 4, 4), np.float32)
    args = SimpleNamespace(case="magnumnp", ood_dir=str(tmp_path), first_family=1, families=2)
    with pytest.raises(ConfigError, match="not found"):
        _case_observations(args, {}, data, held_out, held_out[1:])
    np.savez_compressed(tmp_path / "magnumnp.npz", images=images)
    with pytest.raises(ConfigError, match="images only"):
        _case_observations(args, {}, data, held_out, held_out[1:])
    np.savez_compressed(tmp_path / "magnumnp.npz", images=images, curves=curves)
    out = _case_observations(args, {}, data, held_out, held_out[1:])
    assert [int(o[0][0, 0]) for o in out] == [1, 2] and [float(o[1][0, 0]) for o in out] == [1.0, 2.0]
    assert out[0][2]["N_pin"] == 0 and out[0][2]["K_u"] == values["K_u"][2]
    np.savez_compressed(tmp_path / "pinning_beyond_prior.npz", images=images, curves=curves)
    args.case = "pinning_beyond_prior"
    out = _case_observations(args, {"bounds": {"N_pin": [0, 255]}}, data, held_out, held_out[1:])
    assert out[1][2]["N_pin"] == 765
    args.families = 3
    with pytest.raises(ConfigError, match="holds 3 families"):
        _case_observations(args, {}, data, held_out, held_out)


def extended_row(ratio):
    """A fit result in a box with N_pin extended ×4 whose log-likelihood ratio is ``ratio`` at 25 and 50."""
    return {"prior": "draw", "extend": {"N_pin": 4.0},
            "beyond_prior": {"log_likelihood_ratio_by_budget": {"25": ratio, "50": ratio}}}


def test_an_extended_validation_bench_writes_the_reference_that_judges_other_films(tmp_path):
    """``bench fit --extend-prior``: a validation run writes FIT_DIR/extension_reference.json from its
    families' Λ; a run with ``--extension-reference`` judges each family against it and counts the flags
    (conformal: with 20 reference values of 0, a positive Λ gets p = 1/21 < 0.05, Λ = 0 gets p = 1)."""
    import argparse
    import json

    from forcdecode.bench.cli import _extension_check

    said = []
    args = argparse.Namespace(split="validation", case=None, fit_dir=str(tmp_path), round_size=25, prior="draw",
                              extension_reference=None)
    out = {"sample_ids": list(range(20))}
    _extension_check(args, out, [extended_row(0.0)] * 19 + [extended_row(0.002)], 50, {"N_pin": 4.0}, None, said.append)
    reference = json.loads((tmp_path / "extension_reference.json").read_text())
    assert reference["extend"] == {"N_pin": 4.0} and reference["budget"] == 50 and len(reference["values"]) == 20
    assert out["log_likelihood_ratio"]["19"] == 0.002 and "extension_check" not in out
    assert any("reference of 20 validation families" in line for line in said)
    args = argparse.Namespace(split="test", case="pinning_beyond_prior", fit_dir=str(tmp_path / "case"), round_size=25,
                              prior="draw", extension_reference=str(tmp_path / "extension_reference.json"))
    out = {"sample_ids": [7, 13, 33]}
    _extension_check(args, out, [extended_row(2.2), extended_row(0.0), extended_row(0.001)], 50, {"N_pin": 4.0},
                     reference, said.append)
    check = out["extension_check"]
    assert (check["flagged"], check["of"]) == (1, 3)
    assert check["per_family"]["7"]["misspecified"] and check["per_family"]["7"]["p_value"] == pytest.approx(1 / 21)
    assert check["per_family"]["13"]["p_value"] == 1.0 and check["per_family"]["33"]["p_value"] == pytest.approx(2 / 21)
    assert not (tmp_path / "case" / "extension_reference.json").exists()  # a case run writes no reference
    assert said[-2].startswith("extension check: 1 of 3 families flagged")
    assert (tmp_path / "case" / "extension_check.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_reading_choice_ranks_readings_by_their_mean_error_with_paired_intervals():
    """``reading_choice``: the amortized posterior, the answer and every variant present in all rows, each
    scored by its mean |median − truth| over the choice's parameters (K_u here), the lowest named best."""
    from forcdecode.bench.fit import choice_lines, reading_choice

    truths = np.linspace(0.3, 0.8, 8)
    rows = []
    for t in truths:
        r = row(t, t + 0.1, t + 0.05, (t - 0.2, t + 0.2))
        r["refined_by_budget"]["50"]["reading"] = "images_shifted"
        r["variants"] = {"closer": {"50": {"parameters": {"K_u": {"median": t + 0.02, "interval_90": [0, 1]}}}},
                         "farther": {"50": {"parameters": {"K_u": {"median": t - 0.2, "interval_90": [0, 1]}}}}}
        rows.append(r)
    rows[0]["variants"]["only_here"] = rows[0]["variants"]["closer"]
    choice = reading_choice(rows, 50, np.random.default_rng(0))
    table = choice["readings"]
    assert set(table) == {"amortized", "answer", "closer", "farther"} and choice["best"] == "closer"
    assert table["closer"]["mean_mae"] == pytest.approx(0.02) and table["farther"]["mean_mae"] == pytest.approx(0.2)
    assert table["answer"]["mean_mae"] == pytest.approx(0.05) and table["amortized"]["mean_mae"] == pytest.approx(0.1)
    # every family moves by the same amount: the paired intervals are that amount exactly
    assert table["closer"]["minus_answer_ci90"] == pytest.approx([-0.03, -0.03])
    assert table["farther"]["minus_amortized_ci90"] == pytest.approx([0.1, 0.1])
    assert choice["answer_reading"] == ["images_shifted"] and choice["parameters"] == ["K_u"]
    lines = choice_lines(choice)
    assert "answer now: images_shifted" in lines[0] and lines[1].split()[0] == "closer"
