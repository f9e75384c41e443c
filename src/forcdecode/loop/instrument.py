"""A simulated family as an instrument with undeclared effects would record it.

Used to prove the residual analysis: the curves returned go into a real instrument file
(``measured.writers.write_micromag_0015``) and come back through ``measured.read_forc``.

Recorded moment of a point measured at normalized time τ (``effects.measurement_clock``) and true
field μ0H (T), for a film of saturation moment M (A·m²):

    moment = M·[a·m·(1 + d_m·τ) + χ·μ0H + d_a·τ + σ·ε],   ε ~ N(0, 1),

and the recorded field is μ0H + δ (a field offset: the magnet's field at the sample differs from the
one reported). The calibration points are written constant (the writer's default), so the drift is
one the calibration points do not see: undeclared, left for the residual analysis to find.
"""

from __future__ import annotations

import numpy as np

from ..core.streams import stream_rng
from .effects import measurement_clock


def simulated_instrument_curves(family, fields, moment_Am2: float, *, scale: float = 1.0,
                                background_chi_per_T: float = 0.0, field_offset_T: float = 0.0,
                                additive_drift: float = 0.0, multiplicative_drift: float = 0.0,
                                noise: float = 0.0, rng=None):
    """``family``: n × n grid family (rows H_r, NaN below the diagonal) of m normalized to
    saturation, on ``fields`` (T). Returns (recorded reversal fields (T), [(recorded field (T),
    moment (A·m²)) per curve]) in grid order, for ``write_micromag_0015``. ``noise`` σ is in units of
    the film's saturation moment."""
    family = np.asarray(family, dtype=float)
    fields = np.asarray(fields, dtype=float)
    rng = stream_rng(0, "instrument_noise") if rng is None else rng
    tau = measurement_clock(len(fields))
    curves = []
    for i in range(len(fields)):
        m = family[i, i:]
        t = tau[i, i:]
        h = fields[i:]
        value = (scale * m * (1 + multiplicative_drift * t) + background_chi_per_T * h + additive_drift * t
                 + noise * rng.normal(size=m.size))
        curves.append((h + field_offset_T, value * moment_Am2))
    return fields + field_offset_T, curves
