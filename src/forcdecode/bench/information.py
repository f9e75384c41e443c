"""The Fisher core of ``forcdecode bench information`` (issue 43): how much a FORC family tells about
each Hamiltonian parameter, independent of the simulator.

Units. Parameters are in the normalized coordinates u ∈ [0, 1] of the MAE tables
(``core.parameters.normalize``: K_u on a log scale, the others linear on the prior's bounds), so a
Cramér–Rao bound of 0.1 is a tenth of the prior's width and a bound ≥ 1 means "the prior alone".
The data vector is a FORC family flattened to the points it visits (H ≥ H_r, the upper triangle of
the 64×64 grid incl. the diagonal: 2080 values of ⟨m_z⟩ ∈ [−1, 1]; the image's lower half is a copy
of the diagonal and carries nothing more).

Estimator, for a simulator ``f(u, r) -> family`` with realisation index r (disorder):

* Jacobian J (points × parameters) by central differences with common random numbers: the same
  realisations r = 0..R−1 at u ± δ e_i, J_i = mean_r [f(u + δe_i, r) − f(u − δe_i, r)] / (u⁺ − u⁻)
  (the stencil is clipped to [ε, 1 − ε]; then the actual width u⁺ − u⁻ is used).
* Realisation covariance Σ: the R families at u, regularised by Ledoit–Wolf shrinkage towards the
  scaled identity (``ledoit_wolf``; scikit-learn's formula written out), plus an optional fixed
  noise floor (e.g. the 8-bit quantization, Δ²/12 with Δ = 2/255).
* Fisher information of one realisation F = Jᵀ Σ⁻¹ J (Σ⁻¹ applied through Woodbury: Σ is a
  scaled identity plus a rank-(R−1) scatter); of the mean of R realisations, R·F (covariance Σ/R).
* Cramér–Rao bound √(F⁻¹)_ii (∞ where F is singular along a direction touching parameter i).
* The noise in Ĵ inflates F by N_ij = tr(Σ⁻¹ Cov(Ĵ_i, Ĵ_j)); ``noise_fraction`` = N_ii/F_ii
  estimates that share from the per-realisation differences (near 1: the derivative is not resolved,
  the bound is optimistic and not to be trusted).
* Conditional bounds (the other parameters known): 1/√F_ii, 1/√(F_ii − N_ii), and the
  matched-filter bound (``matched_filter_crb``), which needs no Σ⁻¹ and is ≥ the true conditional
  CRB: the conservative figure when R ≪ p makes Σ⁻¹ (and the marginal bounds) unstable in R.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

EPS_U = 1e-4
"""Smallest normalized value a stencil point takes (σ_K = 0 or σ_θ = 0 would skip a random draw of
the disorder and break the common random numbers)."""

QUANT_STEP = 2.0 / 255.0
"""One 8-bit grey level in units of m_z (``forc.raster.quantize``)."""


def upper_triangle(curves: np.ndarray) -> np.ndarray:
    """The points a FORC family visits (j ≥ i of an n×n grid family), flattened row by row."""
    curves = np.asarray(curves, dtype=float)
    i, j = np.triu_indices(curves.shape[0])
    return curves[i, j]


@dataclass
class Shrunk:
    """Σ = a·I + b·XᵀX (X: n × p centred rows), kept in factored form; ``rho`` the shrinkage
    intensity, ``mu`` the identity target's scale tr(S)/p, ``floor`` the added noise variance."""

    X: np.ndarray
    a: float
    b: float
    rho: float
    mu: float
    floor: float

    def solve(self, V: np.ndarray) -> np.ndarray:
        """Σ⁻¹ V (V: p × k) by Woodbury: Σ⁻¹ = (I − b Xᵀ (I_n + b/a X Xᵀ)⁻¹ X / a) / a."""
        V = np.asarray(V, dtype=float)
        if self.b == 0.0 or self.X.shape[0] == 0:
            return V / self.a
        G = self.X @ self.X.T
        inner = np.eye(G.shape[0]) + (self.b / self.a) * G
        return (V - (self.b / self.a) * self.X.T @ np.linalg.solve(inner, self.X @ V)) / self.a

    def dense(self) -> np.ndarray:
        return self.a * np.eye(self.X.shape[1]) + self.b * self.X.T @ self.X


def ledoit_wolf(samples: np.ndarray, floor: float = 0.0) -> Shrunk:
    """Ledoit–Wolf (2004) shrinkage of the sample covariance of ``samples`` (n × p) towards μI.

    S = XᵀX/n (X centred), μ = tr S / p, d² = ‖S − μI‖²/p, b̄² = Σ_k ‖x_k x_kᵀ − S‖² / (n² p),
    ρ = min(b̄², d²)/d², Σ = ρμI + (1 − ρ)S (+ ``floor``·I). The same formula as
    scikit-learn's ``ledoit_wolf`` (not installed here), evaluated through the n × n Gram matrix."""
    Y = np.asarray(samples, dtype=float)
    n, p = Y.shape
    X = Y - Y.mean(axis=0)
    G = X @ X.T  # n × n
    trS = np.trace(G) / n
    mu = trS / p
    normS2 = np.sum(G * G) / n**2  # ‖S‖_F²
    d2 = (normS2 - 2 * mu * trS + mu**2 * p) / p
    sq = np.diag(G)  # ‖x_k‖²
    # ‖x xᵀ − S‖² = ‖x‖⁴ − 2 xᵀSx + ‖S‖², xᵀSx = ‖X x‖²/n = Σ_l G_kl²/n
    b2 = np.sum(sq**2 - 2 * np.sum(G * G, axis=1) / n + normS2) / (n**2 * p)
    rho = 1.0 if d2 <= 0 else float(min(b2, d2) / d2)
    a = rho * mu + floor
    if a <= 0:  # every sample identical and no floor: nothing to regularise with
        a = np.finfo(float).tiny
    return Shrunk(X=X, a=float(a), b=(1.0 - rho) / n, rho=rho, mu=float(mu), floor=float(floor))


def stencil(u: float, delta: float, eps: float = EPS_U) -> tuple[float, float]:
    """(u⁻, u⁺): u ∓ δ clipped to [ε, 1 − ε]."""
    return max(u - delta, eps), min(u + delta, 1.0 - eps)


def crb(F: np.ndarray, rel_tol: float = 1e-10) -> np.ndarray:
    """√(F⁻¹)_ii through the eigen-decomposition; directions with eigenvalue below ``rel_tol``·λ_max
    (or ≤ 0) are unidentified, and every parameter loading on one gets ∞."""
    F = 0.5 * (F + F.T)
    lam, V = np.linalg.eigh(F)
    scale = max(lam.max(), 0.0)
    good = lam > rel_tol * scale if scale > 0 else np.zeros_like(lam, dtype=bool)
    var = (V[:, good] ** 2 / lam[good]) @ np.ones(good.sum()) if good.any() else np.zeros(len(lam))
    touches_null = (V[:, ~good] ** 2).sum(axis=1) > 1e-12
    var = np.where(touches_null, np.inf, var)
    return np.sqrt(var)


@dataclass
class FisherResult:
    """Fisher analysis at one fiducial u (normalized units; see the module docstring)."""

    names: list[str]
    u: np.ndarray  # (k,) fiducial
    steps: np.ndarray  # (k,) actual stencil widths u⁺ − u⁻
    J: np.ndarray  # (p, k) ∂family/∂u
    F: np.ndarray  # (k, k) one realisation
    R: int
    rho: float  # Ledoit–Wolf intensity
    noise_fraction: np.ndarray  # (k,) share of F_ii from the noise of Ĵ_i
    extra: dict = field(default_factory=dict)

    @property
    def crb_single(self) -> np.ndarray:
        return crb(self.F)

    @property
    def crb_mean_R(self) -> np.ndarray:
        """Bound for the mean of R realisations (covariance Σ/R, so F·R)."""
        return crb(self.F * self.R)

    def eigen(self) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (descending) and eigenvectors (columns) of F."""
        lam, V = np.linalg.eigh(0.5 * (self.F + self.F.T))
        order = np.argsort(lam)[::-1]
        return lam[order], V[:, order]

    def to_json(self) -> dict:
        lam, V = self.eigen()
        return {"names": list(self.names), "u": self.u.tolist(), "steps": self.steps.tolist(), "R": self.R,
                "F": self.F.tolist(), "rho": self.rho, "noise_fraction": self.noise_fraction.tolist(),
                "crb_single": _finite_list(self.crb_single), "crb_mean_R": _finite_list(self.crb_mean_R),
                "eigenvalues": lam.tolist(), "eigenvectors": V.T.tolist(), **self.extra}


def _finite_list(x) -> list:
    """JSON has no ∞: unidentified bounds are written as null."""
    return [float(v) if np.isfinite(v) else None for v in np.asarray(x, float)]


def fisher_from_families(center: np.ndarray, plus: np.ndarray, minus: np.ndarray, steps: np.ndarray,
                         names: Sequence[str], u: np.ndarray, floor: float = 0.0) -> FisherResult:
    """The Fisher analysis from simulated families.

    ``center``: (R, p) families at u; ``plus``/``minus``: (k, R, p) at the stencil points of each
    parameter with the same realisations (common random numbers) as ``center``; ``steps`` (k,) the
    stencil widths u⁺ − u⁻; ``floor`` a noise variance added to Σ (units of m_z²)."""
    center, plus, minus = (np.asarray(a, dtype=float) for a in (center, plus, minus))
    R = center.shape[0]
    d = (plus - minus) / np.asarray(steps, float)[:, None, None]  # (k, R, p) per-realisation differences
    J = d.mean(axis=1).T  # (p, k)
    sigma = ledoit_wolf(center, floor=floor)
    SiJ = sigma.solve(J)
    F = J.T @ SiJ
    k = len(names)
    N = np.zeros((k, k))
    if R > 1:
        res = [(d[i] - J[:, i]).T for i in range(k)]  # p × R each
        solved = [sigma.solve(x) for x in res]
        for i in range(k):
            for j in range(i, k):
                N[i, j] = N[j, i] = np.sum(res[i] * solved[j]) / (R * (R - 1))
    noise = np.diag(N)
    frac = np.where(np.diag(F) > 0, noise / np.maximum(np.diag(F), 1e-300), np.nan)
    Fii = np.diag(F)
    conditional = np.where(Fii > 0, 1.0 / np.sqrt(np.maximum(Fii, 1e-300)), np.inf)
    corrected = np.where(Fii - noise > 0, 1.0 / np.sqrt(np.maximum(Fii - noise, 1e-300)), np.inf)
    extra = {"crb_conditional": _finite_list(conditional),
             "crb_conditional_noise_corrected": _finite_list(corrected),
             "crb_conditional_matched": _finite_list(matched_filter_crb(center, d, floor))}
    return FisherResult(names=list(names), u=np.asarray(u, float), steps=np.asarray(steps, float), J=J,
                        F=0.5 * (F + F.T), R=R, rho=sigma.rho, noise_fraction=frac, extra=extra)


def matched_filter_crb(center: np.ndarray, d: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Conservative conditional bound per parameter (the others known): the Fisher information of
    the one projection t_i = J_iᵀx, (J_iᵀJ_i)² / (J_iᵀ S J_i) ≤ J_iᵀΣ⁻¹J_i (Cauchy–Schwarz), so
    its bound is ≥ the conditional CRB of the whole family. S: the unbiased sample covariance of
    ``center`` (R × p) plus ``floor``·I, a scalar variance per parameter (R − 1 degrees of freedom:
    stable at small R, unlike Σ⁻¹ in p ≫ R dimensions); ‖J_i‖² with the noise of Ĵ_i taken out,
    tr Cov(d_i)/R (``d``: k × R × p per-realisation differences). ∞ where ‖J_i‖² is not above it."""
    return matched_filter_crb_pooled([center], d, floor)


def matched_filter_crb_pooled(groups: Sequence[np.ndarray], d: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """``matched_filter_crb`` with the scatter of the projection J_iᵀx pooled over every stencil point
    (``groups``: the R × p families at the centre and at each u ± δ eᵢ, each about its own mean) instead
    of the centre's alone: an average of the points' unbiased variances, so unbiased where Σ is the same
    across the stencil and never noisier than one of them, but with common random numbers the points'
    deviations are correlated, so fewer than (points × (R − 1)) degrees of freedom. The bound is then
    that of the stencil's neighbourhood (size δ), not of the point u alone."""
    d = np.asarray(d, float)
    R = d.shape[1]
    centred = [np.asarray(g, float) - np.asarray(g, float).mean(axis=0) for g in groups]
    out = np.full(d.shape[0], np.inf)
    for i in range(d.shape[0]):
        J = d[i].mean(axis=0)
        norm2 = float(J @ J)
        if R > 1:
            norm2 -= float(np.sum(d[i].var(axis=0, ddof=1))) / R
        var = float(np.mean([np.sum((X @ J) ** 2) / max(R - 1, 1) for X in centred])) + floor * float(J @ J)
        if norm2 > 0 and var > 0:
            out[i] = np.sqrt(var) / norm2
    return out


def matched_direction_crb(center: np.ndarray, d: np.ndarray, idx: Sequence[int], direction: np.ndarray,
                          floor: float = 0.0) -> float:
    """The conservative conditional bound (``matched_filter_crb``) on the combination s = vᵀu of the
    two parameters ``idx`` (v = ``direction`` normalized; the other parameters known): the families'
    derivative along v is Σ vₖ dₖ per realisation, so no new simulation is needed. In prior widths along
    v; at v = e_i it is parameter i's matched bound."""
    v = np.asarray(direction, float)
    v = v / np.linalg.norm(v)
    d = np.asarray(d, float)
    along = np.tensordot(v, d[list(idx)], axes=1)  # R × p
    return float(matched_filter_crb(center, along[None], floor)[0])


def best_matched_direction(center: np.ndarray, d: np.ndarray, idx: Sequence[int], floor: float = 0.0,
                           n_angles: int = 180) -> tuple[float, np.ndarray]:
    """The tightest ``matched_direction_crb`` over unit directions in the plane of ``idx`` (a grid of
    ``n_angles`` angles in [0°, 180°)) and that direction: the best-identified combination. Chosen on
    the same families, so slightly optimistic next to the bound along a direction fixed beforehand."""
    best, best_v = np.inf, np.array([1.0, 0.0])
    for theta in np.linspace(0.0, np.pi, n_angles, endpoint=False):
        v = np.array([np.cos(theta), np.sin(theta)])
        b = matched_direction_crb(center, d, idx, v, floor)
        if b < best:
            best, best_v = b, v
    return float(best), best_v


def fisher_by_simulation(simulate: Callable[[np.ndarray, int], np.ndarray], u: np.ndarray, names: Sequence[str],
                         delta: float, realisations: Sequence[int], floor: float = 0.0,
                         crn: bool = True) -> FisherResult:
    """The Fisher analysis of ``simulate(u, r) -> family vector`` at ``u`` (normalized), central
    differences of half-width ``delta`` with the realisations ``realisations`` (the same at u ± δ;
    ``crn=False`` gives the minus side other realisations, for the check that CRN matters)."""
    u = np.asarray(u, dtype=float)
    reals = list(realisations)
    other = [r + 10_000_019 for r in reals] if not crn else reals
    center = np.stack([simulate(u, r) for r in reals])
    plus, minus, steps = [], [], []
    for i in range(len(names)):
        lo, hi = stencil(u[i], delta)
        up, um = u.copy(), u.copy()
        up[i], um[i] = hi, lo
        plus.append(np.stack([simulate(up, r) for r in reals]))
        minus.append(np.stack([simulate(um, r) for r in other]))
        steps.append(hi - lo)
    return fisher_from_families(center, np.stack(plus), np.stack(minus), np.array(steps), names, u, floor)


def compressed_fisher(center: np.ndarray, d: np.ndarray, idx: Sequence[int], floor: float = 0.0) -> np.ndarray:
    """Fisher matrix of the k projections t = J_Sᵀx (S = ``idx``, k ≪ R): (J_SᵀJ_S) C⁻¹ (J_SᵀJ_S),
    C the unbiased k × k sample covariance of t over the R families at u (+ ``floor``·J_SᵀJ_S),
    its inverse debiased by the Hartlap factor (R − k − 2)/(R − 1) (zero matrix when R ≤ k + 2).
    A compression can only lose information, so its marginal bounds are conservative for the
    parameters in S given the others; no inverse covariance in p dimensions is needed.
    ``d``: k_all × R × p per-realisation differences."""
    center, d = np.asarray(center, float), np.asarray(d, float)
    R, k = center.shape[0], len(idx)
    if R <= k + 2:
        return np.zeros((k, k))
    J = d[list(idx)].mean(axis=1).T  # p × k
    X = center - center.mean(axis=0)
    T = X @ J
    G = J.T @ J
    C = T.T @ T / (R - 1) + floor * G
    try:
        F = G @ np.linalg.solve(C, G)
    except np.linalg.LinAlgError:
        return np.zeros((k, k))
    return 0.5 * (F + F.T) * (R - k - 2) / (R - 1)


def principal_angle_deg(v: np.ndarray, g: np.ndarray) -> float:
    """Angle (degrees, 0..90) between the lines spanned by ``v`` and ``g``."""
    v, g = np.asarray(v, float), np.asarray(g, float)
    nv, ng = np.linalg.norm(v), np.linalg.norm(g)
    if nv == 0 or ng == 0 or not (np.isfinite(nv) and np.isfinite(ng)):
        return float("nan")
    c = abs(float(v @ g)) / (nv * ng)
    return float(np.degrees(np.arccos(min(c, 1.0))))


def best_direction(F: np.ndarray, names: Sequence[str], which: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (descending) and eigenvectors of the block of F on ``which`` (the others held
    fixed: the conditional information in that plane)."""
    idx = [list(names).index(n) for n in which]
    block = F[np.ix_(idx, idx)]
    lam, V = np.linalg.eigh(0.5 * (block + block.T))
    order = np.argsort(lam)[::-1]
    return lam[order], V[:, order]


__all__ = ["EPS_U", "QUANT_STEP", "upper_triangle", "Shrunk", "ledoit_wolf", "stencil", "crb", "FisherResult",
           "fisher_from_families", "fisher_by_simulation", "matched_filter_crb", "matched_filter_crb_pooled",
           "matched_direction_crb",
           "best_matched_direction", "compressed_fisher", "principal_angle_deg", "best_direction"]
