"""Reader for Quantum Design MPMS3 / PPMS VSM ``.DAT`` files holding a FORC sequence.

Layout: ``[Header]``, header lines (``; comment``, ``TITLE,...``, ``BYAPP,...``,
``INFO,value,NAME``, ``DATATYPE,...``, ...), ``[Data]``, a CSV column line such as
``Comment,Time Stamp (sec),Temperature (K),Magnetic Field (Oe),Moment (emu),...`` and rows.

The file has no curve structure of its own, so the curves are found from the field history:
the sequence is cut wherever the field steps down by more than half the typical rising step
(a field-direction reversal), each rising run being one curve. Calibration points are isolated
points (a run of one point, or the last point of a run reached by a jump of more than four rising
steps) that sit together at one high field (above the 90th percentile of all fields, at least two
of them); each is the calibration of the curve that follows it. Rows without a field or moment
value (comment rows) are skipped and counted in ``header["n_rows_skipped"]``; a non-numeric
value is an error. The format has no curve count and no end marker, so a file cut at a line
boundary cannot be told from a complete one (a cut inside a line is an error).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from ._text import parse_number, shorten
from .drift import drift_percent
from .model import CalibrationPoint, ForcCurve, ForcFormatError, ForcMeasurement
from .units import FIELD_TO_T, MOMENT_TO_AM2, check_plausible, normalize_field_unit, \
    normalize_moment_unit

_FIELD_RE = re.compile(r"(?:Magnetic )?Field \(([^)]*)\)")
_MOMENT_NAMES = ("Moment", "DC Moment Free Ctr", "DC Moment Fixed Ctr")
_TIME_RE = re.compile(r"Time Stamp \((?:sec|s)\)")
_TEMPERATURE_RE = re.compile(r"Temperature \(K\)")


def looks_like_qd(lines: list[str]) -> bool:
    first = lines[0].strip()
    return first == "[Header]" or (first.startswith("Comment,") and "Field (" in first)


def _find_columns(path: Path, columns: list[str], line: int):
    i_field = next((i for i, name in enumerate(columns) if _FIELD_RE.fullmatch(name)), None)
    i_moment = None
    for wanted in _MOMENT_NAMES:
        i_moment = next((i for i, name in enumerate(columns)
                         if re.fullmatch(rf"{wanted} \(([^)]*)\)", name)), None)
        if i_moment is not None:
            break
    if i_field is None or i_moment is None:
        raise ForcFormatError(path, "expected columns 'Magnetic Field (Oe)' and 'Moment (emu)', "
                              f"found {shorten(','.join(columns), 120)}", line)
    i_time = next((i for i, name in enumerate(columns) if _TIME_RE.fullmatch(name)), None)
    i_temperature = next((i for i, name in enumerate(columns)
                          if _TEMPERATURE_RE.fullmatch(name)), None)
    return i_field, i_moment, i_time, i_temperature


def read_qd(path: Path, lines: list[str], ends_with_newline: bool, *,
            allow_incomplete: bool = False) -> ForcMeasurement:
    """The measurement of a Quantum Design ``.DAT`` file (module docstring): header, column line, data
    rows, curves cut at the field reversals; a ``ForcFormatError`` naming the line where it departs
    from the format."""
    header, index = _read_header(path, lines)
    column_line = index + 1
    columns = [name.strip() for name in _cells(path, lines, index)]
    i_field, i_moment, i_time, i_temperature = _find_columns(path, columns, column_line)
    field_unit, moment_unit = _column_units(path, columns[i_field], columns[i_moment], column_line)
    wanted = [i_field, i_moment] + [i for i in (i_time, i_temperature) if i is not None]
    values, line_numbers, skipped = _read_rows(path, lines, index + 1, columns, wanted)
    if not ends_with_newline and not allow_incomplete:
        raise ForcFormatError(path, "last line has no line end: file truncated", len(lines))
    header["n_rows_skipped"] = skipped
    table = np.array(values, dtype=float)
    field_T = table[:, 0] * FIELD_TO_T[field_unit]
    moment_Am2 = table[:, 1] * MOMENT_TO_AM2[moment_unit]
    check_plausible(path, field_T, moment_Am2, f"field in {field_unit}, moment in {moment_unit}",
                    line_numbers)
    time_s, temperature_K = _time_and_temperature(path, table, i_time is not None, i_temperature is not None,
                                                  line_numbers)
    curves, calibration = _curves(path, (field_T, moment_Am2, time_s, temperature_K), line_numbers)
    return ForcMeasurement(
        curves=curves, calibration=calibration, format="qd-dat",
        units="cgs" if field_unit == "Oe" else "SI",
        units_declared=f"{columns[i_field]}; {columns[i_moment]}", source=path, header=header,
        drift_percent=drift_percent(calibration), drift_corrected=False, n_curves_header=None,
        complete=True)


def _read_header(path: Path, lines: list[str]) -> tuple[dict, int]:
    """The ``[Header]`` block's entries (``INFO,value,NAME`` as NAME → value; a repeated key → a list)
    and the index of the column line (the line after ``[Data]``, or the first line of a file without
    a header)."""
    header: dict = {}
    index = 0
    if lines[0].strip() == "[Header]":
        index = 1
        while index < len(lines) and lines[index].strip() != "[Data]":
            text = lines[index].strip()
            if text and not text.startswith(";"):
                key, _, rest = text.partition(",")
                if key == "INFO" and "," in rest:
                    value, _, name = rest.rpartition(",")
                    header[name.strip() or "INFO"] = value.strip()
                elif key in header:
                    previous = header[key]
                    header[key] = (previous if isinstance(previous, list) else [previous]) + [rest]
                else:
                    header[key] = rest
            index += 1
        if index >= len(lines):
            raise ForcFormatError(path, "expected '[Data]' after the header, found none",
                                  len(lines))
        index += 1
    if index >= len(lines):
        raise ForcFormatError(path, "expected the column line after '[Data]'", len(lines))
    return header, index


def _cells(path: Path, lines: list[str], number: int) -> list[str]:
    """The CSV cells of line index ``number``."""
    try:
        return next(csv.reader([lines[number]]), [])
    except csv.Error as error:
        raise ForcFormatError(path, f"expected a CSV row, found unreadable text ({error})",
                              number + 1) from None


def _column_units(path: Path, field_name: str, moment_name: str, column_line: int) -> tuple[str, str]:
    """The (field, moment) units of the columns named ``field_name`` and ``moment_name``, normalized."""
    field_unit = normalize_field_unit(_FIELD_RE.fullmatch(field_name).group(1))
    moment_unit = normalize_moment_unit(
        re.fullmatch(r".*\(([^)]*)\)", moment_name).group(1))
    if field_unit is None or moment_unit is None:
        raise ForcFormatError(path, f"cannot tell the units of {field_name!r} and "
                              f"{moment_name!r} (expected Oe or T, emu or A m2)",
                              column_line)
    return field_unit, moment_unit


def _read_rows(path: Path, lines: list[str], first: int, columns: list[str], wanted: list[int]) -> tuple:
    """The values of the ``wanted`` columns (field, moment, [time], [temperature]) of every data row from
    line index ``first`` on (an empty cell: NaN); returns (values, 1-based line numbers, number of rows
    skipped for an empty field or moment)."""
    i_field, i_moment = wanted[0], wanted[1]
    values, line_numbers = [], []
    skipped = 0
    for number in range(first, len(lines)):
        cells = _cells(path, lines, number)
        line = number + 1
        if not cells or not any(cell.strip() for cell in cells):
            continue
        if len(cells) <= max(wanted):
            raise ForcFormatError(path, f"expected at least {max(wanted) + 1} comma-separated "
                                  f"values, found {len(cells)}", line)
        if not cells[i_field].strip() or not cells[i_moment].strip():
            skipped += 1
            continue
        row = []
        for position in wanted:
            text = cells[position]
            value = parse_number(text) if text.strip() else float("nan")
            if value is None:
                raise ForcFormatError(path, f"expected a number in column {columns[position]!r}, "
                                      f"found {text!r}", line)
            row.append(value)
        values.append(row)
        line_numbers.append(line)
    if len(values) < 2:
        raise ForcFormatError(path, "expected data rows after the column line, found "
                              f"{len(values)}", len(lines))
    return values, line_numbers, skipped


def _time_and_temperature(path: Path, table: np.ndarray, has_time: bool, has_temperature: bool,
                          line_numbers: list[int]) -> tuple:
    """(time (s, from the first row), temperature (K)) from the table's columns after field and moment;
    None for a column the file lacks or that has an empty cell."""
    column = 2
    time_s = temperature_K = None
    if has_time:
        time_s = table[:, column]
        column += 1
        if np.all(np.isfinite(time_s)):
            time_s = time_s - time_s[0]
            if np.any(np.diff(time_s) < 0):
                bad = int(np.flatnonzero(np.diff(time_s) < 0)[0]) + 1
                raise ForcFormatError(path, "expected increasing time stamps, found one going "
                                      "back", line_numbers[bad])
        else:
            time_s = None
    if has_temperature:
        temperature_K = table[:, column]
        if not np.all(np.isfinite(temperature_K)):
            temperature_K = None
    return time_s, temperature_K


def _curves(path: Path, series: tuple, line_numbers: list[int]) -> tuple[list, list]:
    """(curves, calibration points) cut from the field history (``segment_by_reversals``); ``series`` is
    (field (T), moment (A m²), time (s) or None, temperature (K) or None) per row."""
    field_T, moment_Am2, time_s, temperature_K = series
    curve_runs, calibration_rows = segment_by_reversals(path, field_T, line_numbers)
    curves, calibration = [], []
    for (start, stop), cal_row in zip(curve_runs, calibration_rows):
        curves.append(ForcCurve(
            reversal_field_T=float(field_T[start]), field_T=field_T[start:stop].copy(),
            moment_Am2=moment_Am2[start:stop].copy(),
            time_s=None if time_s is None else time_s[start:stop].copy(),
            temperature_K=None if temperature_K is None else temperature_K[start:stop].copy()))
        if cal_row is not None:
            calibration.append(CalibrationPoint(
                float(field_T[cal_row]), float(moment_Am2[cal_row]),
                None if time_s is None else float(time_s[cal_row]), line=line_numbers[cal_row]))
    return curves, calibration


def segment_by_reversals(path: Path, field_T: np.ndarray, line_numbers: list[int]
                         ) -> tuple[list[tuple[int, int]], list[int | None]]:
    """Cut a field history into rising runs (curves) and calibration points (module docstring).

    Returns the (start, stop) rows of each curve and, per curve, the row of its calibration point
    (all None where the sequence has none).
    """
    steps = np.diff(field_T)
    rising = steps[steps > 0]
    if rising.size == 0:
        raise ForcFormatError(path, "expected rising field sweeps (FORCs), the field never rises",
                              line_numbers[-1])
    typical = float(np.median(rising))
    breaks = np.flatnonzero(steps < -0.5 * typical) + 1
    bounds = list(zip(np.r_[0, breaks], np.r_[breaks, field_T.size]))
    candidates = []
    for start, stop in bounds:
        if stop - start == 1:
            candidates.append(start)
        elif field_T[stop - 1] - field_T[stop - 2] > 4 * typical:
            candidates.append(stop - 1)
    calibration_rows: set[int] = set()
    if len(candidates) >= 2:
        fields = field_T[candidates]
        reference = float(np.median(fields))
        span = float(field_T.max() - field_T.min())
        close = np.abs(fields - reference) <= max(0.01 * span, 2 * typical)
        if close.sum() >= 2 and reference >= np.percentile(field_T, 90):
            calibration_rows = {row for row, ok in zip(candidates, close) if ok}
    runs, cal_for_run = [], []
    pending = None
    for start, stop in bounds:
        rows = [row for row in range(start, stop) if row not in calibration_rows]
        if start in calibration_rows:
            pending = start
        if rows:
            # A calibration point may only sit at the start or the end of a run.
            runs.append((rows[0], rows[-1] + 1))
            cal_for_run.append(pending)
            pending = None
        if stop - 1 in calibration_rows and stop - 1 != start:
            pending = stop - 1
    if calibration_rows and any(row is None for row in cal_for_run):
        missing = cal_for_run.index(None)
        raise ForcFormatError(path, f"calibration points before some curves but not before curve "
                              f"{missing + 1}", line_numbers[runs[missing][0]])
    return runs, cal_for_run
