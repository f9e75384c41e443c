"""Unit conversion to SI and plausibility checks.

cgs -> SI: mu0*H [T] = H [Oe] * 1e-4, m [A m^2] = m [emu] * 1e-3.
True SI MicroMag files give H in A/m: mu0*H [T] = 4*pi*1e-7 * H [A/m].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.physics import MU0
from .model import ForcFormatError

# Factors that turn the number in the file into mu0*H in tesla.
FIELD_TO_T = {"T": 1.0, "mT": 1e-3, "Oe": 1e-4, "G": 1e-4, "A/m": MU0, "kA/m": MU0 * 1e3}
# Factors that turn the number in the file into A m^2.
MOMENT_TO_AM2 = {"Am2": 1.0, "emu": 1e-3}

# Limits beyond which a value means the unit was misread (or the file is garbled).
FIELD_LIMIT_T = 30.0
MOMENT_LIMIT_AM2 = 1.0  # 1000 emu: far above any magnetometer sample


def normalize_field_unit(text: str) -> str | None:
    """``"T"``, ``"mT"``, ``"Oe"``, ``"G"``, ``"A/m"`` or ``"kA/m"`` for a unit label, else None."""
    label = text.strip().strip("()[]").strip()
    for unit in ("kA/m", "A/m", "mT", "Oe", "T", "G"):
        if label == unit:
            return unit
    if label.lower() in {"oe", "oersted"}:
        return "Oe"
    if label.lower() in {"tesla"}:
        return "T"
    return None


def normalize_moment_unit(text: str) -> str | None:
    """``"Am2"`` or ``"emu"`` for a unit label (any spelling of A m^2 incl. Latin-1), else None."""
    label = text.strip().strip("()[]").strip().lower()
    if label == "emu":
        return "emu"
    compact = (label.replace(" ", "").replace("·", "").replace("*", "").replace("^", "")
               .replace("²", "2").replace("_", "").replace(".", ""))
    if compact == "am2":
        return "Am2"
    return None


def check_plausible(path: Path, field_T: np.ndarray, moment_Am2: np.ndarray, assumed: str,
                    line_numbers=None) -> None:
    """Raise ForcFormatError if the converted values cannot be a magnetometer measurement.

    ``line_numbers`` (aligned with the values) lets the error name the offending line.
    """

    def line_of(bad: np.ndarray) -> int | None:
        if line_numbers is None or not np.any(bad):
            return None
        return int(line_numbers[int(np.flatnonzero(bad)[0])])

    field_bad = ~np.isfinite(field_T)
    if np.any(field_bad):
        raise ForcFormatError(path, "expected a finite field value", line_of(field_bad))
    moment_bad = ~np.isfinite(moment_Am2)
    if np.any(moment_bad):
        raise ForcFormatError(path, "expected a finite moment value", line_of(moment_bad))
    field_bad = np.abs(field_T) > FIELD_LIMIT_T
    if np.any(field_bad):
        value = float(field_T[field_bad][0])
        raise ForcFormatError(
            path, f"field of {value:.4g} T after conversion assuming {assumed}: expected at most "
            f"{FIELD_LIMIT_T:g} T, so the unit of the file is not {assumed} or it is garbled",
            line_of(field_bad))
    moment_bad = np.abs(moment_Am2) > MOMENT_LIMIT_AM2
    if np.any(moment_bad):
        value = float(moment_Am2[moment_bad][0])
        raise ForcFormatError(
            path, f"moment of {value:.4g} A m^2 after conversion assuming {assumed}: expected at "
            f"most {MOMENT_LIMIT_AM2:g} A m^2, so the unit of the file is not {assumed} or it is "
            "garbled", line_of(moment_bad))
