"""Quasi-static path: steepest-descent energy minimization with Barzilai–Borwein steps.

Following Exl et al. (J. Appl. Phys. 115, 17D118, 2014), as in mumax3's ``Minimize()``: the
descent direction of cell i is its torque τ_i = B_i − (m_i·B_i) m_i (the negative projected energy
gradient up to the factor M_s V), the update is the norm-preserving Cayley step

    m ← ((4 − h²|τ|²) m + 4h τ) / (4 + h²|τ|²),

and the step h alternates between the two Barzilai–Borwein lengths BB1 = s·s/s·y and BB2 = s·y/y·y
(s = Δm, y = −Δτ). The largest rotation of any cell in one step is capped (``max_rotation_rad``) so
a step never jumps a cell over an anisotropy barrier.

Convergence criterion: max_i |m_i × B_i| < ``torque_tol_T`` (tesla); |m × B| = |τ| for |m| = 1.
Frozen cells are not moved; slaved cells (pinning sites) are put at their local equilibrium after
every field evaluation (``relax_slaved_cells``), and their torque before that update counts in the
convergence test, so a converged state has every cell, slaved ones included, below the criterion.
Everything runs inside numba: no Python overhead per iteration.
"""

from __future__ import annotations

import numba
import numpy as np

from .effective_field import compute_effective_field, relax_slaved_cells, torque_and_max


@numba.njit(cache=True)
def _cayley_step(m, torque, h, step):
    """m ← Cayley(m, hτ), renormalized; ``step`` receives s = m_new − m_old."""
    _, nz, ny, nx = m.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                tx, ty, tz = torque[0, k, j, i], torque[1, k, j, i], torque[2, k, j, i]
                n2 = h * h * (tx * tx + ty * ty + tz * tz)
                inv = 1.0 / (4.0 + n2)
                a = (4.0 - n2) * inv
                b = 4.0 * h * inv
                ox, oy, oz = m[0, k, j, i], m[1, k, j, i], m[2, k, j, i]
                nx_ = a * ox + b * tx
                ny_ = a * oy + b * ty
                nz_ = a * oz + b * tz
                # the Cayley step keeps |m| = 1 exactly only in exact arithmetic: renormalize
                norm = 1.0 / np.sqrt(nx_ * nx_ + ny_ * ny_ + nz_ * nz_)
                nx_ *= norm
                ny_ *= norm
                nz_ *= norm
                m[0, k, j, i] = nx_
                m[1, k, j, i] = ny_
                m[2, k, j, i] = nz_
                step[0, k, j, i] = nx_ - ox
                step[1, k, j, i] = ny_ - oy
                step[2, k, j, i] = nz_ - oz


@numba.njit(cache=True)
def _torque_and_bb_products(m, field, frozen, step, torque_old, torque):
    """New torque τ = B − (m·B)m (zero on frozen cells) and, with y = τ_old − τ, the sums
    s·s, s·y, y·y. Returns (max |τ|, ss, sy, yy)."""
    _, nz, ny, nx = m.shape
    max_sq = 0.0
    ss = 0.0
    sy = 0.0
    yy = 0.0
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                if frozen[k, j, i]:
                    tx = ty = tz = 0.0
                else:
                    mx, my, mz = m[0, k, j, i], m[1, k, j, i], m[2, k, j, i]
                    bx, by, bz = field[0, k, j, i], field[1, k, j, i], field[2, k, j, i]
                    p = mx * bx + my * by + mz * bz
                    tx, ty, tz = bx - p * mx, by - p * my, bz - p * mz
                torque[0, k, j, i] = tx
                torque[1, k, j, i] = ty
                torque[2, k, j, i] = tz
                sq = tx * tx + ty * ty + tz * tz
                if sq > max_sq:
                    max_sq = sq
                sx, sy_, sz = step[0, k, j, i], step[1, k, j, i], step[2, k, j, i]
                yx = torque_old[0, k, j, i] - tx
                yy_ = torque_old[1, k, j, i] - ty
                yz = torque_old[2, k, j, i] - tz
                ss += sx * sx + sy_ * sy_ + sz * sz
                sy += sx * yx + sy_ * yy_ + sz * yz
                yy += yx * yx + yy_ * yy_ + yz * yz
    return np.sqrt(max_sq), ss, sy, yy


@numba.njit(cache=True)
def minimize_bb(m, model, B_ext, torque_tol_T, max_iterations, max_rotation_rad):
    """Relax ``m`` in place. Returns (iterations, final max torque in T, converged flag)."""
    field = np.empty_like(m)
    torque = np.empty_like(m)
    torque_old = np.empty_like(m)
    step = np.empty_like(m)
    compute_effective_field(m, model, B_ext, field)
    max_torque = torque_and_max(m, field, model.frozen, torque)
    max_torque = max(max_torque, relax_slaved_cells(m, field, model))
    if max_torque < torque_tol_T:
        return 0, max_torque, True
    h = 1e-2 / max_torque
    for iteration in range(1, max_iterations + 1):
        # cap the step: a rotation of at most max_rotation_rad for the cell with the largest torque
        h_cap = max_rotation_rad / max_torque
        if not (h > 0.0) or h > h_cap:
            h = h_cap
        _cayley_step(m, torque, h, step)
        torque, torque_old = torque_old, torque  # torque_old now holds the torque the step used
        compute_effective_field(m, model, B_ext, field)
        max_torque, ss, sy, yy = _torque_and_bb_products(m, field, model.frozen, step, torque_old, torque)
        max_torque = max(max_torque, relax_slaved_cells(m, field, model))
        if max_torque < torque_tol_T:
            return iteration, max_torque, True
        if not np.isfinite(max_torque):
            return iteration, max_torque, False
        if sy <= 0.0:
            h = max_rotation_rad / max_torque  # negative curvature along s: take the largest safe step
        elif iteration % 2 == 0:
            h = ss / sy
        else:
            h = sy / yy
    return max_iterations, max_torque, False
