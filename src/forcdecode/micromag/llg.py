"""Landau–Lifshitz–Gilbert dynamics with an adaptive embedded Runge–Kutta (Dormand–Prince 5(4)).

    dm/dt = −γ_LL/(1 + α²) [ m × B_eff + α m × (m × B_eff) ],   γ_LL = 1.7595e11 rad/(T·s).

The step is error-controlled: the embedded 4th-order solution gives err = max_i |m5 − m4|; a step
with err ≤ tol is accepted, and the next step is dt·clamp(0.8 (tol/err)^{1/5}, 0.5, 2) (rejected
steps shrink by at least that rule, never below ×0.1). |m| = 1 is restored after every accepted
step. First-same-as-last: the 7th stage is the next step's 1st. Frozen cells do not move; slaved
(pinning) cells are put at their local equilibrium after every accepted step (adiabatic elimination
of their ~THz precession, which would otherwise set the step size).

The applied field may ramp linearly in time along z: B_ext(t) = B_ext0 + ẑ·ramp_T_per_s·t.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from .constants import GAMMA_LL
from .effective_field import compute_effective_field, relax_slaved_cells

# Dormand–Prince coefficients
_A21 = 1 / 5
_A31, _A32 = 3 / 40, 9 / 40
_A41, _A42, _A43 = 44 / 45, -56 / 15, 32 / 9
_A51, _A52, _A53, _A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
_A61, _A62, _A63, _A64, _A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
_B1, _B3, _B4, _B5, _B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
# difference 5th − 4th order weights (error estimate)
_E1, _E3, _E4, _E5, _E6, _E7 = 71 / 57600, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40
_C2, _C3, _C4, _C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9

StepControl = namedtuple("StepControl", ["dt", "tol", "max_steps"])
"""Step control of ``run_llg_rk45`` (a namedtuple: numba passes it into compiled code): the first step
``dt`` (s), the error tolerance ``tol`` (max cell |m5 − m4| per step, dimensionless) and ``max_steps``
(accepted plus rejected)."""


@numba.njit(cache=True)
def llg_rhs(m, model, B_ext, alpha, field, out):
    """dm/dt (1/s) into ``out``; ``field`` is scratch for B_eff."""
    compute_effective_field(m, model, B_ext, field)
    pref = -GAMMA_LL / (1.0 + alpha * alpha)
    _, nz, ny, nx = m.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                if model.frozen[k, j, i]:
                    out[0, k, j, i] = 0.0
                    out[1, k, j, i] = 0.0
                    out[2, k, j, i] = 0.0
                    continue
                mx, my, mz = m[0, k, j, i], m[1, k, j, i], m[2, k, j, i]
                bx, by, bz = field[0, k, j, i], field[1, k, j, i], field[2, k, j, i]
                px = my * bz - mz * by  # m × B
                py = mz * bx - mx * bz
                pz = mx * by - my * bx
                dx_ = my * pz - mz * py  # m × (m × B)
                dy_ = mz * px - mx * pz
                dz_ = mx * py - my * px
                out[0, k, j, i] = pref * (px + alpha * dx_)
                out[1, k, j, i] = pref * (py + alpha * dy_)
                out[2, k, j, i] = pref * (pz + alpha * dz_)


@numba.njit(cache=True)
def _ramped(B_ext0, ramp_T_per_s, t, out):
    out[0] = B_ext0[0]
    out[1] = B_ext0[1]
    out[2] = B_ext0[2] + ramp_T_per_s * t


@numba.njit(cache=True)
def _normalize(m):
    _, nz, ny, nx = m.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                n = np.sqrt(m[0, k, j, i] ** 2 + m[1, k, j, i] ** 2 + m[2, k, j, i] ** 2)
                m[0, k, j, i] /= n
                m[1, k, j, i] /= n
                m[2, k, j, i] /= n


@numba.njit(cache=True)
def _stage(y, m, h, weights, slopes):
    """y = m + h Σ c_s k_s over the six ``weights`` c_s and ``slopes`` k_s (dm/dt, 1/s; arrays like
    ``m``, any one where its weight is 0), one fused pass without temporaries."""
    c1, c2, c3, c4, c5, c6 = weights
    k1, k2, k3, k4, k5, k6 = slopes
    _, nz, ny, nx = m.shape
    for c in range(3):
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    y[c, k, j, i] = m[c, k, j, i] + h * (
                        c1 * k1[c, k, j, i] + c2 * k2[c, k, j, i] + c3 * k3[c, k, j, i]
                        + c4 * k4[c, k, j, i] + c5 * k5[c, k, j, i] + c6 * k6[c, k, j, i])


@numba.njit(cache=True)
def run_llg_rk45(m, model, B_ext0, ramp_T_per_s, alpha, t_start, t_end, control):
    """Integrate LLG in place from ``t_start`` to ``t_end`` (s); B_ext(t) = B_ext0 + ẑ ramp·(t − t_start)
    (T, T/s), Gilbert damping ``alpha``, steps as ``control`` (a ``StepControl``) says.

    Returns (t reached, next dt, accepted steps, rejected steps, ok). ``ok`` is False if the
    solution became non-finite or ``max_steps`` ran out before ``t_end``.
    """
    dt, tol, max_steps = control.dt, control.tol, control.max_steps
    field = np.empty_like(m)
    k1 = np.empty_like(m)
    k2 = np.empty_like(m)
    k3 = np.empty_like(m)
    k4 = np.empty_like(m)
    k5 = np.empty_like(m)
    k6 = np.empty_like(m)
    k7 = np.empty_like(m)
    y = np.empty_like(m)
    b = np.empty(3)
    t = t_start
    accepted = 0
    rejected = 0
    _ramped(B_ext0, ramp_T_per_s, 0.0, b)
    llg_rhs(m, model, b, alpha, field, k1)
    while t < t_end:
        if accepted + rejected >= max_steps:
            return t, dt, accepted, rejected, False
        h = dt
        last = False
        if t + h >= t_end:
            h = t_end - t
            last = True
        tau = t - t_start
        _stage(y, m, h, (_A21, 0.0, 0.0, 0.0, 0.0, 0.0), (k1, k1, k1, k1, k1, k1))
        _ramped(B_ext0, ramp_T_per_s, tau + _C2 * h, b)
        llg_rhs(y, model, b, alpha, field, k2)
        _stage(y, m, h, (_A31, _A32, 0.0, 0.0, 0.0, 0.0), (k1, k2, k1, k1, k1, k1))
        _ramped(B_ext0, ramp_T_per_s, tau + _C3 * h, b)
        llg_rhs(y, model, b, alpha, field, k3)
        _stage(y, m, h, (_A41, _A42, _A43, 0.0, 0.0, 0.0), (k1, k2, k3, k1, k1, k1))
        _ramped(B_ext0, ramp_T_per_s, tau + _C4 * h, b)
        llg_rhs(y, model, b, alpha, field, k4)
        _stage(y, m, h, (_A51, _A52, _A53, _A54, 0.0, 0.0), (k1, k2, k3, k4, k1, k1))
        _ramped(B_ext0, ramp_T_per_s, tau + _C5 * h, b)
        llg_rhs(y, model, b, alpha, field, k5)
        _stage(y, m, h, (_A61, _A62, _A63, _A64, _A65, 0.0), (k1, k2, k3, k4, k5, k1))
        _ramped(B_ext0, ramp_T_per_s, tau + h, b)
        llg_rhs(y, model, b, alpha, field, k6)
        _stage(y, m, h, (_B1, 0.0, _B3, _B4, _B5, _B6), (k1, k2, k3, k4, k5, k6))
        llg_rhs(y, model, b, alpha, field, k7)
        err = 0.0
        _, nz, ny, nx = m.shape
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    e2 = 0.0
                    for c in range(3):
                        e = h * (_E1 * k1[c, k, j, i] + _E3 * k3[c, k, j, i] + _E4 * k4[c, k, j, i]
                                 + _E5 * k5[c, k, j, i] + _E6 * k6[c, k, j, i] + _E7 * k7[c, k, j, i])
                        e2 += e * e
                    if e2 > err:
                        err = e2
        err = np.sqrt(err)
        if not np.isfinite(err):
            return t, dt, accepted, rejected, False
        if err <= tol:
            m[...] = y
            _normalize(m)
            if model.slaved_cells.shape[0] > 0:
                # slaved (pinning) cells follow their neighbours adiabatically; ``field`` is B_eff(y)
                relax_slaved_cells(m, field, model)
                llg_rhs(m, model, b, alpha, field, k1)
            else:
                k1[...] = k7  # first same as last
            t = t_end if last else t + h
            accepted += 1
            factor = 0.8 * (tol / err) ** 0.2 if err > 0.0 else 2.0
            factor = min(2.0, max(0.5, factor))
            if not last:
                dt = h * factor
        else:
            rejected += 1
            factor = max(0.1, 0.8 * (tol / err) ** 0.2)
            dt = h * factor
    return t, dt, accepted, rejected, True
