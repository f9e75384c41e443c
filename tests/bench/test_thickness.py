"""bench.thickness: the film at another thickness, the table's arithmetic and the safe range's rule."""

import numpy as np
import pytest

from forcdecode.bench.thickness import SAFE_MAE_INCREASE, safe_range, summarize
from forcdecode.config import with_thickness
from forcdecode.core.errors import ConfigError


def test_a_film_at_another_thickness_changes_only_the_layer_thickness():
    cfg = {"mesh": {"nx": 64, "ny": 64, "nz": 1, "dx_nm": 2.0, "dy_nm": 2.0, "dz_nm": 4.0}, "seed": 1}
    thin = with_thickness(cfg, 2.0)
    assert thin["mesh"] == {**cfg["mesh"], "dz_nm": 2.0} and cfg["mesh"]["dz_nm"] == 4.0
    assert with_thickness({**cfg, "mesh": {**cfg["mesh"], "nz": 2}}, 8.0)["mesh"]["nz"] == 1
    with pytest.raises(ConfigError):
        with_thickness(cfg, 0.0)


def _rows(errors_by_thickness, n=80, seed=0):
    """Synthetic decoded rows: K_u read (prediction = truth + error), D prior-only (always the midpoint)."""
    rng = np.random.default_rng(seed)
    truth = rng.random((n, 2))
    rows = []
    for t, spread in errors_by_thickness.items():
        noise = np.random.default_rng(1).normal(0, 1, n)  # common across thicknesses: the pairing matters
        for i in range(n):
            rows.append({"sample_id": i, "thickness_nm": t, "status": "ok",
                         "truth_u": {"K_u": truth[i, 0], "D": truth[i, 1]},
                         "predicted_u": {"K_u": truth[i, 0] + spread * noise[i], "D": 0.5},
                         "ms_only_u": {"K_u": 0.5, "D": 0.5}})
    rows.append({"sample_id": 999, "thickness_nm": 8.0, "status": "failed", "reason": "diverged"})
    return rows


def test_the_table_pairs_each_thickness_with_the_models_own():
    summary = summarize(_rows({2.0: 0.15, 4.0: 0.05, 6.0: 0.05 * 1.1, 8.0: 0.2}), reference_nm=4.0)
    table = summary["table"]
    k = table["4.0"]["K_u"]
    assert k["mae_change"] == 0.0 and k["mae_change_ci90"] == [0.0, 0.0]
    assert k["skill"] > 0.5  # read from the image at 4 nm
    assert table["2.0"]["K_u"]["mae_change"] == pytest.approx(0.10 * np.sqrt(2 / np.pi), rel=0.35)
    assert table["2.0"]["K_u"]["mae_change_ci90"][0] > SAFE_MAE_INCREASE  # clearly worse: an interval above the margin
    assert table["8.0"]["failed"] == 1 and table["8.0"]["n"] == 80
    # D is not read at 4 nm (skill 0): its change never decides the range; 6 nm costs K_u ~0.004: safe
    assert summary["safe_nm"] == [4.0, 6.0]


def test_the_safe_range_is_the_contiguous_run_around_the_models_thickness():
    def row(upper):
        return {"K_u": {"skill": 0.5, "mae_change_ci90": [0.0, upper]}}
    table = {"2.0": row(0.01), "3.0": row(0.05), "4.0": row(0.0), "5.0": row(0.01), "8.0": row(0.01)}
    # 2 nm alone would pass, but 3 nm between it and 4 nm does not: the range stops at 4
    assert safe_range(table, 4.0, ["K_u"]) == [4.0, 8.0]
    table["5.0"] = row(float("nan"))
    assert safe_range(table, 4.0, ["K_u"]) == [4.0, 4.0]
