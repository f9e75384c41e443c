"""`forcdecode bench prior-class`: the rule's rates on families of known K_eff, read from a dataset.h5."""

import json

import h5py
import numpy as np

from forcdecode.cli import main
from forcdecode.forc.raster import quantize

MU0 = 4e-7 * np.pi


def image(descending, side=32):
    h = np.linspace(-1, 1, side)
    m = np.tile(descending(h)[:, None], (1, side))
    m[0] = np.where(descending(h) > 0.99, descending(h), -descending(-h))  # the mirror ascending branch
    np.fill_diagonal(m, descending(h))
    return quantize(m)


def test_the_bench_counts_refusals_per_regime(tmp_path, capsys):
    square = image(lambda h: np.where(h > -0.3, 1.0, -1.0))
    spiral = image(lambda h: np.clip(h / 0.1, -1, 1))  # K_eff > 0, |D| > D_c: low m_r, saturated to 0.09 T
    in_plane = image(lambda h: np.clip(h / 0.6, -1, 1))
    near_zero = image(lambda h: np.clip(h / 0.05, -1, 1))  # K_eff ≲ 0: lets through
    images = np.array([square, square, spiral, in_plane, in_plane, in_plane, near_zero])
    ms = np.full(len(images), 8e5)
    demag = MU0 * ms**2 / 2
    ku = demag * np.array([1.5, 2.0, 1.1, 0.5, 0.6, 0.7, 0.99])
    columns = ["Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K"]
    table = np.zeros((len(images), len(columns)))
    table[:, 0], table[:, 1], table[:, 2], table[:, 3] = ms, 1e-11, ku, 1e-3
    path = tmp_path / "dataset.h5"
    with h5py.File(path, "w") as h5:
        h5["images"] = images
        h5["sample_id"] = np.arange(len(images))
        dset = h5.create_dataset("parameters", data=table)
        dset.attrs["columns"] = columns
        h5.attrs["config_json"] = json.dumps({"seed": 1, "field": {"B_max_T": 1.0, "n_fields": 32}})
        h5.attrs["config_hash"] = "test"
    assert main(["bench", "prior-class", "--dataset", str(path), "--json", "--out", str(tmp_path / "rates.json")]) == 0
    out = capsys.readouterr().out
    result = json.loads(out.strip().splitlines()[-1])
    rule = result["rule"]
    assert (rule["n_keff_positive"], rule["refused_keff_positive"]) == (3, 0)
    assert (rule["n_keff_negative"], rule["caught_keff_negative"]) == (4, 3)
    assert result["remanence_only"]["refused_keff_positive"] == 1  # the spiral film, m_r alone
    assert result["dataset_prior_class"] == "paper" and len(result["passed_keff_negative_K_eff_kJ_m3"]) == 1
    assert "K_eff < 0 caught 3/4" in out and json.loads((tmp_path / "rates.json").read_text())["rule"] == rule
