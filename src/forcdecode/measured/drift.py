"""Drift of a FORC measurement, estimated and corrected from its calibration points.

Before each curve the instrument measures the moment at one fixed calibration field (HCal). Had
nothing drifted, every calibration moment would be the same; their spread is the drift.

Definition used throughout: ``drift_percent = 100 * (max - min) / |mean|`` of the calibration
moments.

Correction (multiplicative): a moment measured when the calibration moment was ``m_cal`` is scaled
by ``m_cal[0] / m_cal``, i.e. the whole data set is brought to the sensitivity of the first
calibration point. Where the file has time stamps, ``m_cal`` at a point's time is linearly
interpolated between the calibration points (held constant after the last one); without time
stamps each curve is scaled by the factor of its own calibration point (measured just before it).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .model import CalibrationPoint, ForcCurve, ForcFormatError

# Beyond this relative change of the calibration moment the calibration points are not trusted.
MAX_CORRECTION_FACTOR = 2.0


def drift_percent(calibration: list[CalibrationPoint]) -> float:
    """``100 * (max - min) / |mean|`` of the calibration moments; NaN without any."""
    if not calibration:
        return float("nan")
    moments = np.array([point.moment_Am2 for point in calibration], dtype=float)
    mean = abs(float(np.mean(moments)))
    if mean == 0.0 or not np.all(np.isfinite(moments)):
        return float("nan")
    return float(100.0 * (moments.max() - moments.min()) / mean)


def correct_drift(path: Path, curves: list[ForcCurve],
                  calibration: list[CalibrationPoint]) -> list[ForcCurve]:
    """Curves with multiplicatively drift-corrected moments (see the module docstring).

    Raises ForcFormatError where the calibration moments cannot support a correction (zero,
    changing sign, or implying a factor beyond ``MAX_CORRECTION_FACTOR``).
    """
    if not calibration:
        return curves
    if len(calibration) != len(curves):
        raise ForcFormatError(path, f"expected one calibration point per curve, found "
                              f"{len(calibration)} for {len(curves)} curves", calibration[-1].line)
    cal_moment = np.array([point.moment_Am2 for point in calibration], dtype=float)
    reference = cal_moment[0]
    ratio = cal_moment / reference if reference != 0.0 else np.full_like(cal_moment, np.nan)
    bad = (~np.isfinite(ratio) | (ratio <= 1.0 / MAX_CORRECTION_FACTOR)
           | (ratio >= MAX_CORRECTION_FACTOR))
    if np.any(bad):
        index = int(np.flatnonzero(bad)[0])
        raise ForcFormatError(
            path, f"calibration moment before curve {index + 1} ({cal_moment[index]:.4g} A m^2) is "
            f"not within a factor {MAX_CORRECTION_FACTOR:g} of the first ({reference:.4g} A m^2): "
            "cannot drift-correct (read with drift_correction=False to see the raw data)",
            calibration[index].line)

    cal_time = [point.time_s for point in calibration]
    use_time = all(t is not None for t in cal_time) and all(c.time_s is not None for c in curves)
    if use_time:
        cal_time_s = np.array(cal_time, dtype=float)
        order = np.argsort(cal_time_s, kind="stable")
        cal_time_s, cal_sorted = cal_time_s[order], cal_moment[order]
        if np.any(np.diff(cal_time_s) <= 0) or not np.all(np.isfinite(cal_time_s)):
            use_time = False  # time stamps unusable: fall back to one factor per curve
    corrected = []
    for index, curve in enumerate(curves):
        if use_time:
            factor = reference / np.interp(curve.time_s, cal_time_s, cal_sorted)
        else:
            factor = reference / cal_moment[index]
        corrected.append(dataclasses.replace(curve, moment_Am2=curve.moment_Am2 * factor))
    return corrected
