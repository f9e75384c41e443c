"""``forcdecode read FILE [--json] [--no-drift-correction]``."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from forcdecode.cli import main
from measured_fixtures import data_file, qd_forc

KEYS = {"format", "units", "n_curves", "n_points", "field_min_T", "field_max_T",
        "moment_max_Am2", "drift_percent"}


def test_read_json(capsys):
    path = data_file("UB199BF.frc")
    assert main(["read", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert KEYS <= set(summary)
    assert summary["format"] == "micromag-0015" and summary["units"] == "SI"
    assert summary["n_curves"] == summary["n_curves_header"] == 140
    assert summary["n_points"] == 15644 - 140  # NData minus the calibration points
    assert -0.2 < summary["field_min_T"] < summary["field_max_T"] < 0.25
    assert summary["drift_corrected"] is True
    assert summary["drift_percent"] == pytest.approx(0.1407, abs=1e-3)


def test_read_json_without_drift_correction(capsys):
    path = data_file("agm_cgs_0141327c.frc")
    assert main(["read", str(path), "--json", "--no-drift-correction"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["units"] == "cgs" and summary["drift_corrected"] is False
    assert summary["n_curves"] == 180
    assert 4.5 < summary["drift_percent"] < 6.0


def test_read_human_summary(capsys):
    assert main(["read", str(data_file("MD00-2361.frc"))]) == 0
    out = capsys.readouterr().out
    assert "micromag-0016" in out and "297 curves" in out and "drift" in out


def test_read_json_no_calibration_gives_null_drift(tmp_path, capsys):
    path = tmp_path / "nocal.dat"
    path.write_bytes(qd_forc(5, calibration=False)["bytes"])
    assert main(["read", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["format"] == "qd-dat" and summary["drift_percent"] is None


def test_format_error_exit_code_2(tmp_path, capsys):
    path = tmp_path / "bad.frc"
    path.write_bytes(b"MicroMag 2900/3900 Data File (Series 0015)\r\n"
                     b"First-order reversal curves\r\n")
    assert main(["read", str(path), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("error: ") and "bad.frc" in captured.err
    assert "Traceback" not in captured.err


def test_incomplete_file_needs_the_flag(capsys):
    path = data_file("lakeshore8600_micromag_layout_excerpt.forc")
    assert main(["read", str(path), "--json"]) == 2
    assert "truncated" in capsys.readouterr().err
    assert main(["read", str(path), "--json", "--allow-incomplete"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["complete"] is False and summary["n_curves"] == 4


def test_missing_file_exit_code_2(tmp_path, capsys):
    assert main(["read", str(tmp_path / "absent.frc")]) == 2
    assert capsys.readouterr().err.startswith("error: cannot read")


def test_command_line_entry_point_no_traceback(tmp_path):
    path = tmp_path / "garbage.frc"
    path.write_bytes(b"\x00\xff garbage\n")
    result = subprocess.run([sys.executable, "-m", "forcdecode.cli", "read", str(path), "--json"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr.startswith("error: ") and "line 1" in result.stderr
    assert "Traceback" not in result.stderr
