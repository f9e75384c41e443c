"""Structural disorder of the seed paper's film: Voronoi grains and pinning sites.

- Grains: the plane is cut into ``n_grains`` periodic Voronoi cells (columnar through z). Grain g
  gets K_u(1 + Δ_g), Δ_g ~ N(0, σ_K), and an easy axis tilted from z by θ_g ~ N(0, σ_θ) at a uniform
  azimuth φ_g ∈ [0, 2π). (K_u(1+Δ) is clipped at 0: a negative uniaxial constant is not drawn.)
- Pinning sites: ``n_pin`` distinct single cells with K_u = 50 MJ/m³ along z and a random initial
  orientation (uniform on the sphere). Their anisotropy field 2K/M_s ~ 80–500 T makes the LLG stiff.
  Treatments (``pinning=``): "full" (default) treats them like any cell: exact, and the minimizer's
  diagonal preconditioner takes their stiffness out of its step lengths; "slaved" keeps each at its
  local equilibrium in the field of its neighbours (adiabatic elimination: the same equilibria, and
  no ~THz precession to limit the LLG time step: use it for LLG protocols); "frozen" holds each at
  the pole nearest its random start (not exact enough: a tilted pinning cell matters).
  tests/micromag/test_pinning.py compares them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .film import TERMS, Film
from .mesh import Mesh

PINNING_K_U = 50e6  # J/m³


def periodic_voronoi_labels(mesh: Mesh, n_grains: int, rng: np.random.Generator) -> np.ndarray:
    """Grain index (ny, nx) of each column: nearest of ``n_grains`` random seeds, minimum-image distance."""
    if n_grains < 1:
        raise ValueError("n_grains must be >= 1")
    lx, ly = mesh.nx * mesh.dx, mesh.ny * mesh.dy
    seeds = rng.random((n_grains, 2)) * (lx, ly)
    x = (np.arange(mesh.nx) + 0.5) * mesh.dx
    y = (np.arange(mesh.ny) + 0.5) * mesh.dy
    labels = np.empty((mesh.ny, mesh.nx), dtype=np.int32)
    for row, y0 in enumerate(y):
        ddx = np.abs(x[:, None] - seeds[None, :, 0])
        ddx = np.minimum(ddx, lx - ddx)
        ddy = np.abs(y0 - seeds[:, 1])
        ddy = np.minimum(ddy, ly - ddy)
        labels[row] = np.argmin(ddx**2 + ddy[None, :] ** 2, axis=1)
    return labels


@dataclass(frozen=True)
class Disorder:
    """Per-cell anisotropy and pinning layout of one sample."""

    K_u: np.ndarray  # (nz, ny, nx) J/m³
    easy_axis: np.ndarray  # (3, nz, ny, nx)
    grain_labels: np.ndarray  # (ny, nx)
    pinning_mask: np.ndarray  # (nz, ny, nx) bool
    pinning_initial: np.ndarray  # (3, n_pin) random initial orientations
    pinning_index: tuple  # flat indices (k, j, i) arrays


def layer_factors(layer_K_u_factor, nz: int) -> np.ndarray | None:
    """Validated per-layer K_u multipliers (nz,), or None for none."""
    if layer_K_u_factor is None:
        return None
    factors = np.asarray(layer_K_u_factor, dtype=np.float64).reshape(-1)
    if factors.shape != (nz,):
        raise ValueError(f"layer_K_u_factor needs one factor per layer (nz = {nz}), got {factors.shape[0]}")
    if not np.all(np.isfinite(factors) & (factors >= 0)):
        raise ValueError(f"layer_K_u_factor must be finite and non-negative, got {factors.tolist()}")
    return factors


def draw_disorder(mesh: Mesh, K_u: float, sigma_K: float, sigma_theta_rad: float, n_pin: int,
                  rng: np.random.Generator, n_grains: int = 255, layer_K_u_factor=None) -> Disorder:
    """Draw grains and pinning sites. ``sigma_K`` is a fraction (0.2 = 20 %), angles in radians.

    ``layer_K_u_factor`` (one factor per layer, default none) multiplies the grains' K_u layer by
    layer (a second, softer or harder phase); pinning cells keep ``PINNING_K_U``. The random draws
    do not depend on it.
    """
    factors = layer_factors(layer_K_u_factor, mesh.nz)
    if not 0 <= n_pin <= mesh.n_cells:
        raise ValueError(f"n_pin = {n_pin} is outside 0..{mesh.n_cells}")
    labels = periodic_voronoi_labels(mesh, n_grains, rng)
    delta = rng.normal(0.0, sigma_K, n_grains) if sigma_K > 0 else np.zeros(n_grains)
    theta = rng.normal(0.0, sigma_theta_rad, n_grains) if sigma_theta_rad > 0 else np.zeros(n_grains)
    phi = rng.uniform(0.0, 2 * np.pi, n_grains)
    grain_K = np.clip(K_u * (1.0 + delta), 0.0, None)
    grain_axis = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    K = np.broadcast_to(grain_K[labels], mesh.shape).copy()
    if factors is not None:
        K *= factors[:, None, None]
    axis = np.broadcast_to(grain_axis[:, labels][:, None], mesh.vector_shape).copy()
    flat = rng.choice(mesh.n_cells, size=n_pin, replace=False)
    index = np.unravel_index(flat, mesh.shape)
    mask = np.zeros(mesh.shape, dtype=bool)
    mask[index] = True
    K[index] = PINNING_K_U
    axis[(slice(None),) + index] = np.array([0.0, 0.0, 1.0])[:, None]
    initial = rng.normal(size=(3, n_pin))
    initial /= np.linalg.norm(initial, axis=0)
    return Disorder(K, axis, labels, mask, initial, index)


@dataclass(frozen=True)
class FilmMaterial:
    """The film quantities of the Hamiltonian that ``disordered_film`` builds a sample from (SI).

    - ``Ms``: saturation magnetization M_s (A/m);
    - ``A_ex``: exchange stiffness (J/m);
    - ``K_u``: mean uniaxial anisotropy of the grains (J/m³);
    - ``D``: interfacial DMI constant (J/m², mumax3 ``Dind`` convention, see ``Film``);
    - ``sigma_K``: standard deviation of the grains' relative K_u spread Δ (a fraction: 0.2 = 20 %);
    - ``sigma_theta_rad``: standard deviation of the grains' easy-axis tilt from z (rad);
    - ``n_pin``: number of pinning cells placed on this mesh (a count, not the paper's N_pin density:
      see ``build.pinning_cells``).
    """

    Ms: float
    A_ex: float
    K_u: float
    D: float
    sigma_K: float
    sigma_theta_rad: float
    n_pin: int


@dataclass(frozen=True)
class FilmExtras:
    """Optional energy terms and layering of a film beyond ``FilmMaterial``; the defaults are off.

    - ``K_2``: second-order uniaxial anisotropy −K_2 (u·m)⁴ along the grains' axes (J/m³; 0: off);
    - ``B_bias_T``: a uniform bias field (T), a 3-vector (x, y, z) added to the applied field;
    - ``layer_K_u_factor``: per-layer K_u multipliers, one per layer (nz), or None for none (see
      ``draw_disorder``; pinning cells keep ``PINNING_K_U``);
    - ``interlayer_coupling_J_m2``: coupling J across the spacer (J/m², > 0 ferromagnetic; see ``Film``);
    - ``spacer_after_layer``: index k of the layer below a non-magnetic spacer between layers k and
      k + 1, or None for no spacer.
    """

    K_2: float = 0.0
    B_bias_T: tuple = (0.0, 0.0, 0.0)
    layer_K_u_factor: tuple | None = None
    interlayer_coupling_J_m2: float = 0.0
    spacer_after_layer: int | None = None


def disordered_film(mesh: Mesh, material: FilmMaterial, rng: np.random.Generator, *, n_grains: int = 255,
                    pinning: str = "full", extras: FilmExtras = FilmExtras(), terms=TERMS, kernel_cache_dir=None):
    """Build the seed paper's film and its initial magnetization.

    ``material``: the Hamiltonian's film quantities (``FilmMaterial``); grains and pinning cells are
    drawn from ``rng`` (``draw_disorder``) over ``n_grains`` grains. ``pinning``: "full", "slaved" or
    "frozen" (module docstring). ``extras``: optional terms (``FilmExtras``: K_2, a bias field,
    per-layer K_u factors, a spacer with interlayer coupling). ``terms``: the energy terms on (subset
    of ``TERMS``); ``kernel_cache_dir``: where the demag kernel is cached (None: not cached).

    Returns (film, m0, disorder): m0 is +z everywhere except the pinning cells, which hold their
    random orientation (snapped to the nearest pole ±z for ``pinning="frozen"``).
    """
    if pinning not in ("slaved", "frozen", "full"):
        raise ValueError(f"pinning must be 'slaved', 'frozen' or 'full', got {pinning!r}")
    disorder = draw_disorder(mesh, material.K_u, material.sigma_K, material.sigma_theta_rad, material.n_pin, rng,
                             n_grains, extras.layer_K_u_factor)
    m0 = np.zeros(mesh.vector_shape)
    m0[2] = 1.0
    pin = disorder.pinning_initial
    if pinning == "frozen":
        pin = np.zeros_like(pin)
        pin[2] = np.where(disorder.pinning_initial[2] >= 0, 1.0, -1.0)
    for c in range(3):
        m0[c][disorder.pinning_index] = pin[c]
    film = Film(mesh, material.Ms, material.A_ex, disorder.K_u, disorder.easy_axis, material.D,
                frozen=disorder.pinning_mask if pinning == "frozen" else None,
                slaved=disorder.pinning_mask if pinning == "slaved" else None, terms=tuple(terms),
                kernel_cache_dir=kernel_cache_dir, K_2=extras.K_2, B_bias_T=extras.B_bias_T,
                interlayer_coupling_J_m2=extras.interlayer_coupling_J_m2,
                spacer_after_layer=extras.spacer_after_layer)
    return film, m0, disorder
