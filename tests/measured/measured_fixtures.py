"""Shared helpers for the measured-file tests: where the real files are, smaller valid variants
of them (built at run time, never stored), and synthetic QD / plain-CSV files."""

from __future__ import annotations

import re
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "measured"

NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_DATA_ROW = re.compile(rf"\s*{NUMBER}\s*,\s*{NUMBER}\s*(?:,\s*{NUMBER}\s*)?")


def data_file(name: str) -> Path:
    """A real measured file, or skip the test where the shared data folder is absent."""
    if not DATA_DIR.is_dir():
        pytest.skip(f"shared data folder {DATA_DIR} is absent")
    path = DATA_DIR / name
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    return path


def split_lines(data: bytes) -> tuple[list[str], str]:
    """Lines (Latin-1, round-trips any byte) and the newline the file uses."""
    text = data.decode("latin-1")
    newline = "\r\n" if "\r\n" in text else "\n"
    return text.split(newline), newline


def join_lines(lines: list[str], newline: str) -> bytes:
    return newline.join(lines).encode("latin-1")


def _set_header_number(line: str, value: int) -> str:
    """Replace the number at the end of a header line, keeping its layout."""
    return re.sub(r"[+-]?\d+(\.\d*)?([eE][+-]?\d+)?\s*$", str(value), line)


def shrink_micromag(path: Path, n_curves: int) -> bytes:
    """A regular MicroMag FORC file cut to its first ``n_curves`` curves, header counts patched."""
    lines, newline = split_lines(path.read_bytes())
    first = next(i for i, line in enumerate(lines) if _DATA_ROW.fullmatch(line))
    blocks, in_block, end = 0, False, None
    for i in range(first, len(lines)):
        if _DATA_ROW.fullmatch(lines[i]):
            if not in_block:
                blocks += 1
                in_block = True
                if blocks == 2 * n_curves + 1:
                    end = i
                    break
        else:
            in_block = False
    assert end is not None, "file has fewer curves than asked for"
    data_lines = lines[first:end]
    n_rows = sum(1 for line in data_lines if _DATA_ROW.fullmatch(line))
    header = []
    for line in lines[:first]:
        key = re.split(r"\s*[=\t]|\s{2,}", line.strip(), maxsplit=1)[0]
        if key in ("NCrv", "NForc"):
            line = _set_header_number(line, n_curves)
        elif key in ("NData", "Number of data"):
            line = _set_header_number(line, n_rows)
        elif key == "Number of segments":
            line = _set_header_number(line, 2 * n_curves)
        header.append(line)
    return join_lines(header + data_lines + ["MicroMag 2900/3900 Data File ends", ""], newline)


def shrink_irregular(path: Path, n_curves: int) -> bytes:
    """A 'Multiple segments' file cut to its first ``n_curves`` curves (table and counts too)."""
    lines, newline = split_lines(path.read_bytes())
    table = [i for i, line in enumerate(lines) if line.count(",") == 6]
    rows = [[float(v) for v in lines[i].split(",")] for i in table]
    holds = [k for k, row in enumerate(rows) if row[2] == row[4]]
    # Calibration holds are the ones followed by a falling segment; cut before the (n+1)-th.
    calibrations = [k for k in holds if k + 1 < len(rows) and rows[k + 1][4] < rows[k + 1][2]]
    keep = calibrations[n_curves]  # number of segments kept
    n_rows = int(rows[keep - 1][6])
    first = next(i for i in range(table[-1] + 1, len(lines)) if _DATA_ROW.fullmatch(lines[i]))
    data, count = [], 0
    for line in lines[first:]:
        if _DATA_ROW.fullmatch(line):
            if count == n_rows:
                break
            count += 1
        data.append(line)
    header = []
    for i, line in enumerate(lines[:first]):
        if i in table[keep:]:
            continue
        key = re.split(r"\s{2,}|\t", line.strip(), maxsplit=1)[0]
        if key == "Number of segments":
            line = _set_header_number(line, keep)
        elif key == "Number of data":
            line = _set_header_number(line, n_rows)
        header.append(line)
    while data and not data[-1].strip():
        data.pop()
    return join_lines(header + data + ["", "MicroMag 2900/3900 Data File ends", ""], newline)


def shrink_lakeshore_csv(path: Path, n_curves: int) -> bytes:
    """A Lake Shore 8600 CSV cut to its first ``n_curves`` curves, count and FINISH TIME patched."""
    lines, newline = split_lines(path.read_bytes())
    column = next(i for i, line in enumerate(lines) if line.startswith("Step,Iteration,Segment"))
    kept = lines[: column + 1]
    last_time = 0.0
    for line in lines[column + 1:]:
        if line.strip():
            cells = line.split(",")
            if int(cells[2]) >= 2 * n_curves:
                break
            last_time = float(cells[5])
        kept.append(line)
    while kept and not kept[-1].strip():
        kept.pop()
    start_line = next(i for i, line in enumerate(kept) if line.startswith("START TIME:"))
    start = datetime.strptime(kept[start_line].split(":", 1)[1].strip(), "%m/%d/%Y %I:%M:%S.%f %p")
    finish = start + timedelta(seconds=last_time)
    for i, line in enumerate(kept):
        if line.startswith("FINISH TIME:"):
            kept[i] = "FINISH TIME: " + finish.strftime("%m/%d/%Y %I:%M:%S.") + \
                f"{finish.microsecond // 1000:03d}" + finish.strftime(" %p")
        elif line.startswith("Number of FORCs:"):
            kept[i] = f"Number of FORCs: {n_curves}"
    return join_lines(kept + [""], newline)


# ---------------------------------------------------------------------------------------------
# Synthetic Quantum Design MPMS3 VSM .DAT (no real FORC file of this kind is available)

QD_COLUMNS = ("Comment,Time Stamp (sec),Temperature (K),Magnetic Field (Oe),Moment (emu),"
              "M. Std. Err. (emu),Transport Action,Averaging Time (sec),Frequency (Hz),"
              "Peak Amplitude (mm),Center Position (mm),Range,Min. Field (Oe),Max. Field (Oe)")


def model_moment_emu(field_Oe: np.ndarray, reversal_Oe: float) -> np.ndarray:
    """A smooth FORC-like moment (emu): tanh loop branch lifted by the reversal history."""
    field_Oe = np.asarray(field_Oe, dtype=float)
    branch = 2e-3 * np.tanh((field_Oe - 300.0) / 1500.0)
    memory = 4e-4 * np.tanh((reversal_Oe + 800.0) / 900.0) \
        * np.exp(-(field_Oe - reversal_Oe) / 2500.0)
    return branch + memory


def qd_forc(n_curves: int = 12, *, calibration: bool = True, drift_per_s: float = 2e-5,
            comment_row: bool = True) -> dict:
    """Synthetic QD VSM FORC sequence in the real MPMS3 .DAT layout.

    Returns the file bytes and the truth: reversal fields (Oe), per-curve fields and undrifted
    moments (emu), calibration field (Oe) and times (s).
    """
    rng = np.random.default_rng(1)
    time0 = 3816019664.25
    time_s = 0.0
    reversal_Oe = 5000.0 - 500.0 * np.arange(n_curves)
    calibration_Oe = 10000.0
    rows, truth_fields, truth_moments, cal_times, curve_times = [], [], [], [], []

    def row(t: float, field: float, moment: float) -> str:
        temperature = 300.0 + 0.01 * rng.standard_normal()
        return (f",{time0 + t:.5f},{temperature:.6f},{field:.6f},{moment:.10E},1.2E-8,5,2,"
                f"1,40,2,35.1,5000,{field:.6f},{field:.6f}")

    if comment_row:
        rows.append("FORC sequence start,,,,,,,,,,,,,")
    for k, hr in enumerate(reversal_Oe):
        time_s += 30.0  # saturation, not measured
        if calibration:
            drift = 1.0 + drift_per_s * time_s
            moment_cal = float(model_moment_emu(calibration_Oe, calibration_Oe)) * drift
            rows.append(row(time_s, calibration_Oe + rng.normal(0, 0.3), moment_cal))
            cal_times.append(time_s)
            time_s += 10.0
        fields = np.arange(hr, 5000.0 + 1e-6, 250.0)
        moments = model_moment_emu(fields, hr)
        measured_fields = fields + rng.normal(0, 0.3, fields.size)
        times = time_s + np.arange(fields.size) * 1.0
        for t, field, moment in zip(times, measured_fields, moments):
            rows.append(row(t, field, moment * (1.0 + drift_per_s * t)))
        truth_fields.append(measured_fields)
        truth_moments.append(moments)
        curve_times.append(times)
        time_s = times[-1] + 1.0
    header = [
        "[Header]",
        "; MPMS3 Data File (default extension .dat)",
        "; Copyright (c) 2001, Quantum Design, Inc. All rights reserved.",
        "TITLE,",
        "FILEOPENTIME,3816019664.24396,12/04/2020,10:41 am",
        "BYAPP,MPMS3,1.1,1.8",
        "INFO,MPMS3 Measurement Release 1.1.8 Build 424, MultiVu Release 1.3.59,APPNAME",
        "INFO,Linear Motor Servo Controller,MOTOR_MODULE_NAME",
        "INFO,0,MOMENT_UNITS",
        "INFO,synthetic FORC test sample,SAMPLE_MATERIAL",
        "INFO,25.228,SAMPLE_MASS",
        "INFO,,SAMPLE_VOLUME",
        "DATATYPE,COMMENT,1",
        "DATATYPE,TIME,2",
        "STARTUPAXIS,X,4",
        "STARTUPAXIS,Y1,5",
        "FIELDGROUP,VSM,2,3,4,5,6,7,8,9,10,11,12,13,14",
        "STARTUPGROUP,All",
        "[Data]",
        QD_COLUMNS,
    ]
    data = ("\r\n".join(header + rows) + "\r\n").encode("latin-1")
    return {"bytes": data, "reversal_Oe": reversal_Oe, "fields_Oe": truth_fields,
            "moments_emu": truth_moments, "calibration_Oe": calibration_Oe,
            "calibration_times_s": np.array(cal_times), "curve_times_s": curve_times,
            "drift_per_s": drift_per_s}


def plain_csv(units: str = "SI", n_curves: int = 6, declare: bool = True) -> bytes:
    """A plain FORC CSV in SI (T, A m^2) or cgs (Oe, emu)."""
    lines = [f"# n_curves: {n_curves}"] if declare else []
    n_points = sum(len(np.arange(1000.0 - 200.0 * k, 1000.0 + 1e-9, 100.0))
                   for k in range(n_curves))
    if declare:
        lines.append(f"# n_points: {n_points}")
    lines.append("reversal_field_T,field_T,moment_Am2" if units == "SI"
                 else "reversal_field_Oe,field_Oe,moment_emu")
    for k in range(n_curves):
        hr_Oe = 1000.0 - 200.0 * k
        for h_Oe in np.arange(hr_Oe, 1000.0 + 1e-9, 100.0):
            m_emu = float(model_moment_emu(h_Oe, hr_Oe))
            if units == "SI":
                lines.append(f"{hr_Oe * 1e-4:.6g},{h_Oe * 1e-4:.6g},{m_emu * 1e-3:.8e}")
            else:
                lines.append(f"{hr_Oe:.6g},{h_Oe:.6g},{m_emu:.8e}")
    return ("\n".join(lines) + "\n").encode()
