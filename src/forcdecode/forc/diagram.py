"""FORC distribution ρ(H_r, H) = −½ ∂²M/∂H_r∂H by Pike et al.'s local polynomial (J. Appl. Phys.
85, 6660, 1999), in the usual coordinates H_c = (H − H_r)/2, H_u = (H + H_r)/2.

For each grid point a second-order surface M = a1 + a2 H_r + a3 H_r² + a4 H + a5 H² + a6 H_r H is
fitted by least squares to the measured points of the (2·SF + 1)² neighbourhood (only points with
H ≥ H_r exist), and ρ = −a6/2. Units: with M normalized (m = M/M_s) and fields in tesla, ρ is in
1/T². Convention pinned by a test: an ensemble of square hysterons with switching fields
(up at α, down at β, α ≥ β) and density P(α, β) gives ρ(H_r = β, H = α) = P(α, β).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ForcDiagram:
    reversal_fields_T: np.ndarray  # (n,) grid of H_r
    fields_T: np.ndarray  # (n,) grid of H
    rho: np.ndarray  # (n, n) [i (H_r), j (H)], NaN where not defined (H < H_r or too few points)
    smoothing_factor: int

    @property
    def coercive_T(self) -> np.ndarray:
        """H_c = (H − H_r)/2 at every grid point."""
        return 0.5 * (self.fields_T[None, :] - self.reversal_fields_T[:, None])

    @property
    def interaction_T(self) -> np.ndarray:
        """H_u = (H + H_r)/2 at every grid point."""
        return 0.5 * (self.fields_T[None, :] + self.reversal_fields_T[:, None])


def forc_distribution(reversal_fields_T, fields_T, curves_m, smoothing_factor: int = 3,
                      min_points: int = 10) -> ForcDiagram:
    """ρ on the grid of a family ``curves_m[i, j]`` = m(H_r = reversal_fields_T[i], H = fields_T[j])
    (NaN where H < H_r or not measured)."""
    hr = np.asarray(reversal_fields_T, dtype=float)
    h = np.asarray(fields_T, dtype=float)
    m = np.asarray(curves_m, dtype=float)
    if m.shape != (hr.size, h.size):
        raise ValueError(f"curves have shape {m.shape}, expected {(hr.size, h.size)}")
    sf = int(smoothing_factor)
    if sf < 1:
        raise ValueError("smoothing_factor must be >= 1")
    rho = np.full(m.shape, np.nan)
    valid = np.isfinite(m)
    # centre and scale coordinates per patch for a well-conditioned fit
    for i in range(hr.size):
        i0, i1 = max(0, i - sf), min(hr.size, i + sf + 1)
        for j in range(h.size):
            if not valid[i, j]:
                continue
            j0, j1 = max(0, j - sf), min(h.size, j + sf + 1)
            patch = valid[i0:i1, j0:j1]
            if patch.sum() < min_points:
                continue
            HR, H = np.meshgrid(hr[i0:i1] - hr[i], h[j0:j1] - h[j], indexing="ij")
            x, y, z = HR[patch], H[patch], m[i0:i1, j0:j1][patch]
            design = np.column_stack([np.ones_like(x), x, x * x, y, y * y, x * y])
            coef, _, rank, _ = np.linalg.lstsq(design, z, rcond=None)
            if rank == 6:
                rho[i, j] = -0.5 * coef[5]
    return ForcDiagram(hr, h, rho, sf)


def plot_diagram(diagram: ForcDiagram, ax=None, title: str | None = None, levels: int = 21):
    """FORC diagram in (H_c, H_u) (mT), contours of ρ (symmetric colour scale around 0)."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4))
    hc, hu, rho = diagram.coercive_T * 1e3, diagram.interaction_T * 1e3, diagram.rho
    finite = np.isfinite(rho) & (hc >= 0)
    if not finite.any():
        raise ValueError("no finite FORC distribution to plot")
    vmax = np.nanmax(np.abs(rho[finite]))
    contours = ax.tricontourf(hc[finite], hu[finite], rho[finite], levels=np.linspace(-vmax, vmax, levels),
                              cmap="RdBu_r")
    ax.set_xlabel(r"$\mu_0 H_c$ (mT)")
    ax.set_ylabel(r"$\mu_0 H_u$ (mT)")
    ax.set_xlim(left=0)
    ax.set_title(title or f"FORC distribution (SF = {diagram.smoothing_factor})")
    ax.figure.colorbar(contours, ax=ax, label=r"$\rho$ (1/T$^2$, m normalized)")
    return ax
