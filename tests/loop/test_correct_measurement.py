"""Removing a measured-side effect from a measurement (``effects.correct_measurement``), the step a
fixed-point iteration of the loop needs: the inverse of every effect model is exact (field offsets of
whole grid rows)."""

import numpy as np

from forcdecode.loop.effects import EFFECTS, correct_measurement, measurement_clock


def test_inverse_of_every_effect_is_exact_on_whole_rows():
    n = 32
    f = np.linspace(-1, 1, n)
    sim = np.full((n, n), np.nan)
    for i in range(n):
        sim[i, i:] = 0.5 * np.tanh((f[i:] - 0.2) / 0.2) + 0.5 * np.tanh((f[i] + 0.3) / 0.3)
    tau = measurement_clock(n)
    values = {"scale": 0.9, "offset_T": 2 * (f[1] - f[0]), "chi_per_T": 0.1, "additive_drift": 0.02,
              "multiplicative_drift": 0.03}
    for name, effect in EFFECTS.items():
        theta = tuple(values[p] for p in effect.parameters)
        measured = effect.model(sim, f, tau, theta)
        back = correct_measurement(measured, f, tau, effect, dict(zip(effect.parameters, theta)))
        ok = np.isfinite(back) & np.isfinite(sim)
        if "field_offset" in effect.components:  # exact away from the window's edges (extended there)
            ok[:3] = False
            ok[:, -3:] = False
            ok[-3:] = False
        assert ok.sum() > 0.6 * np.isfinite(sim).sum(), name
        assert np.abs(back - sim)[ok].max() < 1e-12, name
