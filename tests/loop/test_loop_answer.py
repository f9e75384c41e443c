"""`forcdecode loop` reports the decoded Hamiltonian as `predict` does (issue 44 item 5): each parameter
read from the image, "not read from the image: prior only", or unknown for a model file saved before the
flag; the derived combinations with Alice's Monte-Carlo intervals and their own flags; `--json` prints the
report with them, and report.md has them.

The model files are the training-data check tests' constant networks (``write_models``) with the
identification block a training run saves (``learn.answer.alice_identification``) written into K_u's
(validation predictions close to the truths: read) and D's (the prior median whatever the image: prior
only); A_ex's and the others' files have none, as files saved before the flag."""

import json

import numpy as np
import pytest
import torch

from forcdecode.cli import main
from forcdecode.learn.answer import PREDATES, PRIOR_ONLY, alice_identification

from test_loop_ood_default import measured, noisy_copies, write_dataset, write_models  # noqa: F401


def flagged_models(directory):
    models = write_models(directory)
    rng = np.random.default_rng(5)
    n = 120
    train, val = np.arange(80), np.arange(80, n)
    ms_norm, sample_id = rng.random(n), np.arange(n) * 3
    truth = {"K_u": rng.random(n), "D": rng.random(n)}
    estimate = {"K_u": np.clip(truth["K_u"] + rng.normal(0, 0.03, n), 0, 1),
                "D": np.full(n, np.median(truth["D"][train]))}
    for name in ("K_u", "D"):
        payload = torch.load(models / f"{name}.pt", weights_only=True)
        payload["identification"] = alice_identification(name, truth[name], estimate[name], ms_norm, sample_id,
                                                          train, val, seed=2, n_boot=300)
        torch.save(payload, models / f"{name}.pt")
    return models


def _run(measured, tmp_path, *extra):
    path, cfg, image = measured
    models = flagged_models(tmp_path / "models")
    dataset = write_dataset(tmp_path / "train.h5", noisy_copies(image, 16))
    out = tmp_path / "loop"
    code = main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--models", str(models),
                 "--dataset", str(dataset), "--Ms-kA-m", "600", "--profiles", "1", "--no-physics",
                 "--no-measured-protocol", *extra])
    return code, out


def test_loop_json_carries_each_flag_and_the_combinations(measured, tmp_path, capsys):
    code, out = _run(measured, tmp_path, "--json")
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    report = json.loads((out / "report.json").read_text())
    assert printed["prediction"] == report["prediction"] and report["status"] == "analysed"
    prediction = report["prediction"]
    assert prediction["K_u"]["read_from_image"] is True
    assert prediction["K_u"]["basis"].startswith("validation skill over the best trivial predictor")
    assert prediction["D"]["read_from_image"] is False and len(prediction["D"]["prior_range"]) == 2
    assert prediction["A_ex"]["read_from_image"] is None and prediction["A_ex"]["basis"] == PREDATES
    combos = prediction["combinations"]
    assert set(combos) == {"sigma_w", "delta_w", "D_over_Dc", "Q"}
    assert combos["Q"]["read_from_image"] is True and "interval_90" in combos["Q"]
    for name in ("sigma_w", "delta_w", "D_over_Dc"):      # they need A_ex, whose file predates the flag
        assert combos[name]["read_from_image"] is None and combos[name]["basis"] == PREDATES
    assert "ignores the correlations" in prediction["combinations_method"]
    text = (out / "report.md").read_text()
    assert f"| D | {PRIOR_ONLY}" in text and "Derived combinations" in text and "| Q |" in text
    assert f"- A_ex: {PREDATES}" in text
    # the realisation floor, film by film: the candidates' floor is the largest over the films
    per_film = report["patches"]["null_gain_per_film"]
    assert len(per_film) == report["patches"]["null_films"] >= 2
    for name, record in report["analysis"]["candidates"].items():
        if "null_gain" in record:
            assert record["null_gain"]["relative"] == max(g[name]["relative"] for g in per_film)


def test_loop_prints_the_decoded_hamiltonian_with_its_flags(measured, tmp_path, capsys):
    code, _ = _run(measured, tmp_path)
    assert code == 0
    printed = capsys.readouterr().out
    rows = {line.split()[0]: line for line in printed.splitlines() if line.split()}
    assert PRIOR_ONLY in rows["D"] and rows["K_u"].rstrip().endswith("yes")
    assert rows["A_ex"].rstrip().endswith("unknown") and f"A_ex: {PREDATES}" in printed
    assert "derived combinations" in printed and "verdict:" in printed


def test_the_report_says_along_which_decoded_parameter_the_hamiltonian_moved():
    """report.md names the direction of the decode's neighbourhood the gates used, the change and where it
    took the parameter; nothing where the neighbourhood was K_u's ±6 % (a Hamiltonian given by the user)."""
    from forcdecode.loop.measured_loop import _neighbourhood_lines

    analysis = {"heldout_rms_before": 0.19, "hamiltonian_neighbourhood": {
        "parameter": "A_ex", "change": 3.2e-12, "change_uncertainty": 3.0e-12, "at_interval_edge": False,
        "directions": ["A_ex", "D", "K_u"], "heldout_rms": 0.146}}
    text = "\n".join(_neighbourhood_lines({"parameters": {"A_ex": 2.22e-11}}, analysis))
    assert "best along A_ex, by +3.2e-12" in text and "to 2.54e-11" in text and "0.1900 → 0.1460" in text
    legacy = {"heldout_rms_before": 0.19, "hamiltonian_neighbourhood": {"K_u_change": 0.04, "heldout_rms": 0.18}}
    assert _neighbourhood_lines({}, legacy) == []
