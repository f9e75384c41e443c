"""Parameter draw of the seed paper (its Table of bounds), reproducible from (seed, sample id).

M_s ~ U(200, 1400) kA/m; ln K_u triangular on [ln 1e3, ln 1.5e6] J/m³ with its mode at the maximum;
D ~ U(0, 5) mJ/m²; N_pin ~ U{0..255}; σ_θ ~ U(0, 10°); σ_K ~ U(0, 20 %). A_ex by constrained
sampling: a target exchange length l_ex ~ N(10 nm, 1 nm) gives A_ex = l_ex² μ0 M_s²/2; if that falls
outside 1–35 pJ/m, A_ex is drawn uniformly there instead, redrawn until l_ex = √(2A/(μ0 M_s²)) > 5 nm.
Names, units, default bounds and scales come from the parameter table (``core.parameters``); the
draw uses the ``parameters`` random stream of the sample.

Prior classes (config key ``prior``, ``core.parameters.PRIOR_CLASSES``). ``paper``: the draw above,
bit for bit as it always was. ``perpendicular``: the same draw with K_u conditional on M_s, ln K_u
triangular with its mode at the maximum *truncated* to K_u > K_floor(M_s) = max(K_lo, μ0 M_s²/2)
(``core.parameters.k_u_floor``): in the normalized log coordinate u of K_u, with u_f = u(K_floor),
p(u | M_s) = 2u / (1 − u_f²) on (u_f, 1], CDF (u² − u_f²)/(1 − u_f²). Every draw has K_eff > 0.
It is drawn by the inverse CDF from the same single uniform of the ``parameters`` stream that the
paper draw's triangular variate consumes, so M_s, A_ex, D, N_pin, σ_θ and σ_K of a sample are the
paper draw's exactly (same values for the same (seed, sample id); their marginals unchanged) and only
K_u moves up into the perpendicular range. This is not the paper's joint prior conditioned on
K_eff > 0 (that would also tilt M_s towards small values): M_s keeps its uniform law.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.parameters import DEFAULT_BOUNDS, DEFAULT_PRIOR_CLASS, LOG_SCALE, NAMES, denormalize, k_u_floor, normalize
from ..core.parameters import prior_class as _prior_class
from ..core.streams import stream_rng
from ..micromag.constants import MU0

PARAMETERS = NAMES
"""Column names of the dataset files, M_s first (units: ``core.parameters.UNITS``)."""

_STREAM_NAMES = {0: "parameters", 1: "disorder"}


def sample_rng(seed: int, sample_id: int, stream: int | str = 0) -> np.random.Generator:
    """The generator of one sample for one purpose: ``stream`` 0 / "parameters" (the draw) or
    1 / "disorder" (grains and pinning); ``core.streams`` holds the derivation."""
    return stream_rng(seed, _STREAM_NAMES.get(stream, stream), sample_id)


def perpendicular_floor(Ms, bounds=None) -> np.ndarray:
    """u_f(M_s): the normalized (log) K_u below which the ``perpendicular`` class has no mass
    (``core.parameters.k_u_floor``); ConfigError where the bounds leave no perpendicular film."""
    try:
        floor = k_u_floor(Ms, "perpendicular", bounds)
    except ValueError as error:
        raise ConfigError(str(error)) from None
    return np.clip(normalize("K_u", floor, bounds), 0.0, 1.0)


def draw_parameters(seed: int, sample_id: int, bounds=None, exchange_length_nm=(10.0, 1.0),
                    min_exchange_length_nm: float = 5.0, prior: str = DEFAULT_PRIOR_CLASS) -> dict:
    """One sample's Hamiltonian parameters (SI) under the prior class ``prior`` (module docstring)."""
    prior = _prior_class(prior)
    b = {**DEFAULT_BOUNDS, **(bounds or {})}
    rng = stream_rng(seed, "parameters", sample_id)
    Ms = rng.uniform(*b["Ms"])
    log_lo, log_hi = np.log(b["K_u"][0]), np.log(b["K_u"][1])
    if prior == "paper":
        K_u = float(np.exp(rng.triangular(log_lo, log_hi, log_hi)))
    else:  # the same one uniform as the triangular variate, through the truncated law's inverse CDF
        floor_u = float(perpendicular_floor(Ms, b))
        u = np.sqrt(floor_u**2 + rng.random() * (1.0 - floor_u**2))
        K_u = float(np.exp(log_lo + u * (log_hi - log_lo)))
        K_min = MU0 * Ms**2 / 2
        if not K_u > K_min:  # u at the floor itself (probability 0) or rounding there
            K_u = float(np.nextafter(K_min, np.inf))
    D = rng.uniform(*b["D"])
    N_pin = int(rng.integers(b["N_pin"][0], b["N_pin"][1] + 1))
    sigma_theta = rng.uniform(*b["sigma_theta_deg"])
    sigma_K = rng.uniform(*b["sigma_K"])
    l_ex = rng.normal(exchange_length_nm[0], exchange_length_nm[1]) * 1e-9
    A_ex = l_ex**2 * MU0 * Ms**2 / 2
    a_lo, a_hi = b["A_ex"]
    if not (a_lo <= A_ex <= a_hi):
        for _ in range(10_000):
            A_ex = rng.uniform(a_lo, a_hi)
            if np.sqrt(2 * A_ex / (MU0 * Ms**2)) > min_exchange_length_nm * 1e-9:
                break
        else:  # pragma: no cover - impossible within the paper's bounds
            raise ValueError(f"no A_ex in {a_lo}..{a_hi} J/m gives l_ex > {min_exchange_length_nm} nm at Ms={Ms}")
    return {"Ms": float(Ms), "A_ex": float(A_ex), "K_u": K_u, "D": float(D), "N_pin": N_pin,
            "sigma_theta_deg": float(sigma_theta), "sigma_K": float(sigma_K)}


UNIFORM_DRAWS = ("N_pin", "D", "sigma_theta_deg", "sigma_K")
"""Parameters drawn uniformly on their bounds (N_pin, an integer, treated as continuous)."""


def draw_log_density(u, names, Ms, bounds=None, exchange_length_nm=(10.0, 1.0),
                     min_exchange_length_nm: float = 5.0, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """log p(u | M_s) of :func:`draw_parameters` in normalized units u ∈ [0, 1] (rows of ``u`` in the
    order of ``names``): the prior the dataset was drawn from, given the film's M_s (A/m; one value,
    or one per row).

    Per parameter: uniform (``UNIFORM_DRAWS``) → 0; K_u, ln K_u triangular
    with its mode at the top → p(u) = 2u (u on the log scale); under the ``perpendicular`` class
    p(u | M_s) = 2u / (1 − u_f²) above the floor u_f(M_s) (K_eff = 0) and 0 below; A_ex | M_s, a mixture of the
    exchange-length branch, A = l² μ0 M_s²/2 with l ~ N(l₀, σ_l) (density φ(l) / (2√(A c)) per J/m,
    c = μ0 M_s²/2; the branch's in-bounds part is kept) and, with the probability P_out that l falls
    out of bounds, the fallback: A uniform on the bounds where √(A/c) > l_min. Densities are per unit
    u (× the width of the bounds). Points outside [0, 1] get −∞. The screening of the draws is a
    function of the simulated family, which an observation has passed, so it is not a prior factor."""
    from scipy.stats import norm

    prior = _prior_class(prior)
    b = {**DEFAULT_BOUNDS, **(bounds or {})}
    u = np.atleast_2d(np.asarray(u, float))
    out = np.zeros(len(u))
    inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
    for j, name in enumerate(names):
        x = np.clip(u[:, j], 0.0, 1.0)
        if name == "K_u":
            if prior == "paper":
                with np.errstate(divide="ignore"):
                    out += np.log(2.0 * x)
            else:
                floor_u = perpendicular_floor(np.broadcast_to(np.asarray(Ms, float), (len(u),)), b)
                with np.errstate(divide="ignore"):
                    out += np.where(x > floor_u, np.log(2.0 * x / (1.0 - floor_u**2)), -np.inf)
        elif name == "A_ex":
            lo, hi = (float(v) for v in b["A_ex"])
            c = MU0 * np.broadcast_to(np.asarray(Ms, float), (len(u),)) ** 2 / 2
            A = lo + x * (hi - lo)
            mean, sd = exchange_length_nm[0] * 1e-9, exchange_length_nm[1] * 1e-9
            branch = norm.pdf(np.sqrt(A / c), mean, sd) / (2 * np.sqrt(A * c))
            p_in = norm.cdf(np.sqrt(hi / c), mean, sd) - norm.cdf(np.sqrt(lo / c), mean, sd)
            a_min = np.maximum(lo, min_exchange_length_nm**2 * 1e-18 * c)
            width = np.where(a_min < hi, hi - a_min, np.inf)  # no fallback mass where l_min excludes the bounds
            fallback = np.where(A > a_min, 1.0 / width, 0.0)
            with np.errstate(divide="ignore"):
                out += np.log((branch + (1.0 - p_in) * fallback) * (hi - lo))
        elif name not in UNIFORM_DRAWS:
            raise KeyError(f"no draw density for parameter {name!r}")
    return np.where(inside, out, -np.inf)


def draw_prior_quantiles(name: str, Ms: float, qs, bounds=None, grid: int = 4001,
                         prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """Quantiles (normalized u) of one parameter's draw prior given M_s: the density of
    :func:`draw_log_density` is a product over parameters, so each marginal is its own factor
    (integrated on ``grid`` midpoints). The median is the trivial predictor that reads M_s alone."""
    if name == "K_u" and _prior_class(prior) != "paper":  # closed form (the floor cuts the midpoint table)
        return _prior_transform(name, np.asarray(qs, float), Ms, bounds, inverse=True, prior=prior)
    edges, cdf = _cdf_table(name, Ms, bounds, grid, prior)
    return np.interp(np.asarray(qs, float), cdf, edges)


def _cdf_table(name: str, Ms: float, bounds, grid: int = 4001, prior: str = DEFAULT_PRIOR_CLASS):
    """(u edges, CDF at the edges) of one parameter's draw prior given M_s (midpoint rule)."""
    mid = (np.arange(grid) + 0.5) / grid
    density = np.exp(draw_log_density(mid[:, None], (name,), Ms, bounds, prior=prior))
    cdf = np.concatenate([[0.0], np.cumsum(density)])
    return np.linspace(0.0, 1.0, grid + 1), cdf / cdf[-1]


def _prior_transform(name: str, values, Ms, bounds, inverse: bool, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """F(u | M_s) (``inverse`` False) or its inverse, per row's M_s (see :func:`draw_prior_cdf`)."""
    x, Ms = np.broadcast_arrays(np.clip(np.asarray(values, float), 0.0, 1.0), np.asarray(Ms, float))
    if name == "K_u":
        if _prior_class(prior) == "paper":
            return np.sqrt(x) if inverse else x**2
        f2 = perpendicular_floor(Ms, bounds) ** 2
        if inverse:
            return np.sqrt(f2 + x * (1.0 - f2))
        return np.clip((x**2 - f2) / (1.0 - f2), 0.0, 1.0)
    if name in UNIFORM_DRAWS:
        return x.copy()
    if name != "A_ex":
        raise KeyError(f"no draw density for parameter {name!r}")
    out = np.empty(x.shape)
    for value in np.unique(Ms):
        at = Ms == value
        edges, cdf = _cdf_table(name, float(value), bounds, prior=prior)
        out[at] = np.interp(x[at], cdf, edges) if inverse else np.interp(x[at], edges, cdf)
    return out


def draw_prior_cdf(name: str, u, Ms, bounds=None, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """F(u | M_s) of one parameter's draw prior (the probability integral transform: a drawn value
    maps to a uniform v). ``u`` and ``Ms`` broadcast (one M_s per row). Closed forms where they exist
    (uniform: v = u; K_u: v = u², perpendicular (u² − u_f²)/(1 − u_f²)), a 4001-point table for A_ex | M_s."""
    return _prior_transform(name, u, Ms, bounds, inverse=False, prior=prior)


def draw_prior_ppf(name: str, v, Ms, bounds=None, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """Inverse of :func:`draw_prior_cdf`: v ∈ [0, 1] → u (where the prior has no mass the CDF is flat
    and the inverse jumps across the gap)."""
    return _prior_transform(name, v, Ms, bounds, inverse=True, prior=prior)


__all__ = ["PARAMETERS", "DEFAULT_BOUNDS", "LOG_SCALE", "MU0", "sample_rng", "perpendicular_floor", "draw_parameters",
           "draw_log_density",
           "UNIFORM_DRAWS", "draw_prior_quantiles", "draw_prior_cdf", "draw_prior_ppf", "normalize", "denormalize"]
