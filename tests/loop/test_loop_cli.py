"""`forcdecode loop` end to end: a simulated film written as a MicroMag file with an undeclared
substrate background, and the real (out-of-domain) measured files."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from forcdecode.cli import main
from forcdecode.micromag.build import mesh_from_config
from forcdecode.loop import resimulate
from forcdecode.measured.writers import write_micromag_0015

ROOT = Path(__file__).resolve().parents[2]
MEASURED = ROOT.parent / "shared" / "data" / "measured"


def test_loop_names_an_undeclared_background(tmp_path):
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = 24
    config_path = tmp_path / "cfg.yaml"
    config_path.write_text(yaml.safe_dump(cfg))
    params = {"Ms": 6e5, "A_ex": 1.0e-11, "K_u": 6e5, "D": 1e-3, "N_pin": 2, "sigma_theta_deg": 5.0, "sigma_K": 0.1}
    (tmp_path / "params.json").write_text(json.dumps(params))
    from forcdecode.loop.cli import load_config

    truth = resimulate(load_config(config_path), params, n_profiles=1)
    mesh = mesh_from_config(cfg)
    scale = params["Ms"] * mesh.n_cells * mesh.cell_volume
    fields = np.linspace(-1, 1, 24)
    rng = np.random.default_rng(0)
    curves = [(fields[i:], (truth[i, i:] + 0.1 * fields[i:] + 0.002 * rng.normal(size=24 - i)) * scale) for i in range(24)]
    path = write_micromag_0015(tmp_path / "film.frc", fields, curves)
    out = tmp_path / "loop"
    code = main(["loop", str(path), "--out", str(out), "--params", str(tmp_path / "params.json"),
                 "--config", str(config_path), "--profiles", "1", "--every-k", "3", "--force"])
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert report["effect"] == "background"
    assert report["heldout_rms_after"] < 0.5 * report["heldout_rms_before"]
    assert (out / "residual.png").stat().st_size > 10_000 and (out / "families.png").exists()


def test_real_measured_files_are_reported_out_of_domain(tmp_path):
    path = MEASURED / "UB199BF.frc"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    assert main(["loop", str(path), "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["in_domain"] is False and "does not reach" in report["out_of_domain_reason"]
