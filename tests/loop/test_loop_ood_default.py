"""`forcdecode loop` runs the training-data (out-of-prior) check whatever the estimator: with Alice, the
image-only conformal check against the train split of the networks' own dataset (cached beside the
models); at the given M_s alone, the most favourable p over the sweep only when M_s is swept (and said);
a reference too small to flag anything says so; a check that cannot run says why."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
import yaml

from forcdecode.cli import main
from forcdecode.core.parameters import DEFAULT_BOUNDS, TARGETS
from forcdecode.infer.resimulate import resimulate
from forcdecode.learn.models import build_network
from forcdecode.learn.ood import IMAGE_REFERENCE_FILE, image_ood_check, fit_image_reference, ood_power
from forcdecode.loop import measured_loop
from forcdecode.measured.writers import write_micromag_0015
from forcdecode.micromag.build import mesh_from_config

ROOT = Path(__file__).resolve().parents[2]
N_FIELDS = 24
HASH = "tiny-film"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """A square-loop film in the physics domain (only the training-data check can stop it), its config and
    the image the loop makes of it."""
    from forcdecode.forc.raster import measurement_on_grid
    from forcdecode.loop.command import load_config
    from forcdecode.measured import read_forc

    tmp = tmp_path_factory.mktemp("film")
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = N_FIELDS
    (tmp / "cfg.yaml").write_text(yaml.safe_dump(cfg))
    params = {"Ms": 6e5, "A_ex": 1.0e-11, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 5.0, "sigma_K": 0.1}
    truth = resimulate(load_config(tmp / "cfg.yaml"), params, n_profiles=1)
    scale = params["Ms"] * mesh_from_config(cfg).n_cells * mesh_from_config(cfg).cell_volume
    fields = np.linspace(-1, 1, N_FIELDS)
    path = write_micromag_0015(tmp / "film.frc", fields, [(fields[i:], truth[i, i:] * scale) for i in range(N_FIELDS)])
    image = measurement_on_grid(read_forc(path), 1.0, N_FIELDS)[0]
    return path, tmp / "cfg.yaml", image


def write_models(directory: Path, config_hash=HASH) -> Path:
    """Alice/Bob model files for every parameter whose networks output nothing (zero weights): the softmax
    readout gives the middle of each prior, whatever the image."""
    directory.mkdir(parents=True, exist_ok=True)
    bounds = {**DEFAULT_BOUNDS, "N_pin": [0.0, 4.0]}
    for name in TARGETS:
        nets = []
        for _ in range(2):
            net = build_network("small", width=8, image_size=N_FIELDS)
            with torch.no_grad():
                for p in net.parameters():
                    p.zero_()
            nets.append(net.state_dict())
        payload = {"format": "forcdecode-alice-bob/1", "parameter": name,
                   "architecture": {"model": "small", "width": 8, "image_size": N_FIELDS}, "readout": "softmax",
                   "bounds": {k: [float(v[0]), float(v[1])] for k, v in bounds.items()}, "log_scale": False,
                   "config_hash": config_hash, "alice_state": nets[0], "bob_state": nets[1],
                   "validation_errors": [0.05, 0.1, 0.2], "conformal": {"levels": [0.68, 0.9],
                   "quantiles": {"0.68": 1.0, "0.9": 2.0}, "sigma_floor": 0.01}, "metrics": {}}
        torch.save(payload, directory / f"{name}.pt")
    return directory


def write_dataset(path: Path, images, config_hash=HASH, split=(0.5, 0.25, 0.15, 0.1)) -> Path:
    """The parts of a dataset.h5 the check reads: images, sample ids, the config (seed, learning split)."""
    images = np.asarray(images, dtype=np.uint8)
    with h5py.File(path, "w") as h5:
        h5["images"] = images
        h5["sample_id"] = np.arange(len(images))
        h5.attrs["config_hash"] = config_hash
        h5.attrs["config_json"] = json.dumps({"seed": 7, "learning": {"split": list(split), "protocol": "holdout"}})
    return path


def noisy_copies(image, n, seed=0):
    """Families like the measured one: its image with a few grey levels of noise."""
    rng = np.random.default_rng(seed)
    return np.clip(image[None].astype(int) + rng.integers(-6, 7, (n, *image.shape)), 0, 255).astype(np.uint8)


def bars(n, seed=0):
    """Families unlike it: row bars of random height (the posterior tests' toy images)."""
    rng = np.random.default_rng(seed)
    images = np.zeros((n, N_FIELDS, N_FIELDS))
    for k, row in enumerate(rng.integers(0, N_FIELDS, n)):
        images[k, :row + 1] = 235
    return (images + rng.integers(0, 20, images.shape)).astype(np.uint8)


def test_power_rule():
    assert ood_power(39)["can_flag"] is False and ood_power(40)["can_flag"] is True  # 2/(n + 1) < 0.05
    assert ood_power(19, 1)["can_flag"] is False and ood_power(20, 1)["can_flag"] is True  # 1/(n + 1) < 0.05
    small = ood_power(10)
    assert small["n_reference_needed"] == 40 and "cannot flag anything" in small["warning"]
    assert "warning" not in ood_power(100)


def test_image_check_flags_an_unlike_image_and_passes_a_like_one(measured):
    _, _, image = measured
    images = noisy_copies(image, 120)
    ref = fit_image_reference(images, np.arange(60), np.arange(60, 120))
    like = image_ood_check(ref, noisy_copies(image, 1, seed=5)[0])
    assert like["available"] and not like["out_of_distribution"] and like["can_flag"] and "warning" not in like
    for other in (np.full_like(image, 128), np.random.default_rng(1).integers(0, 256, image.shape).astype(np.uint8)):
        row = image_ood_check(ref, other)
        assert row["out_of_distribution"] and row["p_value"] == pytest.approx(1 / 61), row
        assert row["verdict"].startswith("out of distribution")
    tiny = image_ood_check(fit_image_reference(images, np.arange(10), np.arange(10, 15)), np.full_like(image, 128))
    assert not tiny["can_flag"] and not tiny["out_of_distribution"] and "cannot flag" in tiny["warning"]


def test_alice_check_says_why_it_could_not_run_and_caches_its_reference(measured, tmp_path):
    _, _, image = measured
    models = write_models(tmp_path / "results" / "models")
    loaded = __import__("forcdecode.learn.predictor", fromlist=["load_models"]).load_models(models)
    missing = measured_loop.alice_ood(models, loaded, image, log=lambda *_: None)
    assert not missing["available"] and missing["verdict"].startswith("could not run: no training dataset")
    other = write_dataset(tmp_path / "other.h5", noisy_copies(image, 100), config_hash="another film")
    wrong = measured_loop.alice_ood(models, loaded, image, dataset=other, log=lambda *_: None)
    assert not wrong["available"] and "not the one the networks were trained on" in wrong["verdict"]
    write_dataset(tmp_path / "results" / "dataset.h5", noisy_copies(image, 200))  # the default place
    first = measured_loop.alice_ood(models, loaded, image, log=lambda *_: None)
    assert first["available"] and not first["out_of_distribution"] and first["can_flag"]
    assert first["Ms_note"] == "image only: M_s plays no part in it" and (models / IMAGE_REFERENCE_FILE).exists()
    again = measured_loop.alice_ood(models, loaded, image, log=lambda *_: None)
    assert again["reference"].startswith("cached in") and again["p_value"] == first["p_value"]


def test_posterior_check_at_the_given_ms_alone_and_the_most_favourable_over_a_sweep(monkeypatch):
    """A stand-in check whose p-value grows with M_s: one M_s given is checked alone; a sweep keeps the
    largest p and says that M_s was unknown."""
    import forcdecode.learn.ood as ood

    seen = []

    def check(est, image, ms_norm):
        seen.append(float(ms_norm[0]))
        p = 0.01 + 0.5 * float(ms_norm[0])
        return {"available": True, "p_value": p, "out_of_distribution": p < 0.05, "verdict": f"p {p:.3f}"}

    monkeypatch.setattr(ood, "ood_check", check)
    est = type("Est", (), {"bounds": dict(DEFAULT_BOUNDS)})()
    low, high = DEFAULT_BOUNDS["Ms"]
    given = measured_loop.posterior_ood(est, None, [low])
    assert len(seen) == 1 and given["Ms_mode"] == "given" and given["out_of_distribution"]
    assert "most favourable" not in given["Ms_note"] and "alone" in given["Ms_note"]
    seen.clear()
    swept = measured_loop.posterior_ood(est, None, [low, (low + high) / 2, high])
    assert len(seen) == 3 and swept["Ms_mode"] == "swept" and swept["Ms_A_per_m"] == high
    assert not swept["out_of_distribution"] and swept["Ms_note"].startswith(measured_loop.OOD_SWEPT_NOTE)
    assert [r["p_value"] for r in swept["p_by_Ms"]] == sorted(r["p_value"] for r in swept["p_by_Ms"])


def test_alice_loop_stops_a_family_unlike_the_training_data(measured, tmp_path, capsys):
    path, cfg, _ = measured
    models = write_models(tmp_path / "results" / "models")
    write_dataset(tmp_path / "results" / "dataset.h5", bars(200))
    out = tmp_path / "loop"
    assert main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--models", str(models),
                 "--Ms-kA-m", "600", "--profiles", "1"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "out of distribution", report.get("ood")
    ood = report["ood"]
    assert ood["check"] == "image only (no posterior)" and ood["out_of_distribution"] and ood["can_flag"]
    assert "not decoded" in capsys.readouterr().out and "prediction" not in report
    text = (out / "report.md").read_text()
    assert "Not decoded" in text and "Alice's networks were trained on" in text and (out / "report.html").exists()


def test_alice_loop_records_the_check_and_warns_when_its_reference_cannot_flag(measured, tmp_path):
    """Alice decodes a family like its (too few) training families: the check ran, in distribution, and
    report.json, report.md and report.html say it could not have flagged anything."""
    path, cfg, image = measured
    models = write_models(tmp_path / "models")
    dataset = write_dataset(tmp_path / "train.h5", noisy_copies(image, 16))
    out = tmp_path / "loop"
    assert main(["loop", str(path), "--out", str(out), "--config", str(cfg), "--models", str(models),
                 "--dataset", str(dataset), "--Ms-kA-m", "600", "--profiles", "1", "--no-physics",
                 "--no-measured-protocol"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "analysed" and report["prediction"]["Ms"] == 600e3
    ood = report["ood"]
    assert ood["available"] and ood["check"] == "image only (no posterior)" and not ood["out_of_distribution"]
    assert ood["can_flag"] is False and ood["n_validation"] < 20 and "cannot flag anything" in ood["warning"]
    text = (out / "report.md").read_text()
    assert "Looks like the training data?" in text and f"**Warning: {ood['warning']}.**" in text
    assert "training-data check: warning" in (out / "report.html").read_text()
