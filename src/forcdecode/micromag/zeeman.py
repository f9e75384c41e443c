"""Zeeman energy in a uniform applied field: energy density −M_s m·B_ext, B_ext = μ0H_ext in tesla."""

import numba


@numba.njit(cache=True)
def add_zeeman_field(B_ext, out):
    """Add the uniform applied flux density ``B_ext`` (3,) in tesla to ``out`` (3, nz, ny, nx)."""
    _, nz, ny, nx = out.shape
    for c in range(3):
        b = B_ext[c]
        if b != 0.0:
            for k in range(nz):
                for j in range(ny):
                    for i in range(nx):
                        out[c, k, j, i] += b
