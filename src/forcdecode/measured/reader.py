"""``read_forc``: detect the format of a measured FORC file by its content and read it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..core.errors import InputFileError
from ._text import read_lines, shorten
from .drift import correct_drift
from .lakeshore import looks_like_lakeshore_csv, read_lakeshore_csv
from .micromag import TITLE_PREFIX, read_micromag
from .model import ForcFormatError, ForcMeasurement
from .plain_csv import looks_like_plain_csv, read_plain_csv
from .qd import looks_like_qd, read_qd

FORMATS = ("micromag-0015", "micromag-0016", "micromag-irregular", "lakeshore8600-csv",
           "lakeshore8600-micromag", "qd-dat", "csv")


def detect_format(lines: list[str]) -> str | None:
    """The reader family for a file's lines ("micromag", "lakeshore8600-csv", "qd-dat", "csv")."""
    first = lines[0].lstrip()
    if first.startswith(TITLE_PREFIX):
        return "micromag"
    if looks_like_lakeshore_csv(lines):
        return "lakeshore8600-csv"
    if looks_like_qd(lines):
        return "qd-dat"
    if looks_like_plain_csv(lines):
        return "csv"
    return None


def read_forc(path: str | Path, drift_correction: bool = True, *,
              allow_incomplete: bool = False) -> ForcMeasurement:
    """Read a measured FORC file into SI (see :class:`ForcMeasurement`).

    The format is recognised from the first lines, not from the extension. With
    ``drift_correction`` the curve moments are corrected multiplicatively from the calibration
    points (:mod:`forcdecode.measured.drift`); formats without calibration points are returned
    uncorrected (``drift_corrected`` False). A truncated file (curve count below the header's,
    end marker missing, last line cut) raises :class:`ForcFormatError` unless
    ``allow_incomplete`` is set, in which case the curves present are returned with
    ``complete`` False.

    Raises ForcFormatError for an unknown, garbled or truncated file, InputFileError (its base)
    if the file cannot be read.
    """
    path = Path(path)
    try:
        lines, ends_with_newline = read_lines(path)
    except OSError as error:
        raise InputFileError(f"cannot read {path}: {error.strerror or error}") from error
    family = detect_format(lines)
    if family == "micromag":
        measurement = read_micromag(path, lines, allow_incomplete=allow_incomplete)
    elif family == "lakeshore8600-csv":
        measurement = read_lakeshore_csv(path, lines, ends_with_newline,
                                         allow_incomplete=allow_incomplete)
    elif family == "qd-dat":
        measurement = read_qd(path, lines, ends_with_newline, allow_incomplete=allow_incomplete)
    elif family == "csv":
        measurement = read_plain_csv(path, lines, ends_with_newline,
                                     allow_incomplete=allow_incomplete)
    else:
        raise ForcFormatError(
            path, f"unknown format: expected '{TITLE_PREFIX} (Series ...)', a Lake Shore 8600 "
            "CSV ('#RUN ON SOFTWARE VERSION:'), a Quantum Design '[Header]' or a CSV header "
            f"'reversal_field_T,field_T,moment_Am2'; found {shorten(lines[0])}", 1)
    if drift_correction and measurement.calibration:
        measurement = dataclasses.replace(
            measurement, curves=correct_drift(path, measurement.curves, measurement.calibration),
            drift_corrected=True)
    return measurement
