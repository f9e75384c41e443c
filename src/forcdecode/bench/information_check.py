"""A case of ``bench information`` whose Fisher matrix is known in closed form (issue 43, item 3):
a non-interacting ensemble of N square hysterons (Stoner–Wohlfarth particles with the field along
the easy axis) through the FORC protocol, plus white measurement noise.

Particle k has the switching field h_k > 0 (T): from +saturation it flips down when the field
falls to −h_k and back up when it rises to +h_k. On the FORC reversed at H_r and measured at H ≥ H_r
it is therefore down iff it flipped on the way down (h_k ≤ −H_r) and has not flipped back (h_k > H):

    m_k(H_r, H) = 1 − 2·1[H < h_k ≤ −H_r].

Switching fields are log-normal, ln h ~ N(ln h₀, s), with h₀ = 0.15 + 0.5 u₀ T and s = 0.1 + 0.4 u₁
(u normalized to [0, 1]); u₂ does not enter. One realisation: N particles drawn afresh (common
random numbers: the same standard normals z_k at every u) and the family averaged over them, plus
independent N(0, σ_n²) noise on every point (drawn from the realisation too, so common at u ± δ).

Closed forms. With P(x) = P(h ≤ x) = Φ((ln x − ln h₀)/s) (0 for x ≤ 0), the point q = (H_r, H)
has mean 1 − 2 p_q, p_q = [P(−H_r) − P(H)]₊, and two points q, q′ covary through the joint
indicator, P(both) = [P(min(−H_r, −H_r′)) − P(max(H, H′))]₊:
Σ_qq′ = 4 (P(both) − p_q p_q′)/N + σ_n² δ_qq′, J = −2 ∂p/∂u (derivative of the closed form),
F = Jᵀ Σ⁻¹ J exactly (no simulation).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import norm

from ..config import load_config, shipped_config
from ..core.streams import stream_rng
from ..forc.protocol import quasistatic_family
from ..micromag.build import sweep_options
from ..micromag.film import Film
from ..micromag.mesh import Mesh

NAMES = ("h0", "spread", "inert")


def _grid(n_fields: int, B_max_T: float):
    fields = np.linspace(-B_max_T, B_max_T, n_fields)
    i, j = np.triu_indices(n_fields)
    return fields[i], fields[j]  # H_r, H per visited point


def _params(u) -> tuple[float, float]:
    return 0.15 + 0.5 * float(u[0]), 0.1 + 0.4 * float(u[1])


def _cdf(x, h0: float, s: float):
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x > 0, norm.cdf((np.log(np.where(x > 0, x, 1.0)) - np.log(h0)) / s), 0.0)


def flip_probability(u, n_fields: int = 16, B_max_T: float = 1.0) -> np.ndarray:
    """p_q = P(H < h ≤ −H_r) at every visited point."""
    Hr, H = _grid(n_fields, B_max_T)
    h0, s = _params(u)
    return np.clip(_cdf(-Hr, h0, s) - _cdf(H, h0, s), 0.0, None)


def analytic_mean(u, n_fields: int = 16, B_max_T: float = 1.0) -> np.ndarray:
    return 1.0 - 2.0 * flip_probability(u, n_fields, B_max_T)


def analytic_covariance(u, n_particles: int, noise_sd: float, n_fields: int = 16, B_max_T: float = 1.0) -> np.ndarray:
    Hr, H = _grid(n_fields, B_max_T)
    h0, s = _params(u)
    p = flip_probability(u, n_fields, B_max_T)
    upper = np.minimum(-Hr[:, None], -Hr[None, :])
    lower = np.maximum(H[:, None], H[None, :])
    both = np.clip(_cdf(upper, h0, s) - _cdf(lower, h0, s), 0.0, None)
    return 4.0 * (both - np.outer(p, p)) / n_particles + noise_sd**2 * np.eye(len(p))


def analytic_fisher(u, n_particles: int, noise_sd: float, n_fields: int = 16, B_max_T: float = 1.0,
                    h: float = 1e-6) -> np.ndarray:
    """F = Jᵀ Σ⁻¹ J of one realisation, J from the closed-form mean (a ±1e-6 difference of a
    smooth function: exact to ~1e-10)."""
    u = np.asarray(u, dtype=float)
    J = np.zeros((n_fields * (n_fields + 1) // 2, len(NAMES)))
    for i in range(len(NAMES)):
        e = np.zeros(len(u))
        e[i] = h
        J[:, i] = (analytic_mean(u + e, n_fields, B_max_T) - analytic_mean(u - e, n_fields, B_max_T)) / (2 * h)
    S = analytic_covariance(u, n_particles, noise_sd, n_fields, B_max_T)
    return J.T @ np.linalg.solve(S, J)


def simulator(n_particles: int, noise_sd: float, n_fields: int = 16, B_max_T: float = 1.0, seed: int = 20261122,
              h_shift_T: float = 0.0):
    """f(u, r) → one realisation's family vector (the protocol's outcome per particle, averaged).
    Realisation r's particles and noise come from the ``bench_film`` stream ("information_check", r).
    ``h_shift_T`` moves every switching field (to mark the points a particle within that of a grid
    field decides)."""
    Hr, H = _grid(n_fields, B_max_T)

    def f(u, r: int) -> np.ndarray:
        rng = stream_rng(seed, "bench_film", "information_check", int(r))
        z = rng.standard_normal(n_particles)
        noise = rng.standard_normal(len(H)) * noise_sd
        h0, s = _params(u)
        hk = h0 * np.exp(s * z) + h_shift_T
        down = (H[None, :] < hk[:, None]) & (hk[:, None] <= -Hr[None, :])
        return 1.0 - 2.0 * down.mean(axis=0) + noise

    return f


def protocol_simulator(n_particles: int, noise_sd: float, n_fields: int = 16, B_max_T: float = 1.0,
                       seed: int = 20261122, tilt_deg: float = 0.5, Ms: float = 5e5):
    """The same realisations run through the project's FORC protocol (``forc.protocol.quasistatic_family``)
    on a film of ``n_particles`` non-interacting cells (energy terms anisotropy + Zeeman only): cell k
    is a Stoner–Wohlfarth particle with its easy axis tilted by ``tilt_deg`` (random azimuth, so the
    minimizer leaves the unstable pole) and K_k = h_k M_s / (2 h_SW(ψ)), so that it switches at h_k
    (astroid: h_SW = (cos^{2/3}ψ + sin^{2/3}ψ)^{−3/2} of the anisotropy field 2K/M_s). The particles
    (z_k) and the noise are those of :func:`simulator`; the azimuths come after them in the stream."""
    psi = np.radians(tilt_deg)
    h_sw = (np.cos(psi) ** (2 / 3) + np.sin(psi) ** (2 / 3)) ** -1.5
    i, j = np.triu_indices(n_fields)
    options = sweep_options(load_config(shipped_config("config")))  # the laptop's minimizer and shortcuts
    mesh = Mesh(n_particles, 1, 1, 2e-9, 2e-9, 4e-9)

    def f(u, r: int) -> np.ndarray:
        rng = stream_rng(seed, "bench_film", "information_check", int(r))
        z = rng.standard_normal(n_particles)
        noise = rng.standard_normal(len(i)) * noise_sd
        phi = rng.uniform(0.0, 2 * np.pi, n_particles)
        h0, s = _params(u)
        K = h0 * np.exp(s * z) * Ms / (2 * h_sw)
        axis = np.stack([np.sin(psi) * np.cos(phi), np.sin(psi) * np.sin(phi), np.full(n_particles, np.cos(psi))])
        film = Film(mesh, Ms, 1e-11, K[None, None, :], axis[:, None, None, :], 0.0, terms=("anisotropy", "zeeman"))
        m0 = np.zeros(mesh.vector_shape)
        m0[2] = 1.0
        fam = quasistatic_family(film, m0, n_fields=n_fields, B_max_T=B_max_T, **options)
        return fam.curves_mz[i, j] + noise

    return f


__all__ = ["NAMES", "flip_probability", "analytic_mean", "analytic_covariance", "analytic_fisher", "simulator",
           "protocol_simulator"]
