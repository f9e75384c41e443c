"""Physical constants and the derived quantities of a perpendicular film's Hamiltonian (SI throughout).

The one place they are written: the engine (``micromag``), the prior (``core.parameters``), the readers'
unit table (``measured.units``), the bench and the independent generator read them from here.

Scalar or array arguments broadcast together (numpy); every function returns what numpy returns for its
inputs (a float for floats). Functions that take a √ of K_eff are NaN where K_eff ≤ 0 (an in-plane film
has no perpendicular wall); they never take the √ of a negative number.
"""

from __future__ import annotations

import math

import numpy as np

MU0 = 4e-7 * math.pi
"""Vacuum permeability μ0 in T·m/A (the pre-2019 exact value, as mumax3 and magnum.np use)."""

GAMMA_LL = 1.7595e11
"""Landau–Lifshitz gyromagnetic ratio γ_LL in rad/(T·s) (mumax3's value)."""


def _out(value):
    return value if np.ndim(value) else float(value)


def shape_anisotropy(Ms):
    """Thin-film shape anisotropy K_d = μ0 M_s²/2 (J/m³); ``Ms`` in A/m."""
    return _out(MU0 * np.asarray(Ms, dtype=float) ** 2 / 2)


def k_eff(K_u, Ms):
    """Effective perpendicular anisotropy K_eff = K_u − μ0 M_s²/2 (J/m³) of a thin film."""
    return _out(np.asarray(K_u, dtype=float) - shape_anisotropy(Ms))


def quality_factor(K_u, Ms):
    """Q = 2K_u/(μ0 M_s²) (dimensionless); Q > 1 ⇔ K_eff > 0."""
    return _out(2.0 * np.asarray(K_u, dtype=float) / (MU0 * np.asarray(Ms, dtype=float) ** 2))


def effective_anisotropy_field(K_u, Ms):
    """μ0H_K,eff = 2K_u/M_s − μ0 M_s (T): the field that saturates a perpendicular film's coherent
    rotation, i.e. 2K_eff/M_s."""
    Ms = np.asarray(Ms, dtype=float)
    return _out(2.0 * np.asarray(K_u, dtype=float) / Ms - MU0 * Ms)


def exchange_length(A_ex, Ms):
    """l_ex = √(2A_ex/(μ0 M_s²)) (m)."""
    return _out(np.sqrt(2.0 * np.asarray(A_ex, dtype=float) / (MU0 * np.asarray(Ms, dtype=float) ** 2)))


def _where_positive(keff, fn, *others):
    keff = np.asarray(keff, dtype=float)
    arrays = np.broadcast_arrays(keff, *[np.asarray(o, dtype=float) for o in others])
    out = np.full(arrays[0].shape, np.nan)
    ok = arrays[0] > 0
    out[ok] = fn(*[a[ok] for a in arrays])
    return _out(out)


def wall_parameter(A_ex, K_eff):
    """Bloch wall parameter Δ = √(A_ex/K_eff) (m); NaN where K_eff ≤ 0."""
    return _where_positive(K_eff, lambda k, a: np.sqrt(a / k), A_ex)


def wall_width(A_ex, K_eff):
    """Domain-wall width δ_w = π√(A_ex/K_eff) (m, Lilley's); NaN where K_eff ≤ 0."""
    return _where_positive(K_eff, lambda k, a: np.pi * np.sqrt(a / k), A_ex)


def wall_energy(A_ex, K_eff, D=0.0):
    """Néel-wall energy per area σ_w = 4√(A_ex K_eff) − π|D| (J/m²); NaN where K_eff ≤ 0."""
    return _where_positive(K_eff, lambda k, a, d: 4.0 * np.sqrt(a * k) - np.pi * np.abs(d), A_ex, D)


def critical_dmi(A_ex, K_eff):
    """D_c = 4√(A_ex K_eff)/π (J/m²), the |D| at which σ_w = 0; NaN where K_eff ≤ 0."""
    return _where_positive(K_eff, lambda k, a: 4.0 * np.sqrt(a * k) / np.pi, A_ex)


def spiral_period(A_ex, D):
    """Period of the zero-field DMI spiral 4πA_ex/|D| (m); inf where D = 0."""
    D = np.abs(np.asarray(D, dtype=float))
    with np.errstate(divide="ignore"):
        return _out(np.where(D > 0, 4.0 * np.pi * np.asarray(A_ex, dtype=float) / np.where(D > 0, D, 1.0), np.inf))


__all__ = ["GAMMA_LL", "MU0", "critical_dmi", "effective_anisotropy_field", "exchange_length", "k_eff",
           "quality_factor", "shape_anisotropy", "spiral_period", "wall_energy", "wall_parameter", "wall_width"]
