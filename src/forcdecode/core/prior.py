"""The prior: the law the dataset's Hamiltonians are drawn from, written once.

``Prior(prior_class, bounds)`` has ``sample`` (one sample's Hamiltonian from (seed, sample id), the
``parameters`` random stream), ``log_prob`` (log p(u | M_s) in normalized units u ∈ [0, 1]), ``cdf``,
``ppf`` and ``quantiles`` of one parameter's marginal given M_s, and ``normalize`` / ``denormalize``.
The draw, the learning targets' trivial predictor, the posterior's prior coordinates, the refinement,
the bench and the information map read it (``dataset.params`` keeps its function names as thin views).

The law (the seed paper's Table I; units SI):

- M_s ~ U(bounds); D, N_pin (integer), σ_θ, σ_K uniform on their bounds (``UNIFORM_DRAWS``).
- K_u: ln K_u triangular on [ln K_lo, ln K_hi] with its mode at the top, i.e. p(u) = 2u in the normalized
  log coordinate u. Class ``perpendicular``: truncated to K_u > K_floor(M_s) = max(K_lo, μ0 M_s²/2)
  (K_eff > 0), u_f = u(K_floor): p(u | M_s) = 2u/(1 − u_f²) on (u_f, 1], CDF (u² − u_f²)/(1 − u_f²), drawn
  by that inverse CDF from the same one uniform the paper's triangular variate consumes (so the other
  parameters of a sample are the paper draw's exactly). ``paper`` is u_f = 0.
- A_ex | M_s: a target exchange length l ~ N(10 nm, 1 nm) gives A = l² μ0 M_s²/2; where that falls
  outside the bounds, A is drawn uniformly there instead, redrawn until √(A/(μ0 M_s²/2)) > 5 nm.

Densities are per unit u; points outside [0, 1] get −∞. The screening of the draws is a function of the
simulated family, which an observation has passed, so it is not a prior factor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .parameters import DEFAULT_BOUNDS, DEFAULT_PRIOR_CLASS, denormalize, k_u_floor, normalize, prior_class
from .physics import MU0
from .streams import stream_rng

UNIFORM_DRAWS = ("N_pin", "D", "sigma_theta_deg", "sigma_K")
"""Parameters drawn uniformly on their bounds (N_pin, an integer, treated as continuous)."""

CDF_GRID = 4001
"""Midpoints of the table that integrates A_ex's density into its CDF (no closed form)."""


class PriorError(ValueError):
    """The bounds leave no film of the prior class (e.g. no perpendicular K_u at that M_s)."""


@dataclass(frozen=True)
class Prior:
    """The draw law of one prior class (module docstring) on ``bounds`` (name -> [low, high], SI; missing
    names take ``core.parameters.DEFAULT_BOUNDS``)."""

    prior_class: str = DEFAULT_PRIOR_CLASS
    bounds: dict | None = None
    exchange_length_nm: tuple = (10.0, 1.0)
    min_exchange_length_nm: float = 5.0
    b: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "prior_class", prior_class(self.prior_class))
        object.__setattr__(self, "b", {**DEFAULT_BOUNDS, **(self.bounds or {})})

    # ------------------------------------------------------------ coordinates
    def normalize(self, name: str, value):
        """u ∈ [0, 1] of a value (SI) on these bounds (log scale for K_u)."""
        return normalize(name, value, self.b)

    def denormalize(self, name: str, u):
        """The value (SI) of u on these bounds."""
        return denormalize(name, u, self.b)

    def k_u_floor_u(self, Ms) -> np.ndarray:
        """u_f(M_s): the normalized K_u below which the class has no mass (0 for ``paper``; PriorError where
        the bounds leave no perpendicular film)."""
        if self.prior_class == "paper":
            return np.zeros(np.shape(Ms)) if np.ndim(Ms) else 0.0
        try:
            floor = k_u_floor(Ms, self.prior_class, self.b)
        except ValueError as error:
            raise PriorError(str(error)) from None
        return np.clip(normalize("K_u", floor, self.b), 0.0, 1.0)

    # ------------------------------------------------------------ the draw
    def sample(self, seed: int, sample_id: int) -> dict:
        """One sample's Hamiltonian (SI), from the ``parameters`` stream of (seed, sample id); the order of
        the variates is fixed (M_s, K_u, D, N_pin, σ_θ, σ_K, l_ex, then A_ex's fallback draws)."""
        b = self.b
        rng = stream_rng(seed, "parameters", sample_id)
        Ms = rng.uniform(*b["Ms"])
        K_u = self._sample_k_u(rng, Ms)
        D = rng.uniform(*b["D"])
        N_pin = int(rng.integers(b["N_pin"][0], b["N_pin"][1] + 1))
        sigma_theta = rng.uniform(*b["sigma_theta_deg"])
        sigma_K = rng.uniform(*b["sigma_K"])
        A_ex = self._sample_a_ex(rng, Ms)
        return {"Ms": float(Ms), "A_ex": float(A_ex), "K_u": K_u, "D": float(D), "N_pin": N_pin,
                "sigma_theta_deg": float(sigma_theta), "sigma_K": float(sigma_K)}

    def _sample_k_u(self, rng, Ms) -> float:
        log_lo, log_hi = np.log(self.b["K_u"][0]), np.log(self.b["K_u"][1])
        if self.prior_class == "paper":  # numpy's triangular variate (kept: the draw stays bit for bit)
            return float(np.exp(rng.triangular(log_lo, log_hi, log_hi)))
        floor_u = float(self.k_u_floor_u(Ms))
        u = np.sqrt(floor_u**2 + rng.random() * (1.0 - floor_u**2))
        K_u = float(np.exp(log_lo + u * (log_hi - log_lo)))
        K_min = MU0 * Ms**2 / 2
        if not K_u > K_min:  # u at the floor itself (probability 0) or rounding there
            K_u = float(np.nextafter(K_min, np.inf))
        return K_u

    def _sample_a_ex(self, rng, Ms) -> float:
        l_ex = rng.normal(self.exchange_length_nm[0], self.exchange_length_nm[1]) * 1e-9
        A_ex = l_ex**2 * MU0 * Ms**2 / 2
        a_lo, a_hi = self.b["A_ex"]
        if a_lo <= A_ex <= a_hi:
            return A_ex
        for _ in range(10_000):
            A_ex = rng.uniform(a_lo, a_hi)
            if np.sqrt(2 * A_ex / (MU0 * Ms**2)) > self.min_exchange_length_nm * 1e-9:
                return A_ex
        raise PriorError(f"no A_ex in {a_lo}..{a_hi} J/m gives l_ex > {self.min_exchange_length_nm} nm at Ms={Ms}")

    # ------------------------------------------------------------ densities
    def log_prob(self, u, names, Ms) -> np.ndarray:
        """log p(u | M_s) (rows of ``u`` in the order of ``names``; M_s in A/m, one value or one per row):
        a product over the parameters, each factor its marginal's density per unit u."""
        u = np.atleast_2d(np.asarray(u, float))
        Ms = np.broadcast_to(np.asarray(Ms, float), (len(u),))
        out = np.zeros(len(u))
        inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
        for j, name in enumerate(names):
            out += self._log_density(name, np.clip(u[:, j], 0.0, 1.0), Ms)
        return np.where(inside, out, -np.inf)

    def _log_density(self, name: str, x, Ms) -> np.ndarray:
        if name in UNIFORM_DRAWS:
            return np.zeros_like(x)
        if name == "K_u":
            if self.prior_class == "paper":
                with np.errstate(divide="ignore"):
                    return np.log(2.0 * x)
            floor_u = self.k_u_floor_u(Ms)
            with np.errstate(divide="ignore"):
                return np.where(x > floor_u, np.log(2.0 * x / (1.0 - floor_u**2)), -np.inf)
        if name == "A_ex":
            return self._a_ex_log_density(x, Ms)
        raise KeyError(f"no draw density for parameter {name!r}")

    def _a_ex_log_density(self, x, Ms) -> np.ndarray:
        """The exchange-length branch, A = l² c with l ~ N(l₀, σ_l) and c = μ0 M_s²/2 (density
        φ(l)/(2√(A c)) per J/m, its in-bounds part), plus, with the probability P_out that l falls out of
        bounds, the fallback: A uniform on the bounds where √(A/c) > l_min."""
        from scipy.stats import norm  # scipy.stats costs ~0.5 s to import; only densities need it

        lo, hi = (float(v) for v in self.b["A_ex"])
        c = MU0 * Ms**2 / 2
        A = lo + x * (hi - lo)
        mean, sd = self.exchange_length_nm[0] * 1e-9, self.exchange_length_nm[1] * 1e-9
        branch = norm.pdf(np.sqrt(A / c), mean, sd) / (2 * np.sqrt(A * c))
        p_in = norm.cdf(np.sqrt(hi / c), mean, sd) - norm.cdf(np.sqrt(lo / c), mean, sd)
        a_min = np.maximum(lo, self.min_exchange_length_nm**2 * 1e-18 * c)
        width = np.where(a_min < hi, hi - a_min, np.inf)  # no fallback mass where l_min excludes the bounds
        fallback = np.where(A > a_min, 1.0 / width, 0.0)
        with np.errstate(divide="ignore"):
            return np.log((branch + (1.0 - p_in) * fallback) * (hi - lo))

    # ------------------------------------------------------------ marginals
    def cdf(self, name: str, u, Ms) -> np.ndarray:
        """F(u | M_s) of one parameter's marginal (the probability integral transform); ``u`` and ``Ms``
        broadcast. Closed forms where they exist (uniform: u; K_u: (u² − u_f²)/(1 − u_f²)), a table for A_ex."""
        return self._transform(name, u, Ms, inverse=False)

    def ppf(self, name: str, v, Ms) -> np.ndarray:
        """Inverse of :meth:`cdf`: v ∈ [0, 1] → u (where the prior has no mass the CDF is flat and the
        inverse jumps across the gap)."""
        return self._transform(name, v, Ms, inverse=True)

    def quantiles(self, name: str, Ms: float, qs, grid: int = CDF_GRID) -> np.ndarray:
        """Quantiles (u) of one parameter's marginal given M_s; the median is the trivial predictor that
        reads M_s alone."""
        if name == "K_u" and self.prior_class != "paper":  # closed form (the floor cuts the midpoint table)
            return self.ppf(name, np.asarray(qs, float), Ms)
        edges, cdf = self._cdf_table(name, Ms, grid)
        return np.interp(np.asarray(qs, float), cdf, edges)

    def _cdf_table(self, name: str, Ms: float, grid: int = CDF_GRID):
        """(u edges, CDF at the edges) of one marginal given M_s (midpoint rule)."""
        mid = (np.arange(grid) + 0.5) / grid
        density = np.exp(self.log_prob(mid[:, None], (name,), Ms))
        cdf = np.concatenate([[0.0], np.cumsum(density)])
        return np.linspace(0.0, 1.0, grid + 1), cdf / cdf[-1]

    def _transform(self, name: str, values, Ms, inverse: bool) -> np.ndarray:
        x, Ms = np.broadcast_arrays(np.clip(np.asarray(values, float), 0.0, 1.0), np.asarray(Ms, float))
        if name in UNIFORM_DRAWS:
            return x.copy()
        if name == "K_u":
            if self.prior_class == "paper":
                return np.sqrt(x) if inverse else x**2
            f2 = self.k_u_floor_u(Ms) ** 2
            if inverse:
                return np.sqrt(f2 + x * (1.0 - f2))
            return np.clip((x**2 - f2) / (1.0 - f2), 0.0, 1.0)
        if name != "A_ex":
            raise KeyError(f"no draw density for parameter {name!r}")
        out = np.empty(x.shape)
        for value in np.unique(Ms):
            at = Ms == value
            edges, cdf = self._cdf_table(name, float(value))
            out[at] = np.interp(x[at], cdf, edges) if inverse else np.interp(x[at], edges, cdf)
        return out


__all__ = ["CDF_GRID", "Prior", "PriorError", "UNIFORM_DRAWS"]
