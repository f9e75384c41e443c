"""FORCs by LLG with the seed paper's adaptive slew rate.

1. τ_z,max: saturate at −B_max, switch the field to +B_max at once and integrate LLG until ⟨m_z⟩
   crosses 0; the rate |d⟨m_z⟩/dt| there is τ_z,max. The effective damping α′ follows from
   τ_z = γ α′/(1 + α′²) μ0H_eff,z (1 − m_z²) at m_z = 0 (reported; the smaller root).
2. Sweeps: dH/dt = safety · τ_z,max / χ_zz (safety 0.05), χ_zz = |d⟨m_z⟩/d(μ0H)| from a line
   through the last three recorded points, clipped to [rate_min, rate_max]. A point (μ0H, ⟨m_z⟩) is
   recorded, and the rate re-evaluated, whenever μ0H has moved ``field_step_T`` (0.02 T) or ⟨m_z⟩
   ``mz_step`` (0.05) since the last record (checked every tenth of the field step).
3. Family: descend from +B_max keeping the state at every grid field; each FORC starts from the
   state at its reversal field and sweeps up; a curve whose state equals the descending state at a
   grid field continues as that FORC (remainder shared), so curves that rejoin saturation stop.

Pinning cells should be ``slaved`` here (no THz precession to limit the step).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..micromag.constants import GAMMA_LL
from ..micromag.film import Film, SimulationError
from .protocol import ForcFamily
from .raster import resample_curves


@dataclass
class SlewRate:
    alpha: float = 0.1
    safety: float = 0.05
    field_step_T: float = 0.02
    mz_step: float = 0.05
    rate_min_T_per_s: float = 1e7
    rate_max_T_per_s: float = 1e9
    llg_tol: float = 1e-5
    probe_max_s: float = 5e-9
    same_state_tol: float = 0.02


def estimate_tau_max(film: Film, m0: np.ndarray, B_max_T: float, settings: SlewRate, stats: dict):
    """τ_z,max (1/s) and α′ from the −B_max → +B_max switching experiment."""
    m = -np.array(m0, dtype=np.float64, order="C")
    film.minimize(m, -B_max_T, torque_tol_T=1e-3)
    t, chunk = 0.0, 2e-12
    previous = (0.0, m[2].mean())
    while t < settings.probe_max_s:
        run = film.run_llg(m, chunk, B_max_T, alpha=settings.alpha, tol=settings.llg_tol)
        stats["llg_steps"] += run.accepted_steps + run.rejected_steps
        t += chunk
        mz = m[2].mean()
        if mz >= 0.0:
            rate = (mz - previous[1]) / (t - previous[0])
            B_z = film.effective_field(m, B_max_T)[2].mean()
            c = rate / (GAMMA_LL * max(B_z, 1e-3))
            alpha_prime = 1.0 if c >= 0.5 else (1 - np.sqrt(1 - 4 * c * c)) / (2 * c)
            return float(rate), float(alpha_prime), False
        previous = (t, mz)
    # no switching within the probe time: fall back to the macrospin estimate
    rate = GAMMA_LL * settings.alpha / (1 + settings.alpha**2) * B_max_T
    return float(rate), settings.alpha, True


@dataclass(frozen=True)
class Ramp:
    """What every adaptive sweep of one family shares: the ``film``, the slew-rate ``settings``, the
    switching rate ``tau_max`` (τ_z,max, 1/s: |d⟨m_z⟩/dt| at ⟨m_z⟩ = 0 in the probe experiment) that
    sets the rate dH/dt = safety·τ_z,max/χ_zz (T/s), and ``stats`` (a dict whose ``llg_steps`` counts
    the LLG steps, or None)."""

    film: Film
    settings: SlewRate
    tau_max: float
    stats: dict | None = None


def sweep(ramp: Ramp, m, B_from, B_to, grid, on_grid=None):
    """Ramp μ0H from ``B_from`` to ``B_to`` (T) with the adaptive rate; returns recorded (fields, m_z).

    ``on_grid(index, B, m)`` is called at every grid field passed (sub-steps end exactly there); if it
    returns True the sweep stops.
    """
    film, settings, tau_max, stats = ramp.film, ramp.settings, ramp.tau_max, ramp.stats
    direction = 1.0 if B_to > B_from else -1.0
    B = B_from
    fields, mzs = [B], [m[2].mean()]
    last_B, last_mz = B, mzs[0]
    rate = np.clip(settings.safety * tau_max / 1.0, settings.rate_min_T_per_s, settings.rate_max_T_per_s)
    sub = settings.field_step_T / 10
    targets = [(k, g) for k, g in enumerate(grid) if (g - B) * direction > 1e-12 and (B_to - g) * direction >= -1e-12]
    targets.sort(key=lambda kg: kg[1] * direction)
    next_target = 0
    while (B_to - B) * direction > 1e-12:
        step = min(sub, abs(B_to - B))
        hit = None
        if next_target < len(targets) and abs(targets[next_target][1] - B) <= step + 1e-12:
            step = abs(targets[next_target][1] - B)
            hit = targets[next_target]
            next_target += 1
        if step > 0:
            run = film.run_llg(m, step / rate, B, alpha=settings.alpha, ramp_T_per_s=direction * rate,
                               tol=settings.llg_tol)
            if stats is not None:
                stats["llg_steps"] += run.accepted_steps + run.rejected_steps
            if not run.ok:
                raise SimulationError(f"LLG failed during the sweep at {B:+.3f} T")
        B = hit[1] if hit is not None else B + direction * step
        mz = m[2].mean()
        if not np.isfinite(mz):
            raise SimulationError(f"non-finite magnetization at {B:+.3f} T")
        if abs(B - last_B) >= settings.field_step_T - 1e-12 or abs(mz - last_mz) >= settings.mz_step or hit is not None:
            fields.append(B)
            mzs.append(mz)
            last_B, last_mz = B, mz
            if len(fields) >= 3:
                chi = abs(np.polyfit(fields[-3:], mzs[-3:], 1)[0])
                rate = np.clip(settings.safety * tau_max / max(chi, 1e-12), settings.rate_min_T_per_s,
                               settings.rate_max_T_per_s)
        if hit is not None and on_grid is not None and on_grid(hit[0], B, m):
            break
    return np.array(fields), np.array(mzs)


def adaptive_family(film: Film, m0: np.ndarray, n_fields: int = 64, B_max_T: float = 1.0,
                    settings: SlewRate | None = None, progress=None) -> ForcFamily:
    """A FORC family with the adaptive-slew-rate LLG protocol; curves resampled onto the grid."""
    settings = settings or SlewRate()
    start = time.perf_counter()
    stats = {"llg_steps": 0, "curves_shortened": 0}
    tau_max, alpha_prime, fallback = estimate_tau_max(film, m0, B_max_T, settings, stats)
    stats.update(tau_z_max_per_s=tau_max, alpha_prime=alpha_prime, tau_fallback=fallback)
    grid = np.linspace(-B_max_T, B_max_T, n_fields)
    m = np.array(m0, dtype=np.float64, order="C", copy=True)
    film.minimize(m, B_max_T, torque_tol_T=1e-4)
    states = np.empty((n_fields,) + m.shape)
    states[-1] = m

    def keep(index, B, state):
        states[index] = state
        return False

    ramp = Ramp(film, settings, tau_max, stats)
    desc_fields, desc_mz = sweep(ramp, m, B_max_T, -B_max_T, grid, keep)
    raw = [None] * n_fields
    raw[-1] = (np.array([B_max_T]), np.array([states[-1][2].mean()]))
    for i in range(n_fields - 2, -1, -1):
        m[...] = states[i]
        joined = {}

        def check(index, B, state, joined=joined):
            if index > i and np.abs(state - states[index]).max() < settings.same_state_tol and raw[index] is not None:
                joined["index"] = index
                return True
            return False

        fields, mzs = sweep(ramp, m, grid[i], B_max_T, grid, check)
        if "index" in joined:
            tail_fields, tail_mz = raw[joined["index"]]
            keep_tail = tail_fields > fields[-1] + 1e-12
            fields = np.concatenate([fields, tail_fields[keep_tail]])
            mzs = np.concatenate([mzs, tail_mz[keep_tail]])
            stats["curves_shortened"] += 1
        raw[i] = (fields, mzs)
        if progress is not None:
            progress(n_fields - i, n_fields)
    curves = resample_curves(grid, raw, B_max_T, n_fields)
    stats["wall_s"] = time.perf_counter() - start
    stats["raw_points"] = int(sum(len(f) for f, _ in raw))
    family = ForcFamily(grid, curves, np.diag(curves).copy(), stats)
    family.raw_curves = raw
    family.raw_descending = (desc_fields, desc_mz)
    return family
