"""Heisenberg exchange: energy density A|∇m|², six-neighbour finite differences.

B_ex,i = (2A/M_s) Σ_n (m_n − m_i)/Δ_n² (tesla), with Δ_n = dx, dy or dz. Periodic in x and y;
open (Neumann, no neighbour) at the top and bottom surfaces, so the layers are coupled through the
z-neighbour term 2A/(M_s dz²) only; ``spacer_after_layer = k`` (≥ 0) cuts the link between
layers k and k + 1 (a non-magnetic spacer, coupled instead by ``interlayer``). The discrete energy
is Σ_pairs 2A V (1 − m_i·m_n)/Δ²·½·2 = −(M_s V/2) Σ_i m_i·B_ex,i; a spiral of wave number q along x has energy density
2A(1 − cos q dx)/dx² → A q².
"""

import numba


@numba.njit(cache=True)
def add_exchange_field(m, Ms, A_ex, dx, dy, dz, out, spacer_after_layer=-1):
    """Add the exchange flux density (T) of ``m`` (3, nz, ny, nx) to ``out``; no z link across the
    spacer after layer ``spacer_after_layer`` (−1: none)."""
    _, nz, ny, nx = m.shape
    cx = 2.0 * A_ex / (Ms * dx * dx)
    cy = 2.0 * A_ex / (Ms * dy * dy)
    cz = 2.0 * A_ex / (Ms * dz * dz)
    for c in range(3):  # component outermost: each pass streams one contiguous array
        for k in range(nz):
            has_up = k + 1 < nz and k != spacer_after_layer
            has_down = k > 0 and k - 1 != spacer_after_layer
            for j in range(ny):
                jp = j + 1 if j + 1 < ny else 0
                jm = j - 1 if j > 0 else ny - 1
                for i in range(nx):
                    ip = i + 1 if i + 1 < nx else 0
                    im = i - 1 if i > 0 else nx - 1
                    mc = m[c, k, j, i]
                    b = cx * (m[c, k, j, ip] + m[c, k, j, im] - 2.0 * mc)
                    b += cy * (m[c, k, jp, i] + m[c, k, jm, i] - 2.0 * mc)
                    if has_up:
                        b += cz * (m[c, k + 1, j, i] - mc)
                    if has_down:
                        b += cz * (m[c, k - 1, j, i] - mc)
                    out[c, k, j, i] += b
