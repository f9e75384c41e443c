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

from dataclasses import dataclass, replace

import numpy as np

from ..core.streams import stream_rng
from .effects import measurement_clock


@dataclass(frozen=True)
class InstrumentEffects:
    """The undeclared effects of the module docstring's instrument (each default: none).

    ``scale``: a, the moment's calibration factor (dimensionless); ``background_chi_per_T``: χ, a background
    linear in the field (saturation moments per tesla); ``field_offset_T``: δ, the recorded field's offset (T);
    ``additive_drift``: d_a, a drift added over the run (saturation moments at τ = 1); ``multiplicative_drift``:
    d_m, a gain drift over the run (relative, at τ = 1)."""

    scale: float = 1.0
    background_chi_per_T: float = 0.0
    field_offset_T: float = 0.0
    additive_drift: float = 0.0
    multiplicative_drift: float = 0.0


def simulated_instrument_curves(family, fields, moment_Am2: float, effects: InstrumentEffects | None = None, *,
                                noise: float = 0.0, rng=None, **effect_sizes):
    """``family``: n × n grid family (rows H_r, NaN below the diagonal) of m normalized to
    saturation, on ``fields`` (T), recorded by an instrument with ``effects`` (an ``InstrumentEffects``, none
    where None; keyword ``effect_sizes`` set single ones). Returns (recorded reversal fields (T), [(recorded
    field (T), moment (A·m²)) per curve]) in grid order, for ``write_micromag_0015``. ``noise`` σ is in units of
    the film's saturation moment, drawn from ``rng`` (default: stream ``instrument_noise`` of seed 0)."""
    e = replace(effects or InstrumentEffects(), **effect_sizes)
    scale, background_chi_per_T, field_offset_T = e.scale, e.background_chi_per_T, e.field_offset_T
    additive_drift, multiplicative_drift = e.additive_drift, e.multiplicative_drift
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
