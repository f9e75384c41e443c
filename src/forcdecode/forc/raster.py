"""Rasterize a FORC family into the networks' 64×64 image.

Rows are reversal fields H_r (row 0 = most negative), columns applied fields H (column 0 = −B_max),
both on the same uniform grid of ``n`` fields over [−B_max, +B_max]. Pixel value: ⟨m_z⟩ ∈ [−1, 1]
mapped linearly to 0..255 (round(127.5 (m + 1))). **Rule for H < H_r** (left of the diagonal, never
visited by the curve): the magnetization at the reversal point, m(H_r, H_r), so every row is
continuous at the diagonal and carries no invented physics.

Curves sampled on other fields (LLG protocol, measured data) are interpolated linearly in H on each
curve; a row whose reversal field is not on the grid takes the nearest recorded curve (the grid
spacing is the row resolution).
"""

from __future__ import annotations

import numpy as np
from .saturation import analyse_saturation, domain_of_measurement


def quantize(mz) -> np.ndarray:
    """⟨m_z⟩ in [−1, 1] → uint8 0..255."""
    return np.clip(np.rint(127.5 * (np.asarray(mz, dtype=float) + 1.0)), 0, 255).astype(np.uint8)


def fill_below_reversal(curves_on_grid: np.ndarray) -> np.ndarray:
    """Fill the H < H_r half (NaN) of a grid family with m(H_r, H_r), row by row."""
    out = np.array(curves_on_grid, dtype=float, copy=True)
    n = out.shape[0]
    for i in range(n):
        out[i, :i] = out[i, i]
    if not np.all(np.isfinite(out)):
        raise ValueError("family has missing values on or above the diagonal")
    return out


def rasterize_grid_family(curves_mz: np.ndarray) -> np.ndarray:
    """A family already on the square grid (``ForcFamily.curves_mz``) → uint8 image."""
    return quantize(fill_below_reversal(curves_mz))


def resample_curves(reversal_fields_T, curves, B_max_T: float = 1.0, n: int = 64) -> np.ndarray:
    """Curves on arbitrary fields → the square grid (NaN below the diagonal).

    ``curves`` is a sequence of (field_T, mz) arrays, one per reversal field, fields increasing.
    Values outside a curve's recorded range stay NaN except at the right end, where the last value
    is held (a curve stopped once it rejoined saturation).
    """
    grid = np.linspace(-B_max_T, B_max_T, n)
    reversal_fields_T = np.asarray(reversal_fields_T, dtype=float)
    out = np.full((n, n), np.nan)
    for i, h_r in enumerate(grid):
        k = int(np.argmin(np.abs(reversal_fields_T - h_r)))
        field, mz = (np.asarray(a, dtype=float) for a in curves[k])
        columns = grid >= grid[i] - 1e-12
        values = np.interp(grid[columns], field, mz, left=mz[0], right=mz[-1])
        out[i, columns] = values
    return out


def measured_image(reversal_fields_T, curves, moment_saturation_Am2: float, B_max_T: float = 1.0, n: int = 64):
    """A measured family on the training grid with a known saturation moment (e.g. M_s·V of a
    simulated film): moments divided by it, curves resampled onto the grid (``resample_curves``, no
    completion). Returns (image uint8, grid family, domain note).

    The note (None: in domain) is the physical rule of ``forc.saturation.analyse_saturation``: the
    major loop must saturate inside the measured window, and the grid must be measured or completed
    where the state is known."""

    reversal_fields_T = np.asarray(reversal_fields_T, dtype=float)
    normalized = [(np.asarray(f, dtype=float), np.asarray(m, dtype=float) / moment_saturation_Am2) for f, m in curves]
    note = analyse_saturation(reversal_fields_T, normalized, B_max_T, n).reason
    grid_family = resample_curves(reversal_fields_T, normalized, B_max_T, n)
    image = quantize(fill_below_reversal(grid_family))  # resample_curves leaves no gap above the diagonal
    return image, grid_family, note


def measurement_on_grid(data, B_max_T: float = 1.0, n: int = 64, with_domain: bool = False):
    """A read measurement (``forcdecode.measured`` data: curves with ``reversal_field_T``, ``field_T``,
    ``moment_Am2``) on the training grid (``forc.saturation``): m = (M − M_0)/M_sat from the
    saturated branches, completed where the state is known. Returns (image, grid family, domain note,
    saturation moment A·m²), and the ``MeasuredDomain`` last with ``with_domain``. Cells whose state
    is unknown (only in a family out of domain) hold the last measured value of their curve."""

    domain = domain_of_measurement(data, B_max_T, n)
    family = domain.family
    image = quantize(fill_below_reversal(family))
    out = (image, family, domain.reason, float(domain.moment_saturation_Am2))
    return out + (domain,) if with_domain else out
