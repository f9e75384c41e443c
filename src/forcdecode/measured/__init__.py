"""Readers for measured FORC files (instrument output), in SI units inside.

``read_forc(path)`` recognises by content: PMC / Lake Shore MicroMag VSM/AGM Series 0015 and
0016.002 (also the "Multiple segments" irregular-FORC variant and the Lake Shore 8600 export in
MicroMag layout), the Lake Shore 8600 native CSV, Quantum Design MPMS3/PPMS VSM ``.DAT``, and a
plain CSV ``reversal_field_T,field_T,moment_Am2``. Fields are mu0*H in tesla, moments in A m^2.
"""

from .drift import correct_drift, drift_percent
from .model import CalibrationPoint, ForcCurve, ForcFormatError, ForcMeasurement
from .reader import FORMATS, detect_format, read_forc

__all__ = [
    "FORMATS",
    "CalibrationPoint",
    "ForcCurve",
    "ForcFormatError",
    "ForcMeasurement",
    "correct_drift",
    "detect_format",
    "drift_percent",
    "read_forc",
]
