"""Physics-side effects the Hamiltonian lacks, found by re-simulation, and the whole residual analysis.

Physics-side candidates (m normalized to the film's saturation moment, fields μ0H in tesla):

- gridded effects, e.g. ``K_2`` (second-order anisotropy −K_2 (u·m)⁴, J/m³) and ``bias_field``
  (uniform field B_bias along z, T): the family re-simulated over a small grid of the effect's size;
  the size is chosen on the training curves (one parameter).
- ``second_phase``: m = (1 − f)·m_film + f·m_soft, where m_soft is the family of a second,
  non-interacting phase with the same parameters but a lower uniaxial anisotropy K_u,soft,
  re-simulated over a grid of K_u,soft; for each, the moment fraction f ∈ [0, 1] is fitted by linear
  least squares on the training curves, and K_u,soft is chosen by the training error (two parameters).
- ``field_tilt``: the applied field misaligned from the film normal by ψ (degrees), a gridded
  re-simulation with the field applied at ψ and ⟨m⟩·ĥ recorded (``forc.measured_protocol``).
- ``thermal_activation``: every coercivity reduced by the Sharrock factor 1 − ε at fixed bias
  (``forc.thermal.coercivity_scaled_family``), ε ∈ [0, 0.6] fitted on the training curves (one
  parameter, bounded scalar minimization).

After the selection the residual of the chosen model is tested for structure (``loop.structure``):
when nothing earns its place but the residual is structured, the verdict is "unexplained structured
residual", with where it lives, instead of a forced candidate. Before it, a static measured-side
candidate (scale, background, field offset) and a bias field (an offset to a saturated film) must
leave noise where the film is saturated (``signatures.saturation_residual`` on the grid, or
``saturation_residual_points`` on the measured points; its own terms refitted there); one that
leaves a residual there is refused, and when that residual was all there was to explain, the verdict
names it.

``analyse_residual`` puts these and the measured-side candidates (``effects.py``: singles and
combinations) through one held-out selection rule (``effects.choose_candidate``).

Note: a uniform bias field on the film and an offset δ of the field the instrument reports are one
observable for a film swept continuously (it feels μ0H + B_bias, resp. μ0H − δ). Simulated, they
differ only through the discrete protocol: the bias re-simulation visits other fields (avalanches
move between grid fields), the reported offset interpolates the same states. The report names the
chosen one and lists the other under ``same_observable_as``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.parallel import map_in_order
from ..core.streams import stream_rng
from ..forc.simulate import protocol_name
from ..forc.thermal import coercivity_scaled_family
from ..infer.resimulate import resimulate
from .effects import (EFFECTS, HAMILTONIAN_CHANGE, REALISATION_NOISE, SWITCHING_FIELD_DISTRIBUTION, _beats,
                      _grid_resolution, beats_null_gain, bootstrap_resamples, choose_candidate,
                      equivalent_candidates, fit_effect, heldout_folds, heldout_mse, measurement_clock,
                      separating_measurements)
from .signatures import (Z_BACKGROUND, background_agreement, background_evidence, candidate_shift, drift_agreement,
                         saturation_gated, saturation_residual,
                         saturation_residual_points, saturation_terms, shift_agreement, shifts_field)
from .structure import describe, residual_structure

PHYSICS_PARAMETERS = {"K_2": "K_2_J_per_m3", "bias_field": "B_bias_T", "field_tilt": "tilt_deg"}
"""Parameter name (with unit) of each gridded physics candidate; others are called ``value``."""

SAME_OBSERVABLE = ({"field_offset", "bias_field"},)
"""Candidates no FORC measurement can tell apart."""

NULL_BOOTSTRAPS = 100
"""Bootstrap resamples of a null film's analysis (``null_gains``): its gains are means over held-out
curves and do not depend on them; they enter only the gates, which decide nothing there."""

NULL_REALISATIONS = 10
"""Other disorder realisations of the refitted Hamiltonian whose gains make the realisation floor.
Each is also mirrored, so the floor is the largest gain over 2R effect-free films, and a candidate
that gains no more than effect-free films do beats them all with probability 1/(2R + 1) (a rank
test): with R = 2 one such candidate in five passed, with R = 10 one in 21 (< 5 %). Cost: R
re-simulations and 2R analyses (on the bench's laptop film about +10 s a case)."""

MOMENT_TOLERANCE = 0.02
"""Relative uncertainty of the moment normalization (M_s·V, or the calibration of the magnetometer)
below which a fitted ``scale`` is not named as an effect. M_s is given to the loop, and the volume of a
film (area × a thickness of a few nm) and a VSM's absolute calibration are rarely known to better than
±2 %: a gain inside that band is the normalization's own error, which no FORC measurement can tell
from an instrument effect. Declared here, not chosen on any benchmark; ``analyse_residual(moment_tolerance=)``
and ``forcdecode loop --moment-tolerance`` change it (0 names every scale that beats the floor)."""


@dataclass(frozen=True)
class CandidateGrids:
    """The grid values at which ``physics_candidate_families`` re-simulates the physics-side candidates.

    ``K_2_ratios``: r of K_2 = r·K_u (dimensionless); ``bias_fields_T``: the bias field B_bias (T);
    ``soft_K_u_ratios``: r of a soft second phase's K_u,soft = r·K_u; ``tilts_deg``: the field tilt ψ
    (degrees; quasi-static protocol only); ``K_u_changes``: c of the Hamiltonian's own neighbourhood,
    K_u × (1 + c) without any effect. An empty (or None, except ``soft_K_u_ratios``) grid offers none.
    ``hamiltonian_values``: the Hamiltonian's neighbourhood as the decode leaves it open, ((parameter,
    SI value), ...) (``decode_neighbourhood``); where given it replaces ``K_u_changes``."""

    K_2_ratios: tuple = (-0.15, 0.15, 0.3, 0.45)
    bias_fields_T: tuple = (-0.04, -0.02, 0.02, 0.04)
    soft_K_u_ratios: tuple = (0.05, 0.1, 0.2, 0.3)
    tilts_deg: tuple = (3.0, 6.0, 10.0, 15.0)
    K_u_changes: tuple = (-0.06, -0.03, 0.03, 0.06)
    hamiltonian_values: tuple = ()


NEIGHBOURHOOD_PARAMETERS = ("K_u", "D", "A_ex", "sigma_K", "sigma_theta_deg")
"""The decoded parameters the Hamiltonian's neighbourhood moves. M_s is given, not decoded. N_pin is not
moved: a change of the count redraws where the pins sit (``micromag.disorder.draw_disorder`` chooses the
cells for the count), so along it a family changes as between two disorder realisations, which the
realisation floor judges, not as the Hamiltonian's mean does. Moved, it was the best direction on dev 010
and dev 013 (a field offset, a second phase) and took the second phase's place (docs/loop.md)."""

SMALLEST_SPREAD = 1e-6
"""A disorder spread (σ_K, σ_θ in degrees) the neighbourhood moves to is kept at least this where the
decoded one is positive: a spread of exactly 0 skips its random draw and redraws the rest of the film."""


NEIGHBOURHOOD_MEASUREMENTS = {
    "K_u": "a hard-axis loop (its saturation field gives K_eff independently of the switching field)",
    "D": "asymmetric bubble expansion under an in-plane field, or Brillouin light scattering (the DMI's "
         "frequency shift)",
    "A_ex": "spin-wave spectroscopy (standing modes in FMR, or Brillouin light scattering)",
    "sigma_K": "a hard-axis loop's approach to saturation, or the angle dependence of the switching field",
    "sigma_theta_deg": "a hard-axis loop's approach to saturation, or the angle dependence of the switching field",
}
"""What measures each direction of the Hamiltonian's neighbourhood apart from the FORC family."""


def decode_neighbourhood(prediction: dict, params: dict) -> tuple:
    """The Hamiltonian's neighbourhood as this file's decode leaves it open: each parameter of
    ``NEIGHBOURHOOD_PARAMETERS`` read for this file (``read_for_this_file``) moved, alone, to the edges of
    its own 68 % and 90 % intervals for this file. A parameter the file does not carry is not moved: the
    image does not carry it because a change of it changes the family little beyond what another disorder
    realisation does, so on the single realisation the candidates are simulated on its direction is mostly
    realisation noise (on the dev files the neighbourhood's gain on effect-free films, its floor, matched or
    exceeded its gain on the file once A_ex and the spreads were in it, and it took a second phase's place;
    docs/loop.md).
    ``prediction``: the loop's prediction entries ({name: {"interval_68", "interval_90" (SI),
    "read_for_this_file"}}); ``params``: the decoded Hamiltonian (SI). Returns ((parameter, value), ...),
    values equal to the decoded one dropped, a spread kept above 0 (``SMALLEST_SPREAD``); () where the prediction carries no
    intervals (a Hamiltonian given by the user: ``CandidateGrids.K_u_changes`` then).

    Why: a physics candidate must explain more than a change of the Hamiltonian the decode does not
    exclude. A ±6 % K_u neighbourhood let a K_u decoded 31 % low (outside its own 90 % interval) or a D
    decoded 1 mJ/m² high be named K_2 on effect-free films of an independent code (dev 001, dev 020 of
    the laptop bench; docs/loop.md)."""
    values = []
    for name in NEIGHBOURHOOD_PARAMETERS:
        entry = prediction.get(name) if isinstance(prediction, dict) else None
        if (not isinstance(entry, dict) or name not in params or entry.get("interval_90") is None
                or not entry.get("read_for_this_file")):
            continue
        edges = list(entry["interval_90"]) + list(entry.get("interval_68") or [])
        for v in sorted(float(e) for e in edges if e is not None and np.isfinite(e)):
            v = float(_as_parameter(name, v)) if float(params[name]) > 0 else v
            if v != float(params[name]) and (name, v) not in values:
                values.append((name, v))
    return tuple(values)


def physics_candidate_families(cfg: dict, params: dict, grids: CandidateGrids | None = None, *, n_profiles: int = 1,
                               first_profile: int = 0, key: int | str = "measured", progress=None,
                               **grid_values) -> dict:
    """Re-simulate the physics-side candidates of ``params`` (SI, as ``resimulate``) on ``grids`` (a
    ``CandidateGrids``, its defaults where None; keyword ``grid_values`` replace single grids): K_2 = r·K_u for r in
    ``K_2_ratios``, B_bias in ``bias_fields_T``, soft phases with K_u,soft = r·K_u for r in ``soft_K_u_ratios`` and
    the field tilted by ψ in ``tilts_deg`` (quasi-static protocol only; none for "llg"). ``n_profiles`` disorder
    profiles averaged per family, from ``first_profile``. Cost: one ``resimulate`` (``n_profiles`` families) per
    grid value (16 by default). A family is sensitive to K_2 (on the 16×16 test film, K_2 = 0.25 K_u lies between
    grid families 0.2 and 0.3 K_u that each miss curves badly), so the analysis interpolates between the nodes
    (``fit_interpolated_effect``) instead of naming the nearest one. ``progress(done, total)``, if given, is called
    after each family (one more than the grids: the reference).

    Common random numbers: every family, and a reference family of ``params`` without any effect,
    is simulated on the same disorder profiles (stream keys (``key``, profile)), so a candidate
    differs from the reference by the effect alone. Pass the ``key`` of the base re-simulation the
    candidates will be judged against (``analyse_with_refit`` passes its refit's key): a candidate
    on another realisation carries that film's difference (≈ the realisation floor) on top of its
    effect, and an effect smaller than that floor could never be found by it.

    ``K_u_changes``: the Hamiltonian's own neighbourhood, K_u × (1 + c) without any effect
    (``hamiltonian_families``): a physics candidate must explain more than a further change of K_u
    does (``analyse_residual``). ``hamiltonian_values`` (``decode_neighbourhood``), where given, replace
    it: one family per (parameter, value), the rest of the Hamiltonian as decoded.

    Returns {"physics_families": {"K_2": {K_2: family}, "bias_field": {B: family}},
    "soft_phase_families": {K_u_soft: family}, "hamiltonian_families": {c: family} (K_u's fractional
    changes) or, with ``hamiltonian_values``, {parameter: {value − decoded value (SI): family}},
    "physics_reference_family": family without an effect}, ready for ``analyse_residual(..., **this)``."""
    g = replace(grids or CandidateGrids(), **grid_values)
    K_2_ratios, bias_fields_T, soft_K_u_ratios = g.K_2_ratios, g.bias_fields_T, g.soft_K_u_ratios
    K_u_changes = g.K_u_changes
    tilts_deg = g.tilts_deg if protocol_name(cfg) == "quasistatic" else ()
    K_u = float(params["K_u"])
    # every family to simulate, in the order they were always made: (group, size, the parameters it changes)
    plan = [("K_2", r * K_u, {"K_2": r * K_u}) for r in (K_2_ratios or ())]
    plan += [("bias_field", float(b), {"B_bias_T": float(b)}) for b in (bias_fields_T or ())]
    plan += [("field_tilt", float(t), {"field_tilt_deg": float(t)}) for t in (tilts_deg or ())]
    plan += [("soft", r * K_u, {"K_u": r * K_u}) for r in soft_K_u_ratios]
    if g.hamiltonian_values:
        plan += [("directions", (name, float(v) - float(params[name])), {name: _as_parameter(name, v)})
                 for name, v in g.hamiltonian_values]
    else:
        plan += [("neighbourhood", float(c), {"K_u": (1 + c) * K_u}) for c in (K_u_changes or ())]
    plan += [("reference", None, {})]
    families = map_in_order(_candidate_family, [(cfg, {**params, **extra}, n_profiles, first_profile, key)
                                                for _, _, extra in plan], progress=progress)
    groups: dict = {}
    for (group, size, _), family in zip(plan, families):
        groups.setdefault(group, {})[size] = family
    physics = {name: groups[name] for name in ("K_2", "bias_field", "field_tilt") if name in groups}
    neighbourhood = groups.get("neighbourhood", {})
    if "directions" in groups:  # {parameter: {change (SI): family}}
        neighbourhood = {}
        for (name, change), family in groups["directions"].items():
            neighbourhood.setdefault(name, {})[change] = family
    return {"physics_families": physics, "soft_phase_families": groups.get("soft", {}),
            "hamiltonian_families": neighbourhood, "physics_reference_family": groups["reference"][None]}


def _as_parameter(name: str, value: float):
    """A neighbourhood value as the Hamiltonian holds it (N_pin: a count; a spread kept above 0,
    ``SMALLEST_SPREAD``, so that the film's random draws stay those of the decoded film)."""
    if name == "N_pin":
        return int(round(value))
    if name in ("sigma_K", "sigma_theta_deg"):
        return max(float(value), SMALLEST_SPREAD)
    return float(value)


def _candidate_family(cfg: dict, params: dict, n_profiles: int, first_profile: int, key) -> np.ndarray:
    """One candidate's family (``resimulate`` of ``params``): a module-level worker of ``map_in_order``."""
    return resimulate(cfg, params, n_profiles=n_profiles, first_profile=first_profile, key=key)


def fit_interpolated_effect(measured, families: dict, base_family, train) -> dict:
    """A gridded physics effect as a continuous one-parameter family: the nodes are the grid sizes
    and size 0 (``base_family``, the model without the effect), the family between two neighbouring
    nodes s_a < s < s_b is interpolated linearly, (1 − w)·F_a + w·F_b. On each interval w ∈ [0, 1]
    minimizes the training objective of the selection (mean over ``train`` curves of each curve's
    mean-square misfit: a weighted linear least squares, closed form); the best interval wins.

    Why: an effect whose size lies between grid nodes (e.g. K_2 = −0.1 K_u on a grid −0.15, 0.15, …)
    was judged by the nearest node only, which can miss curves badly, while a continuous
    competitor (the Sharrock factor) could fit it better and be named instead.

    Returns {"value", "uncertainty" (1σ: the larger of the ordinary and the curve-clustered error of
    w times the interval width, combined with the interpolation's width/√12), "model",
    "at_grid_edge", "objective" (the training objective reached)}."""
    measured = np.asarray(measured, float)
    nodes = {float(v): np.asarray(f, float) for v, f in families.items()}
    nodes.setdefault(0.0, np.asarray(base_family, float))
    values = sorted(nodes)
    rows = np.zeros(measured.shape, dtype=bool)
    rows[list(train)] = True
    best = None
    for a, b in zip(values[:-1], values[1:]):
        x = nodes[b] - nodes[a]
        r = measured - nodes[a]
        ok = rows & np.isfinite(x) & np.isfinite(r)
        counts = ok.sum(axis=1)
        weight = np.where(ok, 1.0 / np.maximum(counts, 1)[:, None], 0.0)  # every curve weighs the same
        xs, rs = np.where(ok, x, 0.0), np.where(ok, r, 0.0)
        sxx = float((weight * xs**2).sum())
        w = float(np.clip((weight * xs * rs).sum() / sxx, 0.0, 1.0)) if sxx > 0 else 0.0
        e = rs - w * xs
        n_curves = max(int((counts > 0).sum()), 1)
        objective = float((weight * e**2).sum() / n_curves)
        if best is None or objective < best[0]:
            per_curve = (weight * xs * e).sum(axis=1)
            clustered = np.sqrt((per_curve**2).sum()) / sxx if sxx > 0 else np.nan
            sigma2 = float((e**2).sum()) / max(int(ok.sum()) - 1, 1)  # point misfit variance
            ordinary = np.sqrt(sigma2 * float(((weight * xs) ** 2).sum())) / sxx if sxx > 0 else np.nan
            statistical = float(np.nanmax([clustered, ordinary])) * (b - a)
            # the interpolation's own error: the size is known to within its interval, not better than
            # a uniform distribution over it allows (a quadratic dependence errs by up to a quarter of it)
            best = (objective, a, b, w, float(np.hypot(statistical, (b - a) / np.sqrt(12.0))), nodes[a] + w * x)
    objective, a, b, w, error, model = best
    value = a + w * (b - a)
    return {"value": float(value), "uncertainty": float(error), "model": model,
            "at_grid_edge": bool(value <= values[0] or value >= values[-1]), "objective": objective}


def fit_second_phase(measured, film_family, soft_families: dict, train) -> dict:
    """m = (1 − f)·m_film + f·m_soft fitted on the ``train`` curves for every K_u,soft in
    ``soft_families``; the best by training error. Returns {"K_u_soft_J_per_m3", "fraction",
    "uncertainties", "model"}; the error of f is the larger of the ordinary and the curve-clustered
    one, that of K_u,soft half the grid spacing."""
    measured = np.asarray(measured, float)
    film_family = np.asarray(film_family, float)
    rows = np.zeros(measured.shape, dtype=bool)
    rows[train] = True
    best = None
    for K_soft, soft in soft_families.items():
        x = np.asarray(soft, float) - film_family
        r = measured - film_family
        ok = rows & np.isfinite(x) & np.isfinite(r)
        sxx = float((x[ok] ** 2).sum())
        f = float(np.clip((x[ok] * r[ok]).sum() / sxx, 0.0, 1.0)) if sxx > 0 else 0.0
        e = r - f * x
        mse = float((e[ok] ** 2).mean())
        if best is None or mse < best[0]:
            curve = np.nonzero(ok)[0]
            per_curve = np.bincount(curve, weights=(x * e)[ok], minlength=measured.shape[0])
            clustered = np.sqrt((per_curve**2).sum()) / sxx if sxx > 0 else np.nan
            ordinary = np.sqrt(mse / sxx) if sxx > 0 else np.nan
            best = (mse, K_soft, f, max(clustered, ordinary), film_family + f * x)
    _, K_soft, f, f_error, model = best
    return {"K_u_soft_J_per_m3": float(K_soft), "fraction": f,
            "uncertainties": {"K_u_soft_J_per_m3": float(_grid_resolution(list(soft_families), K_soft)),
                              "fraction": float(f_error)},
            "model": model}


def fit_thermal(measured, base_family, fields, train, bounds=(0.0, 0.6)):
    """Sharrock reduction ε of every coercivity (``forc.thermal.coercivity_scaled_family``) fitted on the
    ``train`` curves: a grid over ``bounds`` in steps of 0.05, then a bounded scalar minimization
    around the best node. Returns (ε, its standard error from the curvature of the training
    sum of squares, model family)."""
    from scipy.optimize import minimize_scalar


    measured = np.asarray(measured, float)
    rows = np.zeros(measured.shape, dtype=bool)
    rows[train] = True

    def sse(epsilon):
        model = coercivity_scaled_family(base_family, fields, epsilon)
        ok = rows & np.isfinite(model) & np.isfinite(measured)
        return float(((model[ok] - measured[ok]) ** 2).sum()), int(ok.sum())

    nodes = np.arange(bounds[0], bounds[1] + 1e-9, 0.05)
    values = [sse(e)[0] for e in nodes]
    k = int(np.argmin(values))
    lo, hi = nodes[max(k - 1, 0)], nodes[min(k + 1, len(nodes) - 1)]
    best = minimize_scalar(lambda e: sse(e)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    epsilon = float(best.x) if best.fun <= values[k] else float(nodes[k])
    value, count = sse(epsilon)
    h = 0.01
    curvature = (sse(min(epsilon + h, bounds[1] + h))[0] - 2 * value + sse(max(epsilon - h, 0.0))[0]) / h**2
    sigma2 = value / max(count - 1, 1)
    error = float(np.sqrt(2 * sigma2 / curvature)) if curvature > 0 else float("nan")
    return epsilon, error, coercivity_scaled_family(base_family, fields, epsilon)


def null_gains(pseudo_measurements, base_family, fields, mirror: bool = True, noise_sigma: float | None = None,
               seed: int = 0, hamiltonian_floor: bool = False, **analysis) -> dict:
    """The largest held-out gains (relative and in mean-square error) of every candidate over
    ``pseudo_measurements``: families of the base model's own Hamiltonian on other disorder
    realisations (no effect in them), analysed against ``base_family`` with the same candidates and
    split (``analysis``: the keyword arguments of ``analyse_residual``). With ``mirror`` each
    deviation is also taken with the opposite sign (2·base − pseudo): to first order a realisation
    is as likely to deviate one way as the other, and a one-sided candidate (a coercivity that can
    only shrink) must not pass because the few realisations drawn happened to deviate the other way.
    ``noise_sigma`` (m units): the measurement's noise, added to every pseudo-measurement (stream
    ``null_noise`` of ``seed``); without it two near-identical realisations leave a residual of almost
    nothing, and a relative gain over it means nothing. Returns {candidate: {"relative": largest 1 − MSE_c/MSE_none, "mse": largest MSE_none − MSE_c}}.

    ``hamiltonian_floor``: where ``analysis`` gives ``hamiltonian_families``, also the gain of K_u moved
    along them (the neighbourhood of ``analyse_residual``), under ``effects.HAMILTONIAN_CHANGE``: what a
    change of the Hamiltonian alone gains on films that need none (``refit.refit_ambiguity``'s floor
    for the refit's own change). Off: the neighbourhood is not fitted (it gates nothing here)."""
    base_family = np.asarray(base_family, float)
    pseudo = [np.asarray(p, float) for p in pseudo_measurements]
    if mirror:
        pseudo = pseudo + [2 * base_family - p for p in pseudo]
    if noise_sigma:
        rng = stream_rng(seed, "null_noise", "null_gains")
        pseudo = [p + float(noise_sigma) * rng.normal(size=p.shape) for p in pseudo]
    # only the gains are kept: the gates (K_u neighbourhood, normalization) decide nothing here, so the
    # candidates are fitted and scored (``gated_candidates``) without the selection, the structure test
    # and the ambiguity stages, and with few bootstrap resamples (they enter only the gates' booleans)
    analysis = {**analysis, "moment_tolerance": 0.0, "saturation_gate": False, "saturation_points": None,
                "n_boot": NULL_BOOTSTRAPS}
    if not hamiltonian_floor:
        analysis["hamiltonian_families"] = None
    analysis = {k: v for k, v in analysis.items() if k in GATED_OPTIONS}
    gains: dict = {}
    for family in pseudo:
        g = gated_candidates(family, base_family, fields, seed=seed, **analysis)
        none_mse = float(np.nanmean(g.fits.mse["none"]))
        found = {name: {"relative": record["relative_gain"], "mse": record["gain_mse_mean"], "none_mse": none_mse}
                 for name, record in g.fits.records.items()}
        if g.baselines.hamiltonian is not None:
            knob = g.baselines.hamiltonian["heldout_rms"] ** 2
            found[HAMILTONIAN_CHANGE] = {"relative": 1 - knob / none_mse if none_mse > 0 else 0.0,
                                         "mse": none_mse - knob}
        gains = merge_null_gains(gains, found)
    return gains


def merge_null_gains(a: dict, b: dict) -> dict:
    """Per candidate, the larger of two null gains (relative and mean-square, each on its own; and the
    larger held-out mean-square residual of "none" on the null films, ``none_mse``, where recorded)."""
    out = dict(a)
    for name, g in b.items():
        old = out.get(name, {"relative": -np.inf, "mse": -np.inf})
        merged = {"relative": max(old["relative"], g["relative"]), "mse": max(old["mse"], g["mse"])}
        if "none_mse" in g or "none_mse" in old:
            merged["none_mse"] = max(old.get("none_mse", -np.inf), g.get("none_mse", -np.inf))
        out[name] = merged
    return out


def _reduction_ci(before, after, rng, n_boot):
    """1 − RMS_after/RMS_before over held-out curves, and its paired-bootstrap 90 % interval."""
    both = np.isfinite(before) & np.isfinite(after)
    before, after = before[both], after[both]
    if before.size == 0 or before.sum() == 0:
        return float("nan"), [float("nan"), float("nan")]
    pick = bootstrap_resamples(rng, n_boot, before.size)
    boots = 1 - np.sqrt(after[pick].sum(axis=1) / np.maximum(before[pick].sum(axis=1), 1e-300))
    return float(1 - np.sqrt(after.sum() / before.sum())), [float(np.quantile(boots, 0.05)),
                                                               float(np.quantile(boots, 0.95))]


def _rms_per_curve(residual):
    counts = np.isfinite(residual).sum(axis=1)
    sums = np.nansum(residual**2, axis=1)
    return [float(np.sqrt(s / c)) if c else None for s, c in zip(sums, counts)]


@dataclass
class ResidualProblem:
    """What every stage of ``analyse_residual`` reads: the measured and re-simulated families on the grid
    ``fields``, the measurement clock ``order``, the held-out ``folds`` and ``everything`` (all curves
    that are fitted)."""

    measured: np.ndarray
    base_family: np.ndarray
    fields: np.ndarray
    order: np.ndarray
    folds: list
    everything: list


@dataclass
class CandidateLibrary:
    """Each candidate: name → (kind, number of fitted parameters, fit(rows) → (model, parameters,
    uncertainties)); ``at_edge``: filled by the physics fits (whether the fitted size lies at the edge of
    its grid); the physics candidates' names, the soft phase's grid and the Hamiltonian's neighbourhood
    (on the base model when the physics families came with their own reference)."""

    fits: dict
    at_edge: dict
    physics_names: list
    soft_phase_families: dict | None
    hamiltonian_families: dict


@dataclass
class CandidateFits:
    """Per candidate: held-out MSE per curve (``mse``), its model fitted on all curves (``models``) and
    its record (kind, parameters, uncertainties, gains, gate outcomes)."""

    mse: dict
    records: dict
    models: dict


@dataclass
class Baselines:
    """What a candidate must also beat: the base model with its normalization free inside the moment
    tolerance (``nuisance_mse``), K_u moved along its neighbourhood (``knob_mse``, summarized in
    ``hamiltonian``)."""

    nuisance_mse: np.ndarray | None
    knob_mse: np.ndarray | None
    hamiltonian: dict | None


@dataclass
class GateSettings:
    """The gates' settings (see ``analyse_residual``)."""

    seed: int
    n_boot: int
    min_relative_gain: float
    equivalence: float
    null_gain: dict | None
    null_margin: float
    field_shift: dict | None
    drift: dict | None
    moment_tolerance: float
    evidence_suffices: bool
    saturation_gate: bool
    saturation_points: object


@dataclass
class Offered:
    """The candidates that passed the gates (name → held-out MSE per curve) and those whose model-free
    evidence spares them the bootstrap bound (``choose_candidate(evidenced=)``)."""

    mse: dict
    evidenced: set
    floored: dict = field(default_factory=dict)
    decisive: set = field(default_factory=set)


@dataclass
class Choice:
    """The chosen candidate, every candidate's record with its scores, and the held-out reduction."""

    chosen: str
    candidates: dict
    reduction: float
    reduction_ci: list


@dataclass
class Verdict:
    """The verdict on the chosen model's residual: its structure, the saturation test, the verdict."""

    verdict: str
    verdict_text: str
    structure: dict
    saturation: dict | None
    ambiguous: list = field(default_factory=list)
    separating_measurements: dict = field(default_factory=dict)


def residual_problem(measured, base_family, fields, order, every_k: int, cross_fit: bool) -> ResidualProblem:
    """The families as float arrays, the clock (default ``measurement_clock``) and the held-out folds."""
    measured = np.asarray(measured, dtype=float)
    base_family = np.asarray(base_family, dtype=float)
    fields = np.asarray(fields, dtype=float)
    n = measured.shape[0]
    order = measurement_clock(n) if order is None else np.asarray(order, dtype=float)
    folds = heldout_folds(measured, every_k, cross_fit)
    everything = sorted(i for fold in folds[:1] for part in fold for i in part)
    return ResidualProblem(measured, base_family, fields, order, folds, everything)


def candidate_library(p: ResidualProblem, *, physics_families, soft_phase_families, measured_candidates,
                      thermal: bool, physics_reference_family, hamiltonian_families) -> CandidateLibrary:
    """Every candidate and its fit: "none", the measured-side effects, the gridded physics effects, the
    second phase and thermal activation."""
    measured, base_family, fields, order = p.measured, p.base_family, p.fields, p.order
    hamiltonian_families = neighbourhood_directions(hamiltonian_families)
    # each candidate: kind, number of fitted parameters, fit(rows) -> (model, parameters, uncertainties)
    candidates = {}
    for name in ["none"] + [k for k in (measured_candidates or EFFECTS) if k != "none"]:
        def fit(rows, effect=EFFECTS[name]):
            theta, errors = fit_effect(effect, measured, base_family, fields, order, rows)
            return (effect.model(base_family, fields, order, theta), dict(zip(effect.parameters, map(float, theta))),
                    dict(zip(effect.parameters, map(float, errors))))
        candidates[name] = ("measured" if name != "none" else "none", len(EFFECTS[name].parameters), fit)
    if physics_reference_family is not None:
        # each gridded effect as the change it makes on its own realisation, put on the base model
        reference = np.asarray(physics_reference_family, float)
        physics_families = {name: {v: base_family + (np.asarray(f, float) - reference) for v, f in families.items()}
                            for name, families in (physics_families or {}).items()}
        hamiltonian_families = {name: {v: base_family + (f - reference) for v, f in nodes.items()}
                                for name, nodes in hamiltonian_families.items()}
    at_edge = {}
    for name, families in (physics_families or {}).items():
        def fit(rows, name=name, families=families, parameter=PHYSICS_PARAMETERS.get(name, "value")):
            result = fit_interpolated_effect(measured, families, base_family, rows)
            at_edge[name] = result["at_grid_edge"]
            return result["model"], {parameter: result["value"]}, {parameter: result["uncertainty"]}
        candidates[name] = ("physics", 1, fit)
    if soft_phase_families:
        def fit(rows):
            result = fit_second_phase(measured, base_family, soft_phase_families, rows)
            model, uncertainties = result.pop("model"), result.pop("uncertainties")
            return model, result, uncertainties
        candidates["second_phase"] = ("physics", 2, fit)
    if thermal:
        def fit(rows):
            epsilon, error, model = fit_thermal(measured, base_family, fields, rows)
            return model, {"epsilon": epsilon}, {"epsilon": error}
        candidates["thermal_activation"] = ("physics", 1, fit)
    return CandidateLibrary(candidates, at_edge, list(physics_families or {}), soft_phase_families,
                            hamiltonian_families)


def fit_candidates(p: ResidualProblem, library: CandidateLibrary) -> CandidateFits:
    """Each candidate's held-out MSE per curve and its fit on all curves."""
    mse, records, models = {}, {}, {}
    for name, (kind, n_parameters, fit) in library.fits.items():
        mse[name] = heldout_mse(p.measured, lambda rows, fit=fit: fit(rows)[0], p.folds)
        models[name], parameters, uncertainties = fit(p.everything)
        records[name] = {"kind": kind, "n_parameters": n_parameters, "parameters": parameters,
                         "uncertainties": uncertainties}
    for name in library.physics_names:
        records[name]["at_grid_edge"] = library.at_edge[name]  # of the fit on all curves, the last one made
    soft_phase_families = library.soft_phase_families
    if soft_phase_families:
        records["second_phase"]["at_grid_edge"] = bool(records["second_phase"]["parameters"]["K_u_soft_J_per_m3"]
                                                       in (min(soft_phase_families), max(soft_phase_families)))
    return CandidateFits(mse, records, models)


def _normalization_fit(p: ResidualProblem, rows, moment_tolerance: float) -> float:
    """The base model with its moment normalization free inside the tolerance: a·m_sim, a fitted
    by least squares on ``rows`` and clipped to 1 ± ``moment_tolerance``."""
    measured, base_family = p.measured, p.base_family
    mask = np.zeros(measured.shape, dtype=bool)
    mask[list(rows)] = True
    ok = mask & np.isfinite(measured) & np.isfinite(base_family)
    sxx = float((base_family[ok] ** 2).sum())
    a = float((base_family[ok] * measured[ok]).sum() / sxx) if sxx > 0 else 1.0
    return float(np.clip(a, 1 - moment_tolerance, 1 + moment_tolerance))


LEGACY_DIRECTION = "K_u (fraction)"
"""The direction a flat neighbourhood {c: family} (K_u × (1 + c), ``CandidateGrids.K_u_changes``) is held under."""


def neighbourhood_directions(hamiltonian_families) -> dict:
    """The Hamiltonian's neighbourhood as {direction: {change: family}}: the nested form of
    ``physics_candidate_families`` (direction = parameter, change in SI), or a flat {c: family} of K_u's
    fractional changes held under ``LEGACY_DIRECTION``. Empty where none is given."""
    if not hamiltonian_families:
        return {}
    if all(isinstance(v, dict) for v in hamiltonian_families.values()):
        return {name: {float(c): np.asarray(f, float) for c, f in nodes.items()}
                for name, nodes in hamiltonian_families.items() if nodes}
    return {LEGACY_DIRECTION: {float(c): np.asarray(f, float) for c, f in hamiltonian_families.items()}}


def fit_neighbourhood(measured, directions: dict, base_family, rows) -> dict:
    """The Hamiltonian moved along the one direction of its neighbourhood (``neighbourhood_directions``)
    that fits the ``rows`` best: each direction a continuous one-parameter family
    (``fit_interpolated_effect``, the base at change 0), the direction with the lowest training objective
    (its ``objective``: mean over the rows of each curve's mean-square misfit) kept. One fitted size and one
    choice among the directions: held out, it is scored as any candidate. Returns
    ``fit_interpolated_effect``'s dict with ``direction`` added."""
    fits = {name: fit_interpolated_effect(measured, nodes, base_family, rows) for name, nodes in directions.items()}
    name = min(fits, key=lambda k: fits[k]["objective"])
    return {**fits[name], "direction": name}


def baselines(p: ResidualProblem, hamiltonian_families: dict, moment_tolerance: float) -> Baselines:
    """The held-out MSE of the free normalization and of the Hamiltonian's neighbourhood (where given:
    ``fit_neighbourhood``, its direction chosen on each fold's training curves)."""
    measured, base_family = p.measured, p.base_family
    nuisance_mse = (heldout_mse(measured, lambda rows: _normalization_fit(p, rows, moment_tolerance) * base_family,
                                p.folds)
                    if moment_tolerance > 0 else None)
    knob_mse, hamiltonian = None, None
    directions = neighbourhood_directions(hamiltonian_families)
    if directions:
        def knob(rows):
            return fit_neighbourhood(measured, directions, base_family, rows)
        knob_mse = heldout_mse(measured, lambda rows: knob(rows)["model"], p.folds)
        fitted = knob(p.everything)
        heldout_rms = float(np.sqrt(np.nanmean(knob_mse)))
        if fitted["direction"] == LEGACY_DIRECTION:
            hamiltonian = {"K_u_change": fitted["value"], "K_u_change_uncertainty": fitted["uncertainty"],
                           "heldout_rms": heldout_rms}
        else:
            hamiltonian = {"parameter": fitted["direction"], "change": fitted["value"],
                           "change_uncertainty": fitted["uncertainty"], "at_interval_edge": fitted["at_grid_edge"],
                           "directions": sorted(directions), "heldout_rms": heldout_rms}
    return Baselines(nuisance_mse, knob_mse, hamiltonian)


def _background_from_saturation(p: ResidualProblem, fits: CandidateFits, evidence: dict) -> None:
    """The "background" candidate with its gain and χ read off the saturated film
    (``signatures.background_evidence``: the background's form fitted on the saturated points) instead of
    fitted on the family: model a·m_sim + χ·μ0H, its held-out MSE per curve (nothing fitted on the
    curves, so every fold's model is the same), parameters and 1σ (χ's from the two sides' lines)."""
    chi, scale, se = float(evidence["model_chi_per_T"]), float(evidence["model_scale"]), float(evidence["se_per_T"])
    model = scale * p.base_family + chi * p.fields[None, :]
    fits.mse["background"] = heldout_mse(p.measured, lambda rows: model, p.folds)
    fits.models["background"] = model
    fits.records["background"].update(parameters={"scale": scale, "chi_per_T": chi},
                                      uncertainties={"scale": None, "chi_per_T": se},
                                      chi_source="the saturated film (signatures.background_evidence)")


def gate_candidates(p: ResidualProblem, fits: CandidateFits, base: Baselines, g: GateSettings) -> Offered:
    """Record each candidate's gain and offer it to the selection only past the gates: the moment
    tolerance, the saturation test, the model-free shift and drift evidence, the free normalization,
    K_u's neighbourhood and the realisation floor (see ``analyse_residual``)."""
    measured, base_family, fields = p.measured, p.base_family, p.fields
    mse, records, models = fits.mse, fits.records, fits.models
    nuisance_mse, knob_mse = base.nuisance_mse, base.knob_mse
    null_gain, null_margin, moment_tolerance = g.null_gain, g.null_margin, g.moment_tolerance
    field_shift, drift, saturation_points = g.field_shift, g.drift, g.saturation_points
    n_boot, min_relative_gain, equivalence = g.n_boot, g.min_relative_gain, g.equivalence
    saturation_gate, evidence_suffices = g.saturation_gate, g.evidence_suffices
    gate_rng = stream_rng(g.seed, "bootstrap", "hamiltonian_gate")

    background = (background_evidence(saturation_points, moment_tolerance=moment_tolerance)
                  if saturation_gate and saturation_points is not None else None)
    # the slope the saturated film shows by itself: the background's χ read there, not fitted on the switching
    # curves (where the decoded Hamiltonian's misfit pulls it, even to the other sign)
    saturated_background = bool(background is not None and background.get("significant") and evidence_suffices
                                and "background" in records)
    if saturated_background:
        _background_from_saturation(p, fits, background)
    none_mse = float(np.nanmean(mse["none"]))
    offered = dict(mse)
    evidenced = set()  # shown by the model-free shift or drift test: ``choose_candidate(evidenced=)``
    decisive = set()  # shown where the effect lives (a background's slope in saturation): ``choose_candidate(decisive=)``
    floored = {}  # passed every gate but the realisation floor
    for name in records:
        gain_mse = none_mse - float(np.nanmean(mse[name]))
        records[name]["gain_mse_mean"] = gain_mse
        records[name]["relative_gain"] = gain_mse / none_mse if none_mse > 0 else 0.0
        records[name]["heldout_mse_per_curve"] = [None if not np.isfinite(v) else float(v) for v in mse[name]]
        if name == "none":
            continue
        if null_gain is not None:
            # recorded for every candidate (the gates below may spare one the floor)
            null = null_gain.get(name, {"relative": 0.0, "mse": 0.0})
            records[name]["null_gain"] = dict(null)
            records[name]["beats_null"] = beats_null_gain(records[name]["relative_gain"], gain_mse, none_mse, null,
                                                          null_margin)
        if name in EFFECTS and "scale" in EFFECTS[name].components:
            scale = records[name]["parameters"].get("scale", 1.0)
            records[name]["within_moment_tolerance"] = bool(abs(scale - 1.0) <= moment_tolerance)
            if records[name]["within_moment_tolerance"]:
                offered.pop(name, None)  # the normalization's own error, not an instrument effect
                continue
        if saturation_gate and saturation_gated(name, records[name]["kind"]):
            # a time-independent map of (H, m) must leave noise where the film is saturated: a reversible
            # residual there (a paramagnet, a non-linear background) is not what it models; a bias field
            # moves the saturated film as an offset does
            if saturation_points is not None:
                shift = candidate_shift(records[name]["parameters"])
                check = saturation_residual_points(saturation_points, offset_T=shift[0] if shift else 0.0,
                                                   moment_tolerance=moment_tolerance, free=saturation_terms(name))
            else:
                check = saturation_residual(measured, models[name], base_family, fields,
                                            moment_tolerance=moment_tolerance, free=saturation_terms(name))
            records[name]["saturation_evidence"] = check
            if check["reversible"]:
                offered.pop(name, None)
                continue
        if name == "background" and saturated_background:
            # judged on the held-out curves only for not making them worse; no realisation floor, no further gate
            records[name]["background_evidence"] = {**background, "agrees": True}
            evidenced.add(name)
            decisive.add(name)
            continue
        background_ok = background_agreement(background, name, records[name]["parameters"])
        if background_ok is not None:
            records[name]["background_evidence"] = {**background, "agrees": background_ok}
            if not background_ok:
                # the saturated film shows no such slope: a fitted background would carry the difference
                # between the model's film and the sample, not a susceptibility
                offered.pop(name, None)
                continue
        shift_checked = field_shift is not None and shifts_field(name) and field_shift.get("offset_T") is not None
        if shift_checked:
            check = shift_agreement(field_shift, records[name]["parameters"], records[name]["uncertainties"],
                                    resolution_T=float(abs(fields[1] - fields[0])) / np.sqrt(12.0))
            records[name]["shift_evidence"] = check
            # a shift combined with a drift needs the drift's evidence too: each component its own
            drift_ok = drift_agreement(drift, name) if drift is not None else None
            if drift_ok is not None:
                records[name]["drift_evidence"] = drift_ok
            if not (field_shift["significant"] and check["agrees"]) or drift_ok is False:
                # the loop's own symmetry shows no shift, or not this one (or the saturated ends show no
                # such drift): a fitted shift would cover the difference between the model's film and
                # the sample, not an effect
                offered.pop(name)
            elif evidence_suffices:
                evidenced.add(name)
            continue  # a shift the data show by themselves: no realisation floor, no further gate
        drift_ok = drift_agreement(drift, name) if drift is not None else None
        if drift_ok is not None:
            records[name]["drift_evidence"] = drift_ok
            if not drift_ok:
                offered.pop(name, None)  # the saturated end points do not drift that way
            elif evidence_suffices:
                evidenced.add(name)
            continue
        if nuisance_mse is not None and records[name]["kind"] == "measured" and "scale" in records[name]["parameters"]:
            # a candidate with its own scale must also beat the base whose normalization is free inside
            # the tolerance (else its other terms only carry a normalization error, e.g. a background
            # of χ = 3e-4 /T beside a 0.45 % gain)
            records[name]["beats_normalization"] = bool(_beats(mse[name], nuisance_mse, gate_rng, n_boot,
                                                               min_relative_gain, equivalence))
            if not records[name]["beats_normalization"]:
                offered.pop(name, None)
                continue
        if knob_mse is not None and (records[name]["kind"] == "physics" or shifts_field(name)):
            # switching fields move with K_u too: beat K_u moved along its neighbourhood
            records[name]["beats_hamiltonian"] = bool(_beats(mse[name], knob_mse, gate_rng, n_boot, min_relative_gain,
                                                             equivalence))
            if not records[name]["beats_hamiltonian"]:
                offered.pop(name, None)
                continue
        if null_gain is not None and not records[name]["beats_null"]:
            withheld = offered.pop(name)  # withheld by the realisation floor
            if records[name]["relative_gain"] >= records[name]["null_gain"]["relative"]:
                floored[name] = withheld  # and gaining as much as effect-free films give it: ambiguous, not none
    return Offered(offered, evidenced, floored, decisive)


def choose(p: ResidualProblem, fits: CandidateFits, offered: Offered, seed: int, n_boot: int,
           min_relative_gain: float, equivalence: float) -> Choice:
    """The candidate chosen on held-out curves among those offered (``effects.choose_candidate``), every
    candidate's scores, and the held-out reduction of the chosen one with its bootstrap interval."""
    mse, records = fits.mse, fits.records
    rng = stream_rng(seed, "bootstrap", "analyse_residual")
    chosen, scores = choose_candidate(offered.mse, {k: v["n_parameters"] for k, v in records.items()}, rng,
                                      n_boot, min_relative_gain, equivalence, evidenced=offered.evidenced,
                                      decisive=offered.decisive)
    for name in set(records) - set(offered.mse):
        scores[name] = {"heldout_rms": float(np.sqrt(np.nanmean(mse[name]))), "gain_mse": None, "gain_ci90": None,
                        "relative_gain_ci90": None, "accepted": False}
    candidates = {k: {**records[k], **scores[k]} for k in records}
    reduction, reduction_ci = _reduction_ci(mse["none"], mse[chosen], rng, n_boot)
    return Choice(chosen, candidates, reduction, reduction_ci)


def judge(p: ResidualProblem, fits: CandidateFits, chosen: str, o: "ResidualOptions") -> Verdict:
    """The structure test of the chosen model's residual (``loop.structure``) and the saturation test:
    the chosen effect, "none", or "unexplained structured residual" (and where it lives). Reads the
    options' ``noise_sigma``, ``floor_variance``, ``n_profiles``, ``measured_patches``, ``null_structure``
    (the structure test) and ``saturation_gate``, ``saturation_points``, ``moment_tolerance`` (the
    saturation test)."""
    noise_sigma, floor_variance, n_profiles = o.noise_sigma, o.floor_variance, o.n_profiles
    saturation_gate, saturation_points, moment_tolerance = o.saturation_gate, o.saturation_points, o.moment_tolerance
    measured_patches, null_structure = o.measured_patches, o.null_structure

    measured, base_family, fields = p.measured, p.base_family, p.fields
    records, models = fits.records, fits.models
    residual_after = measured - models[chosen]
    structure = residual_structure(residual_after, fields, noise_sigma, floor_variance, n_profiles,
                                   measured_patches=measured_patches, null_structure=null_structure)
    saturation = None
    if saturation_gate:
        saturation = (saturation_residual_points(saturation_points, moment_tolerance=moment_tolerance)
                      if saturation_points is not None else
                      saturation_residual(measured, models["none"], base_family, fields,
                                          moment_tolerance=moment_tolerance))
    rejected_in_saturation = sorted(k for k, v in records.items() if v.get("saturation_evidence", {}).get("reversible"))
    if chosen == "none" and saturation is not None and saturation.get("reversible") and rejected_in_saturation:
        verdict = "unexplained structured residual"
        verdict_text = (f"unexplained structured residual: a reversible residual where the film is saturated "
                        f"(column means up to {saturation['max_abs_mean']:.3g} at {min(saturation['fields_T']):.2f}…"
                        f"{max(saturation['fields_T']):.2f} T, χ² {saturation['chi2']:.0f} on {saturation['dof']} dof) that "
                        f"{', '.join(rejected_in_saturation)} do not remove: something outside the library "
                        "(a field-only term such as a paramagnet or a non-linear background, or a signal that "
                        "lags the field)")
    elif chosen == "none" and structure["structured"]:
        verdict, verdict_text = "unexplained structured residual", describe(structure)
    elif chosen == "none":
        verdict, verdict_text = "none", "no candidate earns its place and the residual is not structured beyond the noise"
    else:
        verdict = chosen
        verdict_text = f"{chosen} chosen" + ("; a structured residual remains: " + describe(structure)
                                             if structure["structured"] else "")
    return Verdict(verdict, verdict_text, structure, saturation)


def ambiguity(fits: CandidateFits, base: Baselines, offered: Offered, chosen: str, verdict: Verdict,
              o: "ResidualOptions") -> Verdict:
    """Ambiguity as an answer: the candidates that explain the held-out residual as well as the chosen
    one (``effects.equivalent_candidates``: each beats "none", neither beats the other; nested ones and
    one observable excluded), K_u moved along its neighbourhood included as ``effects.HAMILTONIAN_CHANGE``
    where it was given. Where nothing is chosen, a physics candidate that beats "none" but was withheld
    only because K_u's neighbourhood explains the residual as well (and no better) is ambiguous with
    that K_u change (a field tilt, K_2 or thermal activation against the decoded K_u). The verdict is
    then "ambiguous", with the set and, for each member, the measurement that would separate it.
    A candidate chosen on decisive evidence (``Offered.decisive``) is not made ambiguous by the held-out curves.
    Draws on its own bootstrap stream (``ambiguity`` of ``o.seed``), after the choice: the choice is unchanged;
    the selection's rule: ``o.n_boot``, ``o.min_relative_gain``, ``o.equivalence``."""
    seed, n_boot, min_relative_gain, equivalence = o.seed, o.n_boot, o.min_relative_gain, o.equivalence
    rng = stream_rng(seed, "bootstrap", "ambiguity")
    pool = dict(offered.mse)
    if base.knob_mse is not None:
        pool[HAMILTONIAN_CHANGE] = base.knob_mse
    options = dict(n_boot=n_boot, min_relative_gain=min_relative_gain, equivalence=equivalence)
    if chosen in offered.decisive:
        # shown where it lives (a background's slope in saturation), not by the held-out curves: what explains
        # those equally does not make it ambiguous
        members = []
    elif chosen != "none":
        members = equivalent_candidates(pool, chosen, rng, same_observable=SAME_OBSERVABLE, **options)
        members = sorted(set(members) | {chosen}) if members else []
    elif base.knob_mse is not None and HAMILTONIAN_CHANGE in pool:
        # a candidate that gains no more than it does on effect-free films is no possible effect either
        withheld = {name: fits.mse[name] for name, record in fits.records.items()
                    if record.get("beats_hamiltonian") is False and name not in offered.mse
                    and record.get("beats_null") is not False}
        equal = equivalent_candidates({**withheld, "none": fits.mse["none"], HAMILTONIAN_CHANGE: base.knob_mse},
                                      HAMILTONIAN_CHANGE, rng, same_observable=SAME_OBSERVABLE, **options)
        beats_none = _beats(base.knob_mse, fits.mse["none"], rng, **options)
        members = sorted(set(equal) | {HAMILTONIAN_CHANGE}) if equal and beats_none else []
    else:
        members = []
    if not members:
        return verdict
    separating = separating_measurements(members)
    text = (f"ambiguous: {', '.join(members)} explain the held-out residual equally (neither beats the other "
            "beyond its noise); to tell them apart: " + "; ".join(f"{k}: {v}" for k, v in separating.items()))
    if HAMILTONIAN_CHANGE in members and (base.hamiltonian or {}).get("parameter"):
        h = base.hamiltonian
        text += (f". ({HAMILTONIAN_CHANGE}: the decoded Hamiltonian moved inside what this file's decode leaves "
                 f"open; best along {h['parameter']}, by {h['change']:.4g} ± {h['change_uncertainty']:.2g} SI, "
                 f"which {NEIGHBOURHOOD_MEASUREMENTS.get(h['parameter'], 'an independent measurement of it')} "
                 "measures)")
    return Verdict("ambiguous", text, verdict.structure, verdict.saturation, members, separating)


def realisation_ambiguity(fits: CandidateFits, offered: Offered, chosen: str, verdict: Verdict,
                          o: "ResidualOptions") -> Verdict:
    """The two answers one FORC family cannot give, made ``ambiguous`` (after ``ambiguity``; the choice is
    unchanged, its own bootstrap stream ``realisation_ambiguity`` of ``o.seed``; the selection's rule:
    ``o.n_boot``, ``o.min_relative_gain``, ``o.equivalence``):

    - Realisation noise. Nothing was chosen, but the selection would have named X had the realisation
      floor not withheld it: X beats "none" on held-out curves, and its relative gain reaches the largest
      it has on effect-free films of the decoded Hamiltonian at the file's patch number without beating it
      by the margin (or beats it relatively but not in mean-square error). The verdict is then "ambiguous"
      with {X, ``effects.REALISATION_NOISE``}, never X alone. A candidate gaining less than effect-free
      films give it leaves the verdict as it is ("none": the floor explains it).
    - Thermal activation at one sweep rate (``sweep_rates`` < 2). A Sharrock shift of the switching
      fields and a switching-field distribution the model draws differently (realisation noise, disorder
      statistics) move the same switching fields on one family: a verdict that names thermal activation,
      alone or in a set, becomes "ambiguous" with ``effects.SWITCHING_FIELD_DISTRIBUTION`` beside it, the
      separating measurement a FORC family at another sweep rate (``o.sweep_rates``)."""
    seed, n_boot, min_relative_gain, equivalence = o.seed, o.n_boot, o.min_relative_gain, o.equivalence
    sweep_rates = o.sweep_rates
    members = list(verdict.ambiguous) if verdict.verdict == "ambiguous" else []
    if chosen == "none" and verdict.verdict != "ambiguous" and offered.floored:
        rng = stream_rng(seed, "bootstrap", "realisation_ambiguity")
        pool = {**offered.mse, **offered.floored}
        without_floor, _ = choose_candidate(pool, {k: v["n_parameters"] for k, v in fits.records.items()}, rng,
                                            n_boot, min_relative_gain, equivalence, evidenced=offered.evidenced,
                                            decisive=offered.decisive)
        if without_floor != "none":
            members = [without_floor, REALISATION_NOISE]
    named = set(members) if members else ({chosen} if chosen != "none" else set())
    if sweep_rates < 2 and "thermal_activation" in named:
        members = sorted(named | {SWITCHING_FIELD_DISTRIBUTION})
    if not members or members == list(verdict.ambiguous):
        return verdict
    members = sorted(set(members))
    separating = separating_measurements(members)
    if REALISATION_NOISE in members and SWITCHING_FIELD_DISTRIBUTION not in members:
        lead = ("ambiguous: realisation noise: " + ", ".join(m for m in members if m != REALISATION_NOISE)
                + " gains on held-out curves, but no more than on effect-free films of the decoded Hamiltonian "
                  "averaging as many patches as this file")
    else:
        lead = (f"ambiguous: {', '.join(members)} explain the held-out residual equally on one FORC family at "
                "one sweep rate")
    text = lead + "; to tell them apart: " + "; ".join(f"{k}: {v}" for k, v in separating.items())
    return Verdict("ambiguous", text, verdict.structure, verdict.saturation, members, separating)


def soft_phase_mimics(soft_phase_families: dict, fields, range_T: tuple, chi_per_T: float, se_per_T: float) -> list:
    """The library's soft second phases that add what a linear background χ·μ0H adds where the film is
    saturated (μ0H in ``range_T``, T).

    A soft phase whose K_u,soft is below its shape anisotropy μ0M_s²/2 lies in the film plane; a
    perpendicular field turns it along its hard axis, m_soft ≈ μ0H/μ0H_K,eff, linear up to
    μ0H_K,eff = μ0M_s − 2K_u,soft/M_s. A fraction f of it adds f·m_soft to the saturated film and takes f
    from the switching part, as a background χ = f/μ0H_K,eff and the file's normalization by its saturated
    moment do: within the window the two are one form. For each soft family (n × n on ``fields``, rows
    H_r; its ascending major branch is row 0): the slope s of its branch over ``range_T`` and f = χ/s. A
    mimic where 0 < f ≤ 1 and f times the branch's largest departure from its straight line there is within
    ``Z_BACKGROUND`` × the background's error at the range's ends (``se_per_T`` × half the range): a curvature
    the background's own line could not have told. Returns [{"K_u_soft_J_per_m3", "slope_per_T", "fraction",
    "saturates_at_T" (first field where the branch is within 2 % of 1, None inside the window)}]."""
    fields = np.asarray(fields, float)
    low, high = range_T
    inside = (fields >= low) & (fields <= high)
    mimics = []
    if chi_per_T is None or chi_per_T <= 0 or inside.sum() < 3:
        return mimics
    for K_soft, family in sorted((soft_phase_families or {}).items()):
        branch = np.asarray(family, float)[0]
        ok = inside & np.isfinite(branch)
        if ok.sum() < 3:
            continue
        slope, intercept = np.polyfit(fields[ok], branch[ok], 1)
        if slope <= 0:
            continue
        fraction = chi_per_T / slope
        departure = float(np.max(np.abs(branch[ok] - (intercept + slope * fields[ok]))))
        if fraction > 1 or fraction * departure > Z_BACKGROUND * se_per_T * (high - low) / 2:
            continue
        saturated = np.nonzero((fields > 0) & (branch >= 0.98))[0]
        mimics.append({"K_u_soft_J_per_m3": float(K_soft), "slope_per_T": float(slope), "fraction": float(fraction),
                       "saturates_at_T": float(fields[saturated[0]]) if saturated.size else None})
    return mimics


def soft_phase_ambiguity(p: ResidualProblem, fits: CandidateFits, offered: Offered, chosen: str, verdict: Verdict,
                         o: "ResidualOptions") -> Verdict:
    """A positive background read in the saturated film (``signatures.background_evidence``, the decisive
    choice) against a soft second phase lying in the film plane (``soft_phase_mimics``): where one of the
    library's soft phases adds the same slope over the saturated fields, the verdict is "ambiguous" with
    {background, second_phase} (the choice is unchanged), the separating measurement a loop past the soft
    phase's hard-axis saturation field (the phase stops rising there, a background does not) or an
    in-plane loop. A negative slope (a diamagnetic substrate) is no phase's; a verdict already ambiguous is
    left as it is."""
    if chosen not in offered.decisive or verdict.verdict == "ambiguous" or not o.soft_phase_families:
        return verdict
    evidence = fits.records.get(chosen, {}).get("background_evidence") or {}
    points = o.saturation_points
    if points is not None and evidence.get("file_only") and points.file_only is not None:
        points = points.file_only  # the slope was read on the file's own branches (``background_evidence``)
    if points is None or not np.size(points.field_T):
        return verdict
    magnitude = np.abs(np.asarray(points.field_T, float))
    mimics = soft_phase_mimics(o.soft_phase_families, p.fields, (float(magnitude.min()), float(magnitude.max())),
                               evidence.get("chi_per_T"), evidence.get("se_per_T") or 0.0)
    if not mimics:
        return verdict
    members = sorted({chosen, "second_phase"})
    fractions = [m["fraction"] for m in mimics]
    soft = [m["K_u_soft_J_per_m3"] / 1e3 for m in mimics]
    ends = [m["saturates_at_T"] for m in mimics]
    beyond = "beyond the window's top" if any(e is None for e in ends) else f"at {min(ends):.2f} T and above"
    separating = {**separating_measurements(members),
                  "second_phase": (f"a loop past the soft phase's hard-axis saturation field ({beyond}: the phase "
                                   "stops rising there, a background does not), or an in-plane loop (the phase's "
                                   "easy axis)")}

    def span(values, form):
        low, high = format(min(values), form), format(max(values), form)
        return low if low == high else f"{low}–{high}"

    text = (f"ambiguous: {', '.join(members)}: the slope where the film is saturated (χ {evidence['chi_per_T']:.3g} "
            f"per T) is also what a soft phase in the film plane adds (fraction {span(fractions, '.3g')}, "
            f"K_u,soft {span(soft, '.0f')} kJ/m³, still on its hard axis there); to tell them apart: "
            + "; ".join(f"{k}: {v}" for k, v in separating.items()))
    return Verdict("ambiguous", text, verdict.structure, verdict.saturation, members, separating)


def residual_report(p: ResidualProblem, fits: CandidateFits, base: Baselines, choice: Choice, verdict: Verdict,
                    field_shift: dict | None, drift: dict | None) -> dict:
    """The result of ``analyse_residual`` (see there)."""
    measured, base_family = p.measured, p.base_family
    records, models, folds = fits.records, fits.models, p.folds
    chosen, candidates = choice.chosen, choice.candidates
    residual_before = measured - base_family
    residual_after = measured - models[chosen]
    same = [k for group in SAME_OBSERVABLE if chosen in group for k in sorted(group - {chosen}) if k in candidates]
    return {"verdict": verdict.verdict, "verdict_text": verdict.verdict_text, "structure": verdict.structure,
            "ambiguous": list(verdict.ambiguous), "separating_measurements": dict(verdict.separating_measurements),
            "field_shift": field_shift,
            "saturation": verdict.saturation,
            "hamiltonian_neighbourhood": base.hamiltonian,
            "drift": drift,
            "chosen": chosen, "kind": records[chosen]["kind"], "parameters": records[chosen]["parameters"],
            "uncertainties": records[chosen]["uncertainties"], "same_observable_as": same, "candidates": candidates,
            "residual_rms_before": float(np.sqrt(np.nanmean(residual_before**2))),
            "residual_rms_after": float(np.sqrt(np.nanmean(residual_after**2))),
            "per_curve_rms_before": _rms_per_curve(residual_before),
            "per_curve_rms_after": _rms_per_curve(residual_after),
            "heldout_curves": [i for _, held in folds for i in held],
            "heldout_rms_before": candidates["none"]["heldout_rms"],
            "heldout_rms_after": candidates[chosen]["heldout_rms"], "heldout_reduction": choice.reduction,
            "heldout_reduction_ci90": choice.reduction_ci,
            "arrays": {"model": models[chosen], "residual_before": residual_before, "residual_after": residual_after},
            }


@dataclass
class Gated:
    """The stages of ``analyse_residual`` up to the gates: the problem, every candidate's fit, the
    baselines and the candidates offered to the selection."""

    problem: ResidualProblem
    fits: CandidateFits
    baselines: Baselines
    offered: Offered


@dataclass(frozen=True)
class ResidualOptions:
    """The keyword options of ``analyse_residual`` and ``gated_candidates``, with their defaults.
    ``physics_candidate_families(cfg, params)`` returns a dict of ``physics_families``, ``soft_phase_families``,
    ``physics_reference_family`` and ``hamiltonian_families``, to be given as keywords. Families are n × n on
    the grid, m normalized to the saturation moment.

    ``physics_families``: {name: {size: family}}, e.g. {"K_2": {K_2 (J/m³): family},
    "bias_field": {B (T): family}}; ``soft_phase_families``: {K_u,soft (J/m³): family of the soft
    phase}. ``physics_candidate_families(cfg, params)`` builds both (``**`` it in).
    ``measured_candidates``: names in ``effects.EFFECTS`` (default all: singles and combinations).
    ``every_k``: every ``every_k``-th curve is held out, the rest fit every candidate; with ``cross_fit`` this
    is done for each of the ``every_k`` offsets in turn, so every curve is held out once (an
    effect confined to a few curves, e.g. a bias field moving one avalanche, then still has
    enough held-out evidence). Reported sizes are fitted on all curves.

    The selection's rule (``effects.choose_candidate``): ``n_boot`` paired-bootstrap resamples over held-out
    curves; a candidate earns its place with a held-out error lower by more than ``equivalence`` (relative)
    and a 5 % bootstrap bound of its relative gain above ``min_relative_gain``.

    ``seed``: the config seed; the bootstraps draw from its ``bootstrap`` stream (``core.streams``).

    ``thermal``: offer the ``thermal_activation`` candidate. ``noise_sigma`` (m units; default:
    estimated from the residual), ``floor_variance`` (variance of m between the re-simulation's
    disorder profiles, n × n or scalar) and ``n_profiles`` (profiles averaged in ``base_family``)
    enter the structure test of the chosen model's residual (``loop.structure``): ``structure``,
    and ``verdict``: the chosen effect, "none", or "unexplained structured residual" (nothing earns
    its place but the residual is structured; ``verdict_text`` says where it lives).

    ``null_gain``: {candidate: {"relative": 1 − MSE_c/MSE_none, "mse": MSE_none − MSE_c}}, the largest
    held-out gains it reached when the "measurement" was the model itself on other disorder
    realisations (``null_gains``). A film is one realisation: a candidate that shifts or tilts the
    family can cover the difference between two realisations of the same Hamiltonian as well as an
    effect. With this argument a candidate is offered to the selection only if it beats the floor in
    both senses: relative gain above the null's by ``null_margin``, and mean-square gain above the
    null's by the factor 1 + ``null_margin`` (records: ``relative_gain``, ``gain_mse_mean``,
    ``null_gain``, ``beats_null``).

    ``field_shift``: the model-free inversion-symmetry test of the measured major loop
    (``signatures.field_shift``). With it, a candidate that shifts the loop along the field
    (field_offset, bias_field, their combinations) is offered only if the measured loop shows a
    shift (``significant``) and the shift its fitted size implies agrees with it
    (``signatures.shift_agreement``: within 3 combined standard errors, the candidate's including
    the grid's resolution, spacing/√12: a shift fitted on the grid family), and then without the
    realisation floor: another film of the same Hamiltonian is as symmetric as this one, so a shift
    the data show by themselves is not the difference between two films (records:
    ``shift_evidence``). It still has to beat the current choice on held-out curves; with
    ``evidence_suffices`` (the default) only by a held-out error lower by more than ``equivalence``,
    the bootstrap bound not asked (``choose_candidate(evidenced=)``: its significance is the symmetry
    test's). Why: at this film size the gain of a shift sits on the few held-out curves that cross
    the switching region, and no bootstrap over curves bounds it; chosen on the validation cases of
    ``bench.effects_independent`` (in-library 3 → 5 of 7, no control or outside case changed). The
    symmetry test cannot tell a detector lag of the swept curves from an offset (``signatures``), so
    a lag that shows as a shift is named a field offset; the report says how to tell them apart.

    ``drift``: the model-free drift evidence of the measurement (``signatures.drift_evidence``: the
    end moments in positive saturation against the clock, and the mirror sums that tell an additive
    drift from a gain drift). A candidate with a drift component is offered only if the evidence
    supports that kind of drift (``signatures.drift_agreement``), and then without the realisation
    floor, for the same reason (records: ``drift_evidence``); with ``evidence_suffices`` it too needs
    only a held-out error lower by more than ``equivalence`` than the current choice (on the
    validation cases: a background with an additive drift, named "background" before).

    ``moment_tolerance``: the moment normalization is known to ±this. A candidate named for its scale
    whose fitted scale lies inside the band is not named (records: ``within_moment_tolerance``), and a
    measured-side candidate that fits a scale besides its own terms must beat, on held-out curves, the
    base model whose normalization is free inside the band (a·m_sim, a clipped to 1 ± tolerance;
    records: ``beats_normalization``).

    ``physics_reference_family``: the family without effect on the physics families' own disorder;
    each physics family then enters as base + (family − reference). ``hamiltonian_families``
    ({relative K_u change: family}, or {parameter: {change (SI): family}} from
    ``decode_neighbourhood``; same disorder as the reference): the Hamiltonian's own neighbourhood. A
    physics candidate changes switching fields, and so does a K_u the refit left slightly off (on a
    24-field grid a blend of two families places a jump between grid fields, which no single
    re-simulation does), or a K_u or D off inside the intervals this file's decode gives them: it is
    offered only if it beats, on held-out curves, the Hamiltonian moved along the best of its interpolated directions
    (``fit_neighbourhood``; the rule of ``effects.choose_candidate``; records: ``beats_hamiltonian``; the
    fitted direction, change and held-out RMS: result key ``hamiltonian_neighbourhood``). A candidate
    withheld by it, beating "none" and its realisation floor, and equal to that change is answered
    "ambiguous" with ``effects.HAMILTONIAN_CHANGE`` (``ambiguity``).

    ``saturation_points`` (``signatures.SaturatedPoints``): the measured points past the model's loop
    closure with the re-simulated saturated film there; the saturation gate and the verdict's
    saturation test then run on them (``signatures.saturation_residual_points``) instead of on the
    deep-saturated grid points.

    ``measured_patches``: the number of independent patches the measurement averages
    (``loop.patches``): the structure test's disorder floor is v·(1/patches + 1/``n_profiles``).
    ``null_structure`` (``structure.null_structure_floor``): the structure test's statistics on
    effect-free films; a residual is structured only beyond them.

    ``saturation_gate``: test the candidates' residual where the film is saturated (a candidate whose
    residual there is reversible is not offered) and the verdict's saturation test; ``evidence_suffices``:
    see ``field_shift``. ``sweep_rates``: the sweep rates the measurement holds (below 2, thermal activation
    is ambiguous with a switching-field distribution: ``realisation_ambiguity``).
    """

    physics_families: dict | None = None
    soft_phase_families: dict | None = None
    measured_candidates: object = None
    every_k: int = 4
    cross_fit: bool = True
    n_boot: int = 2000
    seed: int = 0
    min_relative_gain: float = 0.05
    equivalence: float = 0.05
    thermal: bool = True
    noise_sigma: float | None = None
    floor_variance: object = None
    n_profiles: int = 1
    null_gain: dict | None = None
    null_margin: float = 0.05
    field_shift: dict | None = None
    drift: dict | None = None
    physics_reference_family: object = None
    hamiltonian_families: dict | None = None
    moment_tolerance: float = MOMENT_TOLERANCE
    evidence_suffices: bool = True
    saturation_gate: bool = True
    saturation_points: object = None
    measured_patches: int = 1
    sweep_rates: int = 1
    null_structure: dict | None = None


GATED_OPTIONS = frozenset({"physics_families", "soft_phase_families", "measured_candidates", "every_k", "cross_fit",
                           "n_boot", "seed", "min_relative_gain", "equivalence", "thermal", "null_gain", "null_margin",
                           "field_shift", "drift", "physics_reference_family", "hamiltonian_families",
                           "moment_tolerance", "evidence_suffices", "saturation_gate", "saturation_points"})
"""The ``ResidualOptions`` fields the gates read (``gated_candidates``); the rest are the verdict's."""


def residual_options(options: ResidualOptions | None = None, **overrides) -> ResidualOptions:
    """``options`` (defaults where None) with the keyword ``overrides`` set (TypeError for an unknown one)."""
    return replace(options or ResidualOptions(), **overrides)


def gated_candidates(measured, base_family, fields, order=None, options: ResidualOptions | None = None,
                     **overrides) -> Gated:
    """Every candidate fitted and scored on held-out curves (per-curve mean-square misfit, m in units
    of the saturation moment) and put through the gates: the first stages of ``analyse_residual``,
    whose options (``ResidualOptions``, or single ones as keywords) these are. ``refit.refit_ambiguity``
    reads the candidates offered on the unrefitted prediction from it."""
    o = residual_options(options, **overrides)
    p = residual_problem(measured, base_family, fields, order, o.every_k, o.cross_fit)
    library = candidate_library(p, physics_families=o.physics_families, soft_phase_families=o.soft_phase_families,
                                measured_candidates=o.measured_candidates, thermal=o.thermal,
                                physics_reference_family=o.physics_reference_family,
                                hamiltonian_families=o.hamiltonian_families)
    fits = fit_candidates(p, library)
    base = baselines(p, library.hamiltonian_families, o.moment_tolerance)
    offered = gate_candidates(p, fits, base, GateSettings(
        seed=o.seed, n_boot=o.n_boot, min_relative_gain=o.min_relative_gain, equivalence=o.equivalence,
        null_gain=o.null_gain, null_margin=o.null_margin, field_shift=o.field_shift, drift=o.drift,
        moment_tolerance=o.moment_tolerance, evidence_suffices=o.evidence_suffices,
        saturation_gate=o.saturation_gate, saturation_points=o.saturation_points))
    return Gated(p, fits, base, offered)


def analyse_residual(measured, base_family, fields, order=None, options: ResidualOptions | None = None,
                     **overrides) -> dict:
    """Trace the residual measured − re-simulated to the effect the model lacks.

    All families n × n on the grid ``fields`` (μ0H, T), rows H_r, NaN below the diagonal, m normalized to
    the film's saturation moment. The options are the fields of ``ResidualOptions`` (``options``; its docstring
    says what each means), or single ones given as keywords.

    ``base_family``: the re-simulation of the predicted Hamiltonian (``resimulate``).
    ``order``: measurement clock τ ∈ [0, 1], per curve (n,) or per point (n, n); default
    ``measurement_clock(n)`` (MicroMag order: highest H_r first, time ∝ points measured).

    Returns a dict (JSON-ready except ``arrays``):
    ``chosen`` (name, "none" if nothing earns its place), ``kind`` ("measured", "physics", "none"),
    ``parameters`` and ``uncertainties`` of the chosen effect (1σ; gridded sizes: half the grid
    spacing), ``same_observable_as`` (candidates no measurement can tell from the chosen one),
    ``candidates`` {name: {"kind", "n_parameters", "parameters", "uncertainties", "heldout_rms",
    "gain_mse", "gain_ci90", "accepted"}}, ``residual_rms_before`` / ``residual_rms_after`` (all
    points, the chosen model fitted on all curves) and ``per_curve_rms_before`` /
    ``per_curve_rms_after``, ``heldout_curves``, ``heldout_rms_before``, ``heldout_rms_after``,
    ``heldout_reduction`` = 1 − after/before and ``heldout_reduction_ci90`` (paired bootstrap over
    held-out curves, 5 %–95 %), and ``arrays`` {"model", "residual_before", "residual_after"}
    (numpy n × n); ``structure`` (the structure test of the chosen model's residual, ``loop.structure``) and
    ``verdict``: the chosen effect, "none", or "unexplained structured residual" (nothing earns its place but
    the residual is structured; ``verdict_text`` says where it lives), or "ambiguous".

    Two verdicts no single FORC family can settle are answered ``ambiguous`` (``realisation_ambiguity``):
    a candidate the selection would name without the realisation floor but that gains no more than it
    gains on effect-free films ("ambiguous: X, realisation noise"), and thermal activation from a file at
    one sweep rate (``sweep_rates`` < 2: "ambiguous: thermal_activation, switching-field distribution",
    the separating measurement a FORC family at another sweep rate).
    """
    o = residual_options(options, **overrides)
    g = gated_candidates(measured, base_family, fields, order, o)
    p, fits, base, offered = g.problem, g.fits, g.baselines, g.offered
    choice = choose(p, fits, offered, o.seed, o.n_boot, o.min_relative_gain, o.equivalence)
    verdict = judge(p, fits, choice.chosen, o)
    verdict = ambiguity(fits, base, offered, choice.chosen, verdict, o)
    verdict = realisation_ambiguity(fits, offered, choice.chosen, verdict, o)
    verdict = soft_phase_ambiguity(g.problem, fits, offered, choice.chosen, verdict, o)
    return residual_report(p, fits, base, choice, verdict, o.field_shift, o.drift)
