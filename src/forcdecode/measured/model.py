"""Data model of a measured FORC file: curves, calibration points, errors.

Everything is stored in SI: applied field as mu0*H in tesla (``field_T``), magnetic moment in
A m^2 (``moment_Am2``), time in seconds, temperature in kelvin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputFileError


class ForcFormatError(InputFileError, ValueError):
    """A file that is not a readable FORC measurement (unknown, garbled or truncated).

    The message names the file, the line (1-based, where one applies) and what was expected.
    """

    def __init__(self, path: str | Path, message: str, line: int | None = None):
        self.path = str(path)
        self.line = line
        self.detail = message
        where = f"{self.path}: line {line}: " if line is not None else f"{self.path}: "
        super().__init__(where + message)


@dataclass(frozen=True)
class ForcCurve:
    """One first-order reversal curve, measured from its reversal field upward."""

    reversal_field_T: float
    field_T: np.ndarray
    moment_Am2: np.ndarray
    time_s: np.ndarray | None = None
    temperature_K: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.field_T.size)


@dataclass(frozen=True)
class CalibrationPoint:
    """The drift-calibration point measured (at the calibration field) before a curve."""

    field_T: float
    moment_Am2: float
    time_s: float | None = None
    line: int | None = field(default=None, compare=False, repr=False)  # where it is in the file


@dataclass
class ForcMeasurement:
    """A measured FORC data set, in SI.

    Attributes
    ----------
    curves:
        The curves in file order (for MicroMag and Lake Shore files: decreasing reversal field).
    calibration:
        One :class:`CalibrationPoint` per curve (the one measured just before it), or an empty
        list when the format carries no calibration points (plain CSV, QD files without them).
    format:
        ``"micromag-0015"``, ``"micromag-0016"``, ``"micromag-irregular"``,
        ``"lakeshore8600-csv"``, ``"lakeshore8600-micromag"``, ``"qd-dat"`` or ``"csv"``.
    units:
        ``"cgs"`` or ``"SI"`` (or ``"mixed"`` for a plain CSV mixing them): the unit system of the
        numbers in the file. MicroMag "Hybrid SI" (T, A m^2) and Lake Shore "SiMuNaughtH" count
        as ``"SI"``; the literal declaration is in ``units_declared``.
    drift_percent:
        ``100 * (max - min) / |mean|`` of the calibration moments; NaN without calibration points.
    drift_corrected:
        Whether ``moment_Am2`` of the curves has been drift-corrected (see
        :func:`forcdecode.measured.drift.correct_drift`): multiplicative, each moment scaled by
        ``m_cal[0] / m_cal(t)``.
    n_curves_header:
        The curve count the file declares (NCrv, NForc, "Number of FORCs", the segment table),
        or None where it declares none. Equals ``len(curves)`` unless ``complete`` is False.
    complete:
        False only for a file read with ``allow_incomplete=True`` that turned out truncated.
    """

    curves: list[ForcCurve]
    calibration: list[CalibrationPoint]
    format: str
    units: str
    source: Path
    header: dict = field(default_factory=dict)
    drift_percent: float = float("nan")
    drift_corrected: bool = False
    units_declared: str = ""
    n_curves_header: int | None = None
    complete: bool = True

    @property
    def n_curves(self) -> int:
        return len(self.curves)

    @property
    def n_points(self) -> int:
        """Number of measured points on the curves (calibration points excluded)."""
        return sum(len(curve) for curve in self.curves)

    @property
    def reversal_fields_T(self) -> np.ndarray:
        return np.array([curve.reversal_field_T for curve in self.curves], dtype=float)

    def all_fields_T(self) -> np.ndarray:
        if not self.curves:
            return np.empty(0)
        return np.concatenate([curve.field_T for curve in self.curves])

    def all_moments_Am2(self) -> np.ndarray:
        if not self.curves:
            return np.empty(0)
        return np.concatenate([curve.moment_Am2 for curve in self.curves])

    def summary(self) -> dict:
        """A JSON-ready summary (NaN written as None)."""
        fields = self.all_fields_T()
        moments = self.all_moments_Am2()

        def number(value: float) -> float | None:
            return float(value) if np.isfinite(value) else None

        return {
            "source": str(self.source),
            "format": self.format,
            "units": self.units,
            "units_declared": self.units_declared,
            "n_curves": self.n_curves,
            "n_curves_header": self.n_curves_header,
            "complete": self.complete,
            "n_points": self.n_points,
            "n_calibration_points": len(self.calibration),
            "field_min_T": number(fields.min()) if fields.size else None,
            "field_max_T": number(fields.max()) if fields.size else None,
            "reversal_field_min_T": number(self.reversal_fields_T.min()) if self.curves else None,
            "reversal_field_max_T": number(self.reversal_fields_T.max()) if self.curves else None,
            "moment_max_Am2": number(np.abs(moments).max()) if moments.size else None,
            "has_time": bool(self.curves) and self.curves[0].time_s is not None,
            "has_temperature": bool(self.curves) and self.curves[0].temperature_K is not None,
            "drift_percent": number(self.drift_percent),
            "drift_corrected": self.drift_corrected,
        }
