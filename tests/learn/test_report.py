"""metrics.json aggregation (learn/report.py): when does the image add information?"""

import json

from forcdecode.learn.report import aggregate


def _metrics(path, name, ci_ms_only, ci_prior):
    retention = {k: 0.1 for k in ("area_bob", "area_oracle", "area_mc_dropout", "area_random")}
    path.write_text(json.dumps({"parameter": name, "skill_vs_ms_only_ci90": ci_ms_only, "skill_vs_prior_ci90": ci_prior,
                                "bob": {"retention": retention, "oof_mae": 0.1}}))
    return path


def test_the_image_adds_information_only_over_the_best_trivial_predictor(tmp_path):
    paths = [_metrics(tmp_path / "a.json", "K_u", [0.3, 0.7], [0.4, 0.8]),
             # beats an M_s-only k-NN that is worse than the prior, not the prior: no evidence
             _metrics(tmp_path / "b.json", "N_pin", [0.007, 0.13], [-0.1, 0.05]),
             _metrics(tmp_path / "c.json", "A_ex", [-0.05, 0.3], [0.2, 0.5]),
             _metrics(tmp_path / "d.json", "D", None, [0.2, 0.5])]
    result = aggregate(paths, tmp_path / "metrics.json")["parameters"]
    assert result["K_u"]["image_adds_information"] is True
    assert result["N_pin"]["image_adds_information"] is False
    assert result["A_ex"]["image_adds_information"] is False
    assert result["D"]["image_adds_information"] is False
    assert json.loads((tmp_path / "metrics.json").read_text())["parameters"]["K_u"]["image_adds_information"]
