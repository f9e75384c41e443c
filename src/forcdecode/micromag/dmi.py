"""Interfacial Dzyaloshinskii–Moriya interaction (Néel type, C_nv symmetry, z the film normal).

Energy density ε = D [m_z (∇·m) − (m·∇) m_z], the convention of mumax3's ``Dind`` (note that the
DMI standard problem of Cortés-Ortuño et al. 2018 writes the opposite sign: their D = −Dind).
Field (tesla): B_DMI = (2D/M_s)(∂x m_z, ∂y m_z, −∂x m_x − ∂y m_y), central differences, periodic in
x and y (no boundary condition is needed in-plane; there is no z derivative).

Chirality: a cycloid m = (sin θ, 0, cos θ) with θ(x) has ε = D dθ/dx, so D > 0 favours θ decreasing
along +x (winding −2π per period, walls with ∮(m_z ∂x m_x − m_x ∂x m_z) dx = −π each); on the grid
a cycloid of wave number q has ε = −D sin(q dx)/dx for θ = −qx.
"""

import numba


@numba.njit(cache=True)
def add_dmi_field(m, Ms, D, dx, dy, out):
    """Add the interfacial DMI flux density (T) of ``m`` (3, nz, ny, nx) to ``out``."""
    _, nz, ny, nx = m.shape
    cx = 2.0 * D / (Ms * 2.0 * dx)
    cy = 2.0 * D / (Ms * 2.0 * dy)
    for k in range(nz):
        for j in range(ny):
            jp = j + 1 if j + 1 < ny else 0
            jm = j - 1 if j > 0 else ny - 1
            for i in range(nx):
                ip = i + 1 if i + 1 < nx else 0
                im = i - 1 if i > 0 else nx - 1
                out[0, k, j, i] += cx * (m[2, k, j, ip] - m[2, k, j, im])
                out[1, k, j, i] += cy * (m[2, k, jp, i] - m[2, k, jm, i])
                out[2, k, j, i] -= cx * (m[0, k, j, ip] - m[0, k, j, im]) + cy * (m[1, k, jp, i] - m[1, k, jm, i])
