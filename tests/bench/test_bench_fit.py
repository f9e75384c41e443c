"""``bench fit``'s scoring (``bench/fit.py``) on rows whose errors are known."""

import numpy as np
import pytest

from forcdecode.bench.fit import fit_summary, summary_lines


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


@pytest.mark.parametrize("flags", [["--first-family", "-1"], ["--families", "0"]])
def test_a_family_range_that_cannot_exist_is_one_clear_error(flags, capsys):
    from forcdecode.cli import main

    assert main(["bench", "fit", *flags]) == 2
    assert "--first-family must be >= 0 and --families >= 1" in capsys.readouterr().err
