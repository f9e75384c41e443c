"""Is a measured FORC family usable? Domain by physics: the major loop must saturate (close) inside
the measured window; the training-grid image is then completed where the state is known.

Fields are μ0H in tesla; moments in the file's A·m²; m = (M − M_0)/M_sat on the grid.

**Noise σ** (A·m²): every interior point of every curve is compared with the straight line through
its two neighbours, r = M_i − [w M_{i−1} + (1 − w) M_{i+1}], w = (H_{i+1} − H_i)/(H_{i+1} − H_{i−1});
for white noise Var r = σ²(1 + w² + (1 − w)²), so σ = 1.4826·MAD of r/√(1 + w² + (1 − w)²) over all
curves (robust: the few points at a switching jump do not count). Where the file has calibration
points, the scatter of successive ones, 1.4826·MAD(ΔM_cal)/√2, is reported beside it.

**Coincidence** (the noise-only tolerance): a curve coincides with a reference (another curve, or
the upper branch) on a field range when the 5-point running median d_i of their difference stays
within τ_i at each of the K compared points. Under noise alone (a saturated film, the two curves
identical before noise) d_i has the variance

    s_i² = ½·2σ² + 2 σ_f² M_i²,

- 2σ²: the point variance of a difference of two white-noise curves (σ² (1 + t² + (1 − t)²) ≤ 2σ²
  where the reference is interpolated at the fraction t of an interval); the running median
  divides it by 2 or more (measured: 0.29 inside, 0.45 at the ends, up to 0.36 and 0.48 with a
  reference sampled half as densely, whose interpolation correlates neighbours; ½ bounds them,
  1 where fewer than 3 points are compared and nothing is medianed);
- 2 σ_f² M_i²: the reader's drift correction scales each curve by m_cal,0/m_cal,k, its own noisy
  calibration point (``measured.drift``), so each curve carries its own factor error ε_k with
  σ_f = σ_cal/|m̄_cal| (σ_cal: the calibration noise above; σ/|m̄_cal| with fewer than 5 calibration
  points), an offset ε_k·M along the whole curve that the running median does not reduce; M_i the
  measured moment there. σ_f = 0 for curves not drift-corrected (``domain_of_measurement`` of a
  file read without drift correction; ``analyse_saturation`` without calibration moments).

The check takes the maximum over the K points, so the threshold is the Bonferroni (1 − α)-quantile
of max_i |d_i|/s_i, valid whatever the correlation between neighbouring points:

    τ_i = max(z_K s_i, q),  z_K = Φ⁻¹(1 − α/(2K)),

q = one 8-bit level of the training image, (2/255)·M_half, M_half = half the loop height (max − min
of all moments)/2 (a difference below one grey level is invisible to the networks). α is the
whole-file false-refusal rate ``ALPHA_FILE`` = 5 % split evenly over the checks that can refuse a
saturated film: the n_low comparisons that must pass for the lower end to close (curves reversed
up to the first one a training-grid step above the lowest), the lower flatness, the upper closure
and the upper flatness, α = 0.05/(n_low + 3) (1.25 % for 40 evenly spaced curves over ±0.7 T, e.g.
z_40 = 3.60: τ = 6.2σ at saturation when σ_f M = σ, 3.6σ without drift correction). The
rejoining test of the completion (a curve's last 3 points against U) uses the same α with K = 3 ×
the curves it tests.

The flatness checks compare the running median of a pooled branch with its first (last) value, a
difference of two running medians: white part ≤ ½·2σ² as above, K the branch's points, and the
correction part by which curves hold the two windows (``_offset_share``): 0 when a majority of both
windows' points are of one and the same curve (one factor; near the lowest reversal field the lower
branch is the lowest curve alone), ½ σ_f² M² per window of points of distinct curves (the reversal
points on U: independent errors, medianed), σ_f² M² per any other window.

Before issue 45 the tolerance was τ = max(4σ, q) on every point: it ignored the correction's factor
errors (the running-median difference of two drift-corrected curves at saturation has a standard
deviation of about 1.6σ, not 0.75σ, when the calibration points are as noisy as the curves) and
the maximum over K points. Measured false-refusal rate on noise-only saturated Preisach films
(40 curves, 0.3 % noise, written to an instrument file with one noisy calibration point per curve,
read back and drift-corrected by ``measured.read_forc``, ``domain_of_measurement``; 200 seeds each,
seeds 0..199): a perpendicular film (switching ±(0.25 ± 0.01) T in ±0.5 T), calibration noise σ:
0 % (before: 5.5 %, the issue's film among them: "lower end not saturated ... 1.7 % of the half
loop height, 5 σ"); switching ±(0.25 ± 0.04) T in ±0.7 T, calibration noise 3σ: 0 % (before 45 %);
the same as a Lake Shore CSV (time-interpolated correction): 0 % (before 18 %). Power kept: a lowest
curve 3 % or 5 % of the half loop height from the others (not closed) refused in 100 % of 100
seeds, a reversible slope of 1.5 M_s per T in 100 % (1.0 M_s/T: 95 %, 100 % before; over one
training-grid step δ a slope below about 5σ/δ, 0.5 M_s/T at 0.3 % noise, is not resolved). A
real difference must exceed about 6σ (2 % of M_s at 0.3 % noise with the correction's errors).
Re-made by ``.venv/bin/python -m pytest -p no:cacheprovider -q -m "slow or not slow"
tests/forc/test_saturation_noise.py``.

**Rule** (δ = one training-grid step, 2B_max/(n − 1)):

- lower end: the closure field is the largest reversal field up to which every curve coincides with
  the lowest curve (the curves reversed there start from one state); the flat field the largest
  field up to which the lower branch L (those curves' points below the closure field, running
  median) stays within max(τ_i, 0.1·M_half·(H − H_min)/T) of its first value (a steeper branch is a
  reversible, unsaturated magnetization, e.g. a paramagnetic slope). H_− is the smaller of the two;
  the end is saturated when H_− − H_r,min ≥ δ and H_− ≥ −B_max;
- upper end: the longest-reaching of those curves (the ascending major branch, from negative
  saturation) is compared with the upper branch U (the descending branch: the curves' reversal
  points, above the highest reversal field the highest curve reaching there, and the calibration
  point at HCal); the closure field is the lowest field from which on it coincides with U to its
  end, the flat field the lowest field from which U stays within max(τ_i, 0.1·M_half·(top − H)/T)
  of its last value; H_+ is the larger. Saturated when the ascending branch's end − H_+ ≥ δ and
  H_+ ≤ B_max.

Usable when both ends saturate and the completed image has no unknown cell. Completion on the
training grid (rows H_r, columns H, n × n, NaN below the diagonal): a row takes the measured curve
nearest to its reversal field, interpolated linearly in H; rows reversed at or above H_+ are the
reversible upper branch; rows below the lowest reversal field are the ascending branch (m = −1 where
not measured); beyond a curve's last field the state is known only if the curve has rejoined the
upper branch (its last points coincide with U, or it ends above H_+): it continues as U, and as
m = +1 beyond the measured window. A cell that none of these rules reaches is unknown.
Normalization: M_sat = (U_s − L_s)/2 and M_0 = (U_s + L_s)/2, U_s and L_s the medians of the
measured points on the saturated upper (H ≥ H_+) and lower (curves reversed at or below H_−,
H ≤ H_−) branches; a family without both saturated branches (analysed only when forced) is divided
by the median of its curves' values at their largest field, without offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

MAD_TO_SIGMA = 1.4826
ALPHA_FILE = 0.05
"""Whole-file false-refusal rate on a noise-only saturated film, split evenly (Bonferroni) over the
checks that can refuse it (module docstring, **Coincidence**)."""
MEDIAN_FACTOR = 0.5
"""Variance of the running median of a two-curve difference over the difference's point variance
2σ², bounded (measured 0.29 to 0.48, module docstring); 1 where fewer than 3 points are compared."""
RUNNING = 5
FLAT_SLOPE_PER_T = 0.10
"""A saturated branch changes by at most this fraction of the half loop height per tesla (beyond τ):
the completion holds m = ±1 outside the window, off by less than 0.1 one tesla away."""

MEASURED, COMPLETED, UNKNOWN = 1, 2, 0
"""Source of each grid cell (``MeasuredDomain.source``)."""


def noise_level(curves) -> float:
    """σ (moment units) of the point-to-point noise along the curves (module docstring); NaN when no
    curve has three points."""
    values = []
    for h, y in curves:
        h = np.asarray(h, float)
        y = np.asarray(y, float)
        if h.size < 3:
            continue
        span = h[2:] - h[:-2]
        ok = np.abs(span) > 0
        w = np.where(ok, (h[2:] - h[1:-1]) / np.where(ok, span, 1.0), 0.5)
        r = y[1:-1] - (w * y[:-2] + (1 - w) * y[2:])
        values.append((r / np.sqrt(1 + w**2 + (1 - w) ** 2))[ok])
    if not values:
        return float("nan")
    r = np.concatenate(values)
    return float(MAD_TO_SIGMA * np.median(np.abs(r - np.median(r))))


def calibration_noise(calibration_moments) -> float:
    """σ from successive calibration points, 1.4826·MAD(ΔM)/√2; NaN below five points."""
    m = np.asarray(calibration_moments, float)
    if m.size < 5:
        return float("nan")
    d = np.diff(m)
    return float(MAD_TO_SIGMA * np.median(np.abs(d - np.median(d))) / np.sqrt(2))


def correction_noise(calibration_moments, sigma: float = float("nan")) -> float:
    """σ_f: the relative noise of a curve's drift-correction factor m_cal,0/m_cal,k, the calibration
    noise over |mean calibration moment| (σ over it below five calibration points); NaN without any."""
    m = np.asarray(calibration_moments if calibration_moments is not None else [], float)
    m = m[np.isfinite(m)]
    if m.size == 0 or not abs(np.mean(m)) > 0:
        return float("nan")
    s = calibration_noise(m)
    if not np.isfinite(s):
        s = sigma
    return float(s / abs(np.mean(m)))


@dataclass(frozen=True)
class _Noise:
    """The noise-only tolerance of a comparison (module docstring, **Coincidence**)."""

    sigma: float  # white point noise σ (moment units), 0 when unknown
    relative: float  # σ_f, relative noise of a curve's drift-correction factor, 0 without correction
    level: float  # q, one image level
    alpha: float  # false-refusal rate of one check

    def z(self, K: int) -> float:
        """z_K = Φ⁻¹(1 − α/(2K)) (Bonferroni over K points)."""
        return float(-ndtri(self.alpha / (2 * max(int(K), 1))))

    def spread(self, moments, medianed: bool = True, offset_share=2.0):
        """s_i: standard deviation of a (running-median) difference at moments M_i; ``offset_share``:
        the drift-correction variance in units of σ_f² M_i² (2: two curves, ``_offset_share``)."""
        factor = MEDIAN_FACTOR if medianed else 1.0
        m = np.abs(np.asarray(moments, float))
        return np.sqrt(factor * 2 * self.sigma**2 + np.asarray(offset_share, float) * (self.relative * m) ** 2)

    def tolerance(self, moments, K: int | None = None, medianed: bool | None = None, offset_share=2.0):
        """τ_i = max(z_K s_i, q) at moments M_i; K defaults to their number, ``medianed`` to K ≥ 3."""
        moments = np.atleast_1d(np.asarray(moments, float))
        K = moments.size if K is None else K
        medianed = moments.size >= 3 if medianed is None else medianed
        return np.maximum(self.z(K) * self.spread(moments, medianed, offset_share), self.level)


def _offset_share(labels, ref: int, width=RUNNING):
    """Per point i of a branch (points labelled by their curve), the variance of the drift-correction
    part of running-median(i) − running-median(ref), in units of σ_f² M² (windows as
    ``_running_median``). A window held by a majority of the points of one curve follows that curve's
    factor error (1; the minority's errors move its median at most to the majority's next order
    statistic, a white-noise shift), a window of points of distinct curves medians their independent
    errors (``MEDIAN_FACTOR``), any other window takes one curve's error (1). Two windows held by the
    same curve share its error: 0."""
    labels = np.asarray(labels, float)
    if labels.size < 3:
        windows = labels[:, None]
    elif labels.size < width:
        windows = np.broadcast_to(labels, (labels.size, labels.size))
    else:
        half = width // 2
        padded = np.concatenate([np.full(half, np.nan), labels, np.full(half, np.nan)])
        windows = np.lib.stride_tricks.sliding_window_view(padded, width)
    counts = (windows[:, :, None] == windows[:, None, :]).sum(axis=2)  # NaN equals nothing
    mode = windows[np.arange(windows.shape[0]), np.argmax(counts, axis=1)]
    size = np.isfinite(windows).sum(axis=1)
    held = 2 * counts.max(axis=1) > size
    distinct = (counts.max(axis=1) == 1) & (size >= 3)
    side = np.where(distinct, MEDIAN_FACTOR, 1.0)
    return np.where(held & held[ref] & (mode == mode[ref]), 0.0, side + side[ref])


def _running_median(x, width=RUNNING):
    """Median over a centred window of ``width`` points, truncated at the ends (3 points there)."""
    x = np.asarray(x, float)
    if x.size < width:
        return x.copy() if x.size < 3 else np.full(x.size, np.median(x))
    half = width // 2
    padded = np.concatenate([np.full(half, np.nan), x, np.full(half, np.nan)])
    return np.nanmedian(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1)


def _interpolation_allowance(ref_h, ref_y, h):
    """A bound on the error of interpolating the reference linearly at ``h`` (t: the position in the
    interval [k, k + 1]): the smaller of the monotone bound |y_{k+1} − y_k|·max(t, 1 − t) (a curve is
    monotone between two points, so the truth lies between them) and the curvature bound
    max(|Δ²y_k|, |Δ²y_{k+1}|)·max(t, 1 − t) (second differences at the interval's ends: a smooth
    branch, f''Δ², far below its slope; a jump between two points, an avalanche, J on both). Zero
    where the fields coincide."""
    if ref_h.size < 2:
        return np.zeros(h.size)
    k = np.clip(np.searchsorted(ref_h, h) - 1, 0, ref_h.size - 2)
    span = ref_h[k + 1] - ref_h[k]
    t = np.clip(np.where(span > 0, (h - ref_h[k]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)
    bound = np.abs(ref_y[k + 1] - ref_y[k])
    if ref_h.size >= 3:
        d2 = np.abs(ref_y[:-2] - 2 * ref_y[1:-1] + ref_y[2:])
        node = np.concatenate([[d2[0]], d2, [d2[-1]]])
        bound = np.minimum(bound, np.maximum(node[k], node[k + 1]))
    on_node = np.isclose(h, ref_h[k], rtol=0, atol=1e-12) | np.isclose(h, ref_h[k + 1], rtol=0, atol=1e-12)
    return np.where(on_node, 0.0, bound * np.maximum(t, 1 - t))


def _difference(h, y, ref_h, ref_y):
    """(fields, running-median difference y − ref, less the reference's interpolation allowance,
    never below 0 in size) on the fields of (h, y) inside the reference's range."""
    h = np.asarray(h, float)
    inside = (h >= ref_h[0] - 1e-12) & (h <= ref_h[-1] + 1e-12)
    if inside.sum() == 0:
        return h[:0], h[:0]
    d = _running_median(np.asarray(y, float)[inside] - np.interp(h[inside], ref_h, ref_y))
    allowance = _running_median(_interpolation_allowance(np.asarray(ref_h, float), np.asarray(ref_y, float), h[inside]))
    return h[inside], np.sign(d) * np.maximum(np.abs(d) - allowance, 0.0)


def _branch_change(h, y_med):
    """(|change| between the ends, slope of a straight-line fit) of a branch (moment units, per T)."""
    change = float(abs(y_med[-1] - y_med[0]))
    slope = float(np.polyfit(h, y_med, 1)[0]) if h.size >= 2 and np.ptp(h) > 0 else float("nan")
    return change, slope


def _sorted(h, y):
    order = np.argsort(h, kind="stable")
    return np.asarray(h, float)[order], np.asarray(y, float)[order]


@dataclass
class MeasuredDomain:
    """The saturation analysis of one measured family and its completion on the training grid."""

    usable: bool
    reason: str | None
    noise_Am2: float
    tolerance_Am2: float
    M_half_Am2: float
    H_minus_T: float
    H_plus_T: float | None
    lower_saturated: bool
    upper_saturated: bool
    moment_saturation_Am2: float
    moment_offset_Am2: float
    calibration_noise_Am2: float = float("nan")
    high_field_slope_Am2_per_T: float = float("nan")
    family: np.ndarray | None = field(default=None, repr=False)
    source: np.ndarray | None = field(default=None, repr=False)
    summary: dict = field(default_factory=dict)

    def report(self) -> dict:
        """JSON-ready summary (no arrays)."""
        def num(v):
            return None if v is None or not np.isfinite(v) else float(v)

        return {"usable": self.usable, "reason": self.reason, "noise_Am2": num(self.noise_Am2),
                "calibration_noise_Am2": num(self.calibration_noise_Am2), "tolerance_Am2": num(self.tolerance_Am2),
                "half_loop_height_Am2": num(self.M_half_Am2), "H_minus_T": num(self.H_minus_T),
                "H_plus_T": num(self.H_plus_T), "lower_saturated": self.lower_saturated,
                "upper_saturated": self.upper_saturated, "moment_saturation_Am2": num(self.moment_saturation_Am2),
                "moment_offset_Am2": num(self.moment_offset_Am2),
                "high_field_slope_Am2_per_T": num(self.high_field_slope_Am2_per_T), **self.summary}


def _upper_branch(curves_by_hr, calibration):
    """U as (fields, moments, curve of each point (−1: the calibration point)): the reversal points of
    every curve, then, above the highest field covered so far, the points of the highest curve
    reaching there, and the calibration point."""
    points_h = [c[0][0] for c in curves_by_hr]
    points_y = [c[1][0] for c in curves_by_hr]
    labels = list(range(len(curves_by_hr)))
    top = max(points_h)
    for k in range(len(curves_by_hr) - 1, -1, -1):  # highest reversal field first
        h, y = curves_by_hr[k]
        above = h > top + 1e-12
        if above.any():
            points_h.extend(h[above])
            points_y.extend(y[above])
            labels.extend([k] * int(above.sum()))
            top = h[above].max()
    if calibration is not None and calibration[0] > top + 1e-12:
        points_h.append(calibration[0])
        points_y.append(calibration[1])
        labels.append(-1)
    order = np.argsort(points_h, kind="stable")
    h, y, labels = np.asarray(points_h, float)[order], np.asarray(points_y, float)[order], np.asarray(labels)[order]
    keep = np.concatenate([[True], np.diff(h) > 0])
    return h[keep], y[keep], labels[keep]


@dataclass(frozen=True)
class _Family:
    """A measured family as the saturation checks read it (moments in A·m², fields in T)."""

    hr: np.ndarray  # reversal fields, increasing
    curves: list  # per reversal field, (fields, moments) sorted by field
    B_max_T: float  # half width of the training window
    step: float  # training-grid step 2 B_max/(n − 1)
    sigma: float  # white point noise σ (NaN when it cannot be estimated)
    everything: np.ndarray  # every moment of every curve
    M_half: float  # half the loop height, (max − min)/2
    relative: float  # σ_f, relative noise of a curve's drift-correction factor (0 without correction)
    n_checks: int  # checks that can refuse a saturated film (the Bonferroni split of ALPHA_FILE)
    noise: _Noise  # the noise-only tolerance of a comparison


@dataclass(frozen=True)
class _LowerEnd:
    """The lower end: the curves that coincide with the lowest one and the branch they pool (T, A·m²)."""

    accepted: list  # indices of the curves coinciding with the lowest (0 included)
    first_miss: tuple | None  # (curve, fields, differences, tolerances) of the first one that does not
    H_close: float  # closure field: the highest reversal field of a coinciding curve
    low_h: np.ndarray  # the pooled branch up to H_close: fields
    low_y: np.ndarray  # its moments
    low_med: np.ndarray  # their running median
    H_flat: float  # the branch is flat (within τ and FLAT_SLOPE_PER_T) up to here
    H: float  # H_−, the lower saturation field: min(H_close, H_flat)
    saturated: bool  # H_− at least a grid step above the lowest reversal field, inside the window


@dataclass(frozen=True)
class _UpperEnd:
    """The upper end: the ascending major branch against the upper branch U (T, A·m²)."""

    U_h: np.ndarray  # the upper branch: fields
    U_y: np.ndarray  # its moments
    U_med: np.ndarray  # their running median
    a: int  # the curve taken as the ascending branch (the one of the lower end reaching highest)
    h: np.ndarray  # fields where the ascending branch is compared with U
    d: np.ndarray  # the running-median differences there
    tol: np.ndarray  # their tolerances
    H_close: float | None  # the branch coincides with U from here on (None: not at its end)
    H_flat: float  # U is flat (within τ and FLAT_SLOPE_PER_T) from here on
    H: float | None  # H_+, the upper saturation field: max(H_close, H_flat); None without closure
    saturated: bool  # H_+ at least a grid step below the branch's end, inside the window


def _measured_family(reversal_fields_T, curves, B_max_T, n, calibration_moments,
                     correction_noise_relative) -> _Family:
    """Stage 1: the curves sorted, the noise σ and σ_f, the loop height and the Bonferroni split."""
    hr = np.asarray(reversal_fields_T, float)
    order = np.argsort(hr, kind="stable")
    hr = hr[order]
    curves = [_sorted(*curves[k]) for k in order]
    step = 2 * B_max_T / (n - 1)
    sigma = noise_level(curves)
    everything = np.concatenate([y for _, y in curves])
    M_half = float((everything.max() - everything.min()) / 2)
    if correction_noise_relative is None:
        correction_noise_relative = correction_noise(calibration_moments, sigma) if calibration_moments is not None else 0.0
    relative = float(correction_noise_relative)
    relative = relative if np.isfinite(relative) and relative > 0 else 0.0
    # the checks that can refuse a saturated film: the lower-end comparisons up to the first curve a
    # grid step above the lowest, the lower flatness, the upper closure and the upper flatness
    above = np.flatnonzero(hr - hr[0] >= step - 1e-12)
    n_lower = int(above[0]) if above.size else len(curves) - 1
    n_checks = n_lower + 3
    noise = _Noise(sigma=sigma if np.isfinite(sigma) else 0.0, relative=relative, level=2 / 255 * M_half,
                   alpha=ALPHA_FILE / n_checks)
    return _Family(hr, curves, B_max_T, step, sigma, everything, M_half, relative, n_checks, noise)


def _coinciding_with_lowest(fam: _Family):
    """Stage 2a: the curves, from the lowest reversal field up, that coincide with the lowest one
    (each against the coinciding curve reaching highest); returns (their indices, the first miss)."""
    curves, noise = fam.curves, fam.noise
    accepted = [0]
    for k in range(1, len(curves)):
        ref = max(accepted, key=lambda a: curves[a][0][-1])
        h, d = _difference(*curves[k], *curves[ref])
        if h.size < 3:
            h, d = _difference(*curves[ref], *curves[k])  # the reference inside this curve
        tol = noise.tolerance(np.interp(h, *curves[k])) if h.size else h
        if h.size >= 3 and np.all(np.abs(d) <= tol):
            accepted.append(k)
            continue
        return accepted, (k, h, d, tol)
    return accepted, None


def _lower_end(fam: _Family) -> _LowerEnd:
    """Stage 2: closure and flatness of the lower end (module docstring, **Coincidence**)."""
    curves, hr, noise = fam.curves, fam.hr, fam.noise
    accepted, first_miss = _coinciding_with_lowest(fam)
    H_close_minus = float(hr[accepted[-1]])
    lower_points = [(h[h <= H_close_minus + 1e-12], y[h <= H_close_minus + 1e-12])
                    for h, y in (curves[a] for a in accepted)]
    low_h = np.concatenate([p[0] for p in lower_points])
    order = np.argsort(low_h, kind="stable")
    low_h, low_y = low_h[order], np.concatenate([p[1] for p in lower_points])[order]
    low_label = np.concatenate([np.full(p[0].size, a) for p, a in zip(lower_points, accepted)])[order]
    low_med = _running_median(low_y)
    allowed = np.maximum(noise.tolerance(low_med, offset_share=_offset_share(low_label, 0)),
                         FLAT_SLOPE_PER_T * fam.M_half * (low_h - low_h[0]))
    steep = np.abs(low_med - low_med[0]) > allowed
    H_flat_minus = float(low_h[np.argmax(steep) - 1]) if steep.any() and np.argmax(steep) > 0 else (
        float(low_h[0]) if steep.any() else H_close_minus)
    H_minus = min(H_close_minus, H_flat_minus)
    lower_saturated = H_minus - hr[0] >= fam.step - 1e-12 and H_minus >= -fam.B_max_T
    return _LowerEnd(accepted, first_miss, H_close_minus, low_h, low_y, low_med, H_flat_minus, H_minus,
                     lower_saturated)


def _lower_end_reason(fam: _Family, lower: _LowerEnd) -> str | None:
    """Stage 3: why the lower end is not saturated (None when it is)."""
    if lower.saturated:
        return None
    hr, step, sigma, M_half, H_close_minus = fam.hr, fam.step, fam.sigma, fam.M_half, lower.H_close
    if H_close_minus - hr[0] < step - 1e-12:
        if lower.first_miss is not None and lower.first_miss[1].size:
            k, h, d, tol = lower.first_miss
            j = int(np.argmax(np.abs(d) / tol))
            return (f"lower end not saturated: the curves reversed at {hr[0]:+.4f} T and {hr[k]:+.4f} T differ by "
                    f"{abs(d[j]):.3g} A m² ({100 * abs(d[j]) / M_half:.1f} % of the half loop height, "
                    f"{abs(d[j]) / sigma if sigma > 0 else np.inf:.0f} σ; noise alone exceeds {tol[j]:.3g} A m² "
                    f"there with probability {100 * fam.noise.alpha:.2g} %) at {h[j]:+.4f} T; curves coincide only "
                    f"up to H_r = {H_close_minus:+.4f} T, {step:.3f} T (one training-grid step) above the lowest "
                    "reversal field is needed")
        return (f"lower end not saturated: curves coincide only up to H_r = {H_close_minus:+.4f} T "
                f"({H_close_minus - hr[0]:.4f} T above the lowest reversal field; {step:.3f} T needed)")
    if lower.H < -fam.B_max_T:
        return (f"the loop saturates on the negative side only below {lower.H:+.3f} T, beyond the "
                f"training window's {-fam.B_max_T:+.2f} T")
    low_h = lower.low_h
    change, slope = _branch_change(low_h, lower.low_med)
    return (f"lower branch closed (curves coincide up to H_r = {H_close_minus:+.4f} T) but not saturated: "
            f"over [{low_h[0]:+.3f}, {low_h[-1]:+.3f}] T it changes by {change:.3g} A m² "
            f"({100 * change / M_half:.0f} % of the half loop height; "
            f"slope {100 * abs(slope) / M_half:.0f} % "
            f"per T, a saturated branch changes by at most {100 * FLAT_SLOPE_PER_T:.0f} % per T): a "
            "reversible, unsaturated magnetization (a paramagnetic slope or a reversible rotation)")


def _upper_end(fam: _Family, lower: _LowerEnd, calibration) -> _UpperEnd:
    """Stage 4: closure of the ascending major branch on the upper branch U, and U's flatness."""
    curves, noise = fam.curves, fam.noise
    cal = None
    if calibration is not None and np.all(np.isfinite(calibration)):
        cal = (float(calibration[0]), float(calibration[1]))
    U_h, U_y, U_label = _upper_branch(curves, cal)
    a = max(lower.accepted, key=lambda k: curves[k][0][-1])
    A_h, A_y = curves[a]
    h, d = _difference(A_h, A_y, U_h, U_y)
    H_close_plus = None
    tol_plus = noise.tolerance(np.interp(h, A_h, A_y)) if h.size else h
    ok = np.abs(d) <= tol_plus
    if ok.size and ok[-1]:
        start = ok.size - np.argmin(ok[::-1]) if not ok.all() else 0
        H_close_plus = float(h[start])
    top = float(U_h[-1])
    U_med = _running_median(U_y)
    allowed = np.maximum(noise.tolerance(U_med, offset_share=_offset_share(U_label, U_h.size - 1)),
                         FLAT_SLOPE_PER_T * fam.M_half * (top - U_h))
    steep = np.abs(U_med - U_med[-1]) > allowed
    H_flat_plus = float(U_h[U_h.size - np.argmax(steep[::-1])]) if steep.any() else float(U_h[0])
    H_plus = None if H_close_plus is None else max(H_close_plus, H_flat_plus)
    upper_saturated = H_plus is not None and h[-1] - H_plus >= fam.step - 1e-12 and H_plus <= fam.B_max_T
    return _UpperEnd(U_h, U_y, U_med, a, h, d, tol_plus, H_close_plus, H_flat_plus, H_plus, upper_saturated)


def _upper_end_reason(fam: _Family, upper: _UpperEnd) -> str | None:
    """Stage 5: why the upper end is not saturated (None when it is)."""
    if upper.saturated:
        return None
    hr, step, sigma, M_half = fam.hr, fam.step, fam.sigma, fam.M_half
    h, d, tol_plus, H_close_plus = upper.h, upper.d, upper.tol, upper.H_close
    if H_close_plus is None or h[-1] - H_close_plus < step - 1e-12:
        tail = h >= h[-1] - step if h.size else h
        j = int(np.argmax(np.where(tail, np.abs(d) / tol_plus, 0))) if h.size else None
        if j is None:
            return "upper end not saturated: the ascending branch does not reach the upper branch"
        A_h = fam.curves[upper.a][0]
        return (f"upper end not saturated: the branch from the lowest reversal field ({hr[upper.a]:+.4f} T) ends at "
                f"{A_h[-1]:+.4f} T and still differs from the upper (descending) branch by {abs(d[j]):.3g} A m² "
                f"({100 * abs(d[j]) / M_half:.1f} % of the half loop height, "
                f"{abs(d[j]) / sigma if sigma > 0 else np.inf:.0f} σ; noise alone exceeds {tol_plus[j]:.3g} A m² "
                f"there with probability {100 * fam.noise.alpha:.2g} %) at {h[j]:+.4f} T"
                + (f"; it coincides only from {H_close_plus:+.4f} T on ({step:.3f} T needed)"
                   if H_close_plus is not None else ""))
    if upper.H > fam.B_max_T:
        return (f"the loop saturates on the positive side only at {upper.H:+.3f} T, beyond the training "
                f"window's {fam.B_max_T:+.2f} T")
    U_h = upper.U_h
    sel = U_h >= H_close_plus - 1e-12
    change, slope = _branch_change(U_h[sel], upper.U_med[sel])
    return (f"upper branch closed (from {H_close_plus:+.4f} T) but not saturated: over "
            f"[{H_close_plus:+.3f}, {float(U_h[-1]):+.3f}] T it changes by {change:.3g} A m² "
            f"({100 * change / M_half:.0f} % of the half loop height; "
            f"slope {100 * abs(slope) / M_half:.0f} % "
            f"per T, a saturated branch changes by at most {100 * FLAT_SLOPE_PER_T:.0f} % per T): a "
            "reversible, unsaturated magnetization (a paramagnetic slope or a reversible rotation)")


def _normalization(fam: _Family, lower: _LowerEnd, upper: _UpperEnd):
    """Stage 6: M_sat and M_0 (A·m²) from the saturated branches (or the curves' last values when
    they are not saturated), how they were found, and the high-field slope of U (A·m²/T)."""
    curves, U_h, U_y, H_plus = fam.curves, upper.U_h, upper.U_y, upper.H
    if H_plus is not None:
        upper_vals = np.concatenate([y[h >= H_plus - 1e-12] for h, y in curves] + [U_y[U_h >= H_plus - 1e-12]])
    else:
        upper_vals = U_y[-RUNNING:]
    U_s = float(np.median(upper_vals))
    L_s = float(np.median(lower.low_y)) if lower.low_y.size else float(fam.everything.min())
    M_sat, M_0 = (U_s - L_s) / 2, (U_s + L_s) / 2
    normalization = "saturated branches: M_sat = (U_s - L_s)/2, M_0 = (U_s + L_s)/2"
    if not (lower.saturated and upper.saturated) or not M_sat > 0:
        # no saturated branches bracket the loop (a family analysed out of the domain): the median of
        # the curves' values at their largest field, no offset
        M_sat, M_0 = float(np.median([y[-1] for _, y in curves])), 0.0
        normalization = "median of the curves' values at their largest field (no saturated branches), no offset"
    slope = float("nan")
    if H_plus is not None:
        sel = U_h >= H_plus - 1e-12
        if sel.sum() >= 3 and np.ptp(U_h[sel]) > 0:
            slope = float(np.polyfit(U_h[sel], U_y[sel], 1)[0])
    return M_sat, M_0, normalization, slope


def analyse_saturation(reversal_fields_T, curves, B_max_T: float = 1.0, n: int = 64, *,
                       calibration=None, calibration_moments=None,
                       correction_noise_relative: float | None = None) -> MeasuredDomain:
    """The rule of the module docstring for curves (field_T, moment) reversed at ``reversal_fields_T``
    (any order; each curve from its reversal field upward). ``calibration``: (H_cal, M_cal) on the
    upper branch, optional; ``calibration_moments``: all calibration moments (noise cross-check);
    ``correction_noise_relative``: σ_f, the relative noise of each curve's drift-correction factor;
    None: ``correction_noise(calibration_moments)`` when they are given (the curves corrected by them,
    the reader's default), else 0; pass 0 for curves that were not drift-corrected.
    Returns a ``MeasuredDomain`` with the completed grid family (``family``, ``source``)."""
    fam = _measured_family(reversal_fields_T, curves, B_max_T, n, calibration_moments, correction_noise_relative)
    curves = fam.curves
    # reported: the tolerance of a saturated point of a comparison along the lowest curve
    tau = float(fam.noise.tolerance(np.abs(fam.everything).max(), K=curves[0][0].size,
                                    medianed=curves[0][0].size >= 3)[0])
    lower = _lower_end(fam)
    upper = _upper_end(fam, lower, calibration)
    reasons = [r for r in (_lower_end_reason(fam, lower), _upper_end_reason(fam, upper)) if r is not None]
    M_sat, M_0, normalization, slope = _normalization(fam, lower, upper)
    domain = MeasuredDomain(
        usable=False, reason=None, noise_Am2=fam.sigma, tolerance_Am2=tau, M_half_Am2=fam.M_half,
        H_minus_T=lower.H, H_plus_T=upper.H, lower_saturated=bool(lower.saturated),
        upper_saturated=bool(upper.saturated), moment_saturation_Am2=M_sat, moment_offset_Am2=M_0,
        calibration_noise_Am2=calibration_noise(calibration_moments) if calibration_moments is not None else float("nan"),
        high_field_slope_Am2_per_T=slope)
    if not M_sat > 0:
        reasons.append("the saturation moment is not positive (M_sat <= 0)")
    family, source, summary = _complete(fam.hr, curves, upper.U_h, upper.U_y, domain, B_max_T, n, fam.noise)
    summary.update(correction_noise_relative=fam.relative, false_refusal_rate_file=ALPHA_FILE,
                   false_refusal_rate_per_check=fam.noise.alpha, refusing_checks=fam.n_checks,
                   tolerance_rule="tau_i = max(z_K s_i, q), z_K = Phi^-1(1 - alpha/(2K)), "
                                  "s_i^2 = sigma^2 + 2 sigma_f^2 M_i^2, q = (2/255) M_half",
                   closure_field_lower_T=lower.H_close, closure_field_upper_T=upper.H_close,
                   flat_field_lower_T=lower.H_flat, flat_field_upper_T=upper.H_flat, training_grid_step_T=fam.step,
                   normalization=normalization)
    domain.family, domain.source, domain.summary = family, source, summary
    unknown = summary["fraction_unknown"]
    if not reasons and unknown > 0:
        rows = summary["unknown_reversal_fields_T"]
        reasons.append(f"the state is unknown on {100 * unknown:.1f} % of the training image: curves reversed at "
                       f"H_r in [{rows[0]:+.3f}, {rows[1]:+.3f}] T end before rejoining the upper branch")
    domain.usable = not reasons
    domain.reason = "; ".join(reasons) if reasons else None
    return domain


def _complete(hr, curves, U_h, U_y, domain, B_max_T, n, noise):
    """The completed grid family (normalized), the source of every cell and the summary (module docstring)."""
    grid = np.linspace(-B_max_T, B_max_T, n)
    M_sat = domain.moment_saturation_Am2 if domain.moment_saturation_Am2 > 0 else max(domain.M_half_Am2, 1e-300)
    M_0 = domain.moment_offset_Am2

    def norm(y):
        return (np.asarray(y, float) - M_0) / M_sat

    H_plus = domain.H_plus_T if domain.upper_saturated else None
    H_minus = domain.H_minus_T if domain.lower_saturated else None
    U_top = U_h[-1]
    # which curves have rejoined the upper branch by their last field
    merged = []
    # the rejoining checks (last 3 points of each curve ending below H_+): Bonferroni over all of them
    n_rejoin = sum(1 for h, _ in curves if H_plus is None or h[-1] < H_plus - 1e-12)
    for h, y in curves:
        if H_plus is not None and h[-1] >= H_plus - 1e-12:
            merged.append(True)
            continue
        hh, d = _difference(h, y, U_h, U_y)
        tail = hh >= hh[-1] - 1e-12 if hh.size else hh
        tol = noise.tolerance(np.interp(hh[-3:], h, y), K=3 * max(n_rejoin, 1), medianed=hh.size >= 3) if hh.size else hh
        merged.append(bool(hh.size >= 3 and np.all(np.abs(d[-3:]) <= tol) and tail.any()))
    family = np.full((n, n), np.nan)
    source = np.full((n, n), UNKNOWN, dtype=np.int8)
    source[np.tril_indices(n, -1)] = -1  # below the diagonal: not part of the family
    upper = norm(U_y)

    def upper_value(H):
        return np.where(H <= U_top + 1e-12, np.interp(H, U_h, upper), 1.0)

    for i, g in enumerate(grid):
        cols = np.arange(i, n)
        H = grid[cols]
        if H_plus is not None and g >= H_plus - 1e-12:
            family[i, cols] = upper_value(H)
            inside = (H <= U_top + 1e-12) & (g <= hr[-1] + 1e-12)
            source[i, cols] = np.where(inside, MEASURED, COMPLETED)
            continue
        k = int(np.argmin(np.abs(hr - g)))
        h, y = curves[k]
        below_window = g < hr[0] - 1e-12
        if below_window and H_minus is not None:
            k = int(np.argmax([c[0][-1] if hr[j] <= H_minus + 1e-12 else -np.inf for j, c in enumerate(curves)]))
            h, y = curves[k]
        values = np.interp(H, h, norm(y))
        src = np.full(H.size, MEASURED, dtype=np.int8)
        if below_window:  # a curve reversed below the window: inferred, never measured
            before = H < h[0] - 1e-12
            src[:] = COMPLETED if H_minus is not None else UNKNOWN
            if H_minus is not None:
                values[before] = -1.0
        beyond = H > h[-1] + 1e-12
        if beyond.any():
            if merged[k] or (H_plus is not None and h[-1] >= H_plus - 1e-12):
                values[beyond] = upper_value(H[beyond])
                # above the measured upper branch the state is known only when that branch is saturated
                known = (H[beyond] <= U_top + 1e-12) | (H_plus is not None)
                src[beyond] = np.where(known, COMPLETED, UNKNOWN)
            else:
                src[beyond] = UNKNOWN  # values hold the last measured point (np.interp), flagged unknown
        family[i, cols] = values
        source[i, cols] = src
    cells = source >= 0
    total = int(cells.sum())
    unknown_rows = [grid[i] for i in range(n) if np.any(source[i] == UNKNOWN)]
    summary = {
        "grid_B_max_T": float(B_max_T), "grid_n": int(n), "fraction_measured": float((source == MEASURED).sum() / total),
        "fraction_completed": float((source == COMPLETED).sum() / total),
        "fraction_unknown": float((source == UNKNOWN).sum() / total),
        "measured_reversal_fields_T": [float(hr[0]), float(hr[-1])],
        "measured_fields_T": [float(min(c[0][0] for c in curves)), float(max(c[0][-1] for c in curves))],
        "completed": _completed_text(hr, curves, H_minus, H_plus, B_max_T),
        "unknown_reversal_fields_T": [float(min(unknown_rows)), float(max(unknown_rows))] if unknown_rows else None,
        "curves_rejoining_upper_branch": int(sum(merged)), "n_curves": len(curves),
    }
    return family, source, summary


def _completed_text(hr, curves, H_minus, H_plus, B_max_T):
    parts = []
    if H_minus is not None and hr[0] > -B_max_T:
        parts.append(f"rows H_r < {hr[0]:+.3f} T: ascending branch from negative saturation (m = -1 below the window)")
    if H_plus is not None:
        parts.append(f"rows H_r >= {H_plus:+.3f} T: reversible upper branch")
    top = max(c[0][-1] for c in curves)
    if H_plus is not None and top < B_max_T:
        parts.append(f"fields H > {top:+.3f} T: m = +1 (saturated upper branch)")
    parts.append("beyond each curve's last field, where it has rejoined the upper branch: the upper branch"
                 + ("" if H_plus is not None else " (inside the measured window only: it is not saturated)"))
    return parts


def domain_of_measurement(data, B_max_T: float = 1.0, n: int = 64) -> MeasuredDomain:
    """``analyse_saturation`` of a read measurement (``forcdecode.measured``), with its first
    calibration point (on the upper branch, drift-corrected scale) when it has them, and the noise of
    the drift correction (σ_f from the calibration points) when the reader applied it."""
    calibration = None
    moments = None
    relative = 0.0
    if data.calibration:
        moments = [p.moment_Am2 for p in data.calibration]
        calibration = (data.calibration[0].field_T, data.calibration[0].moment_Am2)
        if getattr(data, "drift_corrected", False):
            relative = None  # each curve scaled by its own noisy calibration point: σ_f from them
    return analyse_saturation(data.reversal_fields_T, [(c.field_T, c.moment_Am2) for c in data.curves],
                              B_max_T, n, calibration=calibration, calibration_moments=moments,
                              correction_noise_relative=relative)


__all__ = ["ALPHA_FILE", "MEASURED", "COMPLETED", "UNKNOWN", "MeasuredDomain", "analyse_saturation", "calibration_noise",
           "correction_noise", "domain_of_measurement", "noise_level"]
