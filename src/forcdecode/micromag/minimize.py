"""Quasi-static path: steepest-descent energy minimization with Barzilai–Borwein steps.

Following Exl et al. (J. Appl. Phys. 115, 17D118, 2014), as in mumax3's ``Minimize()``: the
descent direction of cell i is its torque τ_i = B_i − (m_i·B_i) m_i (the negative projected energy
gradient up to the factor M_s V), the update is the norm-preserving Cayley step

    m ← ((4 − h²|τ|²) m + 4h τ) / (4 + h²|τ|²),

and the step h alternates between the two Barzilai–Borwein lengths BB1 = s·s/s·y and BB2 = s·y/y·y
(s = Δm, y = −Δτ), in the metric of a diagonal preconditioner P that shortens the steps of cells
made stiff by their own anisotropy (``diagonal_preconditioner``; with it a FORC family of a film
with pinning sites needs about half the iterations). The largest rotation of any cell in one step is capped (``max_rotation_rad``) so
a step never jumps a cell over an anisotropy barrier.

Convergence criterion: max_i |m_i × B_i| < ``torque_tol_T`` (tesla); |m × B| = |τ| for |m| = 1.
Frozen cells are not moved; slaved cells (pinning sites) are put at their local equilibrium after
every field evaluation (``relax_slaved_cells``), and their torque before that update counts in the
convergence test, so a converged state has every cell, slaved ones included, below the criterion.
Everything runs inside numba: no Python overhead per iteration.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from .effective_field import compute_effective_field, relax_slaved_cells, torque_and_max


# Reassociation lets LLVM vectorize the reductions; NaN/Inf semantics are kept (no nnan/ninf).
_FAST = {"reassoc", "contract", "arcp", "nsz"}
# error_model="numpy": a division by zero gives inf/nan instead of raising, so no branch per division
# stops LLVM from vectorizing the cell loops (measured: the Cayley step 15.7 → 3.0 µs at 64×64×1).
# The loops below touch few arrays each, so LLVM's runtime alias checks stay within its limit.
_KERNEL = dict(cache=True, fastmath=_FAST, error_model="numpy")


@numba.njit(**_KERNEL)
def _cayley_step(m4, torque4, h, precondition, step4):
    """m ← Cayley(m, h p τ) per cell, renormalized; ``step`` receives s = m_new − m_old."""
    m = m4.reshape(3, -1)  # flat views: one cell index, loops the compiler can vectorize
    torque = torque4.reshape(3, -1)
    step = step4.reshape(3, -1)
    for n in range(m.shape[1]):
        tx, ty, tz = torque[0, n], torque[1, n], torque[2, n]
        hp = h * precondition[n]
        n2 = hp * hp * (tx * tx + ty * ty + tz * tz)
        inv = 1.0 / (4.0 + n2)
        a = (4.0 - n2) * inv
        b = 4.0 * hp * inv
        ox, oy, oz = m[0, n], m[1, n], m[2, n]
        nx_ = a * ox + b * tx
        ny_ = a * oy + b * ty
        nz_ = a * oz + b * tz
        # the Cayley step keeps |m| = 1 exactly only in exact arithmetic: renormalize
        norm = 1.0 / np.sqrt(nx_ * nx_ + ny_ * ny_ + nz_ * nz_)
        nx_ *= norm
        ny_ *= norm
        nz_ *= norm
        m[0, n] = nx_
        m[1, n] = ny_
        m[2, n] = nz_
        step[0, n] = nx_ - ox
        step[1, n] = ny_ - oy
        step[2, n] = nz_ - oz


@numba.njit(**_KERNEL)
def _torque_and_squares(m4, field4, frozen3, torque4, squares):
    """τ = B − (m·B)m per cell (zero on frozen cells) into ``torque``; |τ|² into ``squares``."""
    m = m4.reshape(3, -1)
    field = field4.reshape(3, -1)
    frozen = frozen3.reshape(-1)
    torque = torque4.reshape(3, -1)
    mx, my, mz, bx, by, bz = m[0], m[1], m[2], field[0], field[1], field[2]
    tx, ty, tz = torque[0], torque[1], torque[2]
    for n in range(squares.shape[0]):
        p = mx[n] * bx[n] + my[n] * by[n] + mz[n] * bz[n]
        keep = 0.0 if frozen[n] else 1.0
        x = keep * (bx[n] - p * mx[n])
        y = keep * (by[n] - p * my[n])
        z = keep * (bz[n] - p * mz[n])
        tx[n] = x
        ty[n] = y
        tz[n] = z
        squares[n] = x * x + y * y + z * z


@numba.njit(**_KERNEL)
def _bb_products(step4, torque_old4, torque4, precondition, inverse_precondition):
    """With y = τ_old − τ, the sums s·P⁻¹s, s·y, y·P y in the preconditioned metric."""
    step = step4.reshape(3, -1)
    torque_old = torque_old4.reshape(3, -1)
    torque = torque4.reshape(3, -1)
    ss = 0.0
    sy = 0.0
    yy = 0.0
    for c in range(3):
        s, old, new = step[c], torque_old[c], torque[c]
        for n in range(precondition.shape[0]):
            y = old[n] - new[n]
            ss += s[n] * s[n] * inverse_precondition[n]
            sy += s[n] * y
            yy += precondition[n] * y * y
    return ss, sy, yy


@numba.njit(**_KERNEL)
def _torque_and_bb_products(m4, field4, frozen3, metric, step4, torque_old4, torque4, squares):
    """New torque τ = B − (m·B)m (zero on frozen cells) and, with y = τ_old − τ, the sums in the
    preconditioned metric s·P⁻¹s, s·y, y·P y. ``metric``: (P, P⁻¹), the diagonal preconditioner and
    its inverse per cell. Returns (max |τ|, max |P τ|, ss, sy, yy); ``squares`` is scratch (one value
    per cell). Three short loops, each vectorized, not one long one that is not."""
    precondition, inverse_precondition = metric
    _torque_and_squares(m4, field4, frozen3, torque4, squares)
    max_sq = 0.0
    max_p_sq = 0.0
    for n in range(squares.shape[0]):
        max_sq = max(max_sq, squares[n])
        max_p_sq = max(max_p_sq, precondition[n] * precondition[n] * squares[n])
    ss, sy, yy = _bb_products(step4, torque_old4, torque4, precondition, inverse_precondition)
    return np.sqrt(max_sq), np.sqrt(max_p_sq), ss, sy, yy


@numba.njit(cache=True)
def diagonal_preconditioner(model):
    """p_i = S/(S + 2K_i/M_s): shorter steps for cells whose own anisotropy makes them stiff (the
    50 MJ/m³ pinning sites, 2K/M_s ~ 100 T). S (T) is the stiffness every cell shares: the exchange
    self-term 2A/M_s (2/dx² + 2/dy² + 2/dz²), |J|/(M_s dz) with an interlayer spacer, plus 1 T."""
    K = model.K_u.reshape(-1)
    shared = 1.0
    if model.use_exchange:
        shared += 2.0 * model.A_ex / model.Ms * (2.0 / model.dx**2 + 2.0 / model.dy**2 + 2.0 / model.dz**2)
        if model.spacer_after_layer >= 0:
            shared += abs(model.interlayer_J) / (model.Ms * model.dz)
    p = np.empty(K.shape[0])
    for n in range(K.shape[0]):
        own = 2.0 * K[n] / model.Ms if model.use_anisotropy else 0.0
        p[n] = shared / (shared + own)
    return p


@numba.njit(cache=True)
def minimize_bb(m, model, B_ext, torque_tol_T, max_iterations, max_rotation_rad, initial_step=0.0):
    """Relax ``m`` in place. Returns (iterations, final max torque in T, converged flag, last BB step).

    ``initial_step`` > 0 is the first step length h (s/T·rad, as the BB steps); the last BB step of
    the previous relaxation of a nearby state is a good one. Otherwise the first step turns the cell
    of largest torque by 0.01 rad."""
    field = np.empty_like(m)
    torque = np.empty_like(m)
    torque_old = np.empty_like(m)
    step = np.empty_like(m)
    precondition = diagonal_preconditioner(model)
    inverse_precondition = 1.0 / precondition
    squares = np.empty_like(precondition)
    compute_effective_field(m, model, B_ext, field)
    max_torque = torque_and_max(m, field, model.frozen, torque)
    max_torque = max(max_torque, relax_slaved_cells(m, field, model))
    if max_torque < torque_tol_T:
        return 0, max_torque, True, initial_step
    max_p_torque = max_torque
    h = initial_step if initial_step > 0.0 else 1e-2 / max_torque
    for iteration in range(1, max_iterations + 1):
        # cap the step: a rotation of at most max_rotation_rad for the cell turning most
        h_cap = max_rotation_rad / max_p_torque
        if not (h > 0.0) or h > h_cap:
            h = h_cap
        _cayley_step(m, torque, h, precondition, step)
        torque, torque_old = torque_old, torque  # torque_old now holds the torque the step used
        compute_effective_field(m, model, B_ext, field)
        max_torque, max_p_torque, ss, sy, yy = _torque_and_bb_products(
            m, field, model.frozen, (precondition, inverse_precondition), step, torque_old, torque, squares)
        max_torque = max(max_torque, relax_slaved_cells(m, field, model))
        if max_torque < torque_tol_T:
            return iteration, max_torque, True, h
        if not np.isfinite(max_torque):
            return iteration, max_torque, False, 0.0
        if sy <= 0.0:
            h = max_rotation_rad / max_p_torque  # negative curvature along s: take the largest safe step
        elif iteration % 2 == 0:
            h = ss / sy
        else:
            h = sy / yy
    return max_iterations, max_torque, False, h


# ---------------------------------------------------------------- Fourier-preconditioned variant
FourierPreconditioner = namedtuple("FourierPreconditioner", ["filt", "scale", "stiffness_T", "inverse_scale"])
"""P = D^{1/2} F D^{1/2} of ``minimize_bb_fourier`` (a namedtuple: numba passes it into compiled
code): ``filt`` the in-plane exchange filter F(k) (``exchange_filter``), ``scale`` the cell-local
D^{1/2} (``local_scale``), ``stiffness_T`` the shared stiffness S (T) both were built with, and
``inverse_scale`` = D^{-1/2} (for the metric s·P⁻¹s)."""


def fourier_preconditioner(model, stiffness_T: float = 1.0) -> FourierPreconditioner:
    """The ``FourierPreconditioner`` of ``model`` for the shared stiffness ``stiffness_T`` (T)."""
    scale = local_scale(model, stiffness_T)
    return FourierPreconditioner(exchange_filter(model, stiffness_T), scale, stiffness_T, 1.0 / scale)


def exchange_filter(model, stiffness_T: float = 1.0) -> np.ndarray:
    """F(k) = S/(S + λ(k)) on the rfft2 grid (ny, nx//2 + 1): λ(k) = (2A/M_s)(4 sin²(k_x dx/2)/dx² +
    4 sin²(k_y dy/2)/dy²) (T) is the in-plane exchange stiffness of the mode k, S the stiffness every
    mode shares (anisotropy field order, ``stiffness_T``). It flattens the exchange part of the energy
    Hessian, whose short-wavelength modes (≈ 30 T at 2 nm) otherwise force steps ≈ 1/30 s/T."""
    ny, nx = model.K_u.shape[1], model.K_u.shape[2]
    kx = 2.0 * np.pi * np.fft.rfftfreq(nx, d=model.dx)
    ky = 2.0 * np.pi * np.fft.fftfreq(ny, d=model.dy)
    c = 2.0 * model.A_ex / model.Ms if model.use_exchange else 0.0
    lam = c * (4.0 * np.sin(kx[None, :] * model.dx / 2) ** 2 / model.dx**2
               + 4.0 * np.sin(ky[:, None] * model.dy / 2) ** 2 / model.dy**2)
    return np.ascontiguousarray(stiffness_T / (stiffness_T + lam), dtype=np.float32)


def local_scale(model, stiffness_T: float = 1.0) -> np.ndarray:
    """D_i^{1/2} with D_i = S'/(S' + 2K_i/M_s), S' = S plus the z-exchange 4A/(M_s dz²) of stacked layers:
    the cell-local part of the preconditioner P = D^{1/2} F D^{1/2} (the 50 MJ/m³ pinning sites)."""
    K = np.asarray(model.K_u).reshape(-1)
    nz = model.K_u.shape[0]
    shared = stiffness_T
    if model.use_exchange and nz > 1:
        shared += 4.0 * model.A_ex / (model.Ms * model.dz**2)
    own = 2.0 * K / model.Ms if model.use_anisotropy else np.zeros_like(K)
    return np.sqrt(shared / (shared + own))


@numba.njit(cache=True)
def _apply_filter(v4, scale, filt, out4):
    """out = D^{1/2} F D^{1/2} v per component and layer (v, out: (3, nz, ny, nx))."""
    _, nz, ny, nx = v4.shape
    sc = scale.reshape(nz, ny, nx)
    work = np.empty((ny, nx), dtype=np.float32)  # a preconditioner needs no more precision than this
    for c in range(3):
        for k in range(nz):
            for a in range(ny):
                for b in range(nx):
                    work[a, b] = np.float32(sc[k, a, b] * v4[c, k, a, b])
            spec = np.fft.rfft2(work)
            for a in range(ny):
                for b in range(spec.shape[1]):
                    spec[a, b] *= filt[a, b]
            back = np.fft.irfft2(spec, s=(ny, nx))
            for a in range(ny):
                for b in range(nx):
                    out4[c, k, a, b] = sc[k, a, b] * back[a, b]


@numba.njit(**_KERNEL)
def _tangent_and_max(m4, d4, frozen3, out4):
    """out = d − (m·d) m (zero on frozen cells); returns max |out|. Branch-free (a 0/1 factor per
    cell) and the maximum in its own pass, so both loops vectorize."""
    m = m4.reshape(3, -1)
    d = d4.reshape(3, -1)
    out = out4.reshape(3, -1)
    frozen = frozen3.reshape(-1)
    mx, my, mz, dx, dy, dz = m[0], m[1], m[2], d[0], d[1], d[2]
    ox, oy, oz = out[0], out[1], out[2]
    for n in range(mx.shape[0]):
        p = mx[n] * dx[n] + my[n] * dy[n] + mz[n] * dz[n]
        keep = 0.0 if frozen[n] else 1.0
        ox[n] = keep * (dx[n] - p * mx[n])
        oy[n] = keep * (dy[n] - p * my[n])
        oz[n] = keep * (dz[n] - p * mz[n])
    best = 0.0
    for n in range(mx.shape[0]):
        best = max(best, ox[n] * ox[n] + oy[n] * oy[n] + oz[n] * oz[n])
    return np.sqrt(best)


@numba.njit(**_KERNEL)
def _inverse_metric(s4, inverse_scale, c_x, c_y, stiffness):
    """s·P⁻¹s = w·F⁻¹w with w = D^{-1/2}s and F⁻¹ = 1 + L/S: |w|² + (1/S) Σ_bonds c (w_i − w_j)²/Δ²
    over the periodic in-plane bonds (c_x = 2A/(M_s dx²), c_y likewise). ``inverse_scale``: D^{-1/2}
    per cell. One row of w at a time, so the inner loops are plain and vectorize."""
    _, nz, ny, nx = s4.shape
    isc = inverse_scale.reshape(nz, ny, nx)
    w = np.empty((ny, nx))
    total = 0.0
    for c in range(3):
        for k in range(nz):
            for a in range(ny):
                for b in range(nx):
                    w[a, b] = s4[c, k, a, b] * isc[k, a, b]
            squares = 0.0
            bonds_x = 0.0
            bonds_y = 0.0
            for a in range(ny):
                ap = a + 1 if a + 1 < ny else 0
                row, up = w[a], w[ap]
                for b in range(nx - 1):
                    squares += row[b] * row[b]
                    bonds_x += (row[b] - row[b + 1]) ** 2
                    bonds_y += (row[b] - up[b]) ** 2
                b = nx - 1
                squares += row[b] * row[b]
                bonds_x += (row[b] - row[0]) ** 2
                bonds_y += (row[b] - up[b]) ** 2
            total += squares + (c_x * bonds_x + c_y * bonds_y) / stiffness
    return total


@numba.njit(**_KERNEL)
def _bb_sums_fourier(step4, torque_old4, torque4, ptau_old4, ptau4):
    """With y = τ_old − τ and P y = Pτ_old − Pτ: s·y and y·P y = τ_old·Pτ_old − 2 τ_old·Pτ + τ·Pτ
    (P symmetric), in one pass over the cells."""
    step = step4.reshape(-1)
    old = torque_old4.reshape(-1)
    new = torque4.reshape(-1)
    p_old = ptau_old4.reshape(-1)
    p_new = ptau4.reshape(-1)
    sy = 0.0
    yPy = 0.0
    for n in range(step.shape[0]):
        sy += step[n] * (old[n] - new[n])
        yPy += old[n] * p_old[n] - 2.0 * old[n] * p_new[n] + new[n] * p_new[n]
    return sy, yPy


@numba.njit(cache=True)
def minimize_bb_fourier(m, model, B_ext, torque_tol_T, max_iterations, max_rotation_rad, initial_step,
                        preconditioner):
    """``minimize_bb`` with the preconditioner P = D^{1/2} F D^{1/2} (a ``FourierPreconditioner``):
    direction d = tangent part of P τ, BB steps s·P⁻¹s/s·y and s·y/y·Py with y = τ_old − τ
    (P y = Pτ_old − Pτ, no extra transform). Same convergence test (max |τ|)."""
    filt, scale, stiffness = preconditioner.filt, preconditioner.scale, preconditioner.stiffness_T
    field = np.empty_like(m)
    torque = np.empty_like(m)
    torque_old = np.empty_like(m)
    ptau = np.empty_like(m)
    ptau_old = np.empty_like(m)
    direction = np.empty_like(m)
    step = np.empty_like(m)
    ones = np.ones(m.shape[1] * m.shape[2] * m.shape[3])
    c_x = 2.0 * model.A_ex / (model.Ms * model.dx**2) if model.use_exchange else 0.0
    c_y = 2.0 * model.A_ex / (model.Ms * model.dy**2) if model.use_exchange else 0.0
    compute_effective_field(m, model, B_ext, field)
    max_torque = torque_and_max(m, field, model.frozen, torque)
    max_torque = max(max_torque, relax_slaved_cells(m, field, model))
    if max_torque < torque_tol_T:
        return 0, max_torque, True, initial_step
    _apply_filter(torque, scale, filt, ptau)
    max_dir = _tangent_and_max(m, ptau, model.frozen, direction)
    h = initial_step if initial_step > 0.0 else 1e-2 / max(max_dir, 1e-30)
    for iteration in range(1, max_iterations + 1):
        h_cap = max_rotation_rad / max(max_dir, 1e-30)
        if not (h > 0.0) or h > h_cap:
            h = h_cap
        _cayley_step(m, direction, h, ones, step)
        torque, torque_old = torque_old, torque
        ptau, ptau_old = ptau_old, ptau
        compute_effective_field(m, model, B_ext, field)
        max_torque = torque_and_max(m, field, model.frozen, torque)
        max_torque = max(max_torque, relax_slaved_cells(m, field, model))
        if max_torque < torque_tol_T:
            return iteration, max_torque, True, h
        if not np.isfinite(max_torque):
            return iteration, max_torque, False, 0.0
        _apply_filter(torque, scale, filt, ptau)
        max_dir = _tangent_and_max(m, ptau, model.frozen, direction)
        sy, yPy = _bb_sums_fourier(step, torque_old, torque, ptau_old, ptau)
        if sy <= 0.0:
            h = max_rotation_rad / max(max_dir, 1e-30)
        elif iteration % 2 == 0:
            h = _inverse_metric(step, preconditioner.inverse_scale, c_x, c_y, stiffness) / sy
        else:
            h = sy / yPy
    return max_iterations, max_torque, False, h
