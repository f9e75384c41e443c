"""Physical constants (SI), in mumax3's conventions."""

import math

MU0 = 4e-7 * math.pi
"""Vacuum permeability μ0 in T·m/A."""

GAMMA_LL = 1.7595e11
"""Landau–Lifshitz gyromagnetic ratio γ_LL in rad/(T·s) (mumax3's value)."""
