"""FORC distribution ρ(H_r, H) = −½ ∂²M/∂H_r∂H from a family of curves on a grid, in the usual
coordinates H_c = (H − H_r)/2, H_u = (H + H_r)/2.

Every estimator fits a second-order surface to the measured points around each grid point by
(weighted) least squares and reads ρ from its curvature; they differ in the neighbourhood and the
weights:

``kernel="pike"`` (default; Pike, Roberts & Verosub, J. Appl. Phys. 85, 6660, 1999)
    M = a1 + a2 H_r + a3 H_r² + a4 H + a5 H² + a6 H_r H, equal weights on the (2·SF + 1)² square of
    grid points around the node, ρ = −a6/2.
``kernel="loess"`` (the LOESS of FORCinel, Harrison & Feinberg, G³ 9, Q05016, 2008, as PmagPy 4.5
    computes it in ``loess_rho_from_grid_fast``)
    the same surface, tricube weights (1 − u³)³ on the ellipse u = √((ΔH index/SF)² + (ΔH_r
    index/SF)²) ≤ 1 of grid points (points on u = 1 count as neighbours with weight 0).
:func:`variforc_distribution` (VARIFORC, Egli, Glob. Planet. Change 110, 302, 2013)
    the surface in (H_c, H_u), M = b1 + b2 x + b3 y + b4 x² + b5 xy + b6 y² with x, y the offsets
    in H_c, H_u, Egli's weights on an upright rectangle whose half-widths s_c ΔH, s_u ΔH grow with
    the distance from the axes, ρ = (M_cc − M_uu)/8 = (b4 − b6)/4 (per ΔH²).

Only points with H ≥ H_r take part (ρ is not defined below). A node needs ``min_points``
neighbours and a full-rank fit (the 6×6 normal matrix has rank 6: singular values above
6·ε·σ_max), else ρ is NaN. Local coordinates are scaled by the median field steps, so irregular
(Hall-probe) fields are used as measured. Units: with m normalized (m = M/M_s) and fields in tesla,
ρ is in 1/T². Convention pinned by a test: an ensemble of square hysterons (up at α, down at β ≤ α)
with density P(α, β) gives ρ(H_r = β, H = α) = P(α, β).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

KERNELS = ("pike", "loess")
_PIKE, _LOESS, _VARIFORC = 0, 1, 2


@dataclass
class ForcDiagram:
    reversal_fields_T: np.ndarray  # (n_r,) grid of H_r
    fields_T: np.ndarray  # (n,) grid of H
    rho: np.ndarray  # (n_r, n) [i (H_r), j (H)], NaN where not defined (H < H_r or too few points)
    smoothing_factor: float  # SF (pike, loess); the baseline factor s_c1 for VARIFORC
    method: str = "pike"  # "pike", "loess" or "variforc"

    @property
    def coercive_T(self) -> np.ndarray:
        """H_c = (H − H_r)/2 at every grid point."""
        return 0.5 * (self.fields_T[None, :] - self.reversal_fields_T[:, None])

    @property
    def interaction_T(self) -> np.ndarray:
        """H_u = (H + H_r)/2 at every grid point."""
        return 0.5 * (self.fields_T[None, :] + self.reversal_fields_T[:, None])


@dataclass(frozen=True)
class Variforc:
    """VARIFORC smoothing factors (Egli 2013, Eqs. 11–14), in units of the field step ΔH.

    Along each axis s = min[(1 − λ) s1 + λ n, max(s0, n)] with n = |H_c|/ΔH (for s_c) or |H_u|/ΔH
    (for s_u), floored at 1: the window grows with distance from the axes (where Preisach-type
    distributions are smooth) and is held at s0 across a ridge on the axis (the central ridge of
    non-interacting single-domain particles at H_u = 0, the vertical ridge of superparamagnetic
    ones at H_c = 0). λ = 0 and s1 = s0 = SF + 1 give constant smoothing. Egli's published analyses
    use s1 of 7–11 and λ ≈ 0.06–0.12. Same names and defaults as PmagPy's
    ``variforc_smoothing_factors`` (its s_b, λ_b are our s_u, λ_u).
    """

    sc0: float = 3.0
    sc1: float = 7.0
    su0: float = 3.0
    su1: float = 7.0
    lambda_c: float = 0.07
    lambda_u: float = 0.07

    def __post_init__(self):
        for name in ("sc0", "sc1", "su0", "su1"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) <= 0:
                raise ValueError(f"VARIFORC {name} must be a positive smoothing factor")
        for name in ("lambda_c", "lambda_u"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ValueError(f"VARIFORC {name} must be >= 0")

    def factors(self, coercive_T, interaction_T, step_T: float) -> tuple[np.ndarray, np.ndarray]:
        """(s_c, s_u) at nodes with the given H_c, H_u (tesla), for field step ``step_T``."""
        nc = np.abs(np.asarray(coercive_T, dtype=float)) / step_T
        nu = np.abs(np.asarray(interaction_T, dtype=float)) / step_T
        s_c = np.minimum((1 - self.lambda_c) * self.sc1 + self.lambda_c * nc, np.maximum(self.sc0, nc))
        s_u = np.minimum((1 - self.lambda_u) * self.su1 + self.lambda_u * nu, np.maximum(self.su0, nu))
        return np.maximum(s_c, 1.0), np.maximum(s_u, 1.0)


def _checked_grid(reversal_fields_T, fields_T, curves_m):
    hr = np.ascontiguousarray(reversal_fields_T, dtype=float)
    h = np.ascontiguousarray(fields_T, dtype=float)
    m = np.asarray(curves_m, dtype=float)
    if hr.ndim != 1 or h.ndim != 1 or m.shape != (hr.size, h.size):
        raise ValueError(f"curves have shape {m.shape}, expected {(hr.size, h.size)}")
    for name, axis in (("reversal_fields_T", hr), ("fields_T", h)):
        if not np.all(np.isfinite(axis)) or (axis.size > 1 and np.median(np.diff(axis)) <= 0):
            raise ValueError(f"{name} must be finite and increasing")
    valid = np.isfinite(m) & (h[None, :] >= hr[:, None])
    return hr, h, np.ascontiguousarray(np.where(valid, m, 0.0)), valid


def _median_step(axis: np.ndarray, fallback: float = 1.0) -> float:
    steps = np.diff(axis)
    return float(np.median(steps)) if steps.size else fallback


def forc_distribution(reversal_fields_T, fields_T, curves_m, smoothing_factor: int = 3,
                      min_points: int = 10, *, kernel: str = "pike") -> ForcDiagram:
    """ρ on the grid of a family ``curves_m[i, j]`` = m(H_r = reversal_fields_T[i], H = fields_T[j])
    (NaN where H < H_r or not measured); both axes increasing. ``kernel`` is ``"pike"`` (equal
    weights on a (2·SF + 1)² square) or ``"loess"`` (tricube weights on an ellipse of radius SF
    steps), see the module docstring."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, not {kernel!r}")
    sf = int(smoothing_factor)
    if sf < 1 or sf != smoothing_factor:
        raise ValueError("smoothing_factor must be an integer >= 1")
    hr, h, m, valid = _checked_grid(reversal_fields_T, fields_T, curves_m)
    step_h = _median_step(h)
    step_r = _median_step(hr, step_h)
    ci, cj = np.nonzero(valid)
    radius = np.full(ci.size, sf, dtype=np.int64)
    unused = np.zeros(ci.size)
    rho = _local_fits(m, valid, (hr, h, step_r, step_h, 1.0), (ci, cj, radius, radius, unused, unused),
                      _PIKE if kernel == "pike" else _LOESS, int(min_points))
    return ForcDiagram(hr, h, rho, sf, kernel)


def variforc_distribution(reversal_fields_T, fields_T, curves_m, settings: Variforc | None = None,
                          min_points: int = 12, step_T: float | None = None) -> ForcDiagram:
    """ρ with VARIFORC variable smoothing (Egli 2013; see :class:`Variforc`). ``step_T`` is the
    field step ΔH the factors count in (default: the mean of the median H and H_r steps, as PmagPy).
    Points inside a node's rectangle with nonzero weight must number at least ``min_points``."""
    settings = settings or Variforc()
    hr, h, m, valid = _checked_grid(reversal_fields_T, fields_T, curves_m)
    step_h = _median_step(h)
    step_r = _median_step(hr, step_h)
    step = float(step_T) if step_T is not None else 0.5 * (step_h + step_r)
    if not np.isfinite(step) or step <= 0:
        raise ValueError("step_T must be a positive field step")
    ci, cj = np.nonzero(valid)
    s_c, s_u = settings.factors(0.5 * (h[cj] - hr[ci]), 0.5 * (h[cj] + hr[ci]), step)
    # The rectangle |x| ≤ s_c, |y| ≤ s_u in (H_c, H_u) steps is a diamond in (H_r, H): it reaches
    # (s_c + s_u)·ΔH along either axis; count it in the smallest measured steps.
    min_r = float(np.min(np.diff(hr))) if hr.size > 1 else step
    min_h = float(np.min(np.diff(h))) if h.size > 1 else step
    rad_r = np.ceil((s_c + s_u) * step / min_r).astype(np.int64)
    rad_h = np.ceil((s_c + s_u) * step / min_h).astype(np.int64)
    rho = _local_fits(m, valid, (hr, h, step_r, step_h, step), (ci, cj, rad_r, rad_h, s_c, s_u), _VARIFORC,
                      max(6, int(min_points)))
    return ForcDiagram(hr, h, rho, settings.sc1, "variforc")


@numba.njit(cache=True, inline="always")
def _egli_weight(a, s):
    """Egli's (2013, Eq. 6) window: 1 for |a| ≤ s − 1, two quadratic pieces to 0 at |a| = s."""
    a = abs(a)
    if a <= s - 1.0:
        return 1.0
    if a <= s - 0.5:
        t = a - s + 1.0
        return 1.0 - 2.0 * t * t
    if a <= s:
        t = a - s
        return 2.0 * t * t
    return 0.0


@numba.njit(cache=True)
def _local_fits(m, valid, axes, nodes, kind, min_points):
    """ρ at the nodes from weighted local quadratic fits (see the module docstring).

    ``axes``: (H_r, H, their steps ΔH_r and ΔH, the VARIFORC step), fields in T; ``nodes``: (row
    and column of each node, its neighbourhood's half widths in rows and columns, its VARIFORC
    smoothing factors s_c and s_u; per node arrays); ``kind``: _PIKE, _LOESS or _VARIFORC; a node
    needs ``min_points`` weighted points."""
    hr, h, step_r, step_h, step = axes
    ci, cj, rad_r, rad_h, s_c, s_u = nodes
    nr, nh = m.shape
    rho = np.full((nr, nh), np.nan)
    a = np.empty((6, 6))
    b = np.empty(6)
    p = np.empty(6)
    eps = np.finfo(np.float64).eps
    for n in range(ci.size):
        i, j = ci[n], cj[n]
        ri, rj = rad_r[n], rad_h[n]
        a[:, :] = 0.0
        b[:] = 0.0
        count = 0
        for ii in range(max(0, i - ri), min(nr, i + ri + 1)):
            for jj in range(max(0, j - rj), min(nh, j + rj + 1)):
                if not valid[ii, jj]:
                    continue
                w = 1.0
                if kind == _VARIFORC:
                    dr = hr[ii] - hr[i]
                    dh = h[jj] - h[j]
                    x = 0.5 * (dh - dr) / step
                    y = 0.5 * (dh + dr) / step
                    w = _egli_weight(x, s_c[n]) * _egli_weight(y, s_u[n])
                    if w <= 0.0:
                        continue
                    p[0], p[1], p[2], p[3], p[4], p[5] = 1.0, x, y, x * x, x * y, y * y
                else:
                    if kind == _LOESS:
                        u = np.sqrt(((jj - j) / rj) ** 2 + ((ii - i) / ri) ** 2)
                        if u > 1.0:
                            continue
                        w = (1.0 - u ** 3) ** 3
                    x = (hr[ii] - hr[i]) / step_r
                    y = (h[jj] - h[j]) / step_h
                    p[0], p[1], p[2], p[3], p[4], p[5] = 1.0, x, x * x, y, y * y, x * y
                count += 1
                v = m[ii, jj]
                for k in range(6):
                    b[k] += w * p[k] * v
                    for q in range(6):
                        a[k, q] += w * p[k] * p[q]
        if count < min_points:
            continue
        sv = np.linalg.svd(a)[1]
        if sv[5] <= 6.0 * eps * sv[0]:
            continue  # rank-deficient neighbourhood (np.linalg.matrix_rank's criterion)
        c = np.linalg.solve(a, b)
        if kind == _VARIFORC:
            rho[i, j] = 0.25 * (c[3] - c[5]) / (step * step)
        else:
            rho[i, j] = -0.5 * c[5] / (step_r * step_h)
    return rho


def plot_diagram(diagram: ForcDiagram, ax=None, title: str | None = None, levels: int = 21, vmax: float | None = None):
    """FORC diagram in (H_c, H_u) (mT), contours of ρ (symmetric colour scale around 0, ±``vmax``
    when given: diagrams side by side on one scale)."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4))
    hc, hu, rho = diagram.coercive_T * 1e3, diagram.interaction_T * 1e3, diagram.rho
    finite = np.isfinite(rho) & (hc >= 0)
    if not finite.any():
        raise ValueError("no finite FORC distribution to plot")
    vmax = float(vmax) if vmax else np.nanmax(np.abs(rho[finite]))
    contours = ax.tricontourf(hc[finite], hu[finite], rho[finite], levels=np.linspace(-vmax, vmax, levels),
                              cmap="RdBu_r")
    ax.set_xlabel(r"$\mu_0 H_c$ (mT)")
    ax.set_ylabel(r"$\mu_0 H_u$ (mT)")
    ax.set_xlim(left=0)
    label = "VARIFORC" if diagram.method == "variforc" else f"SF = {diagram.smoothing_factor}"
    ax.set_title(title or f"FORC distribution ({label})")
    ax.figure.colorbar(contours, ax=ax, label=r"$\rho$ (1/T$^2$, m normalized)")
    return ax
