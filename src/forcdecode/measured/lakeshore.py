"""Reader for the native CSV of the Lake Shore 8600 VSM FORC measurement.

Layout: ``#SECTION`` lines and ``Key: value`` lines (``#RUN ON SOFTWARE VERSION:`` has its value on
the next line), ``START TIME`` / ``FINISH TIME``, ``#DATA: 1``, ``##DATA TABLE ...``, then the
column line ``Step,Iteration,Segment,Field (µ0H) [T],Moment (m) [A·m²],Time Stamp [s],...`` and
rows, blank lines between segments. Segment 0, 2, 4, ... are the calibration points, segment
1, 3, 5, ... the curves. The number of curves must equal ``Number of FORCs``; since the format
has no end marker, a file is also reported truncated when its last time stamp falls short of
FINISH TIME - START TIME (by more than half a sampling interval; checked where both times parse)
or its last line has no line end. Points whose status columns are not GOOD are kept and counted
in ``header["n_points_status_not_good"]``; a calibration segment of several points is averaged.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from ._text import header_int, header_value, parse_number, shorten
from .drift import drift_percent
from .model import CalibrationPoint, ForcCurve, ForcFormatError, ForcMeasurement
from .units import FIELD_TO_T, MOMENT_TO_AM2, check_plausible, normalize_field_unit, \
    normalize_moment_unit

_TIME_FORMATS = ("%m/%d/%Y %I:%M:%S.%f %p", "%m/%d/%Y %I:%M:%S %p", "%m/%d/%Y %H:%M:%S.%f",
                 "%m/%d/%Y %H:%M:%S")


def looks_like_lakeshore_csv(lines: list[str]) -> bool:
    head = lines[:200]
    return (lines[0].startswith("#RUN ON SOFTWARE VERSION")
            or any(line.startswith("##DATA TABLE") for line in head)
            and any(line.startswith("Step,Iteration,Segment") for line in head))


def _parse_time(text) -> datetime | None:
    if not isinstance(text, str):
        return None
    for fmt in _TIME_FORMATS:
        try:
            return datetime.strptime(text.strip(), fmt)
        except ValueError:
            continue
    return None


def _unit_in_brackets(name: str) -> str:
    match = re.search(r"\[([^\]]*)\]\s*$", name)
    return match.group(1) if match else ""


@dataclass(frozen=True)
class _Columns:
    """Where the values are in a data row: ``names`` (the column line's names), the positions of the
    field, moment, time-stamp (None: no such column) and status columns, the units of the field and
    moment columns (normalized spellings: ``units.FIELD_TO_T``, ``units.MOMENT_TO_AM2``) and
    ``numeric``, the positions parsed as numbers (step, iteration, segment, field, moment[, time])."""

    names: list
    field: int
    moment: int
    time: int | None
    status: list
    field_unit: str
    moment_unit: str
    numeric: list


def read_lakeshore_csv(path: Path, lines: list[str], ends_with_newline: bool, *,
                       allow_incomplete: bool = False) -> ForcMeasurement:
    """The measurement of a Lake Shore 8600 CSV (module docstring): header, column line, data rows,
    segments; a ``ForcFormatError`` naming the line where the file departs from the format."""
    header, columns, column_line = _read_header(path, lines)
    layout = _column_layout(path, columns, column_line)
    rows, not_good = _read_rows(path, lines, column_line, layout)
    if not ends_with_newline and not allow_incomplete:
        raise ForcFormatError(path, "last line has no line end: file truncated", len(lines))
    header["n_points_status_not_good"] = not_good
    line_numbers, table = _checked_table(path, rows)
    segment = table[:, 2]
    field_T = table[:, 3] * FIELD_TO_T[layout.field_unit]
    moment_Am2 = table[:, 4] * MOMENT_TO_AM2[layout.moment_unit]
    time_s = table[:, 5] if layout.time is not None else None
    check_plausible(path, field_T, moment_Am2, f"field in {layout.field_unit}, moment in {layout.moment_unit}",
                    line_numbers)
    _check_time_stamps(path, time_s, line_numbers)
    n_header, complete = _completeness(path, header, segment, time_s, line_numbers, column_line, allow_incomplete)
    curves, calibration = _segments(segment, field_T, moment_Am2, time_s, line_numbers)
    return ForcMeasurement(
        curves=curves, calibration=calibration, format="lakeshore8600-csv",
        units="cgs" if layout.field_unit == "Oe" else "SI",
        units_declared=f"{columns[layout.field]}; {columns[layout.moment]}", source=path, header=header,
        drift_percent=drift_percent(calibration), drift_corrected=False, n_curves_header=n_header,
        complete=complete and (n_header is None or n_header == len(curves)))


def _read_header(path: Path, lines: list[str]) -> tuple[dict, list, int]:
    """The header's ``Key: value`` pairs up to the column line; returns (header, column names, 1-based
    number of the column line)."""
    header: dict = {}
    index = 0
    columns = None
    while index < len(lines):
        text = lines[index].strip()
        if text.startswith("Step,Iteration,Segment"):
            columns = [name.strip() for name in lines[index].split(",")]
            index += 1
            break
        if text.startswith("#DATA:"):
            header["DATA"] = header_value(text[6:])
        elif text.startswith("##"):
            header["DATA TABLE"] = text[2:].strip()
        elif text.startswith("#") and text.endswith(":") and index + 1 < len(lines):
            header[text[1:-1].strip()] = header_value(lines[index + 1])
            index += 1
        elif text.startswith("#"):
            pass  # section title
        elif ":" in text:
            key, value = text.split(":", 1)
            header[key.strip()] = header_value(value)
        index += 1
    if columns is None:
        raise ForcFormatError(path, "expected the column line 'Step,Iteration,Segment,...', "
                              "found none", len(lines))
    return header, columns, index


def _column_layout(path: Path, columns: list, column_line: int) -> _Columns:
    """The positions and units of the columns read (field and moment required, with units in brackets)."""

    def find(pattern: str, required: bool = True) -> int | None:
        for position, name in enumerate(columns):
            if re.match(pattern, name):
                return position
        if required:
            raise ForcFormatError(path, f"expected a column matching {pattern!r}, found "
                                  f"{columns}", column_line)
        return None

    i_step, i_iteration, i_segment = 0, 1, 2
    i_field = find(r"Field\b.*\[.*\]$")
    i_moment = find(r"Moment\b.*\[.*\]$")
    i_time = find(r"Time Stamp \[s\]", required=False)
    i_status = [position for position, name in enumerate(columns) if name.endswith("Status")]
    field_unit = normalize_field_unit(_unit_in_brackets(columns[i_field]))
    moment_unit = normalize_moment_unit(_unit_in_brackets(columns[i_moment]))
    if field_unit is None or moment_unit is None:
        raise ForcFormatError(path, f"cannot tell the units of columns {columns[i_field]!r} and "
                              f"{columns[i_moment]!r} (expected [T], [mT], [Oe] and [A·m²], "
                              "[emu])", column_line)
    numeric = [i_step, i_iteration, i_segment, i_field, i_moment]
    if i_time is not None:
        numeric.append(i_time)
    return _Columns(columns, i_field, i_moment, i_time, i_status, field_unit, moment_unit, numeric)


def _read_rows(path: Path, lines: list[str], first: int, layout: _Columns) -> tuple[list, int]:
    """The data rows from line index ``first`` on: [(1-based line number, numeric values)], and the
    number of rows whose status columns are not GOOD."""
    columns = layout.names
    rows = []
    not_good = 0
    for index in range(first, len(lines)):
        raw = lines[index]
        if not raw.strip():
            continue
        if raw.startswith("#"):
            raise ForcFormatError(path, "expected one data table; a second one (or a comment) "
                                  f"follows: {shorten(raw)}", index + 1)
        cells = raw.split(",")
        if len(cells) != len(columns):
            raise ForcFormatError(path, f"expected {len(columns)} comma-separated values, found "
                                  f"{len(cells)}: {shorten(raw)}", index + 1)
        values = []
        for position in layout.numeric:
            value = parse_number(cells[position])
            if value is None:
                raise ForcFormatError(path, f"expected a number in column {columns[position]!r}, "
                                      f"found {cells[position]!r}", index + 1)
            values.append(value)
        if any(cells[position].strip() != "GOOD" for position in layout.status):
            not_good += 1
        rows.append((index + 1, values))
    if not rows:
        raise ForcFormatError(path, "expected data rows after the column line, found none",
                              len(lines))
    return rows, not_good


def _checked_table(path: Path, rows: list) -> tuple[np.ndarray, np.ndarray]:
    """(line numbers, table of the numeric columns) of one (Step, Iteration) data set whose segment
    numbers run 0, 1, 2, ... in steps of 0 or 1."""
    line_numbers = np.array([line for line, _ in rows])
    table = np.array([values for _, values in rows], dtype=float)
    if np.unique(table[:, :2], axis=0).shape[0] != 1:
        bad = int(np.flatnonzero(np.any(table[:, :2] != table[0, :2], axis=1))[0])
        raise ForcFormatError(path, f"expected one (Step, Iteration) data set, found a second "
                              "one (not supported)", int(line_numbers[bad]))
    segment = table[:, 2]
    if not np.all(segment == np.round(segment)) or segment[0] != 0:
        raise ForcFormatError(path, "expected segment numbers 0, 1, 2, ...", int(line_numbers[0]))
    step = np.diff(segment)
    if np.any((step != 0) & (step != 1)):
        bad = int(np.flatnonzero((step != 0) & (step != 1))[0]) + 1
        raise ForcFormatError(path, f"expected segment {int(segment[bad - 1])} or "
                              f"{int(segment[bad - 1]) + 1}, found {segment[bad]:g}",
                              int(line_numbers[bad]))
    return line_numbers, table


def _check_time_stamps(path: Path, time_s, line_numbers) -> None:
    """Time stamps (s), where the file has them, finite and not decreasing."""
    if time_s is None:
        return
    if not np.all(np.isfinite(time_s)):
        bad = int(np.flatnonzero(~np.isfinite(time_s))[0])
        raise ForcFormatError(path, "expected a finite time stamp", int(line_numbers[bad]))
    if np.any(np.diff(time_s) < 0):
        bad = int(np.flatnonzero(np.diff(time_s) < 0)[0]) + 1
        raise ForcFormatError(path, "expected increasing time stamps, found one going back",
                              int(line_numbers[bad]))


def _completeness(path: Path, header: dict, segment, time_s, line_numbers, column_line: int,
                  allow_incomplete: bool) -> tuple[int | None, bool]:
    """(``Number of FORCs`` of the header, whether the file is complete): the segments must be twice the
    FORCs, and the last time stamp (s) must reach FINISH TIME - START TIME less half a sampling
    interval; a ``ForcFormatError`` where not, unless ``allow_incomplete``."""
    n_header = header_int(header, ("Number of FORCs",))
    n_segments = int(segment[-1]) + 1
    complete = True
    if n_header is None:
        if not allow_incomplete:
            raise ForcFormatError(path, "expected 'Number of FORCs' in the header, found none",
                                  column_line)
    elif n_segments != 2 * n_header:
        if not allow_incomplete:
            raise ForcFormatError(path, f"header declares {n_header} FORCs = {2 * n_header} "
                                  f"segments with the calibration points, found {n_segments}: "
                                  "truncated or garbled", int(line_numbers[-1]))
        complete = False
    if time_s is not None and complete:
        start = _parse_time(header.get("START TIME"))
        finish = _parse_time(header.get("FINISH TIME"))
        if start is not None and finish is not None:
            elapsed = (finish - start).total_seconds()
            steps = np.diff(time_s)
            tolerance = 0.5 * float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.05
            if time_s[-1] < elapsed - tolerance:
                if not allow_incomplete:
                    raise ForcFormatError(
                        path, f"last time stamp {time_s[-1]:g} s is before FINISH TIME - START "
                        f"TIME = {elapsed:g} s: truncated", int(line_numbers[-1]))
                complete = False
    return n_header, complete


def _segments(segment, field_T, moment_Am2, time_s, line_numbers) -> tuple[list, list]:
    """(curves, calibration points): even segments are calibration points (a segment of several points
    averaged; the last one dropped where its curve is not in the file), odd ones the curves."""
    boundaries = np.flatnonzero(np.diff(segment)) + 1
    starts = np.r_[0, boundaries]
    stops = np.r_[boundaries, len(segment)]
    curves, calibration = [], []
    for number, (start, stop) in enumerate(zip(starts, stops)):
        if number % 2 == 0:
            if number + 1 >= len(starts):
                break  # calibration point of a curve that is not in the file
            calibration.append(CalibrationPoint(
                float(field_T[start:stop].mean()), float(moment_Am2[start:stop].mean()),
                None if time_s is None else float(time_s[start:stop].mean()),
                line=int(line_numbers[start])))
        else:
            curves.append(ForcCurve(
                reversal_field_T=float(field_T[start]), field_T=field_T[start:stop].copy(),
                moment_Am2=moment_Am2[start:stop].copy(),
                time_s=None if time_s is None else time_s[start:stop].copy()))
    return curves, calibration
