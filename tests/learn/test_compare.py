"""The Alice-vs-posterior table: who is more accurate, who is calibrated (inside the binomial band),
who is narrower — the last only where both are calibrated; mismatched splits refuse."""

import json

import pytest

from forcdecode.cli import main
from forcdecode.core.errors import DatasetError
from forcdecode.learn.compare import compare_estimators, comparison_markdown


def write(tmp_path, alice_n=22, post_cov=0.91):
    alice = {"parameters": {
        "K_u": {"mae": 0.042, "coverage_90": 0.91, "width_90": 0.20, "n_test": alice_n},
        "D": {"mae": 0.198, "coverage_90": 0.60, "width_90": 0.50, "n_test": alice_n}}}
    post = {"reported_on": "test", "n_test": 22, "coverage_binomial_band": {"90": [0.77, 1.0]},
            "per_parameter": {
                "K_u": {"mae_median": 0.050, "mae_mean": 0.052, "coverage_90": post_cov, "width_90": 0.15, "sbc_ks_p": 0.4},
                "D": {"mae_median": 0.190, "mae_mean": 0.2, "coverage_90": 0.95, "width_90": 0.8, "sbc_ks_p": 0.3}}}
    (tmp_path / "a.json").write_text(json.dumps(alice))
    (tmp_path / "p.json").write_text(json.dumps(post))
    return tmp_path / "a.json", tmp_path / "p.json"


def test_table_verdicts(tmp_path):
    r = compare_estimators(*write(tmp_path))
    k, d = r["parameters"]["K_u"], r["parameters"]["D"]
    assert k["more_accurate"] == "alice" and d["more_accurate"] == "posterior"
    assert k["narrower_at_equal_coverage"] == "posterior"
    assert d["alice_calibrated"] is False and d["narrower_at_equal_coverage"] is None
    assert any("K_u" in line and "posterior |" in line for line in comparison_markdown(r))


def test_mismatched_split_refuses(tmp_path):
    with pytest.raises(DatasetError, match="not the same split"):
        compare_estimators(*write(tmp_path, alice_n=30))


def test_command_line(tmp_path, capsys):
    a, p = write(tmp_path)
    assert main(["learn", "compare", "--metrics", str(a), "--posterior", str(p), "--out", str(tmp_path / "c.json")]) == 0
    assert "| K_u |" in capsys.readouterr().out
    assert json.loads((tmp_path / "c.json").read_text())["n_test"] == 22
    assert main(["learn", "compare", "--metrics", str(tmp_path / "missing.json"), "--posterior", str(p)]) == 2
