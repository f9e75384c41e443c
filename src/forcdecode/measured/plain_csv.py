"""Reader for a plain FORC CSV: one row per point, columns reversal field, field, moment.

The header line names the quantities and units, e.g. ``reversal_field_T,field_T,moment_Am2`` or
``reversal_field_Oe,field_Oe,moment_emu`` (also ``mT``; spellings like ``field (Oe)`` work).
Optional columns ``time_s`` and ``temperature_K``. Lines starting with ``#`` before the header are
comments; ``# n_curves: N`` and ``# n_points: N`` declare the curve and row counts, which are
then checked (without them a file cut at a line end cannot be told from a complete one).
Consecutive rows with the same reversal field form one curve. No calibration points.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ._text import header_int, header_value, parse_number, shorten
from .model import ForcCurve, ForcFormatError, ForcMeasurement
from .units import FIELD_TO_T, MOMENT_TO_AM2, check_plausible, normalize_field_unit, \
    normalize_moment_unit

_COLUMN_RE = re.compile(
    r"\s*(reversal[ _]field|field|moment|time|temperature)[ _]*[(\[]?\s*([^)\]]*?)\s*[)\]]?\s*",
    re.IGNORECASE)


def _first_content_line(lines: list[str]) -> int | None:
    for index, line in enumerate(lines):
        if line.strip() and not line.lstrip().startswith("#"):
            return index
    return None


def looks_like_plain_csv(lines: list[str]) -> bool:
    index = _first_content_line(lines[:100])
    if index is None:
        return False
    names = [name.strip().lower() for name in lines[index].split(",")]
    return (any(name.startswith("reversal") for name in names)
            and any(name.startswith("field") for name in names)
            and any(name.startswith("moment") for name in names))


def read_plain_csv(path: Path, lines: list[str], ends_with_newline: bool, *,
                   allow_incomplete: bool = False) -> ForcMeasurement:
    header: dict = {}
    index = _first_content_line(lines)
    if index is None:
        raise ForcFormatError(path, "expected a column line, found only comments", len(lines))
    for line in lines[:index]:
        key, colon, value = line.lstrip("# ").partition(":")
        if colon:
            header[key.strip()] = header_value(value)
    columns: dict[str, tuple[int, str]] = {}
    for position, name in enumerate(lines[index].split(",")):
        match = _COLUMN_RE.fullmatch(name)
        if match is None:
            raise ForcFormatError(path, f"expected columns like reversal_field_T, field_T, "
                                  f"moment_Am2, found {name.strip()!r}", index + 1)
        quantity = match.group(1).lower().replace(" ", "_")
        columns[quantity] = (position, match.group(2))
    missing = {"reversal_field", "field", "moment"} - set(columns)
    if missing:
        raise ForcFormatError(path, f"missing column(s) {sorted(missing)}", index + 1)
    field_unit = normalize_field_unit(columns["field"][1])
    reversal_unit = normalize_field_unit(columns["reversal_field"][1])
    moment_unit = normalize_moment_unit(columns["moment"][1])
    if field_unit is None or reversal_unit is None or moment_unit is None:
        raise ForcFormatError(path, "cannot tell the units: expected field and reversal field in "
                              "T, mT or Oe and moment in Am2 or emu in the column names",
                              index + 1)
    for optional, unit in (("time", "s"), ("temperature", "K")):
        if optional in columns and columns[optional][1] != unit:
            raise ForcFormatError(path, f"expected column {optional}_{unit}", index + 1)
    n_columns = len(lines[index].split(","))
    rows, line_numbers = [], []
    for number in range(index + 1, len(lines)):
        raw = lines[number]
        if not raw.strip():
            continue
        cells = raw.split(",")
        if len(cells) != n_columns:
            raise ForcFormatError(path, f"expected {n_columns} comma-separated numbers, found "
                                  f"{shorten(raw)}", number + 1)
        values = [parse_number(cell) for cell in cells]
        if any(value is None for value in values):
            raise ForcFormatError(path, f"expected numbers, found {shorten(raw)}", number + 1)
        rows.append(values)
        line_numbers.append(number + 1)
    if not rows:
        raise ForcFormatError(path, "expected data rows after the column line, found none",
                              len(lines))
    if not ends_with_newline and not allow_incomplete:
        raise ForcFormatError(path, "last line has no line end: file truncated", len(lines))
    table = np.array(rows, dtype=float)

    def column(name: str) -> np.ndarray | None:
        return table[:, columns[name][0]] if name in columns else None

    reversal_T = column("reversal_field") * FIELD_TO_T[reversal_unit]
    field_T = column("field") * FIELD_TO_T[field_unit]
    moment_Am2 = column("moment") * MOMENT_TO_AM2[moment_unit]
    time_s, temperature_K = column("time"), column("temperature")
    assumed = f"field in {field_unit}, moment in {moment_unit}"
    check_plausible(path, reversal_T, moment_Am2, assumed, line_numbers)
    check_plausible(path, field_T, moment_Am2, assumed, line_numbers)
    starts = np.r_[0, np.flatnonzero(np.diff(column("reversal_field")) != 0) + 1]
    stops = np.r_[starts[1:], len(table)]
    curves = [ForcCurve(
        reversal_field_T=float(reversal_T[start]), field_T=field_T[start:stop].copy(),
        moment_Am2=moment_Am2[start:stop].copy(),
        time_s=None if time_s is None else time_s[start:stop].copy(),
        temperature_K=None if temperature_K is None else temperature_K[start:stop].copy())
        for start, stop in zip(starts, stops)]
    n_header = header_int(header, ("n_curves",))
    n_points = header_int(header, ("n_points",))
    complete = ((n_header is None or n_header == len(curves))
                and (n_points is None or n_points == len(table)))
    if not complete and not allow_incomplete:
        raise ForcFormatError(path, f"the comments declare {n_header} curves and {n_points} "
                              f"points, found {len(curves)} and {len(table)}: truncated or "
                              "garbled", line_numbers[-1])
    si = field_unit in ("T", "mT") and reversal_unit in ("T", "mT") and moment_unit == "Am2"
    cgs = field_unit == reversal_unit == "Oe" and moment_unit == "emu"
    return ForcMeasurement(
        curves=curves, calibration=[], format="csv",
        units="SI" if si else "cgs" if cgs else "mixed",
        units_declared=lines[index].strip(), source=path, header=header,
        drift_percent=float("nan"), drift_corrected=False, n_curves_header=n_header,
        complete=complete)
