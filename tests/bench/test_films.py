"""The film-comparison benchmark's pieces on tiny films: jobs planned once each, a family written
atomically with its cost, the realisation floor zero for the same disorder and positive for another,
and the summary's comparisons and regions."""

import json

import numpy as np
import pytest

from forcdecode.bench import films
from forcdecode.config import load_config, shipped_config


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setattr(films, "FILMS", {"laptop": dict(nx=16, ny=16, nz=1, n_grains=8),
                                         "paper": dict(nx=16, ny=16, nz=2, n_grains=4)})
    cfg = load_config(shipped_config("test"))
    return cfg


def test_plan_runs_each_job_once():
    hams = [{"sample_id": 3}, {"sample_id": 8}]
    jobs = films.plan(hams, [("laptop", 2, 1), ("laptop", 1, 2), ("paper", 5, 1)])
    keys = [(f, p["sample_id"], r) for f, p, r in jobs]
    assert keys == [("laptop", 3, 0), ("laptop", 8, 0), ("laptop", 3, 1), ("paper", 3, 0), ("paper", 8, 0)]


def test_jobs_floor_and_summary(tiny, tmp_path):
    cfg = tiny
    params = {"sample_id": 1, "Ms": 6e5, "A_ex": 1e-11, "K_u": 5e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 3.0,
              "sigma_K": 0.05}
    for film, r in (("laptop", 0), ("laptop", 1), ("paper", 0)):
        films.run_job(cfg, film, params, r, tmp_path)
    assert not list(tmp_path.glob(".*tmp*"))
    jobs = films.load(tmp_path)
    assert set(jobs) == {("laptop", 1, 0), ("laptop", 1, 1), ("paper", 1, 0)}
    a = jobs[("laptop", 1, 0)]
    assert a["iterations"] > 0 and a["curves"].shape == (16, 16) and json.loads(a["params"])["K_u"] == 5e5
    same = films.compare(a, a)
    assert same["mean_abs_dm"] == 0 and same["image_mean_abs_levels"] == 0 and same["peak_shift_T"] == 0
    summary = films.summarize(tmp_path)
    row = summary["rows"][0]
    assert row["floor_laptop"]["mean_abs_dm"] > 0          # another disorder draw: another family
    assert "paper_vs_laptop" in row
    assert summary["cost"]["paper"]["n_cells"] == 512
    assert summary["by_region"]["N_pin < 85"]["floor_laptop"]["n"] == 1
    assert films.quality_factor(params) == pytest.approx(2 * 5e5 / (4e-7 * np.pi * 36e10))
    films.figure(summary, tmp_path / "films.png")
    assert (tmp_path / "films.png").stat().st_size > 1000
    assert any("floor_laptop" in line for line in films.summary_lines(summary))
