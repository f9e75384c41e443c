"""R = 4 against R = 1 at equal core-hours (bench/realisations.py) on synthetic runs whose answer is
known: costs, matched points, the paired difference and the decision rule."""

import json

import numpy as np
import pandas as pd
import pytest

from forcdecode.bench.realisations import compare, figure, load_run, summary_lines
from forcdecode.core.errors import InputFileError

IDS = np.arange(0, 200, 2)  # validation ids of run A; run B (fewer draws) holds those below 100
TRUTH = np.linspace(0.1, 0.9, IDS.size)


def write_run(folder, realisations, n_draws, screen_cpu, family_cpu, sizes, errors, ids=IDS, truth=TRUTH):
    """A finished learning stage: ``errors[point]`` is the absolute error of every seed at every id
    (the sign alternates between ids), so the MAE of a point is exactly that error."""
    (folder / "learn").mkdir(parents=True)
    pd.DataFrame({"sample_id": np.arange(n_draws), "in_dataset": np.arange(n_draws) % 2 == 0,
                  "screen_cpu_s": screen_cpu, "family_cpu_s": np.where(np.arange(n_draws) % 2 == 0, family_cpu, np.nan)}
                 ).to_parquet(folder / "samples.parquet")
    (folder / "config.json").write_text(json.dumps({"seed": 3, "realisations": realisations}))
    keep = ids < n_draws
    sign = np.where(np.arange(keep.sum()) % 2 == 0, 1.0, -1.0)
    predictions = [[(truth[keep] + sign * e).tolist()] * 2 for e in errors]  # 2 seeds
    for name in ("K_u", "D"):
        curve = {"sizes": sizes, "mae_validation": [[e, e] for e in errors],
                 "baselines_validation": {"prior": 0.3, "ms_only": 0.25},
                 "validation_sample_ids": ids[keep].tolist(), "validation_truth": truth[keep].tolist(),
                 "validation_predictions": predictions}
        (folder / "learn" / f"{name}_metrics.json").write_text(json.dumps({"learning_curve": curve}))


def test_costs_matched_points_and_a_better_b_is_chosen(tmp_path):
    # A: 200 draws at 1 CPU-s screening, 100 families at 3 CPU-s: 500 CPU-s; B: 100 draws, 50 families at
    # 8 CPU-s (4 realisations): 500 CPU-s. B's points at sizes 10, 20, 40 of 40, A's at 20, 40, 80 of 80.
    write_run(tmp_path / "a", 1, 200, 1.0, 3.0, [20, 40, 80], [0.20, 0.15, 0.12])
    write_run(tmp_path / "b", 4, 100, 1.0, 8.0, [10, 20, 40], [0.16, 0.10, 0.08])
    run = load_run(tmp_path / "b")
    assert run["simulation_core_s"] == pytest.approx(500.0) and run["realisations"] == 4
    assert run["parameters"]["K_u"]["core_hours"] == pytest.approx([125 / 3600, 250 / 3600, 500 / 3600])
    result = compare(tmp_path / "a", tmp_path / "b")
    assert [(r["b_point"], r["a_point"]) for r in result["points"]] == [(0, 0), (1, 1), (2, 2)]
    last = result["points"][-1]
    assert last["n_shared"] == 50 and last["cost_ratio_b_over_a"] == pytest.approx(1.0)
    assert last["parameters"]["K_u"]["difference_b_minus_a"] == pytest.approx(0.08 - 0.12)
    assert last["mean_difference_ci90"][1] < 0  # constant per-id difference: a degenerate interval
    assert result["decisive_point"] == 2 and result["decision"].startswith("B")
    assert any("decision" in line for line in summary_lines(result))
    figure(result, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0


def test_b_is_never_given_more_budget_than_a(tmp_path):
    # B's families at 12 CPU-s: 700 CPU-s in all. Its points cost 175, 350, 700 CPU-s; A's 125, 250, 500.
    # Nearest: 175 -> 125 (log-nearest: 1.40 vs 1.43), 350 -> 250, 700 -> 500, every ratio 1.4: none matched
    write_run(tmp_path / "a", 1, 200, 1.0, 3.0, [20, 40, 80], [0.20, 0.15, 0.12])
    write_run(tmp_path / "b", 4, 100, 1.0, 12.0, [10, 20, 40], [0.16, 0.10, 0.08])
    result = compare(tmp_path / "a", tmp_path / "b")
    assert [(r["b_point"], r["a_point"]) for r in result["points"]] == [(0, 0), (1, 1), (2, 2)]
    assert all(r["cost_ratio_b_over_a"] == pytest.approx(1.4) for r in result["points"])
    assert result["decisive_point"] is None and result["decision"].startswith("no matched point")


def test_a_b_no_better_keeps_a(tmp_path):
    # B better on half the ids, worse on the other half by the same amount: interval straddles 0
    rng = np.random.default_rng(0)
    write_run(tmp_path / "a", 1, 200, 1.0, 3.0, [40, 80], [0.10, 0.10])
    write_run(tmp_path / "b", 4, 100, 1.0, 8.0, [20, 40], [0.10, 0.10])
    data = json.loads((tmp_path / "b" / "learn" / "K_u_metrics.json").read_text())
    curve = data["learning_curve"]
    truth = np.asarray(curve["validation_truth"])
    noise = rng.normal(0, 0.05, truth.size)
    curve["validation_predictions"] = [[(truth + 0.10 + noise).tolist()] * 2] * 2
    (tmp_path / "b" / "learn" / "K_u_metrics.json").write_text(json.dumps(data))
    result = compare(tmp_path / "a", tmp_path / "b")
    low, high = result["points"][-1]["mean_difference_ci90"]
    assert low < 0 < high
    assert result["decision"].startswith("A")


def test_runs_of_other_hamiltonians_or_without_predictions_are_refused(tmp_path):
    write_run(tmp_path / "a", 1, 200, 1.0, 3.0, [40, 80], [0.10, 0.10])
    write_run(tmp_path / "b", 4, 100, 1.0, 12.0, [20, 40], [0.10, 0.10], truth=TRUTH + 0.01)
    with pytest.raises(InputFileError, match="truths differ"):
        compare(tmp_path / "a", tmp_path / "b")
    old = tmp_path / "b" / "learn" / "D_metrics.json"
    data = json.loads(old.read_text())
    del data["learning_curve"]["validation_predictions"]
    old.write_text(json.dumps(data))
    with pytest.raises(InputFileError, match="no validation predictions"):
        load_run(tmp_path / "b")


def _zero_model(path, name, side):
    """Alice/Bob with zero weights: the softmax readout gives the middle of the prior (u = 0.5) whatever
    the image."""
    import torch

    from forcdecode.core.parameters import DEFAULT_BOUNDS
    from forcdecode.learn.models import build_network

    net = build_network("small", width=4, image_size=side)
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
    torch.save({"format": "forcdecode-alice-bob/1", "parameter": name,
                "architecture": {"model": "small", "width": 4, "image_size": side}, "readout": "softmax",
                "bounds": {k: [float(v[0]), float(v[1])] for k, v in DEFAULT_BOUNDS.items()},
                "alice_state": net.state_dict(), "bob_state": net.state_dict(), "validation_errors": [0.1, 0.2],
                "conformal": {"levels": [0.9], "quantiles": {"0.9": 1.0}, "sigma_floor": 1e-4}}, path)


def test_cross_reading_scores_each_network_on_both_runs_images(tmp_path):
    import h5py

    from forcdecode.bench.realisations import cross_reading
    from forcdecode.core.parameters import denormalize

    side = 16
    for key, n_draws, cpu in (("a", 200, 3.0), ("b", 100, 8.0)):
        write_run(tmp_path / key, 1 if key == "a" else 4, n_draws, 1.0, cpu, [20, 40], [0.1, 0.1])
        ids = np.arange(n_draws)
        u = (ids % 10) / 10 + 0.05                     # the same truth for an id in both runs
        with h5py.File(tmp_path / key / "dataset.h5", "w") as h5:
            h5["parameters"] = np.stack([np.full(n_draws, 8e5), denormalize("K_u", u), denormalize("D", u)], axis=1)
            h5["parameters"].attrs["columns"] = ["Ms", "K_u", "D"]
            h5["images"] = np.random.default_rng(0).integers(0, 255, (n_draws, side, side), dtype=np.uint8)
            h5["sample_id"], h5["fields_T"] = ids, np.linspace(-1, 1, side)
            h5.attrs["config_json"], h5.attrs["config_hash"] = json.dumps({}), key
        (tmp_path / key / "models").mkdir()
        for name in ("K_u", "D"):
            _zero_model(tmp_path / key / "models" / f"{name}.pt", name, side)
    result = cross_reading(tmp_path / "a", tmp_path / "b")
    shared = IDS[IDS < 100]
    expected = float(np.mean(np.abs(0.5 - ((shared % 10) / 10 + 0.05))))
    for name in ("K_u", "D"):
        row = result[name]
        assert row["n_shared"] == shared.size
        for key in ("A_net_on_A_images", "A_net_on_B_images", "B_net_on_A_images", "B_net_on_B_images"):
            assert row[key] == pytest.approx(expected, abs=1e-6)
        assert row["a_net_mean_images_minus_own"] == pytest.approx(0.0, abs=1e-6)
