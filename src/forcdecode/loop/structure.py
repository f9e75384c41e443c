"""Is a residual structured beyond what the noise and the re-simulation's own disorder explain?

Residual r = m_measured − m_model on the grid (rows H_r, NaN below the diagonal, m normalized).
Each point is standardized, z = r/s, s² = σ² + v(1 + 1/P): σ the measurement noise (normalized;
default: estimated from the residual itself, 1.4826·MAD of the deviation of each point from the line
through its two neighbours along the curve, which a smooth residual does not reach), v the variance
of m between disorder profiles of the re-simulation (a sample is one more realisation; the model
averages P of them), 0 if not given.

Statistics (pooled over the curves, along each curve in order of field):

- ``chi2_ratio`` = mean z² (1 for white noise at the stated level); its one-sided p-value from the
  χ² distribution with N points;
- Wald–Wolfowitz runs test on the signs of z along each curve: runs R against μ = 1 + 2n₊n₋/N,
  Var = 2n₊n₋(2n₊n₋ − N)/(N²(N − 1)), pooled z_runs = Σ(R − μ)/√ΣVar (negative: long runs of one sign);
- lag-1 autocorrelation ρ₁ = Σ z_k z_{k+1}/Σ z_k² along curves, against white noise (0, sd 1/√pairs).

**Structured** when the size is beyond the noise (chi2_ratio > ``min_chi2_ratio`` = 2 with p < 0.001)
and its pattern is not white (z_runs < −3 or ρ₁/sd > 3). Where it lives: the reversal fields of the
curves whose own mean z² exceeds 2 (grouped into contiguous ranges), the applied-field range holding
the central 80 % of the excess Σ(z² − 1)⁺, and the branch: the share of the excess on the reversal
points (the descending major branch, the diagonal) against the return curves above it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ..forc.saturation import noise_level

MIN_CHI2_RATIO = 2.0
Z_PATTERN = 3.0
P_SIZE = 1e-3


def _runs(signs):
    n_pos, n_neg = int((signs > 0).sum()), int((signs < 0).sum())
    n = n_pos + n_neg
    if n < 2 or n_pos == 0 or n_neg == 0:
        return None
    s = signs[signs != 0]
    runs = 1 + int((s[1:] != s[:-1]).sum())
    mu = 1 + 2 * n_pos * n_neg / n
    var = 2 * n_pos * n_neg * (2 * n_pos * n_neg - n) / (n**2 * (n - 1))
    return runs, mu, var


def _ranges(values, step):
    """Contiguous ranges [lo, hi] of sorted grid values (gaps larger than 1.5 steps split them)."""
    if not len(values):
        return []
    out, lo, prev = [], values[0], values[0]
    for v in values[1:]:
        if v - prev > 1.5 * step:
            out.append([float(lo), float(prev)])
            lo = v
        prev = v
    out.append([float(lo), float(prev)])
    return out


@dataclass(frozen=True)
class StructureRule:
    """The thresholds of the structure decision (module docstring): ``min_chi2_ratio``, the mean z² beyond
    which the residual's size is beyond the noise (dimensionless); ``z_pattern``, the runs / lag-1 z-score beyond
    which its pattern is (standard deviations)."""

    min_chi2_ratio: float = MIN_CHI2_RATIO
    z_pattern: float = Z_PATTERN


def residual_structure(residual, fields, noise_sigma: float | None = None, floor_variance=None, n_profiles: int = 1,
                       rule: StructureRule = StructureRule(), measured_patches: int = 1,
                       null_structure: dict | None = None) -> dict:
    """The statistics and decision of the module docstring for the n × n ``residual`` on ``fields`` (T), by the
    thresholds ``rule``.
    ``floor_variance``: v per point (n × n) or a scalar, the variance between single disorder
    realisations; the residual's variance from disorder is v·(1/``measured_patches`` + 1/``n_profiles``)
    (the measurement averages that many independent patches, the re-simulation that many profiles).
    ``null_structure`` (``null_structure_floor``: the largest mean z² and lag-1 z, the lowest runs z, of
    the same test on effect-free films of the re-simulated Hamiltonian): the residual is structured only
    where it is also beyond them, in size and in pattern. Realisation noise is correlated along curves
    and shared by every curve that follows one branch, so it fails the point-independent test; what the
    test finds on films without any effect is its floor. Returns a JSON-ready dict: ``structured``,
    ``noise_sigma``, ``noise_source``, ``chi2_ratio``, ``chi2_p``, ``runs_z``, ``lag1``, ``lag1_z``,
    ``n_points``, ``where`` {``reversal_fields_T`` (ranges), ``fields_T``, ``branch``,
    ``descending_branch_share``}, ``per_curve_chi2`` (None where a curve has no point)."""
    min_chi2_ratio, z_pattern = rule.min_chi2_ratio, rule.z_pattern
    r = np.asarray(residual, float)
    fields = np.asarray(fields, float)
    n = r.shape[0]
    source = "given"
    if noise_sigma is None or not np.isfinite(noise_sigma) or noise_sigma <= 0:
        curves = [(fields[i:][np.isfinite(r[i, i:])], r[i, i:][np.isfinite(r[i, i:])]) for i in range(n)]
        noise_sigma = noise_level([c for c in curves if c[0].size >= 3])
        source = "estimated from the residual (point-to-point scatter)"
    floor = np.zeros_like(r) if floor_variance is None else np.broadcast_to(np.asarray(floor_variance, float), r.shape)
    s2 = noise_sigma**2 + np.nan_to_num(floor) * (1 / max(measured_patches, 1) + 1 / max(n_profiles, 1))
    z = r / np.sqrt(np.where(s2 > 0, s2, np.nan))
    ok = np.isfinite(z)
    N = int(ok.sum())
    if N < 3:
        return {"structured": False, "reason": "fewer than three residual points", "n_points": N}
    chi2_ratio = float(np.mean(z[ok] ** 2))
    chi2_p = float(chi2.sf(chi2_ratio * N, N))
    runs_sum = mu_sum = var_sum = 0.0
    num = den = 0.0
    pairs = 0
    per_curve = []
    for i in range(n):
        zi = z[i][np.isfinite(z[i])]
        per_curve.append(float(np.mean(zi**2)) if zi.size else None)
        if zi.size >= 2:
            result = _runs(np.sign(zi))
            if result is not None:
                runs_sum, mu_sum, var_sum = runs_sum + result[0], mu_sum + result[1], var_sum + result[2]
            num += float((zi[1:] * zi[:-1]).sum())
            pairs += zi.size - 1
        den += float((zi**2).sum())
    runs_z = float((runs_sum - mu_sum) / np.sqrt(var_sum)) if var_sum > 0 else 0.0
    lag1 = num / den if den > 0 else 0.0
    lag1_z = float(lag1 * np.sqrt(pairs)) if pairs else 0.0
    size = chi2_ratio > min_chi2_ratio and chi2_p < P_SIZE
    pattern = runs_z < -z_pattern or lag1_z > z_pattern
    if null_structure:
        size = size and chi2_ratio > null_structure["chi2_ratio"]
        pattern = pattern and (runs_z < min(null_structure["runs_z"], -z_pattern)
                               or lag1_z > max(null_structure["lag1_z"], z_pattern))
    excess = np.where(ok, np.clip(np.nan_to_num(z) ** 2 - 1, 0, None), 0.0)
    step = float(fields[1] - fields[0]) if fields.size > 1 else 1.0
    flagged = [fields[i] for i, c in enumerate(per_curve) if c is not None and c > min_chi2_ratio]
    column = excess.sum(axis=0)
    where = {"reversal_fields_T": _ranges(flagged, step)}
    if column.sum() > 0:
        cdf = np.cumsum(column) / column.sum()
        where["fields_T"] = [float(fields[np.searchsorted(cdf, 0.1)]), float(fields[min(np.searchsorted(cdf, 0.9), n - 1)])]
        diagonal = float(np.trace(excess) / excess.sum())
        where["descending_branch_share"] = diagonal
        where["branch"] = ("descending major branch (reversal points)" if diagonal > 0.5
                           else "return curves (ascending, H > H_r)")
    return {"structured": bool(size and pattern), "noise_sigma": float(noise_sigma), "noise_source": source,
            "chi2_ratio": chi2_ratio, "chi2_p": chi2_p, "runs_z": runs_z, "lag1": float(lag1), "lag1_z": lag1_z,
            "n_points": N, "where": where, "per_curve_chi2": per_curve,
            "null_structure": null_structure,
            "rule": (f"structured: mean z^2 > {min_chi2_ratio:g} (chi-square p < {P_SIZE:g}) and (runs z < "
                     f"-{z_pattern:g} or lag-1 autocorrelation z > {z_pattern:g})"
                     + (", each beyond its largest value on effect-free films" if null_structure else ""))}


def null_structure_floor(null_residuals, fields, noise_sigma: float | None = None, floor_variance=None,
                         n_profiles: int = 1, measured_patches: int = 1) -> dict | None:
    """The structure test's own floor: its statistics on ``null_residuals`` (effect-free films minus the
    re-simulation, each with the measurement's noise), the same floor and settings; the largest mean z²
    and lag-1 z and the lowest runs z over them (None without films)."""
    stats = [residual_structure(r, fields, noise_sigma, floor_variance, n_profiles, measured_patches=measured_patches)
             for r in null_residuals]
    stats = [s for s in stats if "chi2_ratio" in s]
    if not stats:
        return None
    return {"chi2_ratio": max(s["chi2_ratio"] for s in stats), "runs_z": min(s["runs_z"] for s in stats),
            "lag1_z": max(s["lag1_z"] for s in stats), "films": len(stats)}


def describe(structure: dict) -> str:
    """One sentence: where an unexplained structured residual lives."""
    where = structure.get("where", {})
    rows = ", ".join(f"[{a:+.2f}, {b:+.2f}] T" for a, b in where.get("reversal_fields_T", [])) or "no single curve"
    fields = where.get("fields_T")
    return (f"unexplained structured residual (mean z² {structure['chi2_ratio']:.1f}, runs z {structure['runs_z']:.1f}, "
            f"lag-1 z {structure['lag1_z']:.1f}): curves reversed at H_r in {rows}"
            + (f", applied fields {fields[0]:+.2f}..{fields[1]:+.2f} T" if fields else "")
            + (f", mostly on the {where['branch']}" if "branch" in where else ""))


__all__ = ["describe", "residual_structure"]
