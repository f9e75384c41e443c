"""Thermal activation of switching: the Sharrock law, an Arrhenius ensemble of Stoner–Wohlfarth
macrospins on any FORC protocol, and the FORC family of a thermally activated sample built from the
athermal one by scaling coercivities (the library candidate ``thermal_activation``).

Fields μ0H in tesla; energies in joules; times in seconds; K in J/m³, V in m³, T in K.

- Aligned Stoner–Wohlfarth particle (easy axis ∥ field, anisotropy field B_K = 2K/M_s): in a field
  b = B/B_K opposing its moment the barrier is ΔE = KV(1 − |b|)² (|b| < 1; 0 beyond); the escape rate
  is f0·exp(−ΔE/k_BT) (Néel–Arrhenius, attempt frequency f0).
- Sharrock law: held at field B for a time t the particle has switched with probability 1/2 when
  f0·t·exp(−ΔE/k_BT) = ln 2, i.e. B_sw(t) = B_K[1 − ((k_BT/KV)·ln(f0·t/ln 2))^(1/2)].
- Swept at a rate R (T/s), the probability reaches 1/2 where ∫ rate dt = ln 2; with the barrier's
  exponential dominating, β(1 − b)² = ln(f0·B_K/(2βR(1 − b)·ln 2)), β = KV/k_BT (solved by iteration).
- ``arrhenius_family``: an ensemble of such particles, each with its own B_K and a bias (interaction)
  field, relaxed by the two-state master equation for ``dwell_s`` at every field of the protocol.
- ``coercivity_scaled_family``: the family written as a Preisach sum of hysterons (down-switch β,
  up-switch α; coercivity c = (α − β)/2, bias u = (α + β)/2) plus a reversible remainder; thermal
  activation with one KV/k_BT for all particles reduces every coercivity by the common Sharrock factor
  1 − ε, ε = ((k_BT/KV) ln(f0 t/ln 2))^(1/2), at fixed bias. Exact for aligned particles (up to the
  grid); for a film it is the approximation a one-parameter candidate can afford.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

K_B = 1.380649e-23
"""Boltzmann constant (J/K)."""
ATTEMPT_FREQUENCY_HZ = 1e9
"""A common choice of the Néel–Arrhenius attempt frequency f0."""


def sharrock_epsilon(KV_over_kT: float, time_s: float, f0_Hz: float = ATTEMPT_FREQUENCY_HZ) -> float:
    """ε = ((k_BT/KV)·ln(f0 t/ln 2))^(1/2), the relative reduction of the switching field (0 if f0 t ≤ ln 2)."""
    x = np.log(f0_Hz * time_s / np.log(2)) / KV_over_kT
    return float(np.sqrt(x)) if x > 0 else 0.0


def sharrock_switching_field(B_K_T: float, KV_over_kT: float, time_s: float, f0_Hz: float = ATTEMPT_FREQUENCY_HZ) -> float:
    """B_sw(t) = B_K[1 − ε(t)] (T), clipped at 0 (superparamagnetic on the time scale t)."""
    return float(B_K_T * max(0.0, 1.0 - sharrock_epsilon(KV_over_kT, time_s, f0_Hz)))


def ramp_switching_field(B_K_T: float, KV_over_kT: float, rate_T_per_s: float, f0_Hz: float = ATTEMPT_FREQUENCY_HZ,
                         iterations: int = 50) -> float:
    """Median switching field (T) of an aligned particle swept at ``rate_T_per_s``: the root of
    β(1 − b)² = ln(f0 B_K/(2βR(1 − b) ln 2)) by fixed-point iteration from the Sharrock estimate."""
    beta = KV_over_kT
    x = 0.1  # x = 1 − b
    for _ in range(iterations):
        arg = f0_Hz * B_K_T / (2 * beta * rate_T_per_s * max(x, 1e-12) * np.log(2))
        x = np.sqrt(max(np.log(arg), 0.0) / beta)
    return float(B_K_T * (1 - x))


def _escape_rates(B, B_K, bias, beta, f0):
    """(rate up→down, rate down→up) (1/s) of aligned particles at applied field B (arrays over particles)."""
    b = (B + bias) / B_K
    barrier_down = np.where(b > -1, (1 + np.clip(b, -1, 1)) ** 2, 0.0)  # leaving +: field must push down
    barrier_up = np.where(b < 1, (1 - np.clip(b, -1, 1)) ** 2, 0.0)
    with np.errstate(over="ignore", under="ignore"):
        return f0 * np.exp(-beta * barrier_down), f0 * np.exp(-beta * barrier_up)


def _relax_populations(p_up, B, B_K, bias, beta, f0, dwell):
    r_ud, r_du = _escape_rates(B, B_K, bias, beta, f0)
    total = r_ud + r_du
    with np.errstate(invalid="ignore", over="ignore"):
        eq = np.where(total > 0, r_du / np.where(total > 0, total, 1.0), p_up)
        return eq + (p_up - eq) * np.exp(-total * dwell)


@dataclass(frozen=True)
class ParticleEnsemble:
    """Aligned Stoner–Wohlfarth particles of equal weight, m = ±1 each (module docstring).

    - ``B_K_T``: the anisotropy field B_K = 2K/M_s of each particle (T, one value per particle);
    - ``bias_T``: the bias (interaction) field of each particle (T; one value per particle, or one
      for all);
    - ``KV_over_kT``: β = KV/k_BT, the zero-field barrier over the thermal energy (dimensionless,
      common to all);
    - ``f0_Hz``: the Néel–Arrhenius attempt frequency (Hz).
    """

    B_K_T: object
    bias_T: object
    KV_over_kT: float
    f0_Hz: float = ATTEMPT_FREQUENCY_HZ


def arrhenius_family(ensemble: ParticleEnsemble, dwell_s: float, reversal_fields_T, curve_fields_T, *,
                     saturation_field_T: float | None = None, max_step_T: float | None = None) -> list:
    """⟨m⟩ of an ``ensemble`` of aligned Stoner–Wohlfarth particles on a FORC protocol: saturate
    (at ``saturation_field_T``, default the protocol's largest field), descend through the reversal
    fields (decreasing), then each curve from its reversal state through its fields; ``dwell_s``
    (s) at every field (and every sub-step of at most ``max_step_T`` on the way). Fields in T.
    Returns per curve the ensemble m at its fields (input order)."""
    B_K_T, bias_T, KV_over_kT, f0_Hz = ensemble.B_K_T, ensemble.bias_T, ensemble.KV_over_kT, ensemble.f0_Hz
    B_K = np.asarray(B_K_T, float)
    bias = np.broadcast_to(np.asarray(bias_T, float), B_K.shape)
    reversal = np.asarray(reversal_fields_T, float)
    top = saturation_field_T if saturation_field_T is not None else max(reversal.max(),
                                                                     max(np.max(f) for f in curve_fields_T))

    def walk(p, start, stop):
        steps = [stop] if max_step_T is None or abs(stop - start) <= max_step_T else \
            list(np.linspace(start, stop, int(np.ceil(abs(stop - start) / max_step_T)) + 1)[1:])
        for B in steps:
            p = _relax_populations(p, B, B_K, bias, KV_over_kT, f0_Hz, dwell_s)
        return p

    p = np.ones(B_K.shape)  # all up after saturation
    levels = np.unique(reversal)[::-1]
    states, previous = {}, top
    for B in levels:
        p = walk(p, previous, B)
        previous = B
        states[float(B)] = p.copy()
    out = []
    for H_r, fields in zip(reversal, curve_fields_T):
        p = states[float(H_r)].copy()
        previous, values = H_r, []
        for k, B in enumerate(np.asarray(fields, float)):
            if not (k == 0 and B == H_r):
                p = walk(p, previous, B)
            previous = B
            values.append(2 * p.mean() - 1)
        out.append(np.array(values))
    return out


def preisach_weights(family):
    """Hysteron weights of a grid family (n × n, rows H_r, NaN below the diagonal): w[b, a] (b < a ≤ n)
    is the weight of hysterons switching down at grid field b and up at a (a = n: above the window),
    w[b, a] = ½(m[b, a] − m[b+1, a] − m[b, a−1] + m[b+1, a−1]) with m(H_r, H < H_r) = m(H_r, H_r),
    w[b, n] = −½(m[b, n−1] − m[b+1, n−1]); and the reversible remainder M_rev(j) = m[j, j] +
    2 Σ_{b ≥ j} Σ_{a > j} w[b, a]. Then m[i, j] = M_rev(j) − 2 Σ_{b ≥ i, a > j} w[b, a] exactly."""
    m = np.asarray(family, float).copy()
    n = m.shape[0]
    for i in range(n):
        m[i, :i] = m[i, i]
    w = np.zeros((n, n + 1))
    for b in range(n - 1):
        d = m[b] - m[b + 1]  # row difference at every field (filled below the diagonal)
        w[b, b + 1:n] = 0.5 * (d[b + 1:] - d[b:n - 1])
        w[b, n] = -0.5 * d[n - 1]
    cum = np.cumsum(w[::-1, ::-1], axis=0)[::-1, ::-1]  # sum over b' >= b
    tail = np.cumsum(cum[:, ::-1], axis=1)[:, ::-1]  # tail[b, a] = sum over b' >= b, a' >= a
    reversible = np.array([m[j, j] + 2 * tail[j, j + 1] for j in range(n)])
    return w, reversible


def coercivity_scaled_family(family, fields, epsilon: float) -> np.ndarray:
    """The grid family (n × n, rows H_r, NaN below the diagonal, on the uniform ``fields``) with every
    hysteron's coercivity reduced by the factor 1 − ε at fixed bias (module docstring): the weights
    of ``preisach_weights`` move from (β, α) to (u − (1 − ε)c, u + (1 − ε)c), u = (α + β)/2,
    c = (α − β)/2, each spread linearly over one grid step, and are summed again with the reversible
    remainder unchanged. ε = 0 returns the family. NaN where ``family`` is NaN."""
    family = np.asarray(family, float)
    fields = np.asarray(fields, float)
    if not 0 <= epsilon < 1:
        raise ValueError(f"epsilon must be in [0, 1), got {epsilon}")
    n = fields.size
    step = fields[1] - fields[0]
    w, reversible = preisach_weights(family)
    b, a = np.nonzero(w)
    weight = w[b, a]
    beta = fields[b]
    alpha = np.where(a < n, fields[np.minimum(a, n - 1)], fields[-1] + step)
    u, c = (alpha + beta) / 2, (1 - epsilon) * (alpha - beta) / 2
    beta, alpha = u - c, u + c
    down = np.clip((beta[None, :] - fields[:, None]) / step + 1, 0, 1)  # [β' ≥ H_r], softened
    up = np.clip((alpha[None, :] - fields[:, None]) / step, 0, 1)  # [α' > H], softened
    out = reversible[None, :] - 2 * (down * weight[None, :]) @ up.T
    return np.where(np.isfinite(family), out, np.nan)


def activation_volume_m3(epsilon: float, K_eff_J_per_m3: float, temperature_K: float = 300.0, time_s: float = 1.0,
                         f0_Hz: float = ATTEMPT_FREQUENCY_HZ) -> float:
    """V = k_BT ln(f0 t/ln 2)/(K_eff ε²) (m³): the activation volume a Sharrock reduction ε implies."""
    if epsilon <= 0 or K_eff_J_per_m3 <= 0:
        return float("inf")
    return float(K_B * temperature_K * np.log(f0_Hz * time_s / np.log(2)) / (K_eff_J_per_m3 * epsilon**2))


__all__ = ["ATTEMPT_FREQUENCY_HZ", "K_B", "ParticleEnsemble", "activation_volume_m3", "arrhenius_family",
           "coercivity_scaled_family", "ramp_switching_field", "sharrock_epsilon", "sharrock_switching_field"]
