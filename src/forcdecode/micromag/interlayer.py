"""Interlayer exchange coupling (RKKY-like, bilinear) across a non-magnetic spacer.

With a spacer after layer k (``spacer_after_layer = k``, 0 ≤ k < nz − 1) the direct exchange
between layers k and k + 1 is cut (``exchange.add_exchange_field``) and replaced by the surface
energy E = −J ∫ m_k·m_{k+1} dA (J in J/m²; J > 0 ferromagnetic, J < 0 antiferromagnetic), i.e.
−J dx dy m_k·m_{k+1} per column. Its field is B_k = (J/(M_s dz)) m_{k+1} on layer k and
B_{k+1} = (J/(M_s dz)) m_k on layer k + 1 (tesla), bilinear, so the engine's energy
−(M_s V/2) Σ m·B holds. The spacer is not meshed: demag sees the layers as adjacent.
"""

import numba


@numba.njit(cache=True)
def add_interlayer_field(m, Ms, J_m2, dz, spacer_after_layer, out):
    """Add the interlayer coupling flux density (T) across the spacer after ``spacer_after_layer``."""
    below = spacer_after_layer
    above = below + 1
    c = J_m2 / (Ms * dz)
    _, _, ny, nx = m.shape
    for comp in range(3):
        for j in range(ny):
            for i in range(nx):
                m_below = m[comp, below, j, i]
                m_above = m[comp, above, j, i]
                out[comp, below, j, i] += c * m_above
                out[comp, above, j, i] += c * m_below
