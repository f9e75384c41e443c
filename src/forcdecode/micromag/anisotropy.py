"""Uniaxial anisotropy with a per-cell constant and easy axis: energy density −K_u (u·m)² − K_2 (u·m)⁴.

B_anis = (2K_u/M_s)(u·m) u + (4K_2/M_s)(u·m)³ u (tesla), mumax3's K1/K2 convention. K_2 (a scalar,
default 0) is the optional second-order term of the residual analysis (issue: close the loop). Cells carry their own K_u (J/m³) and unit axis u, which is how
grains (K_u(1+Δ), tilted axes) and pinning cells (K_u = 50 MJ/m³ along z) are represented.
"""

import numba


@numba.njit(cache=True)
def add_anisotropy_field(m, Ms, K_u, easy_axis, out, K_2=0.0):
    """Add the uniaxial anisotropy flux density (T); ``K_u`` is (nz, ny, nx), ``easy_axis`` (3, nz, ny, nx)."""
    _, nz, ny, nx = m.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                ux = easy_axis[0, k, j, i]
                uy = easy_axis[1, k, j, i]
                uz = easy_axis[2, k, j, i]
                projection = ux * m[0, k, j, i] + uy * m[1, k, j, i] + uz * m[2, k, j, i]
                s = 2.0 * K_u[k, j, i] / Ms * projection + 4.0 * K_2 / Ms * projection**3
                out[0, k, j, i] += s * ux
                out[1, k, j, i] += s * uy
                out[2, k, j, i] += s * uz
