"""Quasi-static path: steepest-descent energy minimization with Barzilai–Borwein steps.

Following Exl et al. (J. Appl. Phys. 115, 17D118, 2014), as in mumax3's ``Minimize()``: the
descent direction of cell i is its torque τ_i = B_i − (m_i·B_i) m_i (the negative projected energy
gradient up to the factor M_s V), the update is the norm-preserving Cayley step

    m ← ((4 − h²|τ|²) m + 4h τ) / (4 + h²|τ|²),

and the step h alternates between the two Barzilai–Borwein lengths BB1 = s·s/s·y and BB2 = s·y/y·y
(s = Δm, y = −Δτ). The largest rotation of any cell in one step is capped (``max_rotation_rad``) so
a step never jumps a cell over an anisotropy barrier.

Convergence criterion: max_i |m_i × B_i| < ``torque_tol_T`` (tesla); |m × B| = |τ| for |m| = 1.
Frozen cells are not moved. Everything runs inside numba: no Python overhead per iteration.
"""

from __future__ import annotations

import numba
import numpy as np

from .effective_field import compute_effective_field, torque_and_max


@numba.njit(cache=True)
def minimize_bb(m, model, B_ext, torque_tol_T, max_iterations, max_rotation_rad):
    """Relax ``m`` in place. Returns (iterations, final max torque in T, converged flag)."""
    field = np.empty_like(m)
    torque = np.empty_like(m)
    torque_old = np.empty_like(m)
    m_old = np.empty_like(m)
    _, nz, ny, nx = m.shape
    compute_effective_field(m, model, B_ext, field)
    max_torque = torque_and_max(m, field, model.frozen, torque)
    if max_torque < torque_tol_T:
        return 0, max_torque, True
    h = 1e-2 / max_torque
    for iteration in range(1, max_iterations + 1):
        # cap the step: a rotation of at most max_rotation_rad for the cell with the largest torque
        h_cap = max_rotation_rad / max_torque
        if not (h > 0.0) or h > h_cap:
            h = h_cap
        m_old[...] = m
        torque_old[...] = torque
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    tx, ty, tz = torque[0, k, j, i], torque[1, k, j, i], torque[2, k, j, i]
                    n2 = h * h * (tx * tx + ty * ty + tz * tz)
                    inv = 1.0 / (4.0 + n2)
                    a = (4.0 - n2) * inv
                    b = 4.0 * h * inv
                    nx_ = a * m[0, k, j, i] + b * tx
                    ny_ = a * m[1, k, j, i] + b * ty
                    nz_ = a * m[2, k, j, i] + b * tz
                    # the Cayley step keeps |m| = 1 exactly only in exact arithmetic: renormalize
                    norm = 1.0 / np.sqrt(nx_ * nx_ + ny_ * ny_ + nz_ * nz_)
                    m[0, k, j, i] = nx_ * norm
                    m[1, k, j, i] = ny_ * norm
                    m[2, k, j, i] = nz_ * norm
        compute_effective_field(m, model, B_ext, field)
        max_torque = torque_and_max(m, field, model.frozen, torque)
        if max_torque < torque_tol_T:
            return iteration, max_torque, True
        if not np.isfinite(max_torque):
            return iteration, max_torque, False
        ss = 0.0
        sy = 0.0
        yy = 0.0
        for c in range(3):
            for k in range(nz):
                for j in range(ny):
                    for i in range(nx):
                        s = m[c, k, j, i] - m_old[c, k, j, i]
                        y = torque_old[c, k, j, i] - torque[c, k, j, i]
                        ss += s * s
                        sy += s * y
                        yy += y * y
        if sy <= 0.0:
            h = max_rotation_rad / max_torque  # negative curvature along s: take the largest safe step
        elif iteration % 2 == 0:
            h = ss / sy
        else:
            h = sy / yy
    return max_iterations, max_torque, False
