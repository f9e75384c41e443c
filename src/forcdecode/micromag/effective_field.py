"""The effective field B_eff = −(1/M_s) δE/δm (tesla) of all terms, and the total energy.

``FieldModel`` is a namedtuple (numba passes it into compiled code) holding everything the local
terms and the FFT demag need; ``compute_effective_field`` adds the enabled terms in one call.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from .anisotropy import add_anisotropy_field
from .demag import add_demag_field
from .dmi import add_dmi_field
from .exchange import add_exchange_field
from .interlayer import add_interlayer_field
from .zeeman import add_zeeman_field

FieldModel = namedtuple(
    "FieldModel",
    [
        "Ms", "A_ex", "D", "dx", "dy", "dz", "K_2",  # floats (SI)
        "B_bias",  # (3,) tesla: exchange-bias-like unidirectional field (zero by default)
        "K_u", "easy_axis", "frozen",  # (nz,ny,nx), (3,nz,ny,nx), (nz,ny,nx) bool (fixed or slaved cells)
        "slaved_cells",  # (n, 3) int64 (k, j, i) of cells held at their local equilibrium
        "spacer_after_layer",  # int: layer k whose direct exchange to k + 1 is cut (−1: no spacer)
        "interlayer_J",  # J/m²: bilinear coupling −J m_k·m_{k+1} per area across the spacer
        "kxx", "kyy", "kzz", "kxy", "kxz_imag", "kyz_imag",  # demag kernel
        "use_exchange", "use_anisotropy", "use_dmi", "use_demag", "use_zeeman",  # bools
    ],
)


@numba.njit(cache=True)
def compute_effective_field(m, model, B_ext, out):
    """Overwrite ``out`` with the total effective flux density (T) of ``m`` in applied field ``B_ext``."""
    out[...] = 0.0
    if model.use_exchange:
        add_exchange_field(m, model.Ms, model.A_ex, model.dx, model.dy, model.dz, out, model.spacer_after_layer)
        if model.spacer_after_layer >= 0:
            add_interlayer_field(m, model.Ms, model.interlayer_J, model.dz, model.spacer_after_layer, out)
    if model.use_anisotropy:
        add_anisotropy_field(m, model.Ms, model.K_u, model.easy_axis, out, model.K_2)
    if model.use_dmi:
        add_dmi_field(m, model.Ms, model.D, model.dx, model.dy, out)
    if model.use_demag:
        add_demag_field(m, model, out)
    if model.use_zeeman:
        add_zeeman_field(B_ext, out)
    add_zeeman_field(model.B_bias, out)


@numba.njit(cache=True)
def total_energy(m, model, B_ext, field_buffer, cell_volume):
    """Total energy (J): E = −M_s V Σ_i m_i·(½ B_bilinear,i + B_linear) − K_2 V Σ_i (u·m)⁴, with the
    linear fields B_ext and B_bias. Fills ``field_buffer`` with B_eff."""
    compute_effective_field(m, model, B_ext, field_buffer)
    _, nz, ny, nx = m.shape
    acc = 0.0
    quartic = 0.0
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                projection = 0.0
                for c in range(3):
                    b_lin = (B_ext[c] if model.use_zeeman else 0.0) + model.B_bias[c]
                    # B_eff = B_bil + B_quartic + B_lin; −M_s m·(½B_bil + B_lin) = −½M_s m·(B_eff + B_lin) + ½M_s m·B_quartic
                    acc += m[c, k, j, i] * (field_buffer[c, k, j, i] + b_lin)
                    projection += model.easy_axis[c, k, j, i] * m[c, k, j, i]
                quartic += projection**4
    # the quartic term's field enters m·B_eff with weight 4K_2(u·m)⁴/M_s; its energy is −K_2(u·m)⁴
    k2 = model.K_2 if model.use_anisotropy else 0.0
    return -0.5 * model.Ms * cell_volume * acc + k2 * cell_volume * quartic


@numba.njit(cache=True)
def torque_and_max(m, field, frozen, torque):
    """torque = B_⊥ = B − (m·B)m (T) per cell (zero on frozen cells); returns max |torque|."""
    _, nz, ny, nx = m.shape
    max_sq = 0.0
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                if frozen[k, j, i]:
                    torque[0, k, j, i] = 0.0
                    torque[1, k, j, i] = 0.0
                    torque[2, k, j, i] = 0.0
                    continue
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
    return np.sqrt(max_sq)


@numba.njit(cache=True)
def relax_slaved_cells(m, field, model):
    """Put every slaved cell at its local energy minimum in the field of its surroundings.

    A pinning cell's own anisotropy field B_K = 2K/M_s (~80–500 T) dwarfs everything else, so its
    direction is slaved to its neighbours (adiabatic elimination): with B_nb the field of all other
    cells plus the applied field (the cell's own anisotropy and exchange self-term removed), it sits
    where m ∥ B_K (u·m) u + B_nb, solved by fixed-point iteration (contraction |B_nb,⊥|/B_K) from its
    current direction, which keeps it in its hemisphere unless B_nb along −m exceeds B_K (then it
    switches, as a Stoner–Wohlfarth particle would). ``field`` must be B_eff of the current ``m``.
    Returns the largest torque |m × B_eff| (T) the slaved cells had before the update.
    """
    cells = model.slaved_cells
    _, nz, ny, nx = m.shape
    c_x = 2.0 * model.A_ex / (model.Ms * model.dx * model.dx) if model.use_exchange else 0.0
    c_y = 2.0 * model.A_ex / (model.Ms * model.dy * model.dy) if model.use_exchange else 0.0
    c_z = 2.0 * model.A_ex / (model.Ms * model.dz * model.dz) if model.use_exchange else 0.0
    spacer = model.spacer_after_layer
    max_sq = 0.0
    for n in range(cells.shape[0]):
        k, j, i = cells[n, 0], cells[n, 1], cells[n, 2]
        mx, my, mz = m[0, k, j, i], m[1, k, j, i], m[2, k, j, i]
        bx, by, bz = field[0, k, j, i], field[1, k, j, i], field[2, k, j, i]
        p = mx * bx + my * by + mz * bz
        tx, ty, tz = bx - p * mx, by - p * my, bz - p * mz
        sq = tx * tx + ty * ty + tz * tz
        if sq > max_sq:
            max_sq = sq
        ux, uy, uz = model.easy_axis[0, k, j, i], model.easy_axis[1, k, j, i], model.easy_axis[2, k, j, i]
        b_k = 2.0 * model.K_u[k, j, i] / model.Ms if model.use_anisotropy else 0.0
        proj = ux * mx + uy * my + uz * mz
        z_links = (1.0 if k + 1 < nz and k != spacer else 0.0) + (1.0 if k > 0 and k - 1 != spacer else 0.0)
        c_self = 2.0 * c_x + 2.0 * c_y + c_z * z_links
        nbx = bx - b_k * proj * ux + c_self * mx
        nby = by - b_k * proj * uy + c_self * my
        nbz = bz - b_k * proj * uz + c_self * mz
        for _ in range(8):
            proj = ux * mx + uy * my + uz * mz
            vx = b_k * proj * ux + nbx
            vy = b_k * proj * uy + nby
            vz = b_k * proj * uz + nbz
            norm = np.sqrt(vx * vx + vy * vy + vz * vz)
            if norm == 0.0:
                break
            mx, my, mz = vx / norm, vy / norm, vz / norm
        m[0, k, j, i] = mx
        m[1, k, j, i] = my
        m[2, k, j, i] = mz
    return np.sqrt(max_sq)
