"""The parameter table: every Hamiltonian parameter once, with its SI unit, its default draw bounds
(the seed paper's Table I), its scale and whether a network learns it. The draw, the learning, the
loop and the schema's bounds all read this table.

Normalization maps a value to u ∈ [0, 1] by the configured bounds (on a log scale for log-scale
parameters), never by data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Parameter:
    """One Hamiltonian parameter: ``low``/``high`` are the default bounds in ``unit`` (SI unless the
    name says otherwise); ``scale`` is "linear" or "log" (draw and normalization); ``learned``: has
    its own network (M_s is an input of the networks, not a target)."""

    name: str
    unit: str
    low: float
    high: float
    scale: str
    description: str
    learned: bool

    def __post_init__(self):
        if self.scale not in ("linear", "log"):
            raise ValueError(f"scale of {self.name} must be 'linear' or 'log', got {self.scale!r}")
        if not self.low < self.high:
            raise ValueError(f"bounds of {self.name} must satisfy low < high, got {self.low}, {self.high}")

    @property
    def bounds(self) -> list:
        return [self.low, self.high]


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("Ms", "A/m", 2e5, 1.4e6, "linear", "saturation magnetization M_s", False),
    Parameter("A_ex", "J/m", 1e-12, 35e-12, "linear", "exchange stiffness A_ex", True),
    Parameter("K_u", "J/m^3", 1e3, 1.5e6, "log", "uniaxial (perpendicular) anisotropy constant K_u", True),
    Parameter("D", "J/m^2", 0.0, 5e-3, "linear", "interfacial Dzyaloshinskii-Moriya constant D", True),
    Parameter("N_pin", "count", 0, 255, "linear", "pinning sites, counted on the paper's 256x256x2 grid", True),
    Parameter("sigma_theta_deg", "deg", 0.0, 10.0, "linear", "spread of the grains' easy-axis tilt σ_θ", True),
    Parameter("sigma_K", "fraction", 0.0, 0.2, "linear", "relative spread of the grains' K_u σ_K", True),
)
"""Every parameter, M_s first (the column order of the dataset files)."""

NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS)
BY_NAME: dict[str, Parameter] = {p.name: p for p in PARAMETERS}

TARGETS: tuple[str, ...] = ("N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K")
"""The learned parameters, in the order of the networks (one network each)."""

DEFAULT_BOUNDS: dict[str, list] = {p.name: p.bounds for p in PARAMETERS}
"""name -> [low, high] (SI; N_pin a count, σ_θ in degrees, σ_K a fraction)."""

LOG_SCALE: frozenset[str] = frozenset(p.name for p in PARAMETERS if p.scale == "log")
"""Parameters drawn (and normalized) on a log scale."""

UNITS: dict[str, str] = {p.name: p.unit for p in PARAMETERS}


def _bounds(name: str, bounds) -> tuple[float, float]:
    if name not in BY_NAME:
        raise KeyError(f"unknown parameter {name!r} (one of {', '.join(NAMES)})")
    lo, hi = (bounds or {}).get(name, DEFAULT_BOUNDS[name])
    return float(lo), float(hi)


def normalize(name: str, value, bounds=None):
    """Map a value (SI) to u ∈ [0, 1] by ``bounds`` (name -> [low, high]; default the table's), on a
    log scale for log-scale parameters."""
    lo, hi = _bounds(name, bounds)
    value = np.asarray(value, dtype=float)
    if name in LOG_SCALE:
        return (np.log(value) - np.log(lo)) / (np.log(hi) - np.log(lo))
    return (value - lo) / (hi - lo)


def denormalize(name: str, unit_value, bounds=None):
    """Inverse of :func:`normalize`: u ∈ [0, 1] back to the value (SI)."""
    lo, hi = _bounds(name, bounds)
    unit_value = np.asarray(unit_value, dtype=float)
    if name in LOG_SCALE:
        return np.exp(np.log(lo) + unit_value * (np.log(hi) - np.log(lo)))
    return lo + unit_value * (hi - lo)


__all__ = ["Parameter", "PARAMETERS", "NAMES", "BY_NAME", "TARGETS", "DEFAULT_BOUNDS", "LOG_SCALE", "UNITS",
           "normalize", "denormalize"]
