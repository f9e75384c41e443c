"""`forcdecode loop --estimator posterior`: a family unlike the posterior's training data is flagged and
not decoded (unless --force); forced, the report carries the posterior medians, intervals,
correlations and the training-data verdict."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from forcdecode.cli import main
from forcdecode.core.parameters import DEFAULT_BOUNDS, denormalize, normalize
from forcdecode.learn.data import LearningData
from forcdecode.learn.posterior import train_posterior
from forcdecode.infer.resimulate import resimulate
from forcdecode.infer.predictive_check import make_reference
from forcdecode.measured.writers import write_micromag_0015
from forcdecode.micromag.build import mesh_from_config

ROOT = Path(__file__).resolve().parents[2]
NAMES = ["N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K"]
N_FIELDS = 24


@pytest.fixture(scope="module")
def posterior(tmp_path_factory):
    """A posterior trained on bar images (not FORC families) of the loop's grid size, all six parameters."""
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("post")
    rng = np.random.default_rng(0)
    n = 200
    u = rng.random((n, 6))
    images = np.zeros((n, N_FIELDS, N_FIELDS))
    for k, row in enumerate(np.rint(u[:, 2] * (N_FIELDS - 1)).astype(int)):
        images[k, :row + 1] = 235
    images = (images + rng.integers(0, 20, images.shape)).astype(np.uint8)
    ms = rng.uniform(*DEFAULT_BOUNDS["Ms"], n)
    values = {"Ms": ms, **{name: denormalize(name, u[:, j]) for j, name in enumerate(NAMES)}}
    data = LearningData(images=images, ms_norm=normalize("Ms", ms), values=values, sample_id=np.arange(n),
                        bounds=dict(DEFAULT_BOUNDS), config_hash="bars", fields_T=np.linspace(-1, 1, N_FIELDS))
    settings = {"parameters": NAMES, "width": 8, "dropout": 0.0, "epochs": 5, "patience": 3, "batch_size": 32,
                "transforms": 1, "hidden": 8, "draws": 50,
                # the flow on all of train, as when the thresholds below were set (the recalibration's
                # holdout is tested in tests/learn/test_posterior.py; nothing here depends on it)
                "recalibration_holdout": 0.0}
    train_posterior(data, settings, {"split": [0.5, 0.2, 0.2, 0.1], "protocol": "holdout"}, 3, out / "model.pt",
                    out / "metrics.json", out / "fig.png", log=lambda *_: None)
    return out / "model.pt"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("film")
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = N_FIELDS
    (tmp / "cfg.yaml").write_text(yaml.safe_dump(cfg))
    # a square loop that saturates well inside ±1 T: in the physics domain, so only the OOD check can stop it
    params = {"Ms": 6e5, "A_ex": 1.0e-11, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 5.0, "sigma_K": 0.1}
    from forcdecode.loop.command import load_config

    truth = resimulate(load_config(tmp / "cfg.yaml"), params, n_profiles=1)
    mesh = mesh_from_config(cfg)
    scale = params["Ms"] * mesh.n_cells * mesh.cell_volume
    fields = np.linspace(-1, 1, N_FIELDS)
    curves = [(fields[i:], truth[i, i:] * scale) for i in range(N_FIELDS)]
    return write_micromag_0015(tmp / "film.frc", fields, curves), tmp / "cfg.yaml"


def write_reference(path, value):
    """A predictive-check reference of 20 validation families, all with statistic ``value`` (budget 3):
    the smallest p it can give is 1/21 < 0.05."""
    from forcdecode.infer.predictive_check import make_reference

    path.write_text(json.dumps(make_reference([value] * 20, budget=3, round_size=3, prior="draw", sample_ids=range(20))))
    return path


def test_a_family_unlike_the_training_data_is_not_decoded(posterior, measured, tmp_path, capsys):
    path, cfg = measured
    out = tmp_path / "loop"
    assert main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--profiles", "1"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "out of distribution", report.get("ood")
    assert report["ood"]["out_of_distribution"] and "not decoded" in capsys.readouterr().out
    assert "Not decoded" in (out / "report.md").read_text() and (out / "report.html").exists()
    # M_s given: checked at that M_s alone; the reference (validation + calibration) can flag at alpha
    assert report["ood"]["Ms_mode"] == "given" and report["ood"]["Ms_A_per_m"] == 600e3 and "p_by_Ms" not in report["ood"]
    assert report["ood"]["can_flag"] and "warning" not in report["ood"]
    # M_s unknown: the sweep's most favourable p, and the report says so
    assert main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-sweep-kA-m", "470", "1400", "3", "--profiles", "1"]) == 0
    swept = json.loads((out / "report.json").read_text())["ood"]
    assert swept["Ms_mode"] == "swept" and len(swept["p_by_Ms"]) == 3
    assert swept["p_value"] == max(r["p_value"] for r in swept["p_by_Ms"])
    assert "M_s unknown: the most favourable p over the sweep" in (out / "report.md").read_text()


def test_forced_the_report_carries_the_posterior(posterior, measured, tmp_path):
    path, cfg = measured
    out = tmp_path / "loop"
    assert main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--profiles", "1", "--no-physics",
                 "--no-measured-protocol", "--force"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "analysed" and report["prediction"]["estimator"] == "posterior"
    k = report["prediction"]["K_u"]
    assert k["interval_90"][0] <= k["interval_68"][0] <= k["value"] <= k["interval_68"][1] <= k["interval_90"][1]
    assert len(report["prediction"]["posterior_correlation"]["matrix"]) == 6
    text = (out / "report.md").read_text()
    assert "Pairwise correlations" in text and "Looks like the training data?" in text


def test_fit_refines_one_measured_family_end_to_end(posterior, measured, tmp_path, capsys):
    """`forcdecode fit`: amortized draws → rounds of simulations of this film → fit.json with the
    refined posterior at every round's budget (nested)."""
    path, cfg = measured
    out = tmp_path / "fit"
    reference = write_reference(tmp_path / "loose.json", 1e6)  # every validation family fitted worse: not flagged
    assert main(["fit", str(path), "--Ms-kA-m", "600", "--posterior", str(posterior), "--config", str(cfg),
                 "--budget", "6", "--round-size", "3", "--out", str(out), "--predictive-reference", str(reference)]) == 0
    result = json.loads((out / "fit.json").read_text())
    check = result["predictive_check"]
    assert not check["misspecified"] and check["p_value"] == 1.0 and check["budget"] == 3
    assert (out / "predictive_check.png").read_bytes()[:4] == b"\x89PNG"  # the film among the reference's
    assert check["statistic"] == result["observation_rms"]["best_over_floor_by_budget"]["3"]
    assert set(result["observation_rms"]["best_over_floor_by_budget"]) == {"3", "6"}
    assert result["observation_rms"]["best_over_floor_by_budget"]["6"] <= check["statistic"]
    assert set(result["refined_by_budget"]) == {"3", "6"} and result["sigma2"] > 0
    final = result["refined_by_budget"]["6"]
    assert 1.0 <= final["ess"] <= 6.0
    for name in result["names"]:
        lo, hi = final["parameters"][name]["interval_90"]
        assert 0.0 <= lo <= final["parameters"][name]["median"] <= hi <= 1.0
    assert "effective sample size" in capsys.readouterr().out
    assert main(["fit", str(path), "--posterior", str(posterior), "--config", str(cfg), "--out", str(out)]) == 2


def test_fit_in_a_box_extended_beyond_the_prior_reports_the_mass_beyond_and_refuses_what_it_cannot_do(
        posterior, measured, tmp_path, capsys):
    """`forcdecode fit --extend-prior N_pin=3`: the run says where its box ends and, in words and in
    fit.json, how much posterior mass lies past the prior's bound (None until β = 1); with an extension
    reference it is checked against validation families; the options that cannot go with it are one clear
    error each."""
    path, cfg = measured
    out = tmp_path / "fit"
    common = ["fit", str(path), "--Ms-kA-m", "600", "--posterior", str(posterior), "--config", str(cfg),
              "--budget", "6", "--round-size", "3", "--out", str(out)]
    assert main([*common, "--extend-prior", "N_pin=3"]) == 0
    result = json.loads((out / "fit.json").read_text())
    assert result["extend"] == {"N_pin": 3.0}
    beyond = result["beyond_prior"]
    row = beyond["parameters"]["N_pin"]
    assert row["scale"] == 3.0 and row["prior_mass_beyond"] == pytest.approx(2 / 3)
    assert (row["posterior_mass_beyond"] is None) == (not beyond["reached_full_likelihood"])
    assert beyond["best_over_floor"] <= beyond["best_inside_over_floor"]
    for b in result["refined_by_budget"].values():
        assert 0.0 <= b["parameters"]["N_pin"]["median"] <= 3.0
    assert "beyond the prior's bound" in capsys.readouterr().out
    # with an extension reference made in the same box, fit.json says whether a film beyond fits better
    extension = tmp_path / "extension.json"
    extension.write_text(json.dumps(make_reference([-1.0] * 20, budget=6, round_size=3, prior="draw",
                                                   sample_ids=range(20), extend={"N_pin": 3.0})))
    assert main([*common, "--extend-prior", "N_pin=3", "--predictive-reference", str(extension)]) == 0
    check = json.loads((out / "fit.json").read_text())["predictive_check"]
    assert check["check"] == "extension" and check["misspecified"] and check["p_value"] == pytest.approx(1 / 21)
    assert check["statistic"] == json.loads((out / "fit.json").read_text())["beyond_prior"][
        "log_likelihood_ratio_by_budget"]["6"] >= 0
    assert "outside the training prior" in capsys.readouterr().out
    in_box = write_reference(tmp_path / "in_box.json", 1.0)
    for extra, message in [(["--extend-prior", "K_u"], "uniformly on a linear scale"),
                           (["--extend-prior", "N_pin", "--method", "adjusted"], "needs --method pmc"),
                           (["--extend-prior", "N_pin", "--predictive-reference", str(in_box)],
                            "extension_reference.json"),
                           (["--extend-prior", "N_pin=2", "--predictive-reference", str(extension)],
                            "refine with the same --extend-prior"),
                           (["--predictive-reference", str(extension)], "refine with the same --extend-prior")]:
        assert main([*common, *extra]) == 2
        assert message in capsys.readouterr().err


def test_the_loop_refines_in_an_extended_box_and_reports_the_mass_beyond_the_bound(posterior, measured, tmp_path):
    """`loop --refine N --refine-extend-prior N_pin=3`: report.json's refined entry carries beyond_prior, the
    re-simulated N_pin is the refined median even past the bound, report.md says it in words; without
    --refine, with the adjusted method or beside a reference made in the prior's box it is one clear error;
    with an extension reference the report flags a family a film beyond the bound fits better."""
    path, cfg = measured
    out = tmp_path / "loop"
    common = ["loop", str(path), "--config", str(cfg), "--estimator", "posterior", "--posterior", str(posterior),
              "--Ms-kA-m", "600", "--profiles", "1", "--no-physics", "--no-measured-protocol", "--force"]
    assert main([*common, "--out", str(out), "--refine", "6", "--refine-round-size", "3",
                 "--refine-extend-prior", "N_pin=3"]) == 0
    report = json.loads((out / "report.json").read_text())
    refined = report["refined"]
    assert refined["extend"] == {"N_pin": 3.0} and "N_pin" in refined["beyond_prior"]["parameters"]
    low, high = DEFAULT_BOUNDS["N_pin"]
    assert 0 <= report["parameters"]["N_pin"] <= low + 3 * (high - low)
    assert report["parameters"]["N_pin"] == round(refined["parameters"]["N_pin"]["value"])
    assert "beyond the prior's bound" in (out / "report.md").read_text()
    # an extension reference from validation families that all fitted as well inside: flagged in the report
    extension = tmp_path / "extension.json"
    extension.write_text(json.dumps(make_reference([-1.0] * 20, budget=6, round_size=3, prior="draw",
                                                   sample_ids=range(20), extend={"N_pin": 3.0})))
    flagged = tmp_path / "flagged"
    assert main([*common, "--out", str(flagged), "--refine", "6", "--refine-round-size", "3",
                 "--refine-extend-prior", "N_pin=3", "--predictive-reference", str(extension)]) == 0
    check = json.loads((flagged / "report.json").read_text())["refined"]["predictive_check"]
    assert check["check"] == "extension" and check["misspecified"]
    assert "**Outside the prior (N_pin)" in (flagged / "report.md").read_text()
    for extra in (["--refine-extend-prior", "N_pin"],
                  ["--refine", "6", "--refine-extend-prior", "N_pin", "--predictive-reference",
                   str(write_reference(tmp_path / "in_box.json", 1.0))],
                  ["--refine", "6", "--refine-method", "adjusted", "--refine-extend-prior", "N_pin"],
                  ["--refine", "6", "--refine-extend-prior", "K_u"]):
        assert main([*common, "--out", str(tmp_path / "x"), *extra]) == 2


def test_the_loop_analyses_the_refined_posterior_when_asked(posterior, measured, tmp_path, capsys):
    """`loop --estimator posterior --refine N`: the refined medians (not the amortized ones) are the
    Hamiltonian re-simulated and analysed; the report carries both."""
    path, cfg = measured
    out = tmp_path / "loop"
    assert main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--profiles", "1", "--no-physics",
                 "--no-measured-protocol", "--force", "--refine", "6", "--refine-round-size", "3"]) == 0
    report = json.loads((out / "report.json").read_text())
    refined = report["refined"]
    assert report["status"] == "analysed" and refined["budget"] == 6 and 1.0 <= refined["ess"] <= 6.0
    for name, row in refined["parameters"].items():
        assert row["value_90"][0] <= row["value"] <= row["value_90"][1]
        expected = round(row["value"]) if name == "N_pin" else row["value"]
        assert report["parameters"][name] == pytest.approx(expected, rel=1e-9), name  # what was re-simulated
    assert report["parameters"]["Ms"] == pytest.approx(6e5)
    assert "Refined by 6 simulations" in (out / "report.md").read_text()
    # with a reference whose validation families all came closer, the family is flagged, in the report too
    reference = write_reference(tmp_path / "tight.json", 1e-6)
    flagged = tmp_path / "flagged"
    assert main(["loop", str(path), "--out", str(flagged), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--profiles", "1", "--no-physics",
                 "--no-measured-protocol", "--force", "--refine", "6", "--refine-round-size", "3",
                 "--predictive-reference", str(reference)]) == 0
    check = json.loads((flagged / "report.json").read_text())["refined"]["predictive_check"]
    assert check["misspecified"] and check["p_value"] == pytest.approx(1 / 21)
    assert "**Misspecified: no film inside the prior" in (flagged / "report.md").read_text()
    assert "predictive_check.png" in (flagged / "report.md").read_text()  # the figure, embedded in report.html
    assert (flagged / "predictive_check.png").exists() and "data:image/png" in (flagged / "report.html").read_text()
    # a reference made with other rounds cannot judge this refinement: a clear error before any simulation
    assert main(["loop", str(path), "--out", str(tmp_path / "y"), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--force", "--refine", "6",
                 "--refine-round-size", "2", "--predictive-reference", str(reference)]) == 2
    # nor one made with the other prior: the loop refines with fit_cli.DEFAULT_PRIOR, and says so
    from forcdecode.infer.refine import DEFAULT_PRIOR, PRIORS
    from forcdecode.infer.predictive_check import make_reference

    other = tmp_path / "other_prior.json"
    other.write_text(json.dumps(make_reference([1e-6] * 20, budget=3, round_size=3, sample_ids=range(20),
                                               prior=next(p for p in PRIORS if p != DEFAULT_PRIOR))))
    assert main(["loop", str(path), "--out", str(tmp_path / "z"), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--force", "--refine", "6",
                 "--refine-round-size", "3", "--predictive-reference", str(other)]) == 2
    assert f"the {DEFAULT_PRIOR} prior" in capsys.readouterr().err and not (tmp_path / "z").exists()
    # refinement starts from the joint posterior: Alice, or a given Hamiltonian, is refused with exit 2
    assert main(["loop", str(path), "--out", str(tmp_path / "x"), "--config", str(cfg), "--Ms-kA-m", "600",
                 "--refine", "6"]) == 2
    # the adjusted refinement: its medians re-simulated; the pmc particles' predictive check refused with it
    adjusted = tmp_path / "adjusted"
    assert main(["loop", str(path), "--out", str(adjusted), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--profiles", "1", "--no-physics",
                 "--no-measured-protocol", "--force", "--refine", "12", "--refine-round-size", "6",
                 "--refine-method", "adjusted"]) == 0
    report = json.loads((adjusted / "report.json").read_text())
    assert report["refined"]["method"] == "adjusted" and report["refined"]["betas"] is None
    for name, row in report["refined"]["parameters"].items():
        expected = round(row["value"]) if name == "N_pin" else row["value"]
        assert report["parameters"][name] == pytest.approx(expected, rel=1e-9), name
    assert main(["loop", str(path), "--out", str(tmp_path / "z"), "--config", str(cfg), "--estimator", "posterior",
                 "--posterior", str(posterior), "--Ms-kA-m", "600", "--force", "--refine", "6",
                 "--refine-round-size", "3", "--refine-method", "adjusted", "--predictive-reference",
                 str(reference)]) == 2


def test_fit_one_round_per_job_equals_fit_in_one_process(posterior, measured, tmp_path):
    """`fit-step init|round|report` (the workflow's per-round jobs, each a fresh process reading the
    state file) reproduce `forcdecode fit` exactly: same particles, same β, same refined posterior."""
    path, cfg = measured
    common = ["--posterior", str(posterior), "--config", str(cfg)]
    assert main(["fit", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                 "--out", str(tmp_path / "whole")]) == 0
    states = [tmp_path / f"round_{r}.npz" for r in range(3)]
    assert main(["fit-step", "init", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                 "--state", str(states[0])]) == 0
    # a report before the last round is refused, naming what is missing
    assert main(["fit-step", "report", "--state", str(states[0]), "--out", str(tmp_path / "early.json")]) == 2
    for r in (1, 2):
        assert main(["fit-step", "round", *common, "--state-in", str(states[r - 1]), "--state-out", str(states[r])]) == 0
    assert main(["fit-step", "report", "--state", str(states[2]), "--out", str(tmp_path / "steps.json")]) == 0
    whole = json.loads((tmp_path / "whole" / "fit.json").read_text())
    steps = json.loads((tmp_path / "steps.json").read_text())
    assert steps["betas"] == whole["betas"] and steps["ess_per_round"] == whole["ess_per_round"]
    for budget in ("3", "6"):
        a, b = whole["refined_by_budget"][budget], steps["refined_by_budget"][budget]
        assert a["ess"] == b["ess"] and a["parameters"] == b["parameters"], budget
    assert steps["amortized"] == whole["amortized"] and steps["sigma2"] == whole["sigma2"]
    assert main(["fit-step", "round", *common, "--state-in", str(states[2]), "--state-out", str(tmp_path / "x.npz")]) == 2
    # in a box extended beyond the prior the same holds, and the report carries beyond_prior
    assert main(["fit", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                 "--extend-prior", "N_pin=3", "--out", str(tmp_path / "whole_ext")]) == 0
    ext = [tmp_path / f"ext_{r}.npz" for r in range(3)]
    assert main(["fit-step", "init", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                 "--extend-prior", "N_pin=3", "--state", str(ext[0])]) == 0
    for r in (1, 2):
        assert main(["fit-step", "round", *common, "--state-in", str(ext[r - 1]), "--state-out", str(ext[r])]) == 0
    assert main(["fit-step", "report", "--state", str(ext[2]), "--out", str(tmp_path / "steps_ext.json")]) == 0
    whole = json.loads((tmp_path / "whole_ext" / "fit.json").read_text())
    steps = json.loads((tmp_path / "steps_ext.json").read_text())
    assert steps["extend"] == whole["extend"] == {"N_pin": 3.0}
    assert steps["beyond_prior"] == whole["beyond_prior"] and steps["betas"] == whole["betas"]
    assert steps["refined_by_budget"]["6"]["parameters"] == whole["refined_by_budget"]["6"]["parameters"]
    # the report judges the film against a reference made in the same box (Λ), with its figure; one made
    # in another box is refused, at init before any simulation and at report
    from forcdecode.infer.predictive_check import make_reference

    extension = tmp_path / "extension.json"
    extension.write_text(json.dumps(make_reference([-1.0] * 20, budget=6, round_size=3, prior="draw",
                                                   sample_ids=range(20), extend={"N_pin": 3.0})))
    checked = tmp_path / "checked" / "fit.json"
    assert main(["fit-step", "report", "--state", str(ext[2]), "--out", str(checked),
                 "--predictive-reference", str(extension)]) == 0
    check = json.loads(checked.read_text())["predictive_check"]
    assert check["check"] == "extension" and check["misspecified"]
    assert check["statistic"] == whole["beyond_prior"]["log_likelihood_ratio_by_budget"]["6"]
    assert (checked.parent / "predictive_check.png").exists()
    in_box = write_reference(tmp_path / "in_box.json", 1.0)
    assert main(["fit-step", "report", "--state", str(ext[2]), "--out", str(tmp_path / "no.json"),
                 "--predictive-reference", str(in_box)]) == 2
    assert main(["fit-step", "init", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                 "--extend-prior", "N_pin=3", "--predictive-reference", str(in_box),
                 "--state", str(tmp_path / "never.npz")]) == 2
    assert not (tmp_path / "no.json").exists() and not (tmp_path / "never.npz").exists()


def test_fit_adjusted_simulates_own_realisations_nests_budgets_and_resumes(posterior, measured, tmp_path, capsys):
    """`forcdecode fit --method adjusted`: the amortized draws simulated on their own realisations, the
    answer regression-adjusted at every checkpoint; a saved run extended equals the longer run."""
    from forcdecode.config import load_config
    from forcdecode.learn.posterior import PosteriorEstimator
    from forcdecode.infer.fit_cli import print_summary
    from forcdecode.infer.refine import fit_adjusted, observation

    path, cfg_path = measured
    out = tmp_path / "fit"
    assert main(["fit", str(path), "--Ms-kA-m", "600", "--posterior", str(posterior), "--config", str(cfg_path),
                 "--method", "adjusted", "--budget", "12", "--round-size", "6", "--out", str(out)]) == 0
    result = json.loads((out / "fit.json").read_text())
    assert result["method"] == "adjusted" and set(result["refined_by_budget"]) == {"12"}
    # the answer is the reading chosen on validation; the others are read off the same simulations
    # (12 simulations are too few to cross-fit image summaries: the network's shifted reading stands in)
    assert result["reading"] == "shifted"
    assert set(result["variants"]) == {"proposal_as_prior", "prior_weighted", "diagonal", "proposal_as_prior_diagonal",
                                       "anchored"}
    assert all(set(v) == {"12"} for v in result["variants"].values())
    final = result["refined_by_budget"]["12"]
    assert 1.0 <= final["ess"] <= 12.0 and final["failed_simulations"] == 0
    for name in result["names"]:
        lo, hi = final["parameters"][name]["interval_90"]
        assert 0.0 <= lo <= final["parameters"][name]["median"] <= hi <= 1.0
    # how finely one simulated family's summary pins each parameter, in the record and printed
    assert set(final["summary_resolution"]) == set(result["names"])
    assert all(v > 0 for v in final["summary_resolution"].values())
    printed = capsys.readouterr().out
    assert "effective sample size" in printed and "summary resolution" in printed
    assert "answer: reading 'shifted'" in printed
    # shifted: the anchored medians, the amortized intervals moved there (in logit) and narrowed only by a
    # summary resolution below 1
    from forcdecode.infer.fit import _inverse_logit, _logit

    for name in result["names"]:
        row, anchored = final["parameters"][name], result["variants"]["anchored"]["12"]["parameters"][name]
        assert row["median"] == pytest.approx(anchored["median"], abs=1e-9)
        amortized = result["amortized"]["parameters"][name]
        scale = min(1.0, final["summary_resolution"][name])
        # the amortized summary's quantiles come from the same reported draws
        want = _logit(np.array(row["median"])) + scale * (_logit(np.array(amortized["interval_90"]))
                                                          - _logit(np.array(amortized["median"])))
        # in u (the squeeze clips logit near 0 and 1); two quantile rules of the same draws
        np.testing.assert_allclose(row["interval_90"], _inverse_logit(want), atol=0.005)
    # --predictive-reference is the pmc particles' statistic: refused with the adjusted method
    reference = write_reference(tmp_path / "loose.json", 1e6)
    assert main(["fit", str(path), "--Ms-kA-m", "600", "--posterior", str(posterior), "--config", str(cfg_path),
                 "--method", "adjusted", "--budget", "12", "--round-size", "6", "--out", str(out),
                 "--predictive-reference", str(reference)]) == 2

    cfg, est = load_config(cfg_path), PosteriorEstimator.load(posterior)
    image, family, Ms, _ = observation(path, None, cfg, 600)
    common = dict(workers=1, seed=0, key=5, round_size=6)
    state = tmp_path / "adjusted.npz"
    short = fit_adjusted(cfg, est, image, family, Ms, budget=12, checkpoints=(12,), state_path=state, **common)
    longer = fit_adjusted(cfg, est, image, family, Ms, budget=24, checkpoints=(12, 24), state_path=state, **common)
    fresh = fit_adjusted(cfg, est, image, family, Ms, budget=24, checkpoints=(12, 24), **common)
    with np.load(state) as saved:  # the simulated images are kept with the state, one per simulation
        assert saved["images"].shape == (24, *np.shape(image)) and saved["images"].dtype == np.uint8
        assert saved["images"][saved["valid"]].max() > 0
    # equal up to float32 rounding: the flow's log-density of the draws is evaluated as one batch, whose
    # size (12 or 18) may change the summation order of the matrix products
    # the image readings need 20 simulations to cross-fit: at 24 they exist, and only where every budget has them
    assert "image_summaries" in fresh["refined_by_budget"]["24"] and "image_summaries" not in fresh["refined_by_budget"]["12"]
    assert not {"images_anchored", "both_anchored", "images_shifted", "images_likelihood"} & set(fresh["variants"])
    # the answer is chosen per budget: at 12 the network's, at 24 the images' unless refused there
    assert fresh["refined_by_budget"]["12"]["reading"] == "shifted"
    assert fresh["reading"] == fresh["refined_by_budget"]["24"]["reading"]
    assert fresh["reading"] == ("shifted" if fresh["refined_by_budget"]["24"]["image_summaries"]["outside_simulations"]
                                else "images_shifted")
    # the saved state re-read at 24 alone (no new simulation): the image reading is the answer unless the
    # observed image summary lies outside the simulated ones (then the regression would extrapolate)
    reread = fit_adjusted(cfg, est, image, family, Ms, budget=24, checkpoints=(24,), state_path=state, **common)
    at24 = reread["refined_by_budget"]["24"]
    assert set(at24["image_summaries"]["resolution"]) == set(reread["names"]) and reread["wall_s"] == longer["wall_s"]
    images = at24["image_summaries"]
    assert images["outside_simulations"] == (images["distance2_observed"] > images["distance2_simulated_max"])
    network_readings = {"proposal_as_prior", "prior_weighted", "diagonal", "proposal_as_prior_diagonal", "anchored"}
    capsys.readouterr()
    print_summary(reread, 24)
    printed = capsys.readouterr().out
    assert f"answer: reading {reread['reading']!r}" in printed
    assert ("outside the simulated ones" in printed) == images["outside_simulations"]
    if images["outside_simulations"]:  # this film's measured family is far from 24 simulations of the tiny film
        # the image likelihood is formed either way: its misfit says how far the observation lies
        assert reread["reading"] == "shifted" and set(reread["variants"]) == network_readings | {"images_likelihood"}
        assert at24["parameters"] == fresh["refined_by_budget"]["24"]["parameters"]
    else:
        assert reread["reading"] == "images_shifted"
        assert set(reread["variants"]) == network_readings | {"images_anchored", "shifted", "both_anchored",
                                                              "resolved_anchored", "images_likelihood"}
        # the per-parameter pick takes each parameter from the summaries with the finer resolution
        resolved = reread["variants"]["resolved_anchored"]["24"]
        for n in reread["names"]:
            finer = images["resolution"][n] < at24["summary_resolution"][n]
            assert resolved["summary_source"][n] == ("images" if finer else "network")
            source = reread["variants"]["images_anchored" if finer else "anchored"]["24"]
            assert resolved["parameters"][n] == source["parameters"][n]
    for budget, reference in (("12", short), ("24", fresh)):
        a, b = longer["refined_by_budget"][budget], reference["refined_by_budget"][budget]
        assert a["parameters"].keys() == b["parameters"].keys()
        for name in a["parameters"]:
            got, want = a["parameters"][name], b["parameters"][name]
            np.testing.assert_allclose([got["median"], *got["interval_68"], *got["interval_90"]],
                                       [want["median"], *want["interval_68"], *want["interval_90"]], rtol=0, atol=1e-5)


def test_fit_adjusted_reads_a_saved_state_whose_images_encode_k_u(posterior, measured, tmp_path, capsys):
    """The inside branch of the image reading, without simulating: a saved state of 40 draws whose
    images are the observed one with logit K_u written into them (bright pixels dimmed below a value v,
    dark ones lit above it, ±3 counts of noise), so the observed image is the family at u_K = v, well inside
    the simulated cloud. The answer is the image reading, its K_u median is v (not the amortized
    median), and the per-parameter pick takes K_u from the images."""
    from forcdecode.config import load_config
    from forcdecode.core.streams import stream_seed
    from forcdecode.learn.posterior import PosteriorEstimator
    from forcdecode.infer.fit_cli import print_summary
    from forcdecode.infer.refine import fit_adjusted, network_summaries, observation

    path, cfg_path = measured
    cfg, est = load_config(cfg_path), PosteriorEstimator.load(posterior)
    image, family, Ms, _ = observation(path, None, cfg, 600)
    seed, key, budget = 0, 7, 40
    ms_norm = float(normalize("Ms", Ms, est.bounds))
    # the draws fit_adjusted makes (it refuses a state saved for other draws, so a change there fails here)
    u = est.sample(np.asarray(image)[None], [ms_norm], 4000, seed=stream_seed(seed, "posterior", "fit", key),
                   recalibrated=False)[0][:budget]
    k_u = u[:, NAMES.index("K_u")]
    v = float(np.quantile(k_u, 0.25))  # off the draws' median, so a reading that ignores the images misses it
    bright, dark = image >= 200, image < 50
    assert bright.sum() >= 50 and dark.sum() >= 50, "the fixture family needs both bright and dark pixels"
    # linear in logit u, the scale the summaries regress on: at most 200 counts from the observed image
    shift = np.log(k_u / (1 - k_u)) - np.log(v / (1 - v))
    counts = np.rint(200 * shift / np.abs(shift).max()).astype(int)
    rng = np.random.default_rng(1)
    images = np.repeat(image[None].astype(int), budget, axis=0)
    images[:, bright] -= np.maximum(-counts, 0)[:, None]
    images[:, dark] += np.maximum(counts, 0)[:, None]
    images = np.clip(images + rng.integers(-3, 4, images.shape), 0, 255).astype(np.uint8)
    state = tmp_path / "encoded.npz"
    np.savez(state, u=u, summaries=network_summaries(est, images, ms_norm, 11), valid=np.ones(budget, bool),
             wall_s=1.0, images=images)

    result = fit_adjusted(cfg, est, image, family, Ms, budget=budget, checkpoints=(budget,), state_path=state,
                          workers=1, seed=seed, key=key)
    at = result["refined_by_budget"][str(budget)]
    reading = at["image_summaries"]
    assert not reading["outside_simulations"] and reading["distance2_observed"] < reading["distance2_simulated_max"]
    assert result["reading"] == "images_shifted" and result["wall_s"] == 1.0
    assert {"anchored", "images_anchored", "both_anchored", "resolved_anchored"} <= set(result["variants"])
    # K_u is what the images encode: resolved (the draws span logit ±7, so the ridge's shrinkage, which
    # changes from fold to fold, leaves ~0.2), the others not; read to within 0.03 of v
    assert reading["resolution"]["K_u"] < 0.5 and min(r for n, r in reading["resolution"].items() if n != "K_u") > 2
    median = at["parameters"]["K_u"]["median"]
    amortized = result["amortized"]["parameters"]["K_u"]["median"]
    assert abs(median - v) < 0.03 < abs(amortized - v), (median, v, amortized)
    lo, hi = at["parameters"]["K_u"]["interval_90"]
    assert lo <= v <= hi and hi - lo < 0.5 * np.subtract(*result["amortized"]["parameters"]["K_u"]["interval_90"][::-1])
    assert result["variants"]["resolved_anchored"][str(budget)]["summary_source"]["K_u"] == "images"
    print_summary(result, budget)
    printed = capsys.readouterr().out
    assert "answer: reading 'images_shifted'" in printed and "outside the simulated ones" not in printed
