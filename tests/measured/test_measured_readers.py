"""Readers of measured FORC files: real instrument files, variants built from them, synthetic
QD and plain-CSV files, truncation and unit traps."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from forcdecode.measured import FORMATS, ForcFormatError, read_forc
from measured_fixtures import (data_file, join_lines, plain_csv, qd_forc, shrink_irregular,
                               shrink_lakeshore_csv, shrink_micromag, split_lines)

# name -> (format, curves, units, rows the header declares incl. calibration points or None)
REAL_FILES = {
    "MD00-2361.frc": ("micromag-0016", 297, "SI", 83882),
    "UB199BF.frc": ("micromag-0015", 140, "SI", 15644),
    "MSM33-55-1_d330.forc": ("micromag-0015", 120, "SI", 8514),
    "MSM33-53-1-d400_5.irforc": ("micromag-irregular", 99, "SI", 15814),
    "B-9-3-85-87-FORC-1.5T.csv": ("lakeshore8600-csv", 251, "SI", None),
    "agm_cgs_0141327c.frc": ("micromag-0015", 180, "cgs", 28736),
}
EXCERPT = "lakeshore8600_micromag_layout_excerpt.forc"

_cache: dict = {}


def read_cached(name: str, drift_correction: bool = True):
    key = (name, drift_correction)
    if key not in _cache:
        _cache[key] = read_forc(data_file(name), drift_correction=drift_correction)
    return _cache[key]


def assert_consistent(measurement, require_complete: bool = True) -> None:
    """Invariants every successfully read data set satisfies."""
    assert measurement.format in FORMATS
    assert measurement.n_curves >= 1
    if require_complete or measurement.complete:
        assert measurement.complete
        if measurement.n_curves_header is not None:
            assert measurement.n_curves == measurement.n_curves_header
    assert len(measurement.calibration) in (0, measurement.n_curves)
    for curve in measurement.curves:
        assert curve.field_T.ndim == 1 and curve.field_T.shape == curve.moment_Am2.shape
        assert len(curve) >= 1
        assert np.all(np.isfinite(curve.field_T)) and np.all(np.isfinite(curve.moment_Am2))
        assert np.isfinite(curve.reversal_field_T)
        assert np.max(np.abs(curve.field_T)) <= 30.0 and np.max(np.abs(curve.moment_Am2)) <= 1.0
        for extra in (curve.time_s, curve.temperature_K):
            assert extra is None or (extra.shape == curve.field_T.shape
                                     and np.all(np.isfinite(extra)))
    for point in measurement.calibration:
        assert np.isfinite(point.field_T) and np.isfinite(point.moment_Am2)
    json.dumps(measurement.summary(), allow_nan=False)


# ---------------------------------------------------------------------------------------------
# Real files


@pytest.mark.parametrize("name", sorted(REAL_FILES))
def test_real_file_format_count_units(name):
    fmt, n_curves, units, n_rows = REAL_FILES[name]
    measurement = read_cached(name)
    assert measurement.format == fmt
    assert measurement.n_curves == n_curves
    assert measurement.n_curves_header == n_curves
    assert measurement.units == units
    assert len(measurement.calibration) == n_curves
    assert measurement.drift_corrected
    assert_consistent(measurement)
    if n_rows is not None:
        trailing = len(measurement.header.get("trailing_segment", {}).get("field_T", []))
        assert measurement.n_points + len(measurement.calibration) + trailing == n_rows


@pytest.mark.parametrize("name", sorted(REAL_FILES))
def test_real_file_plausible_si_values(name):
    measurement = read_cached(name)
    fields = measurement.all_fields_T()
    moments = measurement.all_moments_Am2()
    # Hall-probe readbacks of these measurements stay within a few hundred mT.
    assert 0.05 < np.max(np.abs(fields)) < 1.0
    assert 1e-10 < np.max(np.abs(moments)) < 1e-3
    for curve in measurement.curves:
        assert curve.reversal_field_T == pytest.approx(curve.field_T[0])
        # each curve runs from its reversal field upward (Hall-probe noise allowed)
        assert curve.field_T[-1] >= curve.field_T[0] - 1e-3
    # curves come in order of decreasing reversal field
    assert np.all(np.diff(measurement.reversal_fields_T) < 0)
    # the calibration field lies above every reversal field
    calibration_fields = np.array([point.field_T for point in measurement.calibration])
    assert calibration_fields.min() > measurement.reversal_fields_T.max()


def test_cgs_file_converted_to_si():
    measurement = read_cached("agm_cgs_0141327c.frc", drift_correction=False)
    # first calibration point "+1.086690E+03,+1.405986E-05" (Oe, emu)
    assert measurement.calibration[0].field_T == pytest.approx(1.086690e3 * 1e-4, rel=1e-12)
    assert measurement.calibration[0].moment_Am2 == pytest.approx(1.405986e-5 * 1e-3, rel=1e-12)
    # first curve "+2.458496E+02,+8.794520E-06"
    first = measurement.curves[0]
    assert first.field_T[0] == pytest.approx(0.02458496, rel=1e-12)
    assert first.moment_Am2[0] == pytest.approx(8.794520e-9, rel=1e-12)
    # Hb1/Hc2/HCal stay header values in the file's units: the diagram window, not fields
    assert measurement.header["Hb1"] == pytest.approx(-200.0)
    assert measurement.header["HCal"] == pytest.approx(1086.242)
    assert measurement.units_declared == "cgs"


def test_hybrid_si_file_kept_in_tesla():
    measurement = read_cached("UB199BF.frc", drift_correction=False)
    assert measurement.units_declared == "Hybrid SI"
    assert measurement.calibration[0].field_T == pytest.approx(0.2074594)
    assert measurement.calibration[0].moment_Am2 == pytest.approx(9.187522e-05)
    np.testing.assert_allclose(measurement.curves[1].field_T, [0.06700292, 0.06878607, 0.07061973])
    assert measurement.header["Date"] == "03/23/2005  09:15"
    assert measurement.header["Sample"] == "UB199B"


def test_agm_cgs_drift_about_five_percent():
    measurement = read_cached("agm_cgs_0141327c.frc")
    assert measurement.drift_percent == pytest.approx(5.36, abs=0.2)
    assert 4.0 < measurement.drift_percent < 6.5


def test_drift_correction_is_multiplicative_by_curve_order():
    raw = read_cached("agm_cgs_0141327c.frc", drift_correction=False)
    corrected = read_cached("agm_cgs_0141327c.frc")
    assert not raw.drift_corrected and corrected.drift_corrected
    assert raw.drift_percent == pytest.approx(corrected.drift_percent)
    reference = raw.calibration[0].moment_Am2
    for index in (0, 1, 90, 179):
        factor = reference / raw.calibration[index].moment_Am2
        np.testing.assert_allclose(corrected.curves[index].moment_Am2,
                                   raw.curves[index].moment_Am2 * factor, rtol=1e-12)
    np.testing.assert_array_equal(corrected.curves[5].field_T, raw.curves[5].field_T)


def test_lakeshore_csv_time_stamps_and_time_interpolated_drift():
    raw = read_cached("B-9-3-85-87-FORC-1.5T.csv", drift_correction=False)
    corrected = read_cached("B-9-3-85-87-FORC-1.5T.csv")
    assert raw.calibration[0].field_T == pytest.approx(0.29981130288479396)
    assert raw.calibration[0].moment_Am2 == pytest.approx(1.1532817254763294e-05)
    assert raw.calibration[0].time_s == pytest.approx(0.0)
    np.testing.assert_allclose(raw.curves[1].time_s, [10.37, 10.74, 10.84])
    np.testing.assert_allclose(raw.curves[1].field_T,
                               [0.098362309630794481, 0.10047573094346068, 0.1020822334735131])
    assert raw.header["Number of FORCs"] == 251
    assert raw.drift_percent == pytest.approx(1.918, abs=0.01)
    times = np.array([point.time_s for point in raw.calibration])
    moments = np.array([point.moment_Am2 for point in raw.calibration])
    for index in (3, 100, 250):
        curve = raw.curves[index]
        factor = moments[0] / np.interp(curve.time_s, times, moments)
        np.testing.assert_allclose(corrected.curves[index].moment_Am2, curve.moment_Am2 * factor,
                                   rtol=1e-12)


def test_irregular_segments_follow_the_table():
    measurement = read_cached("MSM33-53-1-d400_5.irforc", drift_correction=False)
    first = measurement.curves[0]
    np.testing.assert_allclose(first.field_T, [0.2786242, 0.2786437, 0.2883136, 0.2882867,
                                               0.3068904])
    assert first.moment_Am2[0] == pytest.approx(6.455497e-06)
    assert measurement.calibration[0].field_T == pytest.approx(0.3068889)
    assert measurement.header["Number of segments"] == 8105
    trailing = measurement.header["trailing_segment"]
    np.testing.assert_allclose(trailing["field_T"], [0.3067963, -0.001587348])
    assert measurement.units_declared == "Hybrid SI"
    assert measurement.header["Temperature in"] == "Celsius"


def test_lakeshore_micromag_excerpt_is_reported_truncated():
    path = data_file(EXCERPT)
    with pytest.raises(ForcFormatError) as info:
        read_forc(path)
    message = str(info.value)
    assert path.name in message and "line" in message and "76" in message
    measurement = read_forc(path, allow_incomplete=True)
    assert measurement.format == "lakeshore8600-micromag"
    assert measurement.units == "SI" and measurement.units_declared == "SiMuNaughtH"
    assert measurement.n_curves == 4 and measurement.n_curves_header == 76
    assert not measurement.complete
    np.testing.assert_allclose(measurement.curves[1].field_T, [0.035, 0.04, 0.045])
    assert measurement.calibration[0].moment_Am2 == pytest.approx(9.66700955586433e-6)


# ---------------------------------------------------------------------------------------------
# Variants of real files (built at run time): layout traps


@pytest.fixture
def small_msm(tmp_path):
    """MSM33-55-1 (Series 0015, Hybrid SI) cut to 10 curves."""
    data = shrink_micromag(data_file("MSM33-55-1_d330.forc"), 10)
    return tmp_path, data


def write(tmp_path, name: str, data: bytes):
    path = tmp_path / name
    path.write_bytes(data)
    return path


def test_shrunk_variant_reads(small_msm):
    tmp_path, data = small_msm
    measurement = read_forc(write(tmp_path, "small.forc", data))
    assert measurement.n_curves == 10 and measurement.format == "micromag-0015"
    assert_consistent(measurement)


def test_joined_first_lines_lf_endings_and_garbled_date(small_msm):
    tmp_path, data = small_msm
    reference = read_forc(write(tmp_path, "a.forc", data))
    lines, newline = split_lines(data)
    joined = [lines[0] + lines[1]] + lines[2:]
    date_line = next(i for i, line in enumerate(joined) if line.startswith("04/13/2016"))
    joined[date_line] = "0\xff/1?/2\x0016  1#:2\xb5"
    measurement = read_forc(write(tmp_path, "b.forc", join_lines(joined, "\n")))
    assert measurement.n_curves == reference.n_curves
    assert measurement.header["Date"] == joined[date_line]
    for a, b in zip(measurement.curves, reference.curves):
        np.testing.assert_array_equal(a.field_T, b.field_T)
        np.testing.assert_array_equal(a.moment_Am2, b.moment_Am2)


@pytest.mark.parametrize("unit, value, kelvin", [("Kelvin", "+2.950000E+02", 295.0),
                                                 ("Celsius", "+2.185000E+01", 295.0)])
def test_third_temperature_column(small_msm, unit, value, kelvin):
    tmp_path, data = small_msm
    lines, newline = split_lines(data)
    out = []
    for line in lines:
        if re.fullmatch(r"[+-][\d.]+E[+-]\d+,[+-][\d.]+E[+-]\d+", line):
            line += "," + value
        elif line.startswith("Temperature in"):
            line = f"Temperature in  :  {unit}"
        out.append(line)
    measurement = read_forc(write(tmp_path, "t.forc", join_lines(out, newline)))
    assert measurement.curves[3].temperature_K == pytest.approx(kelvin, abs=1e-9)
    assert_consistent(measurement)


def test_wrong_units_declaration_is_an_error_naming_the_unit(tmp_path):
    data = shrink_micromag(data_file("agm_cgs_0141327c.frc"), 5)
    lines, newline = split_lines(data)
    lines = [line.replace("Units of measure:  cgs", "Units of measure:  Hybrid SI")
             for line in lines]
    path = write(tmp_path, "wrong.frc", join_lines(lines, newline))
    with pytest.raises(ForcFormatError) as info:
        read_forc(path)
    message = str(info.value)
    assert "wrong.frc" in message and "Hybrid SI" in message and "30 T" in message
    assert info.value.line is not None


def test_missing_units_declaration_is_an_error(tmp_path):
    data = shrink_micromag(data_file("UB199BF.frc"), 5)
    lines, newline = split_lines(data)
    lines = [line for line in lines if not line.startswith("Units of measure")]
    with pytest.raises(ForcFormatError, match="Units of measure"):
        read_forc(write(tmp_path, "nounits.frc", join_lines(lines, newline)))


def test_units_conflicting_with_column_units_is_an_error(tmp_path):
    data = shrink_micromag(data_file("MD00-2361.frc"), 5)
    lines, newline = split_lines(data)
    lines = [re.sub(r"Hybrid SI$", "cgs", line) for line in lines]
    with pytest.raises(ForcFormatError, match="column units"):
        read_forc(write(tmp_path, "conflict.frc", join_lines(lines, newline)))


def test_hysteresis_loop_included_is_refused(tmp_path):
    data = shrink_micromag(data_file("MD00-2361.frc"), 5)
    lines, newline = split_lines(data)
    lines = [re.sub(r"(Includes hysteresis loop\?\s+)No", r"\1Yes", line) for line in lines]
    with pytest.raises(ForcFormatError, match="hysteresis"):
        read_forc(write(tmp_path, "loop.frc", join_lines(lines, newline)))


# ---------------------------------------------------------------------------------------------
# Truncated and damaged files


def _cuts(n_lines: int) -> list[int]:
    return sorted({5, 30, n_lines // 3, (2 * n_lines) // 3, n_lines - 3, n_lines - 2,
                   n_lines - 1})


@pytest.mark.parametrize("name", sorted(REAL_FILES))
def test_truncated_real_files_raise_with_line(tmp_path, name):
    lines, newline = split_lines(data_file(name).read_bytes())
    while lines and not lines[-1].strip():
        lines.pop()
    for keep in _cuts(len(lines)):
        path = write(tmp_path, f"cut{keep}_{name}", join_lines(lines[:keep] + [""], newline))
        with pytest.raises(ForcFormatError) as info:
            read_forc(path)
        error = info.value
        assert error.line is not None, str(error)
        assert f"line {error.line}" in str(error) and path.name in str(error)
    # cut inside the last line (no line end)
    data = join_lines(lines, newline)
    path = write(tmp_path, f"midline_{name}", data[:-7])
    with pytest.raises(ForcFormatError) as info:
        read_forc(path)
    assert info.value.line is not None


@pytest.mark.parametrize("name", ["UB199BF.frc", "MD00-2361.frc", "agm_cgs_0141327c.frc",
                                  "MSM33-53-1-d400_5.irforc"])
def test_deleted_data_line_is_detected(tmp_path, name):
    lines, newline = split_lines(data_file(name).read_bytes())
    row = next(i for i in range(len(lines) // 2, len(lines)) if "," in lines[i]
               and "," in lines[i + 1])
    path = write(tmp_path, name, join_lines(lines[:row] + lines[row + 1:], newline))
    with pytest.raises(ForcFormatError, match=r"line \d+"):
        read_forc(path)


def test_deleted_curve_is_detected(tmp_path):
    data = shrink_micromag(data_file("UB199BF.frc"), 8)
    lines, newline = split_lines(data)
    # the 4th curve: its calibration point, blank, rows, blank
    blank = [i for i, line in enumerate(lines) if not line.strip()]
    first_data = next(i for i, line in enumerate(lines) if re.match(r"[+-]\d", line))
    blocks = [b for b in blank if b > first_data]
    start, stop = blocks[5] + 1, blocks[7] + 1
    path = write(tmp_path, "gap.frc", join_lines(lines[:start] + lines[stop:], newline))
    with pytest.raises(ForcFormatError, match="NData|curves"):
        read_forc(path)


def test_garbled_number_reports_its_line(tmp_path):
    lines, newline = split_lines(data_file("UB199BF.frc").read_bytes())
    lines[199] = lines[199].replace("E-0", "X-0", 1)
    path = write(tmp_path, "garbled.frc", join_lines(lines, newline))
    with pytest.raises(ForcFormatError) as info:
        read_forc(path)
    assert info.value.line == 200
    assert "line 200" in str(info.value) and "expected a data row" in str(info.value)


def test_lakeshore_csv_last_line_dropped_is_detected(tmp_path):
    data = shrink_lakeshore_csv(data_file("B-9-3-85-87-FORC-1.5T.csv"), 6)
    assert read_forc(write(tmp_path, "ok.csv", data)).n_curves == 6
    lines, newline = split_lines(data)
    while not lines[-1].strip():
        lines.pop()
    with pytest.raises(ForcFormatError, match="FINISH TIME"):
        read_forc(write(tmp_path, "cut.csv", join_lines(lines[:-1] + [""], newline)))


def test_shrunk_irregular_variant_reads(tmp_path):
    data = shrink_irregular(data_file("MSM33-53-1-d400_5.irforc"), 5)
    measurement = read_forc(write(tmp_path, "small.irforc", data))
    assert measurement.format == "micromag-irregular" and measurement.n_curves == 5
    assert_consistent(measurement)


def test_unknown_and_empty_files(tmp_path):
    path = write(tmp_path, "notes.txt", b"hello\nworld\n")
    with pytest.raises(ForcFormatError, match=r"notes\.txt: line 1: unknown format"):
        read_forc(path)
    with pytest.raises(ForcFormatError, match="empty"):
        read_forc(write(tmp_path, "empty.frc", b""))


def test_format_detected_by_content_not_extension(tmp_path):
    data = shrink_micromag(data_file("MSM33-55-1_d330.forc"), 4)
    assert read_forc(write(tmp_path, "looks_like.csv", data)).format == "micromag-0015"
    assert read_forc(write(tmp_path, "looks_like.frc", qd_forc(4)["bytes"])).format == "qd-dat"


# ---------------------------------------------------------------------------------------------
# Quantum Design .DAT (synthetic, real MPMS3 layout)


def test_qd_dat_curves_units_and_calibration(tmp_path):
    truth = qd_forc(12)
    path = write(tmp_path, "forc.dat", truth["bytes"])
    raw = read_forc(path, drift_correction=False)
    assert raw.format == "qd-dat" and raw.units == "cgs"
    assert raw.n_curves == 12 and raw.n_curves_header is None
    assert len(raw.calibration) == 12
    assert raw.header["n_rows_skipped"] == 1  # the comment row
    assert raw.header["SAMPLE_MATERIAL"] == "synthetic FORC test sample"
    for index, curve in enumerate(raw.curves):
        np.testing.assert_allclose(curve.field_T, truth["fields_Oe"][index] * 1e-4, atol=1e-9)
        drift = 1.0 + truth["drift_per_s"] * truth["curve_times_s"][index]
        np.testing.assert_allclose(curve.moment_Am2, truth["moments_emu"][index] * drift * 1e-3,
                                   rtol=1e-8)
        np.testing.assert_allclose(curve.temperature_K, 300.0, atol=0.1)
        assert curve.reversal_field_T == pytest.approx(truth["reversal_Oe"][index] * 1e-4,
                                                       abs=1e-4)
    for point in raw.calibration:
        assert point.field_T == pytest.approx(1.0, abs=1e-4)
    cal_drift = 1.0 + truth["drift_per_s"] * truth["calibration_times_s"]
    expected = 100 * (cal_drift.max() - cal_drift.min()) / cal_drift.mean()
    assert raw.drift_percent == pytest.approx(expected, rel=1e-6)
    assert_consistent(raw)


def test_qd_dat_drift_correction_removes_linear_drift(tmp_path):
    truth = qd_forc(12)
    corrected = read_forc(write(tmp_path, "forc.dat", truth["bytes"]))
    assert corrected.drift_corrected
    level = 1.0 + truth["drift_per_s"] * truth["calibration_times_s"][0]
    for index, curve in enumerate(corrected.curves[:-1]):  # the last runs past the last cal
        np.testing.assert_allclose(curve.moment_Am2, truth["moments_emu"][index] * level * 1e-3,
                                   rtol=1e-7)


def test_qd_dat_without_calibration_points(tmp_path):
    truth = qd_forc(8, calibration=False, comment_row=False)
    measurement = read_forc(write(tmp_path, "nocal.dat", truth["bytes"]))
    assert measurement.n_curves == 8 and measurement.calibration == []
    assert not measurement.drift_corrected and np.isnan(measurement.drift_percent)
    assert len(measurement.curves[0]) == 1  # the first curve is its reversal point only
    assert_consistent(measurement)


def test_qd_dat_garbage_value_reports_line(tmp_path):
    lines, newline = split_lines(qd_forc(4)["bytes"])
    cells = lines[30].split(",")
    cells[4] = "1.2.3E-5"  # Moment (emu)
    lines[30] = ",".join(cells)
    with pytest.raises(ForcFormatError) as info:
        read_forc(write(tmp_path, "bad.dat", join_lines(lines, newline)))
    assert info.value.line == 31


# ---------------------------------------------------------------------------------------------
# Plain CSV


def test_plain_csv_si_and_cgs_agree(tmp_path):
    si = read_forc(write(tmp_path, "si.csv", plain_csv("SI")))
    cgs = read_forc(write(tmp_path, "cgs.csv", plain_csv("cgs")))
    assert si.format == cgs.format == "csv"
    assert si.units == "SI" and cgs.units == "cgs"
    assert si.n_curves == cgs.n_curves == 6 == si.n_curves_header
    for a, b in zip(si.curves, cgs.curves):
        assert a.reversal_field_T == pytest.approx(b.reversal_field_T)
        np.testing.assert_allclose(a.field_T, b.field_T, rtol=1e-5)
        np.testing.assert_allclose(a.moment_Am2, b.moment_Am2, rtol=1e-7)
    assert si.curves[1].field_T[0] == pytest.approx(0.08)
    assert si.calibration == [] and not si.drift_corrected


def test_plain_csv_declared_count_checked(tmp_path):
    lines = plain_csv("SI").decode().splitlines()
    lines = [line for line in lines if not line.startswith("0.1,")]  # drop the first curve
    with pytest.raises(ForcFormatError, match="truncated"):
        read_forc(write(tmp_path, "short.csv", ("\n".join(lines) + "\n").encode()))
    undeclared = read_forc(write(tmp_path, "plain.csv", plain_csv("cgs", declare=False)))
    assert undeclared.n_curves_header is None and undeclared.n_curves == 6


def test_plain_csv_unknown_unit_is_an_error(tmp_path):
    with pytest.raises(ForcFormatError, match="units"):
        read_forc(write(tmp_path, "u.csv", b"reversal_field_kG,field_kG,moment_Am2\n1,1,1e-6\n"))
