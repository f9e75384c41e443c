"""Unit conversion to SI and plausibility checks.

cgs -> SI: mu0*H [T] = H [Oe] * 1e-4, m [A m^2] = m [emu] * 1e-3.
True SI MicroMag files give H in A/m: mu0*H [T] = 4*pi*1e-7 * H [A/m].
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .model import ForcFormatError

MU0 = 4e-7 * math.pi

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


def check_plausible(path: Path, field_T: np.ndarray, moment_Am2: np.ndarray, assumed: str) -> None:
    """Raise ForcFormatError if the converted values cannot be a magnetometer measurement."""
    if field_T.size and not np.all(np.isfinite(field_T)):
        raise ForcFormatError(path, "non-finite field value")
    if moment_Am2.size and not np.all(np.isfinite(moment_Am2)):
        raise ForcFormatError(path, "non-finite moment value")
    if field_T.size and np.max(np.abs(field_T)) > FIELD_LIMIT_T:
        raise ForcFormatError(
            path, f"field of {np.max(np.abs(field_T)):.4g} T after conversion assuming {assumed}: "
            f"beyond {FIELD_LIMIT_T:g} T, so the unit of the file is not {assumed} or it is garbled")
    if moment_Am2.size and np.max(np.abs(moment_Am2)) > MOMENT_LIMIT_AM2:
        raise ForcFormatError(
            path, f"moment of {np.max(np.abs(moment_Am2)):.4g} A m^2 after conversion assuming "
            f"{assumed}: beyond {MOMENT_LIMIT_AM2:g} A m^2, so the unit of the file is not "
            f"{assumed} or it is garbled")
