"""Refinement for one file: sequential importance sampling (population Monte Carlo) around the
amortized posterior, by simulation of *this* film.

Why this and not sequential NPE: with budgets of 50–500 simulations in a 6-parameter space, a
neural density estimator retrained per round has far too few samples to learn a conditional
density, while importance sampling is exact in the limit and its error is visible (the effective
sample size). The amortized posterior q₀(u | x_o) is the first proposal; the target is
π(u) ∝ p(u | M_s) L(u), p the prior the dataset was drawn from given the film's M_s
(``dataset.params.draw_log_density``: far from uniform — A_ex follows M_s through the exchange
length, ln K_u is triangular; a uniform box prior, used before, threw that knowledge away and the
refined A_ex was worse than the amortized one) and L a synthetic Gaussian likelihood in observation
space:

    log L(u) = −½ · n_curves · MSE(u) / σ²,

with MSE(u) the mean square difference, over every FORC point (H ≥ H_r), between the family simulated
at u and the observed one; σ² the variance of that difference at the true parameters, which is
twice the variance one disorder realisation causes (the candidate's realisation and the
observation's are two independent ones: ``difference_variance``), and ν the number of independent
observations a family carries, both measured from a few disorder realisations of the amortized
posterior median (``effective_observations``): a candidate as close as the truth on new disorder
scores like the truth. (Counting every curve as
independent, ν = 64, made the weights collapse to one particle on the laptop film: its curves share
one disorder realisation.)

Rounds of ``round_size`` simulations (fixed sizes: the state after b simulations of a longer run is
exactly the budget-b result). Round 1 draws from q₀; round r > 1 from a defensive mixture of q₀ (20 %)
and a Gaussian in logit space fitted to the weighted particles so far. Weights are deterministic-
mixture importance weights w_i = π_β(u_i) / Σ_r (N_r/N) q_r(u_i), over all particles of all rounds.
Common random numbers: every candidate of every round is simulated on the same disorder realisation,
so two candidates differ by their parameters only. The simulator is a callable (u (k, d) → families
(k, n, n)), so the method is tested on a synthetic problem in seconds; ``simulate_on_film`` runs the
laptop film in parallel processes.

Tempering (adaptive SMC across rounds). Measured without it: on the laptop film the candidates of a
broad 6-D proposal miss the observation by far more than the floor, log-weights span hundreds of nats
and the ESS is ≈ 1; on the synthetic problem of the tests the 90 % intervals held the truth in only
72–83 % of 100 runs (budget 200), the proposal being fitted to a handful of particles. So the
target of round r is a tempered π_β, β rising from 0 to 1: after each round β is the largest value
≥ the previous one at which the ESS of all particles so far stays ≥ ``target_ess_fraction`` ×
``round_size`` (``next_beta``), and the next proposal is fitted to the weights at that β. Path
``"amortized"`` (default): π_β ∝ q₀^{1−β} (p L)^β, a geometric bridge from the amortized posterior,
so round 1 starts with equal weights. Path ``"prior"``: π_β ∝ p L^β, which at small β is the box
prior, badly covered by a narrow q₀ (measured: round-1 ESS ≈ 1–3 of 25 with a proposal 2 logits off).
Summaries use the weights at the β of their round; one with β < 1 is flagged ``tempered`` with a
note (not the posterior: the likelihood enters only to the power β).

Beyond the prior's bound (``scale``). A film pinned more densely than any training film is decoded,
inside the prior, as the densest pinning the prior allows with other parameters bent to compensate
(measured on the laptop film). To ask whether the family wants a parameter past its bound, the box of
that parameter is stretched to ``scale`` times its prior range and the prior continued uniformly
there: the particles live in u' = u / scale ∈ [0, 1]^d, the proposals are fitted in logit u', and q₀
(0 beyond the bound) enters the mixture with its Jacobian. The bridge q₀^{1−β}(pL)^β is 0 beyond
the bound while β < 1; at β = 1 every candidate weighs p L / q_mix, those simulated beyond included.
Measured on one over-pinned laptop film, that left 27 of 200 candidates beyond and a mass beyond no
better than the prior's, so the caller widens q₀ first (``widen_draws``, ``widened_logpdf``: each
extended parameter's marginal replaced by the extended box's uniform law) and the bridge runs over
the whole box from round 1. ``beyond_prior`` reports the posterior mass past the bound against the
prior's."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.stats import multivariate_normal

from ..core.errors import ConfigError, InputFileError
from ..core.io import atomic_path
from ..core.parameters import denormalize
from .resimulate import run_tasks

SQUEEZE = 1e-4
DEFENSIVE = 0.2
INFLATION = 2.0  # the Gaussian proposal is the weighted particles' covariance times this (PMC practice: a
# proposal narrower than the target starves the tails and the intervals)


def _logit(u):
    s = SQUEEZE + (1 - 2 * SQUEEZE) * np.clip(u, 0.0, 1.0)
    return np.log(s) - np.log1p(-s)


def _inverse_logit(z):
    """u ∈ [0, 1] of logit ``z`` (the inverse of ``_logit``, clipped where the squeeze leaves [0, 1])."""
    return np.clip((1 / (1 + np.exp(-z)) - SQUEEZE) / (1 - 2 * SQUEEZE), 0.0, 1.0)


def _log_jacobian(u):
    """log |dz/du| of the logit map (for densities of u from densities in z)."""
    s = SQUEEZE + (1 - 2 * SQUEEZE) * np.clip(u, 0.0, 1.0)
    return (np.log1p(-2 * SQUEEZE) - np.log(s) - np.log1p(-s)).sum(axis=-1)


def synthetic_loglik(families, observed, sigma2: float, n_curves: int) -> np.ndarray:
    """log L per candidate family (k, n, n) against ``observed`` (n, n): −½ n_curves MSE / σ²."""
    valid = np.isfinite(observed)
    out = np.empty(len(families))
    for k, fam in enumerate(families):
        ok = valid & np.isfinite(fam)
        out[k] = -np.inf if not ok.any() else -0.5 * n_curves * float(np.mean((fam[ok] - observed[ok]) ** 2)) / sigma2
    return out


def weighted_quantiles(values, weights, qs) -> np.ndarray:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    cum /= cum[-1]
    return np.interp(qs, cum, values[order])


def _summary_levels(levels) -> np.ndarray:
    """The quantile levels a summary reports, ascending: the median and both ends of each central interval."""
    return np.array(sorted({0.5} | {round(q, 6) for a in levels for q in ((1 - a) / 2, (1 + a) / 2)}))


def _summary_row(qs, values, levels) -> dict:
    """{"median", "interval_<pct>": [lo, hi]} from ``values`` at the levels ``qs`` of ``_summary_levels``."""
    at = dict(zip(qs, (float(v) for v in values)))
    row = {"median": at[0.5]}
    for a in levels:
        row[f"interval_{int(round(a * 100))}"] = [at[round((1 - a) / 2, 6)], at[round((1 + a) / 2, 6)]]
    return row


def summarize_particles(u, w, names, levels=(0.68, 0.9)) -> dict:
    """Weighted median and central intervals per parameter (normalized), and the effective sample size."""
    w = np.asarray(w, float)
    w = w / w.sum()
    qs = _summary_levels(levels)
    out = {"ess": float(1.0 / np.sum(w ** 2)), "parameters": {}}
    for j, name in enumerate(names):
        out["parameters"][name] = _summary_row(qs, weighted_quantiles(u[:, j], w, qs), levels)
    return out


def effective_observations(families) -> tuple[float, float]:
    """(σ², ν) from R ≥ 3 disorder realisations of one Hamiltonian (families (R, n, n)): the pairwise
    mean square differences D_ij have mean 2σ² and, if a family carried ν independent Gaussian
    observations, relative variance 2/ν; so ν = 2 mean(D)² / var(D), clipped to [1, n_curves]. The
    curves of a family share one disorder realisation, so ν is far below the number of curves."""
    fams = np.asarray(families, float)
    pairs = []
    for i in range(len(fams)):
        for j in range(i + 1, len(fams)):
            ok = np.isfinite(fams[i]) & np.isfinite(fams[j])
            pairs.append(float(np.mean((fams[i][ok] - fams[j][ok]) ** 2)))
    pairs = np.asarray(pairs)
    sigma2 = float(pairs.mean()) / 2
    var = float(pairs.var(ddof=1)) if len(pairs) > 1 else 0.0
    nu = 2 * pairs.mean() ** 2 / var if var > 0 else float(fams.shape[1])
    return sigma2, float(np.clip(nu, 1.0, fams.shape[1]))


def difference_variance(realisations, quantization_step: float = 0.0) -> tuple[float, float]:
    """(variance of one point of candidate − observation, ν) for the synthetic likelihood, from R ≥ 3
    disorder realisations of one Hamiltonian (``effective_observations``).

    With common random numbers every candidate is simulated on one realisation, the observation is
    another: at the true parameters the two still differ by two independent realisations, so the
    per-point variance of the difference is 2σ², not σ². (Using σ² made the likelihood twice as sharp
    in log: the 90 % intervals of a linear-Gaussian problem then hold the truth 75 % of the time;
    ``tests/loop/test_fit.py`` measures it.) ``quantization_step``: the observation's digitization
    step (e.g. 2/255 for an 8-bit image of m ∈ [−1, 1]), adding step²/12 once."""
    sigma2, nu = effective_observations(realisations)
    return 2.0 * sigma2 + quantization_step ** 2 / 12, nu


def _log_weights(loglik, log_q, beta: float) -> np.ndarray:
    """β · loglik − log_q; a particle whose simulation failed (loglik = −∞) weighs 0 at every β."""
    ok = np.isfinite(loglik) & np.isfinite(log_q)
    return np.where(ok, beta * np.where(ok, loglik, 0.0) - np.where(ok, log_q, 0.0), -np.inf)


def _normalized(logw) -> np.ndarray:
    if not np.isfinite(logw).any():
        return np.full(len(logw), 1.0 / len(logw))
    w = np.exp(logw - logw.max())
    return w / w.sum()


def _ess(logw) -> float:
    return float(1.0 / np.sum(_normalized(logw) ** 2))


def next_beta(loglik, log_q, beta_prev: float, target_ess: float, steps: int = 30) -> float:
    """The adaptive inverse temperature: the largest β ∈ [β_prev, 1] at which the weights
    exp(β · loglik − log_q) keep an ESS ≥ ``target_ess`` (1 if β = 1 does; β_prev if none does: the
    next proposal, fitted at β_prev, must first cover the current target). The ESS need not be
    monotone in β, so a geometric grid of β − β_prev brackets the last crossing, then bisection."""
    grid = beta_prev + (1.0 - beta_prev) * np.concatenate([[0.0], np.geomspace(1e-6, 1.0, 61)])
    ok = [i for i, g in enumerate(grid) if _ess(_log_weights(loglik, log_q, g)) >= target_ess]
    if not ok:
        return beta_prev
    if ok[-1] == len(grid) - 1:
        return 1.0
    lo, hi = grid[ok[-1]], grid[ok[-1] + 1]
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _ess(_log_weights(loglik, log_q, mid)) >= target_ess else (lo, mid)
    return float(lo)


PATHS = ("amortized", "prior")


@dataclass(frozen=True)
class RefinementOptions:
    """How a ``Refinement`` weighs and reports its particles (each default the former keyword's).

    ``checkpoints``: budgets (simulations; multiples of the round size) at which the posterior summary is
    also kept (``by_budget``); ``n_effective``: the effective number of independent curves of the synthetic
    likelihood (None: the observation's rows); ``tempering``: after each round β rises (never falls) to the
    largest value at which the ESS of all particles so far is ≥ ``target_ess_fraction`` × the round size (β = 1
    at once where that allows; False: β = 1 throughout, plain PMC); ``target_ess_fraction``: in (0, 1];
    ``path``: the tempered family (of ``PATHS``: ``"amortized"``: q₀^{1−β} (pL)^β; ``"prior"``: p L^β);
    ``scale``: one factor ≥ 1 per parameter, the box extended beyond the prior's bound (None: all 1)."""

    checkpoints: tuple = ()
    n_effective: float | None = None
    tempering: bool = True
    target_ess_fraction: float = 0.3
    path: str = "amortized"
    scale: object = None


class Refinement:
    """The state of one tempered population Monte Carlo run between rounds (see the module docstring):
    every particle so far (u, log-likelihood, log q₀), the rounds' proposals, β, the per-round ESS, the
    checkpoint summaries and the random generator. ``propose`` → simulate the candidates → ``update``
    is one round; ``save``/``load`` (one .npz, written atomically) let each round run as its own job
    (``forcdecode fit-round``, the workflow's ``fit_round`` rule) with results identical to ``refine``."""

    def __init__(self, observed, proposal_draws, sigma2: float, budget: int, round_size: int, rng: np.random.Generator,
                 names, options: RefinementOptions | None = None):
        """``observed``: the grid family; ``proposal_draws`` (m, d): draws of q₀ in u ∈ [0, 1]^d; ``sigma2``:
        the synthetic likelihood's variance (m² normalized); ``budget``: simulations in all, in rounds of
        ``round_size``; ``rng``: the rounds' generator; ``names``: the parameters; ``options``:
        ``RefinementOptions`` (its defaults where None). ConfigError for inconsistent settings."""
        options = options or RefinementOptions()
        checkpoints, n_effective, tempering = options.checkpoints, options.n_effective, options.tempering
        target_ess_fraction, path, scale = options.target_ess_fraction, options.path, options.scale
        if budget < round_size or round_size < 2:
            raise ConfigError(f"budget ({budget}) must be at least one round ({round_size} >= 2 simulations)")
        if not 0.0 < target_ess_fraction <= 1.0:
            raise ConfigError(f"target_ess_fraction ({target_ess_fraction}) must lie in (0, 1]")
        if path not in PATHS:
            raise ConfigError(f"tempering path {path!r} is not one of {PATHS}")
        self.observed = np.asarray(observed, float)
        self.n_curves = float(self.observed.shape[0] if n_effective is None else n_effective)
        draws = np.asarray(proposal_draws, float)
        d = draws.shape[1]
        self.scale = np.ones(d) if scale is None else np.asarray(scale, float)
        if self.scale.shape != (d,) or not np.all(np.isfinite(self.scale)) or np.any(self.scale < 1.0):
            raise ConfigError(f"scale must hold one factor >= 1 per parameter ({d}); got {np.asarray(scale).tolist()}")
        self.extended = bool(np.any(self.scale != 1.0))
        self.pool = draws / self.scale  # the particles live in u' = u / scale ∈ [0, 1]^d
        self.sigma2, self.budget, self.round_size, self.rng = float(sigma2), int(budget), int(round_size), rng
        self.names, self.checkpoints = tuple(names), tuple(int(c) for c in checkpoints)
        self.tempering, self.target_ess_fraction, self.path = bool(tempering), float(target_ess_fraction), path
        self.u, self.loglik, self.log_q0, self.log_prior = np.zeros((0, d)), np.zeros(0), np.zeros(0), np.zeros(0)
        self.rounds = []  # (size, mean_z, cov_z); mean None: the round drew from q₀
        self.cursor, self.beta, self.betas, self.ess = 0, 0.0, [], []
        self.by_budget, self.wall_s, self.logw = {}, 0.0, np.zeros(0)
        self.context = {}  # plain values the caller keeps with the state (saved with it)

    def extend(self, budget: int, checkpoints=()) -> None:
        """Raise the budget (never lower it) and add checkpoints: the rounds already run are the first
        rounds of the longer run, so its result is the one a run with that budget from the start gives."""
        if budget % self.round_size:
            raise ConfigError(f"budget {budget} is not a multiple of the round size {self.round_size}")
        self.budget = max(self.budget, int(budget))
        self.checkpoints = tuple(sorted(set(self.checkpoints) | {int(c) for c in checkpoints}))

    @property
    def n_rounds(self) -> int:
        return self.budget // self.round_size

    @property
    def done(self) -> bool:
        return len(self.rounds) >= self.n_rounds

    def _log_mixture(self, u, q0):
        """log Σ_r (N_r/N) q_r(u) over the rounds so far (q₀ for round 1 and the defensive part)."""
        total = sum(r[0] for r in self.rounds)
        z, lj = _logit(u), _log_jacobian(u)
        terms = []
        for size, mean, cov in self.rounds:
            if mean is None:
                terms.append(np.log(size / total) + q0)
            else:
                gauss = multivariate_normal(mean, cov, allow_singular=True).logpdf(z) + lj
                terms.append(np.log(size / total) + np.logaddexp(np.log(DEFENSIVE) + q0, np.log(1 - DEFENSIVE) + gauss))
        return np.logaddexp.reduce(np.stack(terms), axis=0)

    def propose(self) -> np.ndarray:
        """The next round's candidates (round_size, d) in u; records the round's proposal."""
        if self.done:
            raise ConfigError(f"the refinement has run all its {self.n_rounds} rounds")
        d, size = self.pool.shape[1], self.round_size
        if not self.rounds:
            take = self.pool[self.cursor:self.cursor + size]
            self.cursor += size
            self.rounds.append((size, None, None))
            return take * self.scale
        w = _normalized(self.logw)
        z = _logit(self.u)
        mean = w @ z
        centred = z - mean
        cov = (centred * w[:, None]).T @ centred
        cov = INFLATION * 0.5 * (cov + cov.T) + 1e-3 * np.eye(d)
        n_def = self.rng.binomial(size, DEFENSIVE)
        if self.cursor + n_def > len(self.pool):
            self.cursor = 0
        from_q0 = self.pool[self.cursor:self.cursor + n_def]
        self.cursor += n_def
        z_new = self.rng.multivariate_normal(mean, cov, size=size - n_def)
        self.rounds.append((size, mean, cov))
        return np.concatenate([np.clip(from_q0, 0.0, 1.0), _inverse_logit(z_new)]) * self.scale

    def update(self, take, families, log_q0, wall_s: float = 0.0, log_prior=None) -> None:
        """Add the round's candidates with their simulated families, log q₀ and log prior (None: the
        uniform box, 0); raise β; summarize at checkpoints (``wall_s``: the round's time, accumulated
        into the summaries' ``wall_s``)."""
        self.u = np.concatenate([self.u, np.asarray(take, float) / self.scale])
        self.loglik = np.concatenate([self.loglik, synthetic_loglik(families, self.observed, self.sigma2, self.n_curves)])
        # q₀'s density per unit u' (the Jacobian of u = scale · u'; 0 where the draws of q₀ never reach)
        self.log_q0 = np.concatenate([self.log_q0, np.asarray(log_q0, float) + float(np.log(self.scale).sum())])
        self.log_prior = np.concatenate([self.log_prior, np.zeros(len(take)) if log_prior is None
                                         else np.asarray(log_prior, float)])
        with np.errstate(invalid="ignore"):
            log_q = self._log_mixture(self.u, self.log_q0)
        # log π_β / q_mix = β·tilt − base: the bridge from q₀ shifts both by log q₀
        with np.errstate(invalid="ignore"):
            tilt, base = ((self.loglik + self.log_prior - self.log_q0, log_q - self.log_q0) if self.path == "amortized"
                          else (self.loglik, log_q - self.log_prior))
        tilt = np.where(np.isneginf(self.log_prior), -np.inf, tilt)  # outside the prior: weight 0 (not −∞ − −∞)
        self.beta = (next_beta(tilt, base, self.beta, self.target_ess_fraction * self.round_size)
                     if self.tempering else 1.0)
        self.logw = _log_weights(tilt, base, self.beta)
        if self.extended and self.beta == 1.0:
            # at β = 1 the target no longer involves q₀, so candidates beyond its support (q₀ = 0: the
            # extended part of the box) weigh by p L / q_mix like any other
            self.logw = _log_weights(np.where(np.isneginf(self.log_prior), -np.inf, self.loglik + self.log_prior),
                                     log_q, 1.0)
        self.betas.append(self.beta)
        self.ess.append(_ess(self.logw))
        self.wall_s += float(wall_s)
        spent = len(self.rounds) * self.round_size
        if spent in self.checkpoints or spent == self.n_rounds * self.round_size:
            summary = summarize_particles(self.u * self.scale, _normalized(self.logw), self.names)
            summary.update(beta=self.beta, tempered=self.beta < 1.0, wall_s=self.wall_s)
            if self.beta < 1.0:
                summary["note"] = (f"tempered posterior: likelihood to the power beta = {self.beta:.3g} < 1 "
                                   + ("(wider than the target)" if self.path == "prior" else
                                      "(between the amortized posterior and the target)")
                                   + "; not the posterior: a larger budget is needed")
            self.by_budget[spent] = summary

    def result(self) -> dict:
        return {"u": self.u * self.scale, "loglik": self.loglik, "weights": _normalized(self.logw),
                "summary": self.by_budget[max(self.by_budget)], "by_budget": dict(self.by_budget),
                "sigma2": self.sigma2, "n_curves": self.n_curves, "betas": list(self.betas), "ess": list(self.ess),
                "reached_full_likelihood": self.beta == 1.0, "path": self.path if self.tempering else None}

    def save(self, path) -> None:
        """Atomic .npz of the whole state (arrays, the rounds' proposals, the generator's state)."""
        import json


        d = self.pool.shape[1]
        means = np.array([np.full(d, np.nan) if m is None else m for _, m, _ in self.rounds]).reshape(-1, d)
        covs = np.array([np.full((d, d), np.nan) if c is None else c for _, _, c in self.rounds]).reshape(-1, d, d)
        meta = {"sigma2": self.sigma2, "n_curves": self.n_curves, "budget": self.budget, "round_size": self.round_size,
                "names": list(self.names), "checkpoints": list(self.checkpoints), "tempering": self.tempering,
                "target_ess_fraction": self.target_ess_fraction, "path": self.path, "cursor": self.cursor,
                "beta": self.beta, "betas": self.betas, "ess": self.ess, "wall_s": self.wall_s,
                "round_sizes": [r[0] for r in self.rounds], "by_budget": {str(k): v for k, v in self.by_budget.items()},
                "rng": self.rng.bit_generator.state, "context": self.context, "scale": self.scale.tolist()}
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                np.savez(handle, observed=self.observed, pool=self.pool, u=self.u, loglik=self.loglik,
                         log_q0=self.log_q0, log_prior=self.log_prior, logw=self.logw, means=means, covs=covs,
                         meta=np.array(json.dumps(meta)))

    @classmethod
    def load(cls, path) -> "Refinement":
        import json


        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            meta = json.loads(str(arrays["meta"]))
        except (OSError, KeyError, ValueError) as error:
            raise InputFileError(f"{path}: not a refinement state ({error})") from None
        rng = np.random.Generator(getattr(np.random, meta["rng"]["bit_generator"])())
        rng.bit_generator.state = meta["rng"]
        state = cls(arrays["observed"], arrays["pool"], meta["sigma2"], meta["budget"], meta["round_size"], rng,
                    meta["names"], RefinementOptions(meta["checkpoints"], meta["n_curves"], tempering=meta["tempering"],
                                                     target_ess_fraction=meta["target_ess_fraction"], path=meta["path"],
                                                     scale=meta.get("scale")))
        state.pool = arrays["pool"]  # saved in u' (not divided twice)
        state.u, state.loglik, state.log_q0, state.logw = arrays["u"], arrays["loglik"], arrays["log_q0"], arrays["logw"]
        state.log_prior = arrays.get("log_prior", np.zeros(len(state.u)))
        state.rounds = [(size, None if np.isnan(m).all() else m, None if np.isnan(c).all() else c)
                        for size, m, c in zip(meta["round_sizes"], arrays["means"], arrays["covs"])]
        state.cursor, state.beta, state.betas, state.ess = meta["cursor"], meta["beta"], meta["betas"], meta["ess"]
        state.wall_s = meta["wall_s"]
        state.by_budget = {int(k): v for k, v in meta["by_budget"].items()}
        state.context = meta.get("context", {})
        return state


def regression_adjust(u, summaries, observed_summary, log_weights, ridge: float = 1e-3, diagonal: bool = False):
    """Local-linear regression adjustment (Beaumont, Zhang & Balding 2002, Genetics 162:2025) of
    particles ``u`` (k, d) in [0, 1] whose simulated families have summaries ``summaries`` (k, q), at
    the observed summary ``observed_summary`` (q,). In logit space z_i = α + B (s_i − s_o) + ε_i is fitted
    by weighted least squares, weights ∝ exp(``log_weights``) × an Epanechnikov kernel on the
    Mahalanobis distance of s_i to s_o (bandwidth: the largest distance, so every particle counts);
    the adjusted particles z_i* = z_i − B (s_i − s_o) are a sample of p(u | s = s_o) where the
    regression holds. ``ridge`` regularizes B on standardized summaries (a summary that varies little
    adds no noise). ``diagonal`` (needs q = d, one summary per parameter): each logit z_j regressed on
    its own summary s_j only, so a summary that scatters with the disorder moves no other parameter.
    Returns (u adjusted (k, d), normalized weights (k,), B (q, d) per standardized summary; zero off
    the diagonal when ``diagonal``)."""
    u = np.atleast_2d(np.asarray(u, float))
    s = np.atleast_2d(np.asarray(summaries, float))
    if len(s) != len(u) or len(log_weights) != len(u):
        raise ValueError(f"{len(u)} particles, {len(s)} summaries and {len(log_weights)} weights: they must match")
    ok = np.all(np.isfinite(s), axis=1) & np.isfinite(np.asarray(log_weights, float))
    if ok.sum() < s.shape[1] + 2:
        raise ValueError(f"{int(ok.sum())} usable particles cannot fit a regression on {s.shape[1]} summaries")
    w = np.zeros(len(u))
    w[ok] = _normalized(np.asarray(log_weights, float)[ok])
    delta = s - np.asarray(observed_summary, float)
    scale = np.sqrt(np.average((s[ok] - np.average(s[ok], axis=0, weights=w[ok])) ** 2, axis=0, weights=w[ok]))
    scale = np.where(scale > 0, scale, 1.0)
    x = np.where(ok[:, None], delta / scale, 0.0)
    cov = np.cov(x[ok].T, aweights=w[ok] + 1e-300).reshape(x.shape[1], x.shape[1])
    dist2 = np.einsum("ij,jk,ik->i", x, np.linalg.pinv(cov), x)
    h2 = dist2[ok].max() * (1 + 1e-9) if dist2[ok].max() > 0 else 1.0
    kernel = np.where(ok, np.clip(1.0 - dist2 / h2, 0.0, None), 0.0)
    w = w * kernel
    w /= w.sum()
    z = _logit(u)

    def slopes_on(columns, targets):  # weighted ridge least squares of targets on [1, x[:, columns]]
        design = np.column_stack([np.ones(len(u)), x[:, columns]])
        gram = design.T @ (design * w[:, None]) + ridge * np.diag([0.0] + [1.0] * len(columns))
        return np.linalg.solve(gram, design.T @ (targets * w[:, None]))[1:]

    if diagonal:
        if x.shape[1] != z.shape[1]:
            raise ValueError(f"a diagonal regression needs one summary per parameter: {x.shape[1]} summaries, "
                             f"{z.shape[1]} parameters")
        slopes = np.diag([slopes_on([j], z[:, j:j + 1])[0, 0] for j in range(z.shape[1])])
    else:
        slopes = slopes_on(list(range(x.shape[1])), z)
    return _inverse_logit(z - x @ slopes), w, slopes


def anchored_summary(reported, u, u_adjusted, adjusted_weights, names, levels=(0.68, 0.9)) -> dict:
    """The regression-adjusted posterior with the Monte-Carlo error of its k particles removed by a
    control variate: the amortized posterior itself, known from many more draws.

    ``u`` (k, d): the simulated draws of q₀ (equal weights); ``u_adjusted``, ``adjusted_weights``: the
    same draws after ``regression_adjust``; ``reported`` (m, d), m ≫ k: the amortized posterior as
    reported (all its draws, recalibrated where a map applies). Per parameter j and quantile level q,
    in logit z: Q(q) = Q_adjusted(q) + c_j [Q_reported(q) − Q_u(q)], c_j = cov(z*_j, z_j) / var(z_j)
    over the particles (clipped to [0, 1]), the variance-minimizing coefficient of a control variate.
    The adjusted particles z* = z − B(s − s_o) share the k draws' sampling error in proportion c_j (a
    median of k = 200 draws alone scatters by about 1.25 σ/√k): where the summaries say little (B ≈ 0,
    c_j ≈ 1) the answer is the reported posterior moved by the adjustment, recalibration kept; where
    they pin the parameter (c_j ≈ 0) it is the adjusted particles'. A constant summary (no adjustment,
    equal kernel weights) gives the reported posterior itself. Same layout as ``summarize_particles``
    (the ESS is the adjusted weights'); interval ends are kept ordered."""
    reported = np.atleast_2d(np.asarray(reported, float))
    u = np.atleast_2d(np.asarray(u, float))
    u_adjusted = np.atleast_2d(np.asarray(u_adjusted, float))
    w = np.asarray(adjusted_weights, float)
    if u.shape != u_adjusted.shape or len(w) != len(u) or reported.shape[1] != u.shape[1]:
        raise ValueError(f"draws {u.shape}, adjusted {u_adjusted.shape}, weights {w.shape} and reported "
                         f"{reported.shape}: the same particles and parameters are needed")
    w = w / w.sum()
    qs = _summary_levels(levels)
    out = {"ess": float(1.0 / np.sum(w ** 2)), "parameters": {}}
    equal = np.full(len(u), 1.0 / len(u))
    z_u, z_adjusted = _logit(u), _logit(u_adjusted)
    for j, name in enumerate(names):
        spread = z_u[:, j].var()
        c = 0.0 if spread <= 0 else float(np.clip(np.cov(z_adjusted[:, j], z_u[:, j])[0, 1] / spread, 0.0, 1.0))
        z = (_logit(weighted_quantiles(u_adjusted[:, j], w, qs))
             + c * (_logit(np.quantile(reported[:, j], qs)) - _logit(weighted_quantiles(u[:, j], equal, qs))))
        out["parameters"][name] = _summary_row(qs, _inverse_logit(np.maximum.accumulate(z)), levels)
    return out


def shifted_summary(reported, centre, names, resolution=None, levels=(0.68, 0.9)) -> dict:
    """The reported amortized posterior moved to a new centre and narrowed only as far as the
    simulations alone can pin each parameter, never by multiplying the two.

    The regression adjustment with q₀ as the prior multiplies q₀, which already holds the observation,
    by the summary's likelihood of that same observation: the information counts twice and the
    adjusted intervals are too narrow (the refined A_ex held the truth in 70 % of 20 test families
    against 85 % amortized; ``tests/loop/test_fit.py`` shows the mechanism on a linear-Gaussian
    problem). The part of the adjustment the double count leaves alone is the move of the centre (the
    network's local bias). The width: both q₀ and the summary are functions of one observation, so the
    exact posterior is at least as narrow as either alone, and no narrower than their product. Per
    parameter j, in logit: every quantile of ``reported`` (m, d) is moved so the median lands on
    ``centre``'s (a summary of ``summarize_particles``' layout, e.g. ``anchored_summary``'s) and its
    distance from the median is scaled by min(1, ``resolution[j]``): the width at which one simulated
    family's summary locates θ_j over the spread of the draws (``summary_resolution``), i.e. the width of
    the summary's own likelihood relative to q₀'s. A summary that pins θ_j finer than q₀ (q₀ wasted
    information) narrows it to the summary's width; one that does not leaves q₀'s width, whose coverage
    is measured. ``resolution``: {name: ratio}, missing or non-finite names unscaled. Same layout as
    ``summarize_particles``; ESS and any other key of ``centre`` are kept."""
    reported = np.atleast_2d(np.asarray(reported, float))
    if reported.shape[1] != len(names):
        raise ValueError(f"reported draws of {reported.shape[1]} parameters for {len(names)} names")
    qs = _summary_levels(levels)
    middle = list(qs).index(0.5)
    out = {**centre, "parameters": {}}
    for j, name in enumerate(names):
        z = _logit(np.quantile(reported[:, j], qs))
        ratio = (resolution or {}).get(name, np.inf)
        scale = float(min(1.0, ratio)) if np.isfinite(ratio) and ratio > 0 else 1.0
        target = float(_logit(np.array(centre["parameters"][name]["median"])))
        out["parameters"][name] = _summary_row(qs, _inverse_logit(target + scale * (z - z[middle])), levels)
    return out


def summary_resolution(u, summaries) -> np.ndarray:
    """How finely one simulated family's summary locates each parameter, relative to the spread of the
    draws it was simulated at: per parameter j, ŝ_j = a + Σ_k b_jk logit u_k is fitted by least squares
    (one summary per parameter, ``summaries`` (k, d) beside ``u`` (k, d) in [0, 1]), and the ratio is
    (residual sd of s_j / |b_jj|) / sd(logit u_j). The numerator is the width at which one realisation's
    summary pins θ_j. Below 1 the simulations can sharpen θ_j beyond the draws; far above 1 (a summary
    flat in θ_j, or one the disorder scatters) a regression adjustment can only remove a local bias of
    the summary, not narrow it. inf where the slope is 0. Rows with a non-finite summary are left out."""
    u = np.atleast_2d(np.asarray(u, float))
    s = np.atleast_2d(np.asarray(summaries, float))
    if s.shape != u.shape:
        raise ValueError(f"one summary per parameter: summaries {s.shape} beside draws {u.shape}")
    ok = np.all(np.isfinite(s), axis=1)
    if ok.sum() < u.shape[1] + 3:
        raise ValueError(f"{int(ok.sum())} usable simulations cannot fit {u.shape[1]} slopes and a residual")
    z = _logit(u[ok])
    design = np.column_stack([np.ones(len(z)), z])
    coef, *_ = np.linalg.lstsq(design, s[ok], rcond=None)
    residual_sd = (s[ok] - design @ coef).std(axis=0, ddof=design.shape[1])
    constant = s[ok].std(axis=0) <= 1e-12 * (1.0 + np.abs(s[ok]).mean(axis=0))
    own_slope = np.where(constant, 0.0, np.abs(np.diag(coef[1:])))  # a constant summary pins nothing
    spread = z.std(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(own_slope > 0, residual_sd / own_slope, np.inf) / np.where(spread > 0, spread, np.nan)
    return ratio


IMAGE_SUMMARY_COMPONENTS = (5, 10, 20, 40)
"""Principal components of a family's own simulated images tried by ``image_summaries``."""
IMAGE_SUMMARY_RIDGES = (1.0, 10.0, 100.0)
"""Ridge penalties (on standardized components) tried by ``image_summaries``."""


def _ridge_fit(features, targets, ridge: float):
    """Ridge least squares of ``targets`` on standardized ``features`` with a free intercept: a function
    that predicts the targets of new feature rows."""
    mean, sd = features.mean(axis=0), features.std(axis=0)
    sd = np.where(sd > 0, sd, 1.0)
    design = np.column_stack([np.ones(len(features)), (features - mean) / sd])
    gram = design.T @ design + ridge * np.diag([0.0] + [1.0] * features.shape[1])
    coef = np.linalg.solve(gram, design.T @ targets)
    return lambda new: np.column_stack([np.ones(len(new)), (new - mean) / sd]) @ coef


def _image_inputs(u, images, observed_image):
    """(draws (k, d), simulated images as rows of pixels in [0, 1] (k, n²), the observed image as one such
    row (1, n²)) from uint8-scaled inputs; ValueError unless there is one image of the observed shape per draw."""
    u = np.atleast_2d(np.asarray(u, float))
    images = np.asarray(images, float)
    observed = np.asarray(observed_image, float).reshape(1, -1) / 255.0
    if len(images) != len(u) or images.ndim != 3 or images.shape[1] * images.shape[2] != observed.shape[1]:
        raise ValueError(f"{len(u)} draws, images {images.shape} and an observed image of {observed.shape[1]} "
                         "pixels: one image of the observed shape per draw is needed")
    return u, images.reshape(len(u), -1) / 255.0, observed


def image_summaries(u, images, observed_image, folds: int = 10) -> tuple[np.ndarray, np.ndarray, dict]:
    """Summaries read from the family's own simulations instead of the network: semi-automatic ABC
    (Fearnhead & Prangle 2012) fitted locally. The k simulated images (k, n, n) of draws ``u`` (k, d) are
    projected on their first m principal components; logit u is regressed on them by ridge; the
    prediction is the summary (one per parameter). The network is trained once over the whole prior;
    near one film a linear map of the image can read what its mean smooths away.

    Each simulation's summary is predicted out of fold (``folds`` folds), so its scatter is the one a new
    realisation would have; the observed image's by the fit on all k. m ∈ ``IMAGE_SUMMARY_COMPONENTS``
    (at most k/4) and the ridge ∈ ``IMAGE_SUMMARY_RIDGES`` are the pair with the smallest out-of-fold
    squared error of logit u (each parameter over its own variance, averaged): ordinary cross-validation
    on the simulations alone, never on the observation. (Choosing instead the pair with the best
    ``summary_resolution`` let a parameter the images do not encode look resolved by the luckiest of
    the pairs.) Returns (summaries (k, d), observed summary (d,), {"components", "ridge",
    "resolution": the out-of-fold summaries' ``summary_resolution``}). ValueError for mismatched shapes
    or fewer than 2 × folds simulations."""
    u, pixels, observed = _image_inputs(u, images, observed_image)
    if len(u) < 2 * folds:
        raise ValueError(f"{len(u)} simulations cannot be cross-fitted in {folds} folds")
    centre = pixels.mean(axis=0)
    _, _, basis = np.linalg.svd(pixels - centre, full_matrices=False)
    z = _logit(u)
    fold = np.arange(len(u)) % folds
    best = None
    for m in [c for c in IMAGE_SUMMARY_COMPONENTS if c <= len(u) // 4 and c <= len(basis)]:
        scores = (pixels - centre) @ basis[:m].T
        for ridge in IMAGE_SUMMARY_RIDGES:
            out_of_fold = np.empty_like(z)
            for f in range(folds):
                held = fold == f
                out_of_fold[held] = _ridge_fit(scores[~held], z[~held], ridge)(scores[held])
            score = float(np.mean(np.mean((out_of_fold - z) ** 2, axis=0) / np.maximum(z.var(axis=0), 1e-12)))
            if best is None or score < best[0]:
                best = (score, m, ridge, out_of_fold)
    if best is None:
        raise ValueError(f"{len(u)} simulations are too few for {min(IMAGE_SUMMARY_COMPONENTS)} components")
    _, m, ridge, out_of_fold = best
    resolution = summary_resolution(u, out_of_fold)
    scores = (pixels - centre) @ basis[:m].T
    observed_summary = _ridge_fit(scores, z, ridge)((observed - centre) @ basis[:m].T)[0]
    return out_of_fold, observed_summary, {"components": int(m), "ridge": float(ridge),
                                           "resolution": [float(v) for v in resolution]}


IMAGE_LIKELIHOOD_COMPONENTS = 10
"""Principal components of the simulated images in which ``image_likelihood`` models the observation."""


class ImageLikelihood:
    """A synthetic Gaussian likelihood of the observed image in the space of the simulated images'
    principal components (Wood 2010, Nature 466:1102, in its regression form): built by
    ``image_likelihood``; ``loglik(u)`` for draws u (n, d) in [0, 1], and the record ``info``."""

    def __init__(self, intercept, slopes, precision, observed_scores, info):
        self.intercept, self.slopes, self.precision = intercept, slopes, precision
        self.observed_scores, self.info = observed_scores, info

    def loglik(self, u) -> np.ndarray:
        """log L(u) = −½ (s_o − a − B logit u)ᵀ Σ⁻¹ (s_o − a − B logit u), up to a constant (nats)."""
        mean = self.intercept + _logit(np.atleast_2d(np.asarray(u, float))) @ self.slopes
        delta = self.observed_scores - mean
        return -0.5 * np.einsum("ij,jk,ik->i", delta, self.precision, delta)


def image_likelihood(u, images, observed_image, components: int = IMAGE_LIKELIHOOD_COMPONENTS) -> ImageLikelihood:
    """The observed image's likelihood read from the family's own simulations, not from the network.

    The k simulated images x_i (k, n, n; uint8, each on its own disorder realisation) at draws u_i are
    projected on their first m principal components, s = V_m (x − x̄) (pixels in [0, 1]). The scores
    are modelled as s_i = a + B z_i + ε_i with z = logit u, ε ~ N(0, Σ): (a, B) by least squares over the
    k simulations, Σ the Ledoit–Wolf shrinkage covariance (scikit-learn) of the residuals, scaled by
    k/(k − d − 1) for the d + 1 fitted coefficients. ε holds the disorder's scatter (a new realisation
    of the same Hamiltonian) and what a linear mean misses over the draws' spread, so the likelihood is
    no sharper than the simulations support. The components are those of the simulated cloud: the
    directions in which the observation differs from everything the simulator made at these draws
    enter only through the misfit below.

    ``info``: ``components``; ``fisher`` F = Bᵀ Σ⁻¹ B (logit units); ``resolution`` per parameter,
    √(F⁻¹)_jj over the draws' spread of z_j (pseudo-inverse; below 1 the images pin the parameter finer
    than the draws, inf where F is singular in it); ``misfit``: χ² = r_oᵀ Σ⁻¹ r_o of the observed scores'
    residual at their generalized-least-squares fit ẑ, against the simulations' own residual χ²
    (``misfit_simulated_max``, ``misfit_p``: the share of simulations with a larger one; 0 says the
    observed image lies where no simulation does, at any parameter the linear model reaches);
    ``outside_components``: the observed image's squared distance from its projection on the m
    components, against the simulations' own (``outside_components_simulated_max``,
    ``outside_components_p``): a departure in a direction no simulation varies in (the simulations'
    distances are in-sample, so the p is if anything too large, never too small).
    ValueError for mismatched shapes or fewer than d + m + 3 simulations."""
    from sklearn.covariance import LedoitWolf

    u, pixels, observed = _image_inputs(u, images, observed_image)
    k, d = u.shape
    m = int(min(components, k - d - 3))
    if m < 1:
        raise ValueError(f"{k} simulations cannot fit {d} slopes and a covariance of any component")
    centre = pixels.mean(axis=0)
    _, _, basis = np.linalg.svd(pixels - centre, full_matrices=False)
    basis = basis[:m]
    scores = (pixels - centre) @ basis.T
    observed_scores = ((observed - centre) @ basis.T)[0]
    z = _logit(u)
    design = np.column_stack([np.ones(k), z])
    coef, *_ = np.linalg.lstsq(design, scores, rcond=None)
    residual = scores - design @ coef
    scale = residual.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    # shrunk as a correlation matrix (towards the diagonal): the components' variances differ by orders
    # of magnitude, and a shrinkage towards their mean would inflate the smallest (measured: 1.9× the
    # closed-form sd of a parameter the first component carries)
    correlation = LedoitWolf(assume_centered=True).fit(residual / scale).covariance_
    covariance = correlation * np.outer(scale, scale) * k / (k - d - 1)
    precision = np.linalg.inv(covariance)
    intercept, slopes = coef[0], coef[1:]
    fisher = slopes @ precision @ slopes.T
    inverse = np.linalg.pinv(fisher)
    spread = z.std(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        resolution = np.where(np.diag(inverse) > 0, np.sqrt(np.abs(np.diag(inverse))), np.inf) / spread
    z_hat = inverse @ slopes @ precision @ (observed_scores - intercept)
    r_obs = observed_scores - intercept - z_hat @ slopes
    misfit = float(r_obs @ precision @ r_obs)
    simulated = np.einsum("ij,jk,ik->i", residual, precision, residual)
    # what the components leave out: the squared distance of an image from its projection on them
    left = np.sum((pixels - centre - scores @ basis) ** 2, axis=1)
    left_observed = float(np.sum((observed[0] - centre - observed_scores @ basis) ** 2))
    info = {"components": m, "fisher": fisher.tolist(), "resolution": [float(v) for v in resolution],
            "misfit": misfit, "misfit_simulated_max": float(simulated.max()),
            "misfit_p": float(np.mean(simulated >= misfit)), "z_hat": z_hat.tolist(),
            "outside_components": left_observed, "outside_components_simulated_max": float(left.max()),
            "outside_components_p": float(np.mean(left >= left_observed))}
    return ImageLikelihood(intercept, slopes, precision, observed_scores, info)


def likelihood_posterior(loglik, proposal_u, log_proposal, log_prior, names, levels=(0.68, 0.9)) -> dict:
    """Posterior π(u) ∝ p(u) L(u) by importance sampling: ``proposal_u`` (n, d) drawn from a proposal of
    log density ``log_proposal`` (n,), weights p L / q (−∞ prior: weight 0). No simulation: L is
    evaluated by ``loglik`` (e.g. ``ImageLikelihood.loglik``). Returns ``summarize_particles``'s record
    (medians, intervals, ESS). ValueError where no proposal draw has a finite weight."""
    u = np.atleast_2d(np.asarray(proposal_u, float))
    with np.errstate(invalid="ignore"):
        logw = np.asarray(log_prior, float) + np.asarray(loglik(u), float) - np.asarray(log_proposal, float)
    logw = np.where(np.isfinite(logw), logw, -np.inf)
    if not np.isfinite(logw).any():
        raise ValueError("no proposal draw has a finite weight under the prior and the likelihood")
    return summarize_particles(u, _normalized(logw), names, levels)


def outside_simulations(summaries, observed_summary) -> tuple[bool, float, float]:
    """Whether an observed summary lies outside the cloud of the simulated ones, where a local-linear
    regression adjustment (valid near the simulations, Beaumont et al. 2002) would extrapolate: its
    squared Mahalanobis distance from the simulations' mean (their covariance, pseudo-inverted) beyond
    the largest of the simulations' own. No tuned threshold: the simulated cloud is the reference.
    Returns (outside, observed distance², largest simulated distance²); rows with a non-finite summary
    are left out."""
    s = np.atleast_2d(np.asarray(summaries, float))
    s = s[np.all(np.isfinite(s), axis=1)]
    if len(s) < s.shape[1] + 2:
        raise ValueError(f"{len(s)} finite summaries cannot give a covariance of {s.shape[1]} dimensions")
    centre = s.mean(axis=0)
    precision = np.linalg.pinv(np.atleast_2d(np.cov(s.T)))
    simulated = np.einsum("ij,jk,ik->i", s - centre, precision, s - centre)
    delta = np.asarray(observed_summary, float) - centre
    observed = float(delta @ precision @ delta)
    return bool(observed > simulated.max()), observed, float(simulated.max())


def _rms_over_floor(state) -> np.ndarray:
    """Each candidate's observation RMS over the realisation floor, from its synthetic log-likelihood
    (MSE = −2 log L σ² / ν); ∞ where its simulation failed."""
    ok = np.isfinite(state.loglik)
    return np.sqrt(np.clip(-2.0 * np.where(ok, state.loglik, -np.inf) * state.sigma2 / state.n_curves, 0, None)) \
        / np.sqrt(state.sigma2)


def observation_rms(state) -> dict:
    """The posterior-predictive check the particles give for free: each candidate's observation RMS
    against the observed family (from its synthetic log-likelihood, MSE = −2 log L σ² / ν; on the
    common disorder realisation) over the floor √σ² (the RMS the true Hamiltonian reaches on another
    realisation). ``amortized``: median over round 1 (draws of the amortized posterior);
    ``refined``: weighted median over every particle at the final β; ``best_over_floor_by_budget``:
    per round boundary b, the smallest ratio among the first b candidates (the statistic of the
    calibrated misspecification check, ``infer.predictive_check``: it does not depend on the budget
    run beyond b)."""
    ok = np.isfinite(state.loglik)
    ratio_all = _rms_over_floor(state)
    ratio = ratio_all[ok]
    first = np.zeros(len(state.loglik), bool)
    first[: state.round_size] = True
    weights = _normalized(state.logw)[ok]
    best = {str(b): float(np.min(ratio_all[:b])) for b in range(state.round_size, len(state.loglik) + 1, state.round_size)}
    return {"floor_rms": float(np.sqrt(state.sigma2)),
            "amortized_over_floor": float(np.median(ratio[first[ok]])) if first[ok].any() else float("nan"),
            "refined_over_floor": float(weighted_quantiles(ratio, weights, [0.5])[0]) if weights.sum() > 0
            else float("nan"),
            "best_over_floor_by_budget": best}


WIDENING_NODES = 32
"""Midpoint nodes per extended parameter on which ``widened_logpdf`` integrates q₀ over the prior's range."""


def widen_draws(draws, scale, rng: np.random.Generator) -> np.ndarray:
    """Draws of the widened proposal q̃₀ (``widened_logpdf``): each extended parameter's column of the
    q₀ draws (k, d) replaced by uniform draws on [0, scale_j], the rest kept (q₀'s marginal of them)."""
    scale = np.asarray(scale, float)
    out = np.array(draws, dtype=float, copy=True)
    for j in np.flatnonzero(scale != 1.0):
        out[:, j] = rng.uniform(0.0, scale[j], len(out))
    return out


def widened_logpdf(logpdf, scale, nodes: int = WIDENING_NODES):
    """log q̃₀(u) = log ∫ q₀(u) du_E over the prior's range of the extended parameters E, minus
    Σ_E log scale_j: q₀ with the marginal of each extended parameter replaced by the extended box's
    uniform law. q₀ (a flow trained on the prior) has no mass beyond the bound, so the tempered bridge
    q₀^{1−β}(pL)^β cannot reach there before β = 1, and a 200-simulation run arrived with a handful of
    candidates beyond (measured on the laptop film); q̃₀ puts (scale − 1)/scale of round 1 beyond. The
    amortized posterior of N_pin, the parameter this is for, is about its prior anyway (README), so
    little of q₀ is given up. The integral is the midpoint rule on ``nodes`` points per extended
    parameter (q₀ evaluated nodes^|E| times per candidate). −∞ outside the extended box."""
    scale = np.asarray(scale, float)
    extended = np.flatnonzero(scale != 1.0)
    grid = (np.arange(nodes) + 0.5) / nodes
    combos = np.array(np.meshgrid(*[grid] * len(extended), indexing="ij")).reshape(len(extended), -1).T
    constant = -float(np.log(scale[extended]).sum()) - np.log(len(combos))

    def log_density(u):
        u = np.atleast_2d(np.asarray(u, float))
        at_nodes = np.repeat(u, len(combos), axis=0)
        at_nodes[:, extended] = np.tile(combos, (len(u), 1))
        values = np.asarray(logpdf(at_nodes), float).reshape(len(u), len(combos))
        top = np.max(values, axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            marginal = np.where(np.isfinite(top[:, 0]),
                                top[:, 0] + np.log(np.exp(values - np.where(np.isfinite(top), top, 0.0)).sum(axis=1)),
                                -np.inf)
        inside = np.all((u[:, extended] >= 0.0) & (u[:, extended] <= scale[extended]), axis=1)
        return np.where(inside, marginal + constant, -np.inf)

    return log_density


def log_likelihood_ratio(loglik, inside) -> float:
    """max log L over all candidates − max over those ``inside`` the prior's box (failed simulations,
    log L = −∞ or NaN, left out): 0 when the best candidate lies inside, ∞ when none inside succeeded,
    NaN when none succeeded at all."""
    loglik = np.where(np.isfinite(loglik), loglik, -np.inf)
    best = float(loglik.max()) if loglik.size else -np.inf
    if best == -np.inf:
        return float("nan")
    best_inside = float(loglik[inside].max()) if np.any(inside) else -np.inf
    return best - best_inside


def beyond_prior(state) -> dict:
    """Where a refinement run in an extended box (``Refinement(scale=…)``: parameter j may reach
    ``scale[j]`` times its prior's range) puts the film: per extended parameter, the posterior mass
    beyond the prior's bound (u > 1), that mass under the extended prior (1 − 1/scale: the extension
    is uniform in u), and the Bayes factor of "beyond" against "inside"
    (posterior odds / prior odds). Beside them, the observation RMS over the floor of the best
    candidate inside the prior box and of the best overall, and their ratio: a film the prior cannot
    make is reproduced better beyond it. The masses hold only at β = 1 (``reached_full_likelihood``: before,
    the target is bridged to q₀, which is 0 beyond the bound). ``log_likelihood_ratio`` Λ = max log L over
    every candidate − max log L over the candidates inside the prior's box (≥ 0; = ν/2 · (T_in² − T_all²)
    in floor units T): the generalized likelihood ratio of "the film lies beyond the bound", the statistic
    of the calibrated extension check (``infer.predictive_check``), per round boundary b in
    ``log_likelihood_ratio_by_budget`` (first b candidates: a longer run gives the same Λ at b). Unlike
    the ratio of RMS it stays ≈ 0 where both best fits lie far below a floor measured too high (measured:
    a validation film at 0.006 vs 0.004 × its floor, ratio 1.6, Λ 2·10⁻⁵). {} for a run in the prior's box."""
    if not state.extended:
        return {}
    ratio = _rms_over_floor(state)
    u = state.u * state.scale
    inside = np.all(u <= 1.0 + 1e-9, axis=1)
    w = _normalized(state.logw)
    reached = bool(state.beta == 1.0)
    best_inside = float(ratio[inside].min()) if inside.any() else float("nan")
    out = {"reached_full_likelihood": reached, "best_inside_over_floor": best_inside,
           "best_over_floor": float(ratio.min()),
           # ≥ 1; above 1 a film beyond the bound reproduces the family better than any simulated inside. Unlike
           # the masses it needs no β = 1 (measured: an over-pinned film 8.4 → 1.14 × the floor at β = 0.77)
           "inside_over_anywhere": best_inside / float(ratio.min()),
           "log_likelihood_ratio": log_likelihood_ratio(state.loglik, inside),
           "log_likelihood_ratio_by_budget": {str(b): log_likelihood_ratio(state.loglik[:b], inside[:b])
                                              for b in range(state.round_size, len(state.loglik) + 1,
                                                             state.round_size)},
           "parameters": {}}
    for j, name in enumerate(state.names):
        if state.scale[j] == 1.0:
            continue
        beyond = u[:, j] > 1.0 + 1e-9
        prior_mass = 1.0 - 1.0 / float(state.scale[j])
        mass = factor = None  # before β = 1 there is no posterior mass beyond the bound to report
        if reached:
            mass = float(w[beyond].sum())
            factor = (mass / (1.0 - mass)) / (prior_mass / (1.0 - prior_mass)) if mass < 1.0 else float("inf")
        out["parameters"][name] = {"scale": float(state.scale[j]), "posterior_mass_beyond": mass,
                                   "prior_mass_beyond": prior_mass, "bayes_factor_beyond": factor,
                                   "candidates_beyond": int(beyond.sum())}
    return out


def refine(state: Refinement, simulate, proposal_logpdf, *, prior_logpdf=None, progress=None) -> dict:
    """Tempered population Monte Carlo for one observation (see the module docstring): the rounds of the
    fresh ``state`` (a ``Refinement``: the observation, q₀'s draws, σ², the budget, the rounds, the
    ``RefinementOptions``) run to its budget.

    ``simulate(u (k, d)) → families (k, n, n)``; ``proposal_logpdf(u (k, d)) → (k,)``: the log density of the
    amortized posterior q₀ whose draws the state holds (round 1 takes the first ``round_size``; the mixture
    reuses the rest); ``prior_logpdf``: the prior's (None: uniform on the box); ``progress(done, total)``: per
    round, in simulations.

    Returns particles, weights at the final β, the final summary, ``by_budget`` (each summary with its
    ``beta``, ``tempered`` and, if tempered, a ``note``), per round ``betas`` and ``ess``, and
    ``reached_full_likelihood`` (final β = 1; otherwise the result is a tempered posterior, not the
    target: raise the budget)."""
    while not state.done:
        started = time.perf_counter()
        take = state.propose()
        families = simulate(take)
        state.update(take, families, proposal_logpdf(take), wall_s=time.perf_counter() - started,
                     log_prior=None if prior_logpdf is None else prior_logpdf(take))
        if progress is not None:
            progress(len(state.rounds) * state.round_size, state.n_rounds * state.round_size)
    return state.result()


def simulate_on_film(cfg: dict, names, Ms: float, bounds: dict, key, workers: int = 1):
    """A batch simulator u (k, d) → grid families (k, n, n) on the config's film, every candidate on the
    same disorder realisation (stream ``closed_loop_disorder``, keys (``key``, 0)): common random numbers."""
    def simulate(u):
        tasks = []
        for row in np.atleast_2d(u):
            params = {"Ms": float(Ms), **{n: float(denormalize(n, row[j], bounds)) for j, n in enumerate(names)}}
            if "N_pin" in params:
                params["N_pin"] = int(round(params["N_pin"]))
            tasks.append((params, key, 0))
        out = []
        for curves, _reason in run_tasks(cfg, tasks, workers):
            n = cfg["field"]["n_fields"]
            out.append(curves if curves is not None else np.full((n, n), np.nan))
        return np.stack(out)

    return simulate


__all__ = ["Refinement", "RefinementOptions", "WIDENING_NODES", "beyond_prior", "log_likelihood_ratio", "refine", "widen_draws", "widened_logpdf", "regression_adjust", "summary_resolution", "difference_variance", "effective_observations", "next_beta", "synthetic_loglik", "summarize_particles", "observation_rms", "simulate_on_film", "weighted_quantiles"]
