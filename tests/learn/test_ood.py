"""The conformal out-of-distribution check of the posterior's embedding: held-out families of the
training distribution are flagged at most at about the nominal rate (binomial band), families from
another generator are flagged, the reference survives save/load, and `predict` reports it."""

import numpy as np
import pytest
import torch

from forcdecode.cli import main
from forcdecode.learn.ood import ood_check
from forcdecode.learn.posterior import PosteriorEstimator, train_posterior
from forcdecode.learn.scoring import binomial_band
from forcdecode.learn.splits import assign_splits

from test_posterior import LEARNING, SEED, SETTINGS, bar_dataset


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("ood")
    data = bar_dataset(n=400)
    metrics = train_posterior(data, {**SETTINGS, "epochs": 40}, LEARNING, SEED, out / "model.pt", out / "metrics.json",
                              out / "fig.png", log=lambda *_: None)
    return data, metrics, out


def test_in_distribution_families_are_rarely_flagged(trained):
    data, metrics, out = trained
    est = PosteriorEstimator.load(out / "model.pt")
    fresh = bar_dataset(n=200, seed=99)  # new families from the same generator
    rows = ood_check(est, fresh.images, fresh.ms_norm)
    rate = np.mean([r["out_of_distribution"] for r in rows])
    low, high = binomial_band(200, 0.05)
    # the test split is held out like the calibration families (exchangeable with them): its flag rate
    # is a false-alarm rate too, at most alpha up to the binomial band of its size (n_test = 55 here: 0.109)
    test_high = binomial_band(metrics["n_test"], metrics["ood_alpha"])[1]
    print(f"in-distribution flag rate {rate:.3f} (alpha 0.05, band up to {high:.3f}); test split "
          f"{metrics['ood_test_flagged_fraction']:.3f} of {metrics['n_test']} (band up to {test_high:.3f})")
    assert rate <= high
    assert metrics["ood_alpha"] == 0.05 and metrics["n_test"] >= 40  # n >= 40: a flag at alpha 0.05 is resolvable
    assert metrics["ood_test_flagged_fraction"] <= test_high


def test_families_from_another_generator_are_flagged(trained):
    data, _, out = trained
    est = PosteriorEstimator.load(out / "model.pt")
    rng = np.random.default_rng(3)
    # the bar image's physics changed: bars from the bottom (columns instead of rows) and a diagonal
    other = np.zeros((40, 16, 16), np.uint8)
    for k in range(40):
        height = rng.integers(2, 15)
        other[k, :, :height] = 235 if k % 2 else 0
        if k % 2 == 0:
            other[k] = np.tril(np.full((16, 16), 235, np.uint8), k=height - 8)
    other = (other + rng.integers(0, 20, other.shape)).astype(np.uint8)
    rows = ood_check(est, other, data.ms_norm[:40])
    rate = np.mean([r["out_of_distribution"] for r in rows])
    print(f"other-generator flag rate {rate:.2f}; p_image up to {max(r['p_image'] for r in rows):.4f}, "
          f"floor 1/{rows[0]['n_validation'] + 1}")
    assert rate >= 0.8
    # each row's flag is its Bonferroni-combined conformal p-value below alpha, and its verdict says so
    n_ref = rows[0]["n_validation"]
    for r in rows:
        assert r["p_value"] == pytest.approx(min(1.0, 2 * min(r["p_features"], r["p_image"])))
        assert r["p_value"] >= 2 / (n_ref + 1) - 1e-12  # the smallest combined p-value n held-out scores allow
        assert r["out_of_distribution"] == (r["p_value"] < r["alpha"])
        assert r["can_flag"] and r["smallest_p"] == pytest.approx(2 / (n_ref + 1)) and "warning" not in r
        assert r["verdict"].startswith("out of distribution" if r["out_of_distribution"] else "in distribution")
    # columns and diagonals lie off the principal subspace of the row-bar training images (no training
    # involved): each image score beyond every held-out one, p_image at its floor 1/(n + 1), so p = 2/(n + 1)
    assert all(r["p_image"] == pytest.approx(1 / (n_ref + 1)) for r in rows)


def test_reference_survives_reload_and_predict_reports_it(trained, tmp_path, capsys):
    data, _, out = trained
    a = ood_check(PosteriorEstimator.load(out / "model.pt"), data.images[0], [data.ms_norm[0]])
    b = ood_check(PosteriorEstimator.load(out / "model.pt"), data.images[0], [data.ms_norm[0]])
    assert a["available"] and a == b
    np.save(tmp_path / "img.npy", data.images[0])
    assert main(["predict", str(tmp_path / "img.npy"), "--Ms-kA-m", "800", "--estimator", "posterior",
                 "--posterior", str(out / "model.pt"), "--draws", "50"]) == 0
    assert "looks like the training data?" in capsys.readouterr().out


def test_a_model_without_reference_says_so(trained):
    data, _, out = trained
    est = PosteriorEstimator.load(out / "model.pt")
    est.metadata.pop("ood")
    assert ood_check(est, data.images[0], [data.ms_norm[0]]) == {
        "available": False, "verdict": "not available (the posterior model has no OOD reference)"}
