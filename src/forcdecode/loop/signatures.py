"""Model-free evidence for instrument effects: a field shift (the inversion symmetry of the major
loop, ``field_shift``), a drift (the end moments in saturation, ``drift_evidence``) and a field-only
term no static candidate describes (the saturated film, ``saturation_residual``).

A film without a bias field has a Hamiltonian symmetric under (m, B) → (−m, −B) (Zeeman, exchange,
uniaxial anisotropy, DMI, demagnetization and the frozen disorder all are), so its ascending major
branch is the mirror of its descending one: a(B) = −d(−B). Odd instrument terms (a linear or Langevin
background, a scale) keep the symmetry; a field offset b of the magnet (or a bias field of the film:
the same observable) breaks it as a pure horizontal shift, a(B) = −d(−B + 2b). The test does not need
the re-simulation, so a model that is a different film (another disorder realisation, another code)
cannot fake it.

What it cannot tell from an offset: a lag of the swept branch behind the reversal points. In a FORC
protocol the descending branch is the reversal points, each measured after a pause (settled); the
ascending branch is swept. A first-order detector lag of p averaging times delays a smooth swept
branch by a/(1 − a) points (a = e^(−1/p)), and the loop reads as shifted by half that
(``tests/loop/test_signatures.py``). To first order a lag is an offset of half its delay plus a
coercivity wider by half its delay, which a refit of the Hamiltonian absorbs; on the independent
bench a lag of 1.5 points (21 mT points) read +15.3 ± 2.3 mT and its held-out curves favoured a
field offset more than those of the true 31 mT offset did. A second measurement at another sweep
rate tells them apart (an offset does not depend on the rate); the report says so.

A reversible residual in saturation (``saturation_residual``). Where the film is saturated (the
re-simulation at |m| ≥ 0.995, ``SATURATION_DEPTH`` grid steps past its switching) every curve carries
the same moment whatever the disorder, the exchange or the code: what differs there between
measurement and model is the instrument. A time-independent measured-side candidate (scale,
background, field offset) describes it with its own terms (a gain, χ·μ0H, nothing); a field-only term
outside that form (a Langevin paramagnet, a non-linear background) leaves column means that differ
from zero beyond the scatter between curves. Such a candidate is refused (``analyse_residual``,
``saturation_gate``); if it was the residual's only explanation, the verdict is an unexplained
structured residual in saturation.

The same test on the measured points (``saturation_residual_points``): the re-simulated film's major
loop on a 10 mT lattice (``resimulate.major_loop_branches``) says where its two branches meet for good
(``loop_closure``); every measured point ``SATURATION_MARGIN_T`` beyond that closure is compared with
the re-simulated saturated film at its own field. The grid's deep-saturated columns start where the
film has reached |m| ≥ 0.995, three 87 mT steps further out: a perpendicular film with tilted grains
approaches saturation slowly (1 − m ≈ 0.008 at 0.3 T on the bench's film), so the grid sees only the
fields where a paramagnet of 0.08–0.12 T already looks like a linear background. The measured points
begin about 0.3 T, where its curvature shows (on the validation cases: background p = 0.72 on the
grid, 2.7e-12 on the points).

A field-shift candidate may explain a residual only where the test finds a shift and the
candidate's size agrees with it (``shift_agreement``); it is then spared the realisation floor
(``physics_effects.analyse_residual``, ``field_shift=``).

Estimate. For levels m_L inside both branches, the field B_d(−m_L) where the descending branch
crosses −m_L and B_a(m_L) where the ascending one crosses m_L (linear interpolation between the
measured points); each level gives a centre c_L = (B_a(m_L) + B_d(−m_L))/2, which is b for a
shifted loop and 0 for a symmetric one. Uncertainty of one crossing (T): the noise √2 σ (m units)
over the local slope, and the interpolation: |m''|(x − x₀)(x₁ − x)/2 over the slope, the error of
linear interpolation with the curvature m'' taken as the larger second difference at the interval's
ends, or Δ/√12 where that error at the interval's middle would exceed a quarter of it (the branch is
not resolved: a step anywhere in an interval of width Δ — a pure step gives Δ/8 there, above the
quarter, Δ/13.9; also at the branch's ends). Two levels that cross a branch inside the same
interval share that interval's error (fully correlated); crossings in different intervals are
independent (the position of a step in one interval says nothing about another). The offset is the
mean of the centres weighted by their inverse variances, its standard error computed with that
covariance (before: the levels' mean error, as if every level shared one interval, which over-states
the error of a loop that switches over several intervals by up to √(number of intervals)).
A field shift is claimed when |b| / se > ``Z_SHIFT`` and the levels agree with one constant shift
(χ² of c_L about their mean, with the per-level errors, below its 99 % point): a vertical
asymmetry (an additive drift) moves the centres by v / slope, different at every level. A vertical
asymmetry is also measured where it shows directly: at the saturated ends the two branches must be
mirror images too, a(B) + d(−B) = 0 at the ``N_END`` outermost points of each end; if either end's
mean differs from 0 by more than ``Z_SHIFT`` standard errors (σ√(2/N_END)) plus the slope of the
branches times the lattice mismatch, the asymmetry is not a pure field shift and no shift is claimed
(a gain or additive drift, not a field offset).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

Z_SHIFT = 3.0
"""A field shift is claimed at |offset| > 3 standard errors."""

LEVELS = (-0.6, -0.4, -0.2, 0.0, 0.2, 0.4, 0.6)
"""Levels of normalized m at which the two branches' crossings are compared."""

N_END = 3
"""Outermost points per end of the ascending branch used for the vertical-asymmetry check."""

MIRROR_FRACTION = 0.8
"""Mirror sums use curves reversed at or below −0.8 B_top only: there both the reversal point and its
mirror on the curve (on the ascending branch) lie in saturation for a loop that closes below 0.8 B_top."""

_CHI2_99 = {1: 6.63, 2: 9.21, 3: 11.34, 4: 13.28, 5: 15.09, 6: 16.81}
"""99 % points of χ² with k degrees of freedom (levels − 1)."""


def _curvature(fields, values, i):
    """|m''| (1/T²) at point i from its neighbours (non-uniform second difference), or None at an end."""
    if i <= 0 or i >= len(fields) - 1 or not np.all(np.isfinite(values[i - 1:i + 2])):
        return None
    h0, h1 = fields[i] - fields[i - 1], fields[i + 1] - fields[i]
    return abs(2.0 * ((values[i + 1] - values[i]) / h1 - (values[i] - values[i - 1]) / h0) / (h0 + h1))


def _crossing(fields, values, level, rising: bool, sigma: float):
    """First crossing of ``level`` along the branch (``fields`` in traversal order): (field T,
    uncertainty T, index of the interval) or None if the branch never crosses it."""
    for i in range(len(fields) - 1):
        y0, y1 = values[i], values[i + 1]
        if not (np.isfinite(y0) and np.isfinite(y1)):
            continue
        crosses = (y0 < level <= y1) if rising else (y0 > level >= y1)
        if not crosses:
            continue
        x0, x1 = fields[i], fields[i + 1]
        slope = (y1 - y0) / (x1 - x0)
        x = x0 + (level - y0) / slope
        width = abs(x1 - x0)
        step_bound = width / np.sqrt(12.0)  # a step anywhere in the interval
        curvatures = [c for c in (_curvature(fields, values, i), _curvature(fields, values, i + 1)) if c is not None]
        u_interp = step_bound
        if len(curvatures) == 2 and max(curvatures) * width**2 / 8.0 / abs(slope) < 0.25 * step_bound:
            # a resolved smooth branch: linear interpolation errs by |m''| (x − x0)(x1 − x) / 2 in m
            u_interp = max(curvatures) * abs((x - x0) * (x1 - x)) / 2.0 / abs(slope)
        u_noise = np.sqrt(2.0) * sigma / abs(slope)
        return float(x), float(np.hypot(u_interp, u_noise)), i
    return None


def major_branches(curves, moment: float):
    """(descending, ascending) major branches from FORC curves [(reversal field T, fields T, moments)]:
    the descending branch is the reversal points (first point of every curve), highest field first;
    the ascending branch is the curve of the lowest reversal field. Moments divided by ``moment``."""
    curves = sorted(curves, key=lambda c: c[0])
    reversal = np.array([c[0] for c in curves], float)
    first = np.array([np.asarray(c[2], float)[0] for c in curves]) / moment
    descending = (reversal[::-1], first[::-1])
    ascending = (np.asarray(curves[0][1], float), np.asarray(curves[0][2], float) / moment)
    return descending, ascending


def _vertical_asymmetry(d_fields, d_m, a_fields, a_m, sigma):
    """a(B) + d(−B) at the N_END outermost points of each end of the ascending branch (d interpolated):
    {"top", "bottom", "se", "significant"}."""
    order = np.argsort(d_fields)
    dx, dy = d_fields[order], d_m[order]
    ok = np.isfinite(dy)
    dx, dy = dx[ok], dy[ok]
    ends = {}
    tolerance = 0.0
    for name, idx in (("bottom", np.arange(N_END)), ("top", np.arange(len(a_fields) - N_END, len(a_fields)))):
        B = a_fields[idx]
        ends[name] = float(np.mean(a_m[idx] + np.interp(-B, dx, dy)))
        # the lattices differ: the branch's own slope there times the largest field mismatch
        slope = abs(np.polyfit(B, a_m[idx], 1)[0]) if len(B) > 1 else 0.0
        tolerance = max(tolerance, slope * float(np.max(np.abs(np.diff(dx)))) / 2.0)
    se = float(sigma * np.sqrt(2.0 / N_END))
    significant = any(abs(v) > Z_SHIFT * se + tolerance for v in ends.values())
    return {**ends, "se": se, "tolerance": tolerance, "significant": bool(significant)}


def field_shift(descending, ascending, noise_sigma: float, levels=LEVELS) -> dict:
    """Inversion-symmetry test of the major loop (module docstring).

    ``descending``/``ascending``: (fields T, m) in traversal order (fields falling / rising), m
    normalized to saturation; ``noise_sigma``: noise of one point in m units. Returns
    {"offset_T", "se_T", "z", "levels", "centres_T", "errors_T", "chi2", "chi2_limit", "consistent",
    "significant", "rule"}; with fewer than two usable levels ``offset_T`` is None and nothing is
    significant."""
    d_fields, d_m = map(np.asarray, descending)
    a_fields, a_m = map(np.asarray, ascending)
    used, centres, errors, crossings = [], [], [], []
    for level in levels:
        a = _crossing(a_fields, a_m, level, True, noise_sigma)
        d = _crossing(d_fields, d_m, -level, False, noise_sigma)
        if a is None or d is None:
            continue
        used.append(float(level))
        centres.append(0.5 * (a[0] + d[0]))
        errors.append(0.5 * float(np.hypot(a[1], d[1])))
        crossings.append((a, d))
    rule = (f"|offset| > {Z_SHIFT:g} se (errors correlated between levels crossing a branch in one interval), the "
            "levels consistent with one shift (χ² below its 99 % point) and the saturated ends mirror images")
    if len(used) < 2:
        return {"offset_T": None, "se_T": None, "z": None, "levels": used, "centres_T": centres, "errors_T": errors,
                "chi2": None, "chi2_limit": None, "vertical": None, "consistent": False, "significant": False,
                "rule": rule}
    vertical = _vertical_asymmetry(d_fields, d_m, a_fields, a_m, noise_sigma)
    centres_arr, errors_arr = np.array(centres), np.maximum(np.array(errors), 1e-9)
    weights = 1.0 / errors_arr**2
    offset = float(np.sum(weights * centres_arr) / np.sum(weights))
    covariance = _centre_covariance(crossings)
    se = float(np.sqrt(weights @ covariance @ weights) / np.sum(weights))
    chi2 = float(np.sum(((centres_arr - offset) / errors_arr) ** 2))
    limit = _CHI2_99.get(len(used) - 1, float(len(used) - 1 + 3.0 * np.sqrt(2.0 * (len(used) - 1))))
    z = abs(offset) / se
    consistent = chi2 <= limit and not vertical["significant"]
    return {"offset_T": offset, "se_T": se, "z": float(z), "levels": used, "centres_T": centres,
            "errors_T": errors, "chi2": chi2, "chi2_limit": limit, "vertical": vertical, "consistent": bool(consistent),
            "significant": bool(z > Z_SHIFT and consistent), "rule": rule}


def _centre_covariance(crossings) -> np.ndarray:
    """Covariance (T²) of the levels' centres c_L = (B_a + B_d)/2 from their crossings [(ascending,
    descending)], each (field, uncertainty, interval). Two crossings inside the same interval of a
    branch share its unknown (the position of a step in it, the same two noisy points): fully
    correlated; crossings in different intervals are independent."""
    k = len(crossings)
    covariance = np.zeros((k, k))
    for i, (a_i, d_i) in enumerate(crossings):
        for j, (a_j, d_j) in enumerate(crossings):
            same_a = a_i[2] == a_j[2]
            same_d = d_i[2] == d_j[2]
            covariance[i, j] = 0.25 * (same_a * a_i[1] * a_j[1] + same_d * d_i[1] * d_j[1])
    return covariance


def field_shift_of(data, moment: float, noise_sigma: float, moment_offset: float = 0.0) -> dict:
    """``field_shift`` of a ``ForcMeasurement`` (moments less ``moment_offset``, over ``moment``)."""
    curves = [(c.reversal_field_T, c.field_T, c.moment_Am2 - moment_offset) for c in data.curves]
    return field_shift(*major_branches(curves, moment), noise_sigma)


def major_loop_protocol(reversal_fields_T, curve_fields_T):
    """The part of a FORC protocol the shift test reads: every reversal field with its first point
    only, and the whole curve of the lowest reversal field (the ascending branch). A sweep sampled
    at fewer points is the same sweep (``forc.measured_protocol``), so re-simulating this is the
    whole protocol's major loop at a fraction of the cost. Returns (reversal fields, curve fields)."""
    reversal = np.asarray(reversal_fields_T, float)
    lowest = int(np.argmin(reversal))
    curves = [np.asarray(f, float) if k == lowest else np.asarray(f, float)[:1]
              for k, f in enumerate(curve_fields_T)]
    return reversal, curves


def calibrated_shift(measured: dict, null_offsets) -> dict:
    """The field-shift test calibrated by simulation: ``null_offsets`` are the offsets ``field_shift``
    reads on films of the refitted Hamiltonian *without* a shift, re-simulated on the file's own
    protocol (other disorder realisations). Their mean is the test's bias on this protocol and film
    (interpolating branches sampled on lattices that are not mirror images: on the bench's H0 sample
    with 48 curves, +3.7 mT where the analytic error model gives 1.2 mT) and their
    spread its error. Returns ``measured`` with ``offset_T`` = raw − mean, ``se_T`` = max(analytic se,
    sd·√(1 + 1/R)), ``z`` and ``significant`` recomputed (the levels' consistency is the data's), and
    ``raw_offset_T``, ``analytic_se_T``, ``null_offsets_T``, ``calibration``. Needs R ≥ 3 offsets
    (ValueError); a measurement without an offset (too few levels) is returned unchanged."""
    offsets = np.asarray([o for o in null_offsets if o is not None and np.isfinite(o)], float)
    if offsets.size < 3:
        raise ValueError(f"the shift test's calibration needs at least 3 simulated films (got {offsets.size})")
    if measured.get("offset_T") is None:
        return dict(measured)
    spread = float(np.std(offsets, ddof=1) * np.sqrt(1 + 1 / offsets.size))
    se = max(float(measured["se_T"]), spread)
    offset = float(measured["offset_T"] - offsets.mean())
    z = abs(offset) / se
    return {**measured, "offset_T": offset, "se_T": se, "z": float(z),
            "significant": bool(z > Z_SHIFT and measured["consistent"]),
            "raw_offset_T": float(measured["offset_T"]), "analytic_se_T": float(measured["se_T"]),
            "null_offsets_T": offsets.tolist(),
            "calibration": (f"less the mean offset of {offsets.size} simulated films without a shift on the file's "
                            f"protocol ({offsets.mean() * 1e3:+.1f} mT, sd {np.std(offsets, ddof=1) * 1e3:.1f} mT)")}


def candidate_shift(parameters: dict, uncertainties: dict | None = None):
    """(shift T, 1σ T) of the major loop that a candidate's fitted parameters imply: a field offset
    ``offset_T`` moves the measured loop by +offset_T, a bias field ``B_bias_T`` of the film by −B_bias_T
    (it adds to the applied field); None if the candidate has neither."""
    uncertainties = uncertainties or {}
    if "offset_T" in parameters:
        return float(parameters["offset_T"]), float(uncertainties.get("offset_T", 0.0) or 0.0)
    if "B_bias_T" in parameters:
        return -float(parameters["B_bias_T"]), float(uncertainties.get("B_bias_T", 0.0) or 0.0)
    return None


def shift_agreement(measured_shift: dict, parameters: dict, uncertainties: dict | None = None,
                    resolution_T: float = 0.0) -> dict:
    """Does the loop shift a candidate's fitted parameters imply (``candidate_shift``) agree with the
    measured one within ``Z_SHIFT`` combined standard errors? ``resolution_T``: the error of a shift
    fitted on a family known at grid fields only (a jump between two nodes is anywhere between them:
    spacing/√12), combined with the fit's own. {"candidate_shift_T", "difference_z", "agrees"}
    (agrees when either side has no shift to compare)."""
    implied = candidate_shift(parameters, uncertainties)
    if implied is None or measured_shift.get("offset_T") is None:
        return {"candidate_shift_T": None if implied is None else implied[0], "difference_z": None, "agrees": True}
    combined = float(np.sqrt(measured_shift["se_T"] ** 2 + implied[1] ** 2 + resolution_T**2))
    z = abs(measured_shift["offset_T"] - implied[0]) / max(combined, 1e-12)
    return {"candidate_shift_T": implied[0], "difference_z": float(z), "agrees": bool(z <= Z_SHIFT)}


def _measured_order(curves):
    """Curves in the order they were measured: by the time of their first point where every curve
    has one, else highest reversal field first (the MicroMag and Lake Shore order)."""
    if all(len(c) > 3 and c[3] is not None for c in curves):
        return sorted(curves, key=lambda c: float(np.asarray(c[3], float)[0]))
    return sorted(curves, key=lambda c: -c[0])


def drift_evidence(curves, moment: float, noise_sigma: float) -> dict:
    """Model-free evidence for a drift of the magnetometer during the run.

    Every curve ends in positive saturation at (nearly) the same field, where the film's state is the
    same whatever its history: the end moments m_k(B_top) (interpolated at the lowest last field of
    all curves) must not change with the measurement clock t_k ∈ [0, 1]. A linear fit gives the trend
    (m units over the run) and its error σ·√((AᵀA)⁻¹₁₁); ``significant`` at |z| > ``Z_SHIFT``.

    Additive or multiplicative? On a curve whose reversal point lies in negative saturation (the
    flat low end of the descending branch: consecutive reversal points within 3√2 σ, and
    B_r ≤ −``MIRROR_FRACTION`` B_top so that the mirror point is saturated too), the moments at
    B_r and at −B_r on the same curve are mirror states measured a curve-time apart: their sum
    S = m(B_r) + m(−B_r) cancels every odd term (background, Langevin term) and a gain (−g + g) but
    doubles an additive drift (2a). ``additive``: |mean S| > ``Z_SHIFT`` standard errors (σ√(2/n)).
    Curves are [(reversal field T, fields T, moments A·m², times s or None)]."""
    ordered = _measured_order(curves)
    n = len(ordered)
    out = {"trend": None, "se": None, "z": None, "significant": False, "mirror_sum": None, "mirror_se": None,
           "mirror_curves": 0, "additive": False}
    if n < 3:
        return out
    top = min(float(np.asarray(c[1], float)[-1]) for c in ordered)
    ends = np.array([np.interp(top, np.asarray(c[1], float), np.asarray(c[2], float) / moment) for c in ordered])
    clock = np.arange(n) / (n - 1)
    design = np.vstack([np.ones(n), clock]).T
    coef = np.linalg.lstsq(design, ends, rcond=None)[0]
    se = float(noise_sigma * np.sqrt(np.linalg.inv(design.T @ design)[1, 1]))
    z = float(coef[1] / se) if se > 0 else 0.0
    out.update(trend=float(coef[1]), se=se, z=z, significant=bool(abs(z) > Z_SHIFT))
    # negative saturation: the flat low end of the descending branch
    by_field = sorted(ordered, key=lambda c: c[0])
    reversal_m = np.array([float(np.asarray(c[2], float)[0]) / moment for c in by_field])
    flat = 3.0 * np.sqrt(2.0) * noise_sigma
    k = 1
    while k < n and abs(reversal_m[k] - reversal_m[k - 1]) < flat:
        k += 1
    sums = []
    for c in by_field[:k] if k > 1 else []:
        fields, m = np.asarray(c[1], float), np.asarray(c[2], float) / moment
        if c[0] <= -MIRROR_FRACTION * top and fields[-1] >= -c[0]:
            sums.append(m[0] + np.interp(-c[0], fields, m))
    if sums:
        mirror = float(np.mean(sums))
        mirror_se = float(noise_sigma * np.sqrt(2.0 / len(sums)))
        out.update(mirror_sum=mirror, mirror_se=mirror_se, mirror_curves=len(sums),
                   additive=bool(abs(mirror) > Z_SHIFT * mirror_se))
    return out


def drift_evidence_of(data, moment: float, noise_sigma: float, moment_offset: float = 0.0) -> dict:
    """``drift_evidence`` of a ``ForcMeasurement`` (moments less ``moment_offset``)."""
    return drift_evidence([(c.reversal_field_T, c.field_T, c.moment_Am2 - moment_offset, c.time_s) for c in data.curves],
                          moment, noise_sigma)


DRIFT_COMPONENTS = ("additive_drift", "multiplicative_drift")


def drift_agreement(evidence: dict, name: str) -> bool | None:
    """May candidate ``name`` explain a residual, given the drift evidence? None: it has no drift
    component. A drift component needs a significant end-moment trend; an additive one also a
    non-zero mirror sum, a multiplicative one a zero mirror sum (where the sum could be measured)."""
    parts = name.split("+")
    if not any(p in DRIFT_COMPONENTS for p in parts):
        return None
    if not evidence.get("significant"):
        return False
    if evidence.get("mirror_sum") is None:
        return True
    if "additive_drift" in parts and not evidence["additive"]:
        return False
    if "multiplicative_drift" in parts and "additive_drift" not in parts and evidence["additive"]:
        return False
    return True


SATURATION_LEVEL = 0.995
"""|m| of the re-simulated film at and beyond which a grid point counts as saturated."""

SATURATION_DEPTH = 3
"""Grid steps a point must lie inside the re-simulation's saturation (the points between it and the
switching saturated too): beyond the closure field every curve of the sample is the same saturated
film only if the sample closes where the model does, so a margin covers a Hamiltonian a little off."""

P_SATURATION = 1e-3
"""A candidate leaves a reversible residual in saturation when the column means' χ² has p below this."""

STATIC_CANDIDATES = ("scale", "background", "field_offset")
"""Measured-side components that are one map of (H, m) for every curve, whatever the time: after them,
the residual of the saturated film must be noise (``saturation_residual``)."""


def saturated_points(base_family, level: float = SATURATION_LEVEL, depth: int = SATURATION_DEPTH) -> np.ndarray:
    """Sign of saturation per grid point of the re-simulated ``base_family`` (n × n, rows H_r, fields
    ascending along a row, NaN below the diagonal): +1 where m ≥ level at the point and at the
    ``depth`` points before it on its curve, −1 where m ≤ −level at the point and the ``depth`` points
    after it (the negative end, before the curve switches), 0 elsewhere. The saturated film's moment
    does not depend on its disorder or exchange: there the re-simulation is exact up to its M_s."""
    m = np.asarray(base_family, float)
    pos = np.nan_to_num(m, nan=0.0) >= level
    neg = np.nan_to_num(m, nan=0.0) <= -level
    deep_pos, deep_neg = pos.copy(), neg.copy()
    n_cols = m.shape[1]
    for k in range(1, depth + 1):
        deep_pos[:, k:] &= pos[:, :-k]
        deep_pos[:, :k] = False
        deep_neg[:, :n_cols - k] &= neg[:, k:]
        deep_neg[:, n_cols - k:] = False
    return deep_pos.astype(int) - deep_neg.astype(int)


def saturation_residual(measured, model, base_family, fields, p_threshold: float = P_SATURATION,
                        moment_tolerance: float = 0.0, free: tuple = ()) -> dict:
    """Does ``model`` leave a reversible residual where the film is saturated (on the grid)?

    In saturation every curve at the field H carries the same film moment (±1), so a residual
    r = measured − model that is a function of H alone (a paramagnetic or Langevin term, a
    non-linear background) shows as column means that differ from zero by more than the scatter
    between the curves at that field. Per saturated column j (and sign) with n_j ≥ 2 curves: the mean
    r̄_j; the scatter s is pooled over the columns from the deviations of r from its column means
    (it holds the noise and anything that differs between curves, e.g. a drift left over);
    χ² = Σ n_j r̄_j²/s² on as many degrees of freedom as columns. Returns a JSON-ready dict:
    ``reversible`` (p < ``p_threshold``), ``chi2``, ``dof``, ``p``, ``n_points``, ``scatter``,
    ``fields_T`` and ``column_means`` of the saturated columns, ``max_abs_mean``, ``normalization``.

    The normalization's own errors are not a residual: a constant (the offset M_0 of a family
    normalized by its saturated ends) is always fitted on the saturated points, and with
    ``moment_tolerance`` a gain δ·model clipped to ± the tolerance (a degree of freedom fewer each).
    ``free``: terms of the candidate's own form refitted on the saturated points, "scale" (δ
    unclipped) and "background" (a term χ·μ0H): the test asks whether the candidate's *form* can
    describe the saturated residual, not its values fitted on the whole family (those also carry the
    difference between the model's film and the sample's in the hysteretic region).
    ``saturation_residual_points`` is the same test on the measured points themselves."""
    model = np.asarray(model, float)
    r = np.asarray(measured, float) - model
    sign = saturated_points(base_family)
    fields = np.asarray(fields, float)
    inside = (sign != 0) & np.isfinite(r) & np.isfinite(model)
    H = np.broadcast_to(fields[None, :], r.shape)
    column = np.broadcast_to(np.arange(r.shape[1])[None, :], r.shape)
    return _column_test(r[inside], model[inside], H[inside], sign[inside], column[inside], fields,
                        SaturationTest(p_threshold, moment_tolerance, free))


@dataclass(frozen=True)
class SaturationTest:
    """The settings of the saturation test (``saturation_residual``): ``p_threshold``, the chi-square p below
    which the saturated residual is reversible; ``moment_tolerance``, the relative band (dimensionless) inside
    which a gain is the normalization's own error and fitted away; ``free``, the terms the candidate fits
    ("scale", "background", "approach": the first law of ``APPROACH_LAW_POWERS``), fitted away in full."""

    p_threshold: float = P_SATURATION
    moment_tolerance: float = 0.0
    free: tuple = ()


def _column_test(r, model, H, sign, column, column_fields, test: SaturationTest) -> dict:
    """The statistic of ``saturation_residual`` on saturated points given flat: residual ``r``, model,
    field ``H``, saturation ``sign`` (±1) and ``column`` (index into ``column_fields``, T), with the settings
    ``test``."""
    p_threshold, moment_tolerance, free = test.p_threshold, test.moment_tolerance, test.free
    from scipy.stats import chi2 as chi2_distribution

    r, model, H = np.asarray(r, float), np.asarray(model, float), np.asarray(H, float)
    sign, column = np.asarray(sign, int), np.asarray(column, int)
    delta, chi, offset, n_fitted = 0.0, 0.0, 0.0, 0
    if r.size > 3:
        scale_free, background_free = "scale" in free, "background" in free
        with_scale = scale_free or moment_tolerance > 0

        def least_squares(columns, target):
            return np.linalg.lstsq(np.stack(columns, axis=1), target, rcond=None)[0]

        # the constant: a measured family normalized by its own saturated ends carries the offset M_0
        # of that normalization, even in m (the odd terms are the candidate's)
        ones = np.ones(r.size)
        odd = [H] if background_free else []
        # the law of approach where the reference is ±1 (``SaturatedPoints.approach`` "law")
        approach = [law_of_approach(H, sign, APPROACH_LAW_POWERS[0])] if "approach" in free else []
        if with_scale:
            delta = float(least_squares([ones, model, *odd, *approach], r)[1])
            if not scale_free:
                delta = float(np.clip(delta, -moment_tolerance, moment_tolerance))
        # the other terms at that gain (the joint least-squares solution where the gain is not clipped)
        terms = [ones, *odd, *approach]
        coefficients = least_squares(terms, r - delta * model)
        offset = float(coefficients[0])
        chi = float(coefficients[1]) if background_free else 0.0
        n_fitted = int(with_scale) + len(terms)
        r = r - delta * model - np.stack(terms, axis=1) @ coefficients
    means, counts, where, deviations = [], [], [], []
    for s_ in (1, -1):
        for j in np.unique(column[sign == s_]):
            values = r[(sign == s_) & (column == j)]
            if values.size < 2:
                continue
            means.append(float(values.mean()))
            counts.append(int(values.size))
            where.append(float(column_fields[j]))
            deviations.append(values - values.mean())
    if len(means) < 3:
        return {"reversible": False, "reason": "fewer than three saturated fields with two curves each",
                "n_points": int(sum(counts)), "dof": len(means)}
    deviations = np.concatenate(deviations)
    n_points = int(sum(counts))
    scatter = float(np.sqrt((deviations**2).sum() / max(n_points - len(means), 1)))
    if not scatter > 0:
        return {"reversible": False, "reason": "no scatter between the saturated curves", "n_points": n_points,
                "dof": len(means)}
    means_a, counts_a = np.asarray(means), np.asarray(counts)
    statistic = float((counts_a * means_a**2).sum() / scatter**2)
    dof = len(means) - n_fitted
    if dof < 1:
        return {"reversible": False, "reason": "no saturated field left after the candidate's own terms",
                "n_points": n_points, "dof": dof}
    p = float(chi2_distribution.sf(statistic, dof))
    return {"reversible": bool(p < p_threshold), "chi2": statistic, "dof": dof, "p": p, "n_points": n_points,
            "scatter": scatter, "fields_T": where, "column_means": means, "max_abs_mean": float(np.abs(means_a).max()),
            "normalization": delta, "normalization_offset": offset, "background_per_T": chi, "free": list(free),
            "rule": f"column means of the saturated residual, chi-square p < {p_threshold:g}"}


CLOSURE_TOLERANCE = 2e-3
"""The major loop is closed at a field where its two branches differ by less than this (m units) there
and at every field beyond it."""

SATURATION_MARGIN_T = 0.1
"""Measured points enter the saturation test this far (T) beyond the model's loop closure: the
sample is another film, and its own closure may lie a little further out. Chosen on the validation
files of the independent bench (``results/explore/raw_saturation_margin.py``, the major loop at the
truth and at K_u × 1.04): at 0.1 T every case whose truth is a static candidate passes that
candidate's form (background p ≥ 0.69, scale ≥ 0.97), and the paramagnet is refused by the
background's form at the truth (p = 1e-5); at 0.05 T the effect-free film fails the bare model at the
truth (p < 1e-100: the sample's own closure lies further out), at 0.2 T the paramagnet passes the
background's form (p = 0.35)."""


@dataclass(frozen=True)
class SaturatedPoints:
    """Measured points where the re-simulated film is saturated (past its major loop's closure by
    ``SATURATION_MARGIN_T``), with the model's reversible branch there.

    ``field_T``, ``m`` (normalized moment), ``sign`` (+1 positive, −1 negative saturation), ``column``
    (index of the field bin, ``column_fields_T``) per point; ``branch_fields_T``, ``branch_m``: the
    re-simulated saturated film (the major branch that comes from each saturation: the descending one
    above zero field, the ascending one below; past the loop's closure both branches are the same film);
    ``closure_T``: where the points start (negative, positive). ``file_only``: the points past the file's
    own closure with no model (``file_saturated_points``), where the model gives none (its film not
    saturated where the sample is): ``background_evidence`` reads the slope there by the law of approach.
    ``approach``: what the sample's approach to saturation is fitted with, "model" (the model's own
    shortfall from ±1) or "law" (the law of approach, ``law_of_approach``)."""

    field_T: np.ndarray
    m: np.ndarray
    sign: np.ndarray
    column: np.ndarray
    column_fields_T: np.ndarray
    branch_fields_T: np.ndarray
    branch_m: np.ndarray
    closure_T: tuple
    file_only: "SaturatedPoints | None" = None
    approach: str = "model"

    def model(self, offset_T: float = 0.0) -> np.ndarray:
        """The re-simulated film at the points' fields, the field offset ``offset_T`` applied (the
        film feels μ0H − δ)."""
        return np.interp(self.field_T - offset_T, self.branch_fields_T, self.branch_m)


def loop_closure(fields_T, descending, ascending, tolerance: float = CLOSURE_TOLERANCE) -> tuple[float, float]:
    """(negative, positive) closure fields of a major loop given on ascending ``fields_T``: the
    innermost fields beyond which the branches differ by less than ``tolerance`` everywhere. A loop
    open at the window's edge gives ∓inf there."""
    fields = np.asarray(fields_T, float)
    open_ = np.abs(np.asarray(descending, float) - np.asarray(ascending, float)) >= tolerance
    if not open_.any():
        return float(fields[fields <= 0].max(initial=0.0)), float(fields[fields >= 0].min(initial=0.0))
    first, last = int(np.argmax(open_)), int(open_.size - 1 - np.argmax(open_[::-1]))
    negative = float(fields[first - 1]) if first > 0 else -np.inf
    positive = float(fields[last + 1]) if last + 1 < fields.size else np.inf
    return negative, positive


SATURATED_BRANCH_DEFICIT = 0.05
"""A major branch coming from saturation is still the saturated film where |m| lies within this of 1 (at
that field and every field nearer its saturation): a saturated film's approach to ±1 (the grains' easy axes
tilted by σ_θ, pulled toward the field against H_K) is a few 10⁻³ on the prior's perpendicular films
(σ_θ ≤ 10°, H_K ≥ 0.3 T), a reversal domain or a labyrinth takes a whole step more."""


def saturated_reach(fields_T, descending, ascending, deficit: float = SATURATED_BRANCH_DEFICIT) -> tuple[float, float]:
    """(negative, positive): the innermost fields to which the major branches coming from saturation are
    still the saturated film (``SATURATED_BRANCH_DEFICIT``): the descending branch from +top on the positive
    side, the ascending one from −top on the negative side. Before its loop closes a film harder than the
    sample is still the saturated film on that branch (laptop bench dev 007: the decoded K_u +17 %, its
    ascending branch not closed at the window's top). A branch not saturated at the window's edge gives
    ±inf there."""
    fields = np.asarray(fields_T, float)
    top = np.asarray(descending, float) >= 1.0 - deficit
    bottom = np.asarray(ascending, float) <= -(1.0 - deficit)
    positive = np.inf
    if top[-1]:
        first_bad = fields.size - 1 - int(np.argmin(top[::-1])) if not top.all() else -1
        positive = float(max(fields[first_bad + 1], 0.0))
    negative = -np.inf
    if bottom[0]:
        first_bad = int(np.argmin(bottom)) if not bottom.all() else fields.size
        negative = float(min(fields[first_bad - 1], 0.0))
    return negative, positive


def measured_point_arrays(data, moment: float, moment_offset: float = 0.0):
    """Every measured point of a read FORC file (``forcdecode.measured``) as flat arrays: (reversal
    field per point, field, m = (M − M_0)/M_sat)."""
    reversal = np.concatenate([np.full(len(c.field_T), float(c.reversal_field_T)) for c in data.curves])
    field = np.concatenate([np.asarray(c.field_T, float) for c in data.curves])
    m = (np.concatenate([np.asarray(c.moment_Am2, float) for c in data.curves]) - moment_offset) / moment
    return reversal, field, m


MEASURED_CLOSURE_TOLERANCE = 0.02
"""The file's own major loop is closed where its two branches differ by less than this (m units, 2 % of
the saturation moment): several times a magnetometer's noise on a difference of two points (0.1–0.5 % each),
so noise alone does not hold the loop open, and below the reversible residual the saturation test reads."""


def measured_loop_closure(points, tolerance: float = MEASURED_CLOSURE_TOLERANCE) -> tuple[float, float]:
    """(negative, positive) closure of the file's own major loop (``loop_closure``) from its flat ``points``
    (reversal field, field, m per point): the major branches of ``major_branches`` (the reversal points
    against the curve reversed lowest, interpolated at the reversal fields it spans). A loop open at an
    end of the window gives ∓inf there."""
    reversal, field, m = (np.asarray(a, float) for a in points)
    ok = np.isfinite(field) & np.isfinite(m)
    reversal, field, m = reversal[ok], field[ok], m[ok]
    curves = []
    for r in np.unique(reversal):
        on = reversal == r
        order = np.argsort(field[on], kind="stable")
        curves.append((float(r), field[on][order], m[on][order]))
    if not curves:
        return -np.inf, np.inf
    (d_fields, d_m), (a_fields, a_m) = major_branches(curves, 1.0)
    d_fields, d_m = d_fields[::-1], d_m[::-1]  # ascending fields, as loop_closure reads them
    inside = (d_fields >= a_fields.min()) & (d_fields <= a_fields.max())
    if inside.sum() < 3:
        return -np.inf, np.inf
    return loop_closure(d_fields[inside], d_m[inside], np.interp(d_fields[inside], a_fields, a_m), tolerance)


def saturated_measured_points(points, branch_fields_T, descending, ascending,
                              margin_T: float = SATURATION_MARGIN_T, bin_T: float | None = None,
                              measured_closure: bool = False, closure_T: tuple | None = None) -> SaturatedPoints:
    """The measured ``points`` ((reversal field, field, m) per point, ``measured_point_arrays``) that
    lie ``margin_T`` beyond the closure of the model's major loop (``branch_fields_T``,
    ``descending``, ``ascending``: ``resimulate.major_loop_branches``): fields above the positive
    closure (any curve: each has re-saturated there), or below the negative closure on curves reversed
    below it (still saturated). Points are binned in field by ``bin_T`` (default: the median step
    between a curve's points) so that a column holds the curves measured near one field.

    ``measured_closure``: the closure is also the file's own (``measured_loop_closure``), whichever lies
    further out on each side (a finite one): a decoded film softer than the sample closes before it, and
    points of a sample still switching are no saturated film (laptop bench dev 006: the decoded K_u −24 %,
    column means up to 0.23 "past the closure"). A side where the file's loop does not close in its window
    keeps the model's. Where the model's loop closes further out than the file's (a decoded film harder
    than the sample, or one whose loop does not close in the window), the file's own closure is kept as
    long as the model's branch from that saturation is still the saturated film there (``saturated_reach``):
    the points are compared with that branch, the reversible film the sample is past its own closure.
    ``closure_T``: (negative, positive) closure given instead (``file_saturated_points``)."""
    reversal, field, m = (np.asarray(a, float) for a in points)
    fields = np.asarray(branch_fields_T, float)
    negative, positive = loop_closure(fields, descending, ascending) if closure_T is None else closure_T
    if measured_closure and closure_T is None:
        own_negative, own_positive = measured_loop_closure(points)
        reach_negative, reach_positive = saturated_reach(fields, descending, ascending)
        if np.isfinite(own_negative):
            negative = min(own_negative, max(negative, reach_negative))
        if np.isfinite(own_positive):
            positive = max(own_positive, min(positive, reach_positive))
    ok = np.isfinite(field) & np.isfinite(m)
    top, bottom = field >= positive + margin_T, (field <= negative - margin_T) & (reversal <= negative - margin_T)
    keep = ok & (top | bottom) & (field <= fields.max()) & (field >= fields.min())
    if bin_T is None:
        steps = np.abs(np.diff(field))
        steps = steps[(steps > 1e-9) & (np.diff(reversal) == 0)]
        bin_T = float(np.median(steps)) if steps.size else 1e-3
    index = np.round(field[keep] / bin_T).astype(int)
    unique, column = np.unique(index, return_inverse=True)
    branch = np.where(fields >= 0, descending, ascending)  # the branch from each saturation
    return SaturatedPoints(field_T=field[keep], m=m[keep], sign=np.where(top[keep], 1, -1), column=column,
                           column_fields_T=unique * bin_T, branch_fields_T=fields, branch_m=np.asarray(branch, float),
                           closure_T=(negative, positive))


def file_saturated_points(points, margin_T: float = SATURATION_MARGIN_T, bin_T: float | None = None,
                          ) -> SaturatedPoints | None:
    """The measured ``points`` (reversal field, field, m per point) ``margin_T`` past the file's own loop
    closure (``measured_loop_closure``), with no model: the reference film is ±1 (``branch_m`` the sign
    of the field), its approach to saturation left to ``background_evidence``'s law of approach. None where
    the file's loop does not close on either side. For a decoded film that is not saturated where the sample
    is (laptop bench dev 007: A_ex at the prior's floor and D above its critical value, a labyrinth to the
    window's top, the sample closed at ±0.37 T)."""
    field = np.asarray(points[1], float)
    own_negative, own_positive = measured_loop_closure(points)
    if not (np.isfinite(own_negative) or np.isfinite(own_positive)):
        return None
    fields = np.array([np.nanmin(field), -1e-12, 1e-12, np.nanmax(field)])
    file_points = saturated_measured_points(points, fields, np.sign(fields), np.sign(fields), margin_T=margin_T,
                                            bin_T=bin_T, closure_T=(own_negative, own_positive))
    return replace(file_points, approach="law")


APPROACH_LAW_POWERS = (2, 1)
"""The law of approach on the file's own saturated branches (``law_of_approach``, ``SaturatedPoints.approach``
"law"): 1 − m ∝ H⁻ⁿ. The first, n = 2, is the classical law for uniaxial grains whose axes the field pulls in (its χ is the one
reported); the second, n = 1, the form of a paramagnet's or an inhomogeneous film's slower approach. Where
H_K is not small beside the fields past closure neither form is the film's own, and χ moves with the form:
the difference between the two χ is added to χ's error (``_law_side_slope``); the background's form
(``_column_test``'s "approach", which gives the χ and gain the loop reports) is fitted with the first alone
(both together leave χ free to trade with H⁻¹: dev 007's −0.0225 per T came out −0.044). Chosen on the synthetic files
of tests/loop/test_signatures.py and the laptop dev files (docs/loop.md, 2026-12-03): H⁻² alone named a
background on a film 3 × as dispersed as its law and on a Langevin paramagnet (3–4 se, neither has one);
H⁻¹ alone missed dev 007's −0.0225 per T (2.6 se); both terms fitted together made χ's error 7 × larger and
lost dev 007 and a synthetic −0.02 per T; the first law with the second's spread in its error finds both
and none of the others."""


def law_of_approach(field_T, sign, power: float) -> np.ndarray:
    """The law of approach's term of each point's film, signed toward zero field: −sign·(1 T/μ0H)^power,
    of the law of approach to saturation M = M_s(1 − b/H²) + χH (power 2: the high-field fits of
    magnetometry, e.g. Jackson & Solheid, G³ 11, Q04Z15, 2010; for a film, the easy axes tilted by θ pulled
    toward the field: m ≈ 1 − θ²H_K²/2(H + H_K)², which the H⁻² term and the constant follow over a window
    past closure)."""
    return -np.asarray(sign, float) * np.abs(np.asarray(field_T, float)) ** -float(power)


def saturation_residual_points(points: SaturatedPoints, offset_T: float = 0.0, p_threshold: float = P_SATURATION,
                               moment_tolerance: float = 0.0, free: tuple = ()) -> dict:
    """``saturation_residual`` on the measured points themselves (``SaturatedPoints``): the residual of
    each point against the re-simulated saturated film at its own field (with a candidate's field
    offset ``offset_T``), columns the field bins. The grid's test sees a few deep-saturated grid
    fields; this one every measured field past the loop's closure, where a paramagnet's curvature is
    largest. Adds the model's ``closure_T`` and ``points`` = "measured" to the result."""
    model = points.model(offset_T)
    out = _column_test(points.m - model, model, points.field_T, points.sign, points.column, points.column_fields_T,
                       SaturationTest(p_threshold, moment_tolerance, free))
    return {**out, "closure_T": list(points.closure_T), "points": "measured"}


Z_BACKGROUND = 3.0
"""A linear background is claimed from the saturated film at |χ| > 3 standard errors."""


APPROACH_PRIOR_SD = 2.0
"""The prior's standard deviation of the approach coefficient c against the decoded film (``_side_slope``):
the sample falls short of saturation (1 + c) × as far as the decoded film. The shortfall scales with the
square of the easy axes' spread (m ≈ 1 − θ²H_K²/2(H + H_K)²), so a decode that has the spread wrong by a
factor 2 either way gives c from −0.75 to 3. Without it, where the decoded film's shortfall past closure
is a few 10⁻⁴ (a hard, well-aligned film), the term is a near copy of the constant and the line and the
fit trades χ with it: on the fixed point's test film (χ 0.08 per T, noise 0.002) c came out −8.6 (a
sample beyond saturation) and χ's error 0.026 per T, 3.0 se on one CPU and 2.99 on another."""


def _side_slope(r, H, approach, column, scatter: float, prior_sd: float | None = None) -> dict | None:
    """χ and its standard error (per T, m units) of one saturated side: weighted least squares of the
    column means of the residual ``r`` (each column's weight its count over the between-curve ``scatter``
    squared) on a constant, the field ``H`` and an approach term ``approach``: against the decoded film its
    own shortfall from saturation (m_model − sign m_model: the approach to saturation, which scales with
    the film's tilt and anisotropy dispersion, so a decoded film whose dispersion is off leaves a residual
    of that shape, not a line; ``approach_coefficient`` 0.5: the sample falls short of saturation 1.5 × as
    far as the model), against ±1 the law of approach's term. ``prior_sd``: a Gaussian prior of that width
    centred on 0 for the approach coefficient (``APPROACH_PRIOR_SD`` against the decoded film; None: free).
    The error is inflated by the fit's own misfit (χ²/dof where above 1). None with fewer than four
    columns."""
    columns = np.unique(column)
    if columns.size < 4:
        return None
    means = np.array([r[column == j].mean() for j in columns])
    fields = np.array([H[column == j].mean() for j in columns])
    approaches = np.array([approach[column == j].mean() for j in columns])
    weights = np.array([(column == j).sum() for j in columns], float) / scatter**2
    design = np.stack([np.ones(columns.size), fields, approaches], axis=1)
    normal = design.T @ (weights[:, None] * design)
    if prior_sd is not None:
        normal[2, 2] += 1.0 / prior_sd**2
    try:
        covariance = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return None
    coefficients = covariance @ (design.T @ (weights * means))
    misfit = float((weights * (means - design @ coefficients) ** 2).sum()) / max(columns.size - 3, 1)
    se = float(np.sqrt(max(misfit, 1.0) * covariance[1, 1]))
    if not np.isfinite(se) or se <= 0:
        return None
    return {"chi_per_T": float(coefficients[1]), "se_per_T": se, "approach_coefficient": float(coefficients[2]),
            "columns": int(columns.size), "misfit_chi2_per_dof": misfit}


def background_evidence(points: SaturatedPoints, moment_tolerance: float = 0.0,
                        p_threshold: float = P_SATURATION) -> dict:
    """Is there a linear background χ·μ0H in the measured file, seen where the film is saturated?

    Past its major loop's closure every curve carries the same saturated film whatever the disorder or
    the code (``saturation_residual_points``); a substrate's or a holder's susceptibility adds χ·μ0H
    there, odd in the field, the same χ above the positive closure and below the negative one. The
    held-out curves hardly see it: inside a ±0.5 T window a χ of 0.07 per T moves m by 0.035 at the
    ends, a few per cent of a residual that the decoded Hamiltonian's switching misfit sets at 0.1–0.4
    (laptop bench dev 008: background 6.9 %, held-out gain 2 % against a floor of 7 %).

    ``significant`` when (i) the background's form (gain and χ free) leaves no reversible residual in
    saturation (``saturation_residual_points``, chi-square p not below ``p_threshold``), (ii) χ from both
    saturated sides together exceeds ``Z_BACKGROUND`` standard errors and (iii) the two sides agree within
    the same bound where both are measured (four field columns each). Each side's χ is fitted on its
    column means beside the model's own approach to saturation (``_side_slope``); its error is inflated
    by the fit's misfit, so a curved residual (a sample still saturating where the model already is) is
    no evidence. The bare model's test (``bare_p``: no term free but the normalization's, within
    ``moment_tolerance``) is reported beside it and not asked: its chi-square spreads its power over every
    column, the fit puts it on the one direction a background takes (laptop dev 006, a line alone before
    the approach term: χ −0.0093 ± 0.0031 per T, truth −0.0052, bare p 0.43). ``chi_per_T``: the combined
    estimate (m units per T), with ``se_per_T``; ``model_chi_per_T`` and ``model_scale``: χ and the gain of
    the background's form fitted
    jointly on the saturated points (the file's normalization by its own saturated moment carries the
    background's share of it: a gain 1/(1 + χ·B_top) where the moment is read at the window's top).
    Where the decoded film gives no evidence (no saturated points where the sample is saturated), the same
    test runs on ``points.file_only``: past the file's own closure against ±1, the approach fitted by the
    law of approach (``APPROACH_LAW_POWERS``); ``reference`` says which film the slope was read against
    (in words), ``file_only`` whether it was the file's own branches."""
    out = _background_evidence_on(points, moment_tolerance, p_threshold)
    if out.get("chi_per_T") is None and points.file_only is not None:
        # the decoded film is not saturated where the sample is: the sample's own saturated branches
        file_out = _background_evidence_on(points.file_only, moment_tolerance, p_threshold)
        if file_out.get("chi_per_T") is not None:
            return {**file_out, "model_reason": out.get("reason")}
    return out


def _law_side_slope(r, H, sign, column, scatter: float) -> dict | None:
    """``_side_slope`` of one side of the file's own saturated branches with the law of approach
    (``APPROACH_LAW_POWERS``): χ from the first law, its error widened by the second law's χ (added in
    quadrature: the approach's form is not known where H_K is comparable with the fields)."""
    fits = []
    for n in APPROACH_LAW_POWERS:
        fit = _side_slope(r, H, law_of_approach(H, sign, n), column, scatter)
        if fit is None:
            return None
        fits.append(fit)
    spread = abs(fits[0]["chi_per_T"] - fits[1]["chi_per_T"]) if len(fits) > 1 else 0.0
    return {**fits[0], "se_per_T": float(np.hypot(fits[0]["se_per_T"], spread)), "statistical_se_per_T":
            fits[0]["se_per_T"], "law_spread_per_T": float(spread)}


def _background_evidence_on(points: SaturatedPoints, moment_tolerance: float, p_threshold: float) -> dict:
    """``background_evidence`` on one set of saturated points, against their reference (``approach``)."""
    law = ("approach",) if points.approach == "law" else ()
    bare = saturation_residual_points(points, moment_tolerance=moment_tolerance, p_threshold=p_threshold, free=law)
    linear = saturation_residual_points(points, moment_tolerance=moment_tolerance, p_threshold=p_threshold,
                                        free=("scale", "background", *law))
    out = {"bare_p": bare.get("p"), "linear_p": linear.get("p"), "significant": False, "chi_per_T": None,
           "reference": "the re-simulated saturated film" if not law else "the file's own saturated branches "
                        "(law of approach)",
           "file_only": bool(law),
           "rule": (f"the background's form leaves no reversible residual in saturation (p ≥ {p_threshold:g}), "
                    f"|χ| > {Z_BACKGROUND:g} standard errors, the two saturated sides agreeing")}
    scatter = bare.get("scatter")
    if not scatter:
        return {**out, "reason": bare.get("reason", "no saturated points")}
    model = points.model()
    r, deficit = points.m - model, model - np.sign(model)  # the model's own shortfall from ±1, signed
    sides = {}
    for sign, label in ((1, "positive"), (-1, "negative")):
        on = points.sign == sign
        # each side with its own level: the normalization's offset and gain move the two sides' levels
        side = None
        if on.sum() and law:  # against ±1: the law of approach
            side = _law_side_slope(r[on], points.field_T[on], points.sign[on], points.column[on], scatter)
        elif on.sum():
            side = _side_slope(r[on], points.field_T[on], deficit[on], points.column[on], scatter,
                               prior_sd=APPROACH_PRIOR_SD)
        if side is not None:
            sides[label] = side
    out["sides"] = sides
    if not sides:
        return {**out, "reason": "fewer than four saturated field columns on either side"}
    w = np.array([1 / s["se_per_T"] ** 2 for s in sides.values()])
    chis = np.array([s["chi_per_T"] for s in sides.values()])
    chi, se = float((w * chis).sum() / w.sum()), float(1 / np.sqrt(w.sum()))
    agree = True
    if len(sides) == 2:
        a, b = sides["positive"], sides["negative"]
        agree = bool(abs(a["chi_per_T"] - b["chi_per_T"]) <= Z_BACKGROUND * np.hypot(a["se_per_T"], b["se_per_T"]))
    out.update(chi_per_T=chi, se_per_T=se, sides_agree=agree,
               model_chi_per_T=linear.get("background_per_T"), model_scale=1.0 + float(linear.get("normalization", 0.0)))
    tested = linear.get("p") is not None  # too few saturated columns for the form's test: no evidence
    out["significant"] = bool(tested and not linear["reversible"] and abs(chi) > Z_BACKGROUND * se and agree)
    if not tested:
        out["reason"] = linear.get("reason", "the background's form could not be tested")
    return out


def background_agreement(evidence: dict | None, name: str, parameters: dict) -> bool | None:
    """May candidate ``name`` (fitted ``parameters``) explain a residual, given the background evidence?
    None: it has no background component, or the saturated film could not be tested. A background needs
    the saturated film's slope, of the sign of the candidate's fitted χ."""
    if "background" not in name.split("+") or evidence is None or evidence.get("chi_per_T") is None:
        return None
    chi = parameters.get("chi_per_T")
    return bool(evidence["significant"] and chi is not None and np.sign(chi) == np.sign(evidence["chi_per_T"]))


def static_candidate(name: str) -> bool:
    """Is candidate ``name`` made only of time-independent measured-side maps (``STATIC_CANDIDATES``)?"""
    return all(part in STATIC_CANDIDATES for part in name.split("+"))


SHIFT_IN_SATURATION = ("bias_field",)
"""Physics candidates that act on a saturated film as a field offset does: a bias field B_b felt by the
film moves its reversible branch to m(μ0H + B_b), the offset −B_b (``candidate_shift``). They are the
same observable as an offset (``SAME_OBSERVABLE``), so the saturation test holds them to the same rule."""


def saturation_gated(name: str, kind: str) -> bool:
    """Does the saturation test judge candidate ``name`` of ``kind`` ("measured" or "physics")? The static
    measured-side candidates and the physics candidates that only shift the film (``SHIFT_IN_SATURATION``)."""
    return (kind == "measured" and static_candidate(name)) or (kind == "physics" and name in SHIFT_IN_SATURATION)


def saturation_terms(name: str) -> tuple:
    """The terms of static candidate ``name`` that act on a saturated film: its scale (carried by
    "scale" and "background") and its background; a field offset moves nothing there."""
    parts = name.split("+")
    return tuple(t for t, present in (("scale", "scale" in parts or "background" in parts),
                                      ("background", "background" in parts)) if present)


SHIFT_CANDIDATES = ("field_offset", "bias_field")
"""Candidate components that shift the loop along the field: they need the shift's evidence."""


def shifts_field(name: str) -> bool:
    """Does candidate ``name`` (a single effect or a '+' combination) shift the loop along the field?"""
    return any(part in SHIFT_CANDIDATES for part in name.split("+"))


__all__ = ["background_agreement", "background_evidence", "calibrated_shift", "candidate_shift", "CLOSURE_TOLERANCE",
           "drift_agreement", "DRIFT_COMPONENTS",
           "drift_evidence", "drift_evidence_of", "field_shift", "field_shift_of", "LEVELS", "loop_closure",
           "major_branches", "major_loop_protocol", "MEASURED_CLOSURE_TOLERANCE", "measured_loop_closure",
           "measured_point_arrays", "MIRROR_FRACTION", "N_END",
           "P_SATURATION", "saturated_measured_points", "file_saturated_points", "law_of_approach",
           "APPROACH_LAW_POWERS", "APPROACH_PRIOR_SD", "saturated_reach", "SATURATED_BRANCH_DEFICIT", "saturated_points", "SaturatedPoints",
           "SATURATION_DEPTH",
           "saturation_gated", "SATURATION_LEVEL", "SATURATION_MARGIN_T", "saturation_residual",
           "saturation_residual_points", "saturation_terms", "shift_agreement", "SHIFT_CANDIDATES",
           "SHIFT_IN_SATURATION", "shifts_field", "static_candidate", "STATIC_CANDIDATES", "Z_BACKGROUND", "Z_SHIFT"]
