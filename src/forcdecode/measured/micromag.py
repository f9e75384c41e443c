"""Readers for PMC / Lake Shore MicroMag 2900/3900 FORC files.

Layouts handled (all share the first line ``MicroMag 2900/3900 Data File (Series ...)`` and the
last line ``MicroMag 2900/3900 Data File ends``):

- Series 0015: ``Key : value`` lines, a date line (sometimes garbled, kept verbatim), the quoted
  sample name, then ``Key = value`` lines (NCrv, NData, HCal, ...).
- Series 0016.002: sectioned header (INSTRUMENT, SETTINGS, ..., SCRIPT) with ``Key<spaces>value``
  lines, then column names ``Field Moment`` and their units.
- The Lake Shore 8600 export in that layout: tab-separated header, ``SiMuNaughtH`` units (mu0*H in
  T, moment in A m^2), ``", "`` as separator.
- "Multiple segments" (irregular FORC protocol): a segment table in the SCRIPT block tells which
  blank-line separated data block is a calibration point, a reversal point or a rising segment.

Data of a regular FORC file: for each curve one calibration point (near HCal), a blank line, the
curve's rows from the reversal field upward, a blank line. An optional third column is the
temperature. ``NData`` / ``Number of data`` counts all rows including calibration points; the
curve count (``NCrv`` / ``NForc``) must match, and the end marker must be present, or the file
is reported as truncated. ``Hb1/Hb2/Hc1/Hc2`` describe the FORC-diagram window and are kept in the
header only.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._text import NUMBER, header_int, header_value, shorten
from .drift import drift_percent
from .model import CalibrationPoint, ForcCurve, ForcFormatError, ForcMeasurement
from .units import FIELD_TO_T, MOMENT_TO_AM2, check_plausible, normalize_field_unit, \
    normalize_moment_unit

TITLE_PREFIX = "MicroMag 2900/3900 Data File"
END_MARKER = "MicroMag 2900/3900 Data File ends"
_TITLE_RE = re.compile(r"\s*MicroMag 2900/3900 Data File\s*\(Series\s*([0-9][0-9.]*)\)\s*(.*)")
_DATA_ROW_RE = re.compile(rf"\s*({NUMBER})\s*,\s*({NUMBER})\s*(?:,\s*({NUMBER})\s*)?")
_TABLE_ROW_RE = re.compile(rf"\s*{NUMBER}\s*(?:,\s*{NUMBER}\s*){{6}}")
_NUMBER_FIND_RE = re.compile(NUMBER)
_SECTION_RE = re.compile(r"[A-Z][A-Z ]*[A-Z]")
_KEY_SPACES_RE = re.compile(r"(\S.*?)(?:\t+\s*|\s{2,})(\S.*)")
_KEY_COLON_RE = re.compile(r"([A-Za-z][A-Za-z .()/-]*?)\s*:\s*(.*)")

# "Units of measure" declarations -> (field unit, moment unit) of the numbers in the file.
_DECLARED_UNITS = {
    "hybrid si": ("T", "Am2"),
    "simunaughth": ("T", "Am2"),  # Lake Shore 8600: mu0*H in T
    "cgs": ("Oe", "emu"),
    "si": ("A/m", "Am2"),
}
_TEMPERATURE_UNITS = {"kelvin": 0.0, "k": 0.0, "celsius": 273.15, "c": 273.15, "°c": 273.15}


@dataclass
class _Header:
    series: str
    description: str
    values: dict
    columns: list[str] | None
    column_units: list[str] | None
    table: list[tuple[int, list[float]]]  # (line number, 7 values) of the segment table
    data_start: int  # 0-based index of the first line after the header = last header line
    preamble: list[str]
    key_lines: dict  # header key -> its line number


def _parse_header(path: Path, lines: list[str]) -> _Header:
    match = _TITLE_RE.fullmatch(lines[0])
    if not match:
        raise ForcFormatError(path, f"expected '{TITLE_PREFIX} (Series ...)', found "
                              f"{shorten(lines[0])}", 1)
    series, rest = match.group(1), match.group(2).strip()
    if rest:  # lines 1 and 2 joined
        description, index = rest, 1
    else:
        description, index = (lines[1].strip() if len(lines) > 1 else ""), 2
    sectioned = not series.startswith("0015")
    values: dict = {}
    key_lines: dict = {}
    table: list[tuple[int, list[float]]] = []
    preamble: list[str] = []
    columns = column_units = None
    section = None
    in_table = False

    def store(key: str, value: str) -> None:
        key = key.strip()
        if key in values:
            key = f"{section}/{key}" if section else f"{key} ({len(values)})"
        values[key] = header_value(value)
        key_lines[key] = index + 1

    while index < len(lines):
        raw = lines[index]
        text = raw.strip()
        if _DATA_ROW_RE.fullmatch(raw) or text.startswith(END_MARKER):
            break
        if not text:
            in_table = in_table and not table
            index += 1
            continue
        if in_table or (text.startswith("Segment") and "Averaging" in text):
            in_table = True
            if _TABLE_ROW_RE.fullmatch(raw):
                table.append((index + 1, [float(v) for v in _NUMBER_FIND_RE.findall(raw)]))
            elif table:
                raise ForcFormatError(path, "expected a row of the segment table (7 numbers) or "
                                      f"a blank line, found {shorten(raw)}", index + 1)
            index += 1
            continue
        words = set(text.split())
        if {"Field", "Moment"} <= words <= {"Field", "Moment", "Temperature", "Time"}:
            columns = text.split()
        elif columns is not None and column_units is None and text.startswith("("):
            column_units = re.findall(r"\(([^)]*)\)", text)
        elif sectioned and _SECTION_RE.fullmatch(text):
            section = text
        elif not sectioned and "=" in text:
            key, value = text.split("=", 1)
            store(key, value)
        elif not sectioned and (m := _KEY_COLON_RE.fullmatch(text)):
            store(m.group(1), m.group(2))
        elif sectioned and (m := _KEY_SPACES_RE.fullmatch(text)):
            store(m.group(1), m.group(2))
        elif text.startswith('"'):
            values.setdefault("Sample", text.strip('"'))
        elif not sectioned and "Date" not in values:
            values["Date"] = text  # kept verbatim: some files carry garbled dates
        else:
            preamble.append(text)
        index += 1
    return _Header(series, description, values, columns, column_units, table, index, preamble,
                   key_lines)


def _units(path: Path, header: _Header) -> tuple[str, str, str]:
    """(field unit, moment unit, declaration) from 'Units of measure', checked with the columns."""
    declared = header.values.get("Units of measure")
    line = header.key_lines.get("Units of measure", header.data_start)
    declared_text = declared.strip() if isinstance(declared, str) else ""
    from_header = _DECLARED_UNITS.get(declared_text.lower())
    from_columns = None
    if header.column_units and len(header.column_units) >= 2:
        field_unit = normalize_field_unit(header.column_units[0])
        moment_unit = normalize_moment_unit(header.column_units[1])
        if field_unit and moment_unit:
            from_columns = (field_unit, moment_unit)
    if from_header and from_columns and from_header != from_columns:
        raise ForcFormatError(path, f"'Units of measure' says {declared_text!r} "
                              f"({from_header[0]}, {from_header[1]}) but the column units are "
                              f"{header.column_units}", line)
    units = from_header or from_columns
    if units is None:
        raise ForcFormatError(path, "no recognizable 'Units of measure' in the header (expected "
                              f"cgs, SI, Hybrid SI or SiMuNaughtH; found {declared!r}) and no "
                              "column units: cannot tell the units", line)
    return units[0], units[1], declared_text or f"({units[0]}, {units[1]})"


def _temperature_offset(path: Path, header: _Header) -> float:
    """Kelvin offset for the temperature column."""
    label = header.values.get("Temperature in")
    if header.column_units and len(header.column_units) >= 3:
        label = header.column_units[2].strip()
    if isinstance(label, str) and label.strip().lower() in _TEMPERATURE_UNITS:
        return _TEMPERATURE_UNITS[label.strip().lower()]
    raise ForcFormatError(path, f"third (temperature) column but no known temperature unit "
                          f"('Temperature in' is {label!r}; expected Kelvin or Celsius)",
                          header.key_lines.get("Temperature in", header.data_start))


def _read_blocks(path: Path, lines: list[str], start: int):
    """The blank-line separated blocks of data rows.

    Returns (values array [n_rows, n_columns], line number of each row, blocks as (first row,
    end row, first line number), line number of the end marker or None).
    """
    rows: list[tuple[float, ...]] = []
    row_lines: list[int] = []
    blocks: list[tuple[int, int, int]] = []
    block_start = None
    block_line = 0
    n_columns = None
    end_line = None
    for index in range(start, len(lines)):
        raw = lines[index]
        if not raw.strip():
            if block_start is not None:
                blocks.append((block_start, len(rows), block_line))
                block_start = None
            continue
        match = _DATA_ROW_RE.fullmatch(raw)
        if match is None:
            if raw.strip() == END_MARKER:
                end_line = index + 1
                break
            raise ForcFormatError(path, "expected a data row 'field,moment' (numbers), a blank "
                                  f"line or '{END_MARKER}', found {shorten(raw)}", index + 1)
        row = match.groups()
        if row[2] is None:
            row = row[:2]
        if n_columns is None:
            n_columns = len(row)
        elif len(row) != n_columns:
            raise ForcFormatError(path, f"expected {n_columns} numbers per row like the rows "
                                  f"before, found {shorten(raw)}", index + 1)
        if block_start is None:
            block_start, block_line = len(rows), index + 1
        rows.append(tuple(float(value) for value in row))
        row_lines.append(index + 1)
    if block_start is not None:
        blocks.append((block_start, len(rows), block_line))
    if end_line is not None:
        for index in range(end_line, len(lines)):
            if lines[index].strip():
                raise ForcFormatError(path, f"expected nothing after '{END_MARKER}', found "
                                      f"{shorten(lines[index])}", index + 1)
    if not rows:
        raise ForcFormatError(path, "expected data rows after the header, found none",
                              start + 1 if start < len(lines) else len(lines))
    return np.array(rows, dtype=float), np.array(row_lines), blocks, end_line


def read_micromag(path: Path, lines: list[str], *, allow_incomplete: bool = False
                  ) -> ForcMeasurement:
    """Read any MicroMag-layout FORC file (see the module docstring); values in SI."""
    header = _parse_header(path, lines)
    description = header.description.lower()
    if "multiple segments" in description:
        kind = "irregular"
    elif "first-order reversal curves" in description:
        kind = "regular"
    else:
        raise ForcFormatError(path, "expected a FORC measurement ('First-order reversal curves' "
                              f"or 'Multiple segments'), found {shorten(header.description)}", 2)
    for key in ("Includes hysteresis loop?", "Includes Msi(H)?"):
        if str(header.values.get(key, "No")).lower().startswith("y"):
            raise ForcFormatError(path, f"'{key} Yes' is not supported (expected No)",
                                  header.data_start)
    lake_shore = (any("lake shore" in text.lower() for text in header.preamble)
                  or str(header.values.get("Units of measure", "")).lower() == "simunaughth")
    if kind == "irregular":
        fmt = "micromag-irregular"
    elif lake_shore:
        fmt = "lakeshore8600-micromag"
    elif header.series.startswith("0015"):
        fmt = "micromag-0015"
    else:
        fmt = "micromag-0016"

    field_unit, moment_unit, declared = _units(path, header)
    values, row_lines, blocks, end_line = _read_blocks(path, lines, header.data_start)
    complete = end_line is not None
    if not complete and not allow_incomplete:
        n_header = header_int(header.values, ("NCrv", "NForc", "Number of FORCs"))
        found = f" after {len(blocks)} blank-line separated blocks"
        if n_header is not None and kind == "regular":
            found += f" (about {len(blocks) // 2} of the {n_header} curves the header declares)"
        raise ForcFormatError(path, f"file ends without '{END_MARKER}'{found}: truncated",
                              len(lines))
    field_T = values[:, 0] * FIELD_TO_T[field_unit]
    moment_Am2 = values[:, 1] * MOMENT_TO_AM2[moment_unit]
    assumed = f"{declared} (field in {field_unit}, moment in {moment_unit})"
    check_plausible(path, field_T, moment_Am2, assumed, row_lines)
    temperature_K = None
    if values.shape[1] == 3:
        temperature_K = values[:, 2] + _temperature_offset(path, header)
        bad = (temperature_K <= 0) | (temperature_K > 2000)
        if np.any(bad):
            raise ForcFormatError(path, "expected a temperature within 0-2000 K in the third "
                                  "column", int(row_lines[np.flatnonzero(bad)[0]]))

    n_data = header_int(header.values, ("NData", "Number of data"))
    if n_data is not None and n_data != len(values) and complete:
        raise ForcFormatError(path, f"header declares {n_data} data rows (NData, calibration "
                              f"points included), found {len(values)}: truncated or garbled",
                              end_line)
    last_line = end_line or len(lines)

    def curve(start: int, stop: int) -> ForcCurve:
        return ForcCurve(
            reversal_field_T=float(field_T[start]), field_T=field_T[start:stop].copy(),
            moment_Am2=moment_Am2[start:stop].copy(),
            temperature_K=None if temperature_K is None else temperature_K[start:stop].copy())

    def calibration_point(row: int) -> CalibrationPoint:
        return CalibrationPoint(float(field_T[row]), float(moment_Am2[row]),
                                line=int(row_lines[row]))

    header_values = dict(header.values)
    header_values["Series"] = header.series
    header_values["Description"] = header.description
    if header.preamble:
        header_values["Preamble"] = header.preamble
    if kind == "irregular":
        rows = _DataRows(field_T, moment_Am2, curve, calibration_point)
        curves, calibration, n_header = _assemble_irregular(path, header, blocks, rows, header_values, complete,
                                                            last_line)
    else:
        curves, calibration, n_header = _assemble_regular(
            path, header, blocks, curve, calibration_point, complete, allow_incomplete, last_line)
    if not curves:
        raise ForcFormatError(path, "expected at least one curve, found none", last_line)
    return ForcMeasurement(
        curves=curves, calibration=calibration, format=fmt,
        units="cgs" if field_unit == "Oe" else "SI", units_declared=declared, source=path,
        header=header_values, drift_percent=drift_percent(calibration), drift_corrected=False,
        n_curves_header=n_header,
        complete=complete and (n_header is None or n_header == len(curves)))


def _assemble_regular(path, header, blocks, curve, calibration_point, complete, allow_incomplete,
                      last_line):
    n_header = header_int(header.values, ("NCrv", "NForc", "Number of FORCs"))
    strict = complete or not allow_incomplete
    if n_header is None and strict:
        raise ForcFormatError(path, "expected a curve count ('NCrv' or 'NForc') in the header, "
                              "found none", header.data_start)
    n_segments = header_int(header.values, ("Number of segments",))
    if n_segments is not None and strict and n_segments != len(blocks):
        raise ForcFormatError(path, f"header declares {n_segments} segments, found {len(blocks)} "
                              "blank-line separated blocks: truncated or garbled", last_line)
    if strict and len(blocks) == n_header and len(blocks) != 2 * n_header:
        with_calibration = False  # a file without calibration points
    elif strict and len(blocks) != 2 * n_header:
        raise ForcFormatError(
            path, f"header declares {n_header} curves (NCrv/NForc) = {2 * n_header} blocks with "
            f"their calibration points, found {len(blocks)} blank-line separated blocks: "
            "truncated or garbled", last_line)
    else:
        with_calibration = True
    curves, calibration = [], []
    if not with_calibration:
        return [curve(start, stop) for start, stop, _ in blocks], [], n_header
    for index in range(0, len(blocks) - 1, 2):
        cal_start, cal_stop, cal_line = blocks[index]
        if cal_stop - cal_start != 1:
            raise ForcFormatError(path, "expected one calibration point followed by a blank line, "
                                  f"found {cal_stop - cal_start} rows", cal_line)
        calibration.append(calibration_point(cal_start))
        start, stop, _ = blocks[index + 1]
        curves.append(curve(start, stop))
    return curves, calibration, n_header


def _segment_kind(initial: float, final: float) -> str:
    scale = max(abs(initial), abs(final), 1e-12)
    if abs(final - initial) <= 1e-9 * scale:
        return "hold"
    return "up" if final > initial else "down"


@dataclass(frozen=True)
class _DataRows:
    """A file's data rows in SI: ``field_T`` (T) and ``moment_Am2`` (A m²) per row, ``curve(start, stop)``
    the curve of rows [start, stop) and ``calibration_point(row)`` the calibration point of one row."""

    field_T: np.ndarray
    moment_Am2: np.ndarray
    curve: Callable[[int, int], ForcCurve]
    calibration_point: Callable[[int], CalibrationPoint]


def _assemble_irregular(path, header, blocks, rows: _DataRows, header_values, complete, last_line):
    """Curves of a 'Multiple segments' file, following its segment table (``header_values`` gains a
    ``trailing_segment``, if any).

    Pattern per curve: hold at HCal (1 point: calibration), sweep down (no data), hold at the
    reversal field (1 point: first point of the curve), rising segments (their points, start and
    end of each segment, appended in order; near-duplicate fields at segment joints are kept).
    A final falling segment with data after the last curve is kept in the header as
    ``trailing_segment``.
    """
    field_T, moment_Am2, curve, calibration_point = rows.field_T, rows.moment_Am2, rows.curve, rows.calibration_point
    table = header.table
    if not table:
        raise ForcFormatError(path, "expected a segment table in the SCRIPT block of a "
                              "'Multiple segments' file, found none", header.data_start)
    n_segments = header_int(header.values, ("Number of segments",))
    n_data = header_int(header.values, ("Number of data",))
    if n_segments is not None and n_segments != len(table):
        raise ForcFormatError(path, f"header declares {n_segments} segments, the table has "
                              f"{len(table)} rows", table[-1][0])
    previous_index = 0
    segments = []  # (kind, number of points, table line)
    for number, (line, row) in enumerate(table, start=1):
        if not all(np.isfinite(row)):
            raise ForcFormatError(path, "expected finite numbers in the segment table", line)
        if row[0] != number:
            raise ForcFormatError(path, f"expected segment number {number}, found {row[0]:g}", line)
        if row[6] != int(row[6]) or row[6] < previous_index:
            raise ForcFormatError(path, "expected a whole, non-decreasing final data index in the "
                                  f"segment table, found {row[6]:g}", line)
        final_index = int(row[6])
        segments.append((_segment_kind(row[2], row[4]), final_index - previous_index, line))
        previous_index = final_index
    if n_data is not None and previous_index != n_data:
        raise ForcFormatError(path, f"segment table ends at data index {previous_index}, header "
                              f"declares {n_data} data rows", table[-1][0])
    with_data = [segment for segment in segments if segment[1] > 0]
    n_rows = blocks[-1][1] if blocks else 0
    if complete and (len(with_data) != len(blocks) or n_rows != previous_index):
        raise ForcFormatError(path, f"segment table lists {len(with_data)} segments with "
                              f"{previous_index} data rows, found {len(blocks)} blocks with "
                              f"{n_rows} rows: truncated or garbled", last_line)
    curves, calibration = [], []
    state = "start"
    pending_calibration = None
    curve_start = curve_stop = None
    block_iter = iter(blocks)
    n_reversals = sum(1 for k, (kind, n, _) in enumerate(segments)
                      if kind == "hold" and k > 0 and segments[k - 1][0] == "down")
    for number, (kind, n_points, line) in enumerate(segments, start=1):
        block = next(block_iter, None) if n_points else None
        if n_points and block is None:
            break  # incomplete file (allowed by the caller)
        if block is not None and block[1] - block[0] != n_points:
            raise ForcFormatError(path, f"segment {number} has {n_points} data rows in the table, "
                                  f"found {block[1] - block[0]}", block[2])
        if kind == "hold" and n_points == 1 and state in ("start", "curve"):
            if state == "curve":
                curves.append(curve(curve_start, curve_stop))
            pending_calibration = calibration_point(block[0])
            state = "calibrated"
        elif kind == "down" and n_points == 0 and state == "calibrated":
            state = "descended"
        elif kind == "hold" and n_points == 1 and state == "descended":
            calibration.append(pending_calibration)
            curve_start, curve_stop = block[0], block[1]
            state = "curve"
        elif kind == "up" and state == "curve":
            if block is not None:
                if block[0] != curve_stop:
                    raise ForcFormatError(path, "segment blocks out of order", block[2])
                curve_stop = block[1]
        elif kind == "down" and n_points > 0 and state == "curve" and number == len(segments):
            header_values["trailing_segment"] = {
                "field_T": field_T[block[0]:block[1]].tolist(),
                "moment_Am2": moment_Am2[block[0]:block[1]].tolist()}
        else:
            raise ForcFormatError(path, f"unexpected segment {number} ({kind}, {n_points} points) "
                                  f"after state '{state}' in the segment table", line)
    if state == "curve":
        curves.append(curve(curve_start, curve_stop))
    return curves, calibration, n_reversals
