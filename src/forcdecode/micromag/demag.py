"""Demagnetizing (dipolar) field of a film that is periodic (infinite) in x, y and open in z.

The film is a stack of ``nz`` layers of thickness t = dz. For an in-plane wave vector q the
continuum demag tensor between layers is known in closed form (the field of a sheet of magnetic
charge decays as e^{-q|z|}/(2q)). With f(q) = (1 − e^{−qt})/(qt) and, for layers whose centres are
|d|·dz apart, g_d(q) = (1 − e^{−qt})² e^{−q(|d|dz − t)}/(2qt):

- self (d = 0):   N_zz = f,      N_αβ = (q_α q_β/q²)(1 − f),          N_αz = 0;
- cross (d ≠ 0):  N_zz = −g_d,   N_αβ = +(q_α q_β/q²) g_d,            N_αz = N_zα = sign(d)·i q_α g_d/q,

with α, β ∈ {x, y}, H = −M_s N m, d = (observer layer) − (source layer), z pointing up and the FFT
convention of numpy (∂/∂x ↔ +i k_x). The field averaged over a cell of a piecewise-constant
magnetization is the alias sum over reciprocal vectors G of the in-plane grid,

    N(k) = Σ_G N_cont(k + G) sinc²(q_x dx/2) sinc²(q_y dy/2),   q = k + G,

which is exact for the infinite periodic film up to the truncation of the sum (±20 aliases: ≲1e-4).
A uniform perpendicular film gets N_zz = 1 exactly (only G = 0 survives at k = 0).

The field is evaluated with layer-by-layer 2D real FFTs inside numba (rocket-fft), O(N log N).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from .constants import MU0
from .mesh import Mesh


@dataclass(frozen=True)
class DemagKernel:
    """Cell-averaged demag tensor in Fourier space, for every layer offset d = i − j.

    Arrays have shape (2·nz − 1, ny, nx//2 + 1), index d + nz − 1. ``xx, yy, zz, xy`` are real
    (even in k); ``xz_imag, yz_imag`` hold the imaginary part of the odd components N_xz = N_zx,
    N_yz = N_zy (the real part is zero).
    """

    xx: np.ndarray
    yy: np.ndarray
    zz: np.ndarray
    xy: np.ndarray
    xz_imag: np.ndarray
    yz_imag: np.ndarray

    def arrays(self):
        return (self.xx, self.yy, self.zz, self.xy, self.xz_imag, self.yz_imag)


def _continuum_components(qx, qy, t, layer_offset, dz):
    """Continuum film tensor components at wave vectors (qx, qy) [1/m] for a layer offset."""
    q = np.hypot(qx, qy)
    q_safe = np.where(q > 0, q, 1.0)
    qt = q_safe * t
    one_minus = -np.expm1(-qt)  # 1 − e^{−qt}, accurate at small qt
    with np.errstate(invalid="ignore", divide="ignore"):
        ux = np.where(q > 0, qx / q_safe, 0.0)
        uy = np.where(q > 0, qy / q_safe, 0.0)
    if layer_offset == 0:
        f = np.where(q > 0, one_minus / qt, 1.0)
        zz = f
        inplane = 1.0 - f
        xx, yy, xy = ux * ux * inplane, uy * uy * inplane, ux * uy * inplane
        xz = np.zeros_like(q)
        yz = np.zeros_like(q)
    else:
        separation = abs(layer_offset) * dz
        g = np.where(q > 0, one_minus**2 * np.exp(-q_safe * (separation - t)) / (2.0 * qt), 0.0)
        zz = -g
        xx, yy, xy = ux * ux * g, uy * uy * g, ux * uy * g
        sign = np.sign(layer_offset)
        xz = sign * ux * g
        yz = sign * uy * g
    return xx, yy, zz, xy, xz, yz


def _inplane_projector_row_sums(a, b):
    """Closed-form sums over the aliases n of one in-plane direction (here y, wave number
    q_y = (2π/dy)(n + a), q_x = (2π/dy) b) of the 2D projectors weighted by sinc²(q_y dy/2):

        Σ_n q_x²/q² sinc² = 1 − sin²(πa)/(πb) · sinh 2πb / (cosh 2πb − cos 2πa)
        Σ_n q_x q_y/q² sinc² = sin²(πa)/(πb) · [cot πa − sin 2πa / (cosh 2πb − cos 2πa)]

    (from Σ 1/(n+a)² = π²/sin²πa, Σ 1/((n+a)²+b²) = (π/b) sinh 2πb/(cosh 2πb − cos 2πa) and
    Σ (n+a)/((n+a)²+b²) = π sin 2πa/(cosh 2πb − cos 2πa)). These parts of the self in-plane kernel
    do not decay with |q|, so a truncated alias sum would converge only as 1/n_alias.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    sin2 = np.sin(np.pi * a) ** 2
    b_abs = np.abs(b)
    regular = (b_abs > 1e-12) & (sin2 > 1e-30)
    b_safe = np.where(regular, b, 1.0)
    two_pi_b = np.minimum(2 * np.pi * np.abs(b_safe), 700.0)
    cos2 = np.cos(2 * np.pi * a)
    denominator = np.cosh(two_pi_b) - cos2
    ratio_sinh = np.sinh(two_pi_b) / denominator
    xx = np.where(regular, 1.0 - sin2 / (np.pi * np.abs(b_safe)) * ratio_sinh, np.where(b_abs > 1e-12, 1.0, 0.0))
    sin_a = np.where(regular, np.sin(np.pi * a), 1.0)
    cot = np.cos(np.pi * a) / sin_a
    xy = np.where(regular, sin2 / (np.pi * b_safe) * (cot - np.sin(2 * np.pi * a) / denominator), 0.0)
    return xx, xy


def build_periodic_film_kernel(mesh: Mesh, n_alias: int = 20) -> DemagKernel:
    """Build the cell-averaged alias-sum kernel (see module docstring). Cost O(n_alias² · cells).

    The self-layer in-plane components are split as q_αq_β/q² − (q_αq_β/q²) f(q): the first part is
    summed over one alias direction in closed form (``_inplane_projector_row_sums``), the second
    decays like 1/q and converges quickly; the other components decay on their own.
    """
    nx, ny, nz = mesh.nx, mesh.ny, mesh.nz
    kx = 2 * np.pi * np.fft.rfftfreq(nx, d=mesh.dx)  # (nxh,)
    ky = 2 * np.pi * np.fft.fftfreq(ny, d=mesh.dy)  # (ny,)
    KX, KY = np.meshgrid(kx, ky)  # (ny, nxh)
    n_offsets = 2 * nz - 1
    out = np.zeros((6, n_offsets, ny, nx // 2 + 1))
    gx_step, gy_step = 2 * np.pi / mesh.dx, 2 * np.pi / mesh.dy
    for offset_index in range(n_offsets):
        d = offset_index - (nz - 1)
        acc = np.zeros((6, ny, nx // 2 + 1))
        for ax in range(-n_alias, n_alias + 1):
            qx = KX + ax * gx_step
            sx = np.sinc(qx * mesh.dx / (2 * np.pi)) ** 2  # np.sinc(x) = sin(πx)/(πx)
            for ay in range(-n_alias, n_alias + 1):
                qy = KY + ay * gy_step
                weight = sx * np.sinc(qy * mesh.dy / (2 * np.pi)) ** 2
                comps = _continuum_components(qx, qy, mesh.dz, d, mesh.dz)
                for c in range(6):
                    acc[c] += comps[c] * weight
        if d == 0:
            # comps held (q_αq_β/q²)(1 − f); replace the non-decaying projector part by its exact sum
            projector = np.zeros((3, ny, nx // 2 + 1))
            projector[0] = projector[1] = 1.0
            for ax in range(-n_alias, n_alias + 1):  # closed form over y aliases, explicit over x
                qx = KX + ax * gx_step
                sx = np.sinc(qx * mesh.dx / (2 * np.pi)) ** 2
                xx, xy = _inplane_projector_row_sums(KY * mesh.dy / (2 * np.pi), qx * mesh.dy / (2 * np.pi))
                projector[0] -= sx * (1.0 - xx)  # Σ_m sinc² = 1 exactly: sum only the decaying rest
                projector[2] += sx * xy
            for ay in range(-n_alias, n_alias + 1):  # closed form over x aliases, explicit over y
                qy = KY + ay * gy_step
                sy = np.sinc(qy * mesh.dy / (2 * np.pi)) ** 2
                yy, _ = _inplane_projector_row_sums(KX * mesh.dx / (2 * np.pi), qy * mesh.dx / (2 * np.pi))
                projector[1] -= sy * (1.0 - yy)
            truncated = np.zeros((3, ny, nx // 2 + 1))
            for ax in range(-n_alias, n_alias + 1):
                qx = KX + ax * gx_step
                sx = np.sinc(qx * mesh.dx / (2 * np.pi)) ** 2
                for ay in range(-n_alias, n_alias + 1):
                    qy = KY + ay * gy_step
                    weight = sx * np.sinc(qy * mesh.dy / (2 * np.pi)) ** 2
                    q2 = qx * qx + qy * qy
                    q2_safe = np.where(q2 > 0, q2, 1.0)
                    proj = np.where(q2 > 0, 1.0, 0.0) * weight / q2_safe
                    truncated[0] += qx * qx * proj
                    truncated[1] += qy * qy * proj
                    truncated[2] += qx * qy * proj
            # acc = Σ_trunc P(1 − f)  →  Σ_exact P − Σ_trunc P f = projector − (truncated − acc)
            acc[0] = projector[0] - (truncated[0] - acc[0])
            acc[1] = projector[1] - (truncated[1] - acc[1])
            acc[3] = projector[2] - (truncated[2] - acc[3])
        out[:, offset_index] = acc
    # Components odd in q_x (xy, xz) vanish at the x Nyquist frequency, where the alias sum pairs
    # +q_x with −q_x; likewise those odd in q_y (xy, yz) at the y Nyquist frequency. (N_yz is even in
    # q_x and survives there.) The truncated sum misses one partner, so set them exactly.
    if nx % 2 == 0:
        out[3, :, :, -1] = 0.0
        out[4, :, :, -1] = 0.0
    if ny % 2 == 0:
        out[3, :, ny // 2, :] = 0.0
        out[5, :, ny // 2, :] = 0.0
    return DemagKernel(*(np.ascontiguousarray(a) for a in out))


def _cache_key(mesh: Mesh, n_alias: int) -> str:
    text = f"v3 {mesh.nx} {mesh.ny} {mesh.nz} {mesh.dx:.6e} {mesh.dy:.6e} {mesh.dz:.6e} {n_alias}"
    return hashlib.sha1(text.encode()).hexdigest()[:16]


_MEMORY_CACHE: dict[str, DemagKernel] = {}


def periodic_film_kernel(mesh: Mesh, n_alias: int = 20, cache_dir: str | Path | None = None) -> DemagKernel:
    """The kernel for ``mesh``, memoized in memory and optionally on disk (``.npz``, atomic write)."""
    key = _cache_key(mesh, n_alias)
    if key in _MEMORY_CACHE:
        return _MEMORY_CACHE[key]
    path = Path(cache_dir) / f"demag_{key}.npz" if cache_dir is not None else None
    kernel = None
    if path is not None and path.exists():
        try:
            with np.load(path) as data:
                kernel = DemagKernel(*(data[name] for name in ("xx", "yy", "zz", "xy", "xz_imag", "yz_imag")))
        except (OSError, KeyError, ValueError):
            kernel = None  # a damaged cache file is rebuilt
    if kernel is None:
        kernel = build_periodic_film_kernel(mesh, n_alias)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, **{name: a for name, a in zip(("xx", "yy", "zz", "xy", "xz_imag", "yz_imag"), kernel.arrays())})
            tmp.replace(path)
    _MEMORY_CACHE[key] = kernel
    return kernel


@numba.njit(cache=True, fastmath={"contract"})
def _multiply_kernel(mk, kxx, kyy, kzz, kxy, kxz_imag, kyz_imag, scale):
    """H(k) = −scale Σ_j N(i − j; k) m_j(k) for every observer layer i (``scale`` = μ0 M_s gives
    tesla). The self-layer block (i = j) has no xz, yz part (the module docstring), so it is skipped.

    Real arithmetic on the interleaved (re, im) float view of the spectra: N_αβ is real and N_αz
    imaginary, so (i c)(u + i v) = −c v + i c u needs no complex product (measured 1.9× faster than
    complex arithmetic at 128 × 128 × 2; equal to it within 1e-18 relative)."""
    _, nz, ny, nxh = mk.shape
    hk = np.empty_like(mk)
    mv = mk.view(np.float64)
    hv = hk.view(np.float64)
    for i in range(nz):
        for j in range(nz):
            d = i - j + nz - 1
            cross = i != j
            first = j == 0
            for a in range(ny):
                mx, my, mz = mv[0, j, a], mv[1, j, a], mv[2, j, a]
                hx, hy, hz = hv[0, i, a], hv[1, i, a], hv[2, i, a]
                n_xx, n_yy, n_zz, n_xy = kxx[d, a], kyy[d, a], kzz[d, a], kxy[d, a]
                n_xz, n_yz = kxz_imag[d, a], kyz_imag[d, a]
                for b in range(nxh):
                    xx, yy, xy, zz = scale * n_xx[b], scale * n_yy[b], scale * n_xy[b], scale * n_zz[b]
                    re, im = 2 * b, 2 * b + 1
                    hx_re = xx * mx[re] + xy * my[re]
                    hx_im = xx * mx[im] + xy * my[im]
                    hy_re = xy * mx[re] + yy * my[re]
                    hy_im = xy * mx[im] + yy * my[im]
                    hz_re = zz * mz[re]
                    hz_im = zz * mz[im]
                    if cross:
                        xz, yz = scale * n_xz[b], scale * n_yz[b]
                        hx_re -= xz * mz[im]
                        hx_im += xz * mz[re]
                        hy_re -= yz * mz[im]
                        hy_im += yz * mz[re]
                        hz_re -= xz * mx[im] + yz * my[im]
                        hz_im += xz * mx[re] + yz * my[re]
                    if first:
                        hx[re], hx[im], hy[re], hy[im], hz[re], hz[im] = -hx_re, -hx_im, -hy_re, -hy_im, -hz_re, -hz_im
                    else:
                        hx[re] -= hx_re
                        hx[im] -= hx_im
                        hy[re] -= hy_re
                        hy[im] -= hy_im
                        hz[re] -= hz_re
                        hz[im] -= hz_im
    return hk


@numba.njit(cache=True)
def _inverse_add(hk, out):
    _, nz, ny, nx = out.shape
    for c in range(3):
        for i in range(nz):
            # one 2D inverse per slice: measured 3–4× faster than the batched 4D irfft2
            h = np.fft.irfft2(hk[c, i], s=(ny, nx))
            for a in range(ny):
                for b in range(nx):
                    out[c, i, a, b] += h[a, b]


@numba.njit(cache=True)
def add_demag_field(m, model, out):
    """Add the demag flux density B = −μ0 M_s N m (tesla) of magnetization ``m`` to ``out``.
    ``model``: the film's ``effective_field.FieldModel`` (M_s in A/m and the kernel arrays
    ``kxx`` … ``kyz_imag`` of ``periodic_film_kernel``)."""
    mk = np.fft.rfft2(m)
    hk = _multiply_kernel(mk, model.kxx, model.kyy, model.kzz, model.kxy, model.kxz_imag, model.kyz_imag,
                          MU0 * model.Ms)
    _inverse_add(hk, out)
