"""Write FORC families in a real instrument format (MicroMag 2900/3900 Series 0015, "Hybrid SI"),
so that simulated "measurements" (with or without an undeclared effect) go through exactly the
readers a lab's file would.

Layout (as the instrument writes it, CRLF line ends): the title lines and a ``Name = value`` header
(NCrv curves, NData rows counting calibration points, HCal the calibration field), then per curve a
calibration point at HCal, a blank line, the (field, moment) rows from the reversal field upward,
a blank line; curves in order of decreasing reversal field; the end marker.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.io import atomic_path


def _number(x: float) -> str:
    return f"{x:+.6E}"


def _in_measured_order(reversal_fields_T, curves, calibration_moments_Am2, calibration_field_T):
    """Curves as measured (decreasing reversal field), their calibration moments (default: the top
    point of the highest curve for every curve, a measurement without drift) and the calibration field
    (default: the largest field)."""
    order = np.argsort(reversal_fields_T)[::-1]
    curves = [(np.asarray(curves[k][0], float), np.asarray(curves[k][1], float)) for k in order]
    h_cal = float(calibration_field_T if calibration_field_T is not None else max(f.max() for f, _ in curves))
    if calibration_moments_Am2 is None:
        cal = [curves[0][1][np.argmax(curves[0][0])]] * len(curves)
    else:
        cal = list(np.asarray(calibration_moments_Am2, float)[order])
    return curves, cal, h_cal


def write_micromag_0015(path, reversal_fields_T, curves, calibration_moments_Am2=None, calibration_field_T=None,
                        sample_name: str = "forcdecode simulation") -> Path:
    """``curves``: per reversal field, (field_T, moment_Am2) arrays from H_r upward. Fields in T,
    moments in A·m² (Hybrid SI). ``calibration_moments_Am2``: one per curve (default: the same value
    for every curve, the top point of the highest curve: a measurement without drift)."""
    curves, cal, h_cal = _in_measured_order(reversal_fields_T, curves, calibration_moments_Am2, calibration_field_T)
    n_data = sum(len(f) for f, _ in curves) + len(curves)
    header = [
        "MicroMag 2900/3900 Data File (Series 0015)",
        "First-order reversal curves",
        "Configuration   :  VSM",
        "Hardware version:  0004",
        "Software version:  06/21/2004",
        "Units of measure:  Hybrid SI",
        "Temperature in  :  Kelvin",
        "01/01/2026  00:00",
        f'"{sample_name}"',
        "",
        "Averaging time = +1.000000E-01",
        f"Hb1            = {_number(-0.5 * h_cal)}",
        f"Hb2            = {_number(0.5 * h_cal)}",
        "Hc1            =  0.000000E+00",
        f"Hc2            = {_number(h_cal)}",
        f"HCal           = {_number(h_cal)}",
        f"HNcr           = {_number(float(np.median(np.diff(np.sort(reversal_fields_T)))))}",
        f"HSat           = {_number(h_cal)}",
        f"NCrv           = {len(curves)}",
        "PauseCal       = +1.000000E+00",
        "PauseNtl       = +1.000000E+00",
        "PauseSat       = +1.000000E+00",
        "SlewRate       = +1.000000E+00",
        "Smoothing      = 3",
        "",
        f"Field range    = {_number(h_cal)}",
        f"Moment range   = {_number(max(np.abs(m).max() for _, m in curves))}",
        "Temperature    = N/A",
        "Orientation    =  0.000000E+00",
        "Elapsed time   = +1.000000E+03",
        "Slope corr.    = N/A",
        "Saturation     = N/A",
        f"NData          = {n_data}",
        "",
    ]
    lines = list(header)
    for (fields, moments), m_cal in zip(curves, cal):
        lines.append(f"{_number(h_cal)},{_number(m_cal)}")
        lines.append("")
        lines.extend(f"{_number(h)},{_number(m)}" for h, m in zip(fields, moments))
        lines.append("")
    lines.append("MicroMag 2900/3900 Data File ends")
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1"))
    return path


def write_lakeshore_csv(path, reversal_fields_T, curves, calibration_moments_Am2=None, calibration_field_T=None,
                        sample_name: str = "forcdecode simulation", averaging_s: float = 0.1, pause_s: float = 1.0,
                        sweep_rate_T_per_s: float = 0.05) -> Path:
    """The native CSV of the Lake Shore 8600 VSM (the layout ``measured.lakeshore`` reads, latin-1,
    CRLF): header sections, START/FINISH TIME, then segments 0, 2, ... the calibration points and
    1, 3, ... the curves (highest reversal field first), fields in T, moments in A·m², time stamps
    from the sweep (``pause_s`` at each calibration and reversal field, ``averaging_s`` per point,
    ``sweep_rate_T_per_s`` between fields). Arguments as ``write_micromag_0015``."""
    from datetime import datetime, timedelta

    curves, cal, h_cal = _in_measured_order(reversal_fields_T, curves, calibration_moments_Am2, calibration_field_T)
    rows, t, segment = [], 0.0, 0
    for (fields, moments), m_cal in zip(curves, cal):
        rows.append(f"1,0,{segment},{h_cal!r},{float(m_cal)!r},{t:.3f},GOOD,GOOD")
        rows.append("")
        t += pause_s + abs(h_cal - fields[0]) / sweep_rate_T_per_s + pause_s
        for i, (h, m) in enumerate(zip(fields, moments)):
            t += (abs(h - fields[i - 1]) / sweep_rate_T_per_s if i else 0.0) + averaging_s
            rows.append(f"1,0,{segment + 1},{float(h)!r},{float(m)!r},{t:.3f},GOOD,GOOD")
        rows.append("")
        segment += 2
    start = datetime(2026, 1, 1, 9, 0, 0)
    finish = start + timedelta(seconds=t)

    def stamp(d):
        return d.strftime("%m/%d/%Y %I:%M:%S.") + f"{d.microsecond // 1000:03d} " + d.strftime("%p")

    lines = ["#RUN ON SOFTWARE VERSION:", "1.3", "#SAMPLE SETTINGS", f"ID: {sample_name}",
             "#FORC MEASUREMENT", "#ACQUISITION SETUP", f"Saturation field: {h_cal:g} T", "FORC type: Classic",
             f"Pause at calibration field: {pause_s:g} s", f"Number of FORCs: {len(curves)}",
             f"Pause at reversal fields: {pause_s:g} s", f"Averaging time: {averaging_s:g} s",
             f"START TIME: {stamp(start)}", f"FINISH TIME: {stamp(finish)}", "#DATA: 1",
             "##DATA TABLE Moment (m) [A\u00b7m\u00b2] vs Field (\u00b50H) [T]",
             "Step,Iteration,Segment,Field (\u00b50H) [T],Moment (m) [A\u00b7m\u00b2],Time Stamp [s],Field Status,"
             "Moment (m) Status"] + rows
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1"))
    return path
