"""Predict, correct, predict again: the fixed point of (Hamiltonian, measured-side effect).

The networks read the measured family, and a measured-side effect is in it: a substrate's
paramagnetic background χ·μ0H tilts the saturated branches (normalized by them, a measured family
reaches m = 1.4 there), and a network reads that tilt as physics (a harder or softer film). The
Hamiltonian it predicts is then biased by the very effect the residual analysis is asked to find,
and the effect is fitted on top of a biased re-simulation. So once a measured-side effect is chosen,
its exact inverse (``effects.correct_measurement``) is applied to the measurement, the Hamiltonian
is predicted again from the corrected family, and the analysis is repeated, until neither moves:

    corrected_0 = measured
    params_k    = predict(corrected_k)
    result_k    = analyse_with_refit(params_k, measured)        (the ORIGINAL measurement)
    corrected_{k+1} = correct_measurement(measured, effect_k)   (measured-side effect chosen)
                    = measured                                  (otherwise)

The effect is always judged on what was measured, never on a corrected family (that would make the
chosen effect confirm itself). Fixed point: the same effect chosen twice in a row and every
parameter of the refitted Hamiltonian (refitted with the effect when one is chosen) changed by less
than ``tolerance`` (relative). At ``max_iterations`` without that, ``converged`` is False.
"""

from __future__ import annotations

from dataclasses import dataclass, fields as dataclass_fields, replace

import numpy as np

from ..core.errors import ConfigError
from ..forc.raster import fill_below_reversal, quantize
from .effects import EFFECTS, correct_measurement, measurement_clock
from .physics_effects import NULL_REALISATIONS
from .refit import analyse_with_refit


def image_of_family(family) -> np.ndarray:
    """The networks' uint8 image of a grid family (n × n, NaN below the diagonal), by the rules of
    ``forc.raster``: H < H_r filled with m(H_r, H_r), then quantized. A point left NaN on or above the
    diagonal (a correction that shifted fields out of the window) holds the nearest finite value of
    its curve, as ``resample_curves`` holds a curve's ends."""

    family = np.array(family, dtype=float, copy=True)
    n = family.shape[0]
    for i in range(n):
        row = family[i, i:]
        ok = np.isfinite(row)
        if not ok.any():
            raise ValueError(f"curve {i} of the family has no finite value")
        if not ok.all():
            index = np.arange(row.size)
            family[i, i:] = np.interp(index, index[ok], row[ok])
    return quantize(fill_below_reversal(family))


def _relative_change(new: dict, old: dict) -> dict:
    """|new − old| / max(|new|, |old|) for every numeric parameter both carry (0 where both are 0)."""
    out = {}
    for name in sorted(set(new) & set(old)):
        a, b = new[name], old[name]
        if isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, float, np.integer, np.floating)):
            continue
        if not isinstance(b, (int, float, np.integer, np.floating)):
            continue
        scale = max(abs(float(a)), abs(float(b)))
        out[name] = 0.0 if scale == 0 else abs(float(a) - float(b)) / scale
    return out


@dataclass(frozen=True)
class FixedPointSettings:
    """The iteration's own settings (``predict_correct_iterate``).

    ``max_iterations``: the most predictions made (a positive integer); ``tolerance``: the relative change
    (dimensionless, in (0, 1)) of every refitted parameter below which, with the same effect chosen twice in a
    row, the iteration has reached its fixed point; ``order``: the measurement clock of the correction (None:
    ``effects.measurement_clock``; when given, passed to the analysis too)."""

    max_iterations: int = 4
    tolerance: float = 0.02
    order: object = None


FIXED_POINT_SETTINGS = frozenset(f.name for f in dataclass_fields(FixedPointSettings))
"""The keywords of ``predict_correct_iterate`` that set a ``FixedPointSettings`` field."""

REFIT_DEFAULTS = {"names": ("K_u",), "budget": 20, "null_realisations": NULL_REALISATIONS, "noise_sigma": None}
"""The refit's settings ``predict_correct_iterate`` passes to every analysis unless told otherwise (its
realisation floor is on by default: ``physics_effects.NULL_REALISATIONS`` films)."""


def predict_correct_iterate(cfg: dict, predict, measured, fields, settings: FixedPointSettings | None = None, *,
                            progress=None, log=None, **analysis) -> dict:
    """The iteration of the module docstring.

    ``predict(family) -> params`` (SI, the simulator's dict): the Hamiltonian predicted from a grid
    family (in the loop: the networks on ``image_of_family(family)`` at the chosen M_s).
    ``measured``: the measured grid family (n × n, NaN below the diagonal, m normalized);
    ``fields``: the grid (μ0H, T). ``settings``: the iteration's own (``FixedPointSettings``; keyword
    ``analysis`` entries that name one of its fields replace it). The other ``analysis`` keywords (names,
    budget, null_realisations, noise_sigma, every_k, n_profiles, physics, physics_grids, seed, ...): those of
    ``refit.analyse_with_refit``, with the defaults ``REFIT_DEFAULTS``. ``progress``: that of the refit;
    ``log(text)``: one line per iteration. An iteration whose prediction equals the previous one
    exactly reuses its analysis (the analysis is deterministic).

    Returns the last iteration's analysis dict plus ``iterations`` (per iteration: "prediction",
    "chosen", "kind", "verdict", "effect_parameters" (those the correction used; {} without a
    measured-side effect), "refitted" (the refitted Hamiltonian: with the effect if one is chosen),
    "refit_without_effect", "change" (relative change of the refitted parameters from the previous
    iteration), "reused"), ``converged``, ``n_iterations``, ``tolerance`` and ``corrected_family``
    (the measurement with the last chosen measured-side effect removed; the measurement itself when
    none is chosen). ConfigError for bad options."""
    settings = replace(settings or FixedPointSettings(),
                       **{k: v for k, v in analysis.items() if k in FIXED_POINT_SETTINGS})
    max_iterations, tolerance, order = settings.max_iterations, settings.tolerance, settings.order
    refit = {k: analysis.get(k, v) for k, v in REFIT_DEFAULTS.items()}
    analysis = {k: v for k, v in analysis.items() if k not in FIXED_POINT_SETTINGS and k not in REFIT_DEFAULTS}
    names, null_realisations = refit["names"], refit["null_realisations"]
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)) or max_iterations < 1:
        raise ConfigError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    if isinstance(tolerance, bool) or not (isinstance(tolerance, (int, float, np.floating)) and 0 < tolerance < 1):
        raise ConfigError(f"tolerance must be a relative change in (0, 1), got {tolerance!r}")
    if isinstance(null_realisations, bool) or not isinstance(null_realisations, (int, np.integer)) \
            or null_realisations < 0:
        raise ConfigError(f"null_realisations must be a non-negative integer, got {null_realisations!r}")
    if not callable(predict):
        raise ConfigError("predict must be a callable family -> Hamiltonian (SI dict)")
    measured = np.asarray(measured, dtype=float)
    fields = np.asarray(fields, dtype=float)
    if measured.ndim != 2 or measured.shape != (fields.size, fields.size):
        raise ConfigError(f"measured family has shape {measured.shape}, the grid has {fields.size} fields")
    clock = measurement_clock(fields.size) if order is None else np.asarray(order, dtype=float)
    if order is not None:
        analysis = {**analysis, "order": clock}

    corrected = measured
    iterations, previous, result, last_params = [], None, None, None
    converged = False
    for k in range(max_iterations):
        params = dict(predict(corrected))
        reused = result is not None and params == last_params
        if not reused:
            result = analyse_with_refit(cfg, params, measured, fields, **refit, progress=progress, **analysis)
        last_params = params
        chosen, kind = result["chosen"], result["kind"]
        with_effect = result["hamiltonian"].get("refit_with_effect")
        if with_effect is not None and not with_effect.get("generalises", True):
            with_effect = None  # the joint refit misses the held-out curves: read the effect on the refit without it
        effect_parameters = {}
        if kind == "measured":
            effect_parameters = dict((with_effect or {}).get("effect_parameters") or result["parameters"])
            corrected = correct_measurement(measured, fields, clock, EFFECTS[chosen], effect_parameters)
        else:
            corrected = measured
        refitted = dict(with_effect["params"]) if (kind == "measured" and with_effect) else \
            dict(result["hamiltonian"]["refit_without_effect"])
        change = None if previous is None else _relative_change(refitted, previous["refitted"])
        record = {"iteration": k, "prediction": params, "chosen": chosen, "kind": kind,
                  "verdict": result["verdict"], "effect_parameters": effect_parameters, "refitted": refitted,
                  "refit_without_effect": dict(result["hamiltonian"]["refit_without_effect"]),
                  "change": change, "reused": bool(reused)}
        iterations.append(record)
        if log is not None:
            shown = ", ".join(f"{n} {refitted[n]:.4g}" for n in names if n in refitted)
            log(f"fixed point, iteration {k + 1}/{max_iterations}: {chosen} ({kind}) {effect_parameters}; "
                f"refitted {shown}" + ("" if change is None else f"; largest change {max(change.values(), default=0):.3f}"))
        if previous is not None and chosen == previous["chosen"] and max(change.values(), default=0.0) < tolerance:
            converged = True
            break
        previous = record
    out = dict(result)
    out.update(iterations=iterations, converged=converged, n_iterations=len(iterations), tolerance=tolerance,
               corrected_family=corrected)
    return out


__all__ = ["FIXED_POINT_SETTINGS", "REFIT_DEFAULTS", "FixedPointSettings", "image_of_family", "predict_correct_iterate"]
