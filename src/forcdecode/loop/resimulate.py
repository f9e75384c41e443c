"""Re-simulation of a (predicted) Hamiltonian and the observation-space error.

``simulate_family`` runs the dataset's FORC protocol (``cfg["protocol"]["name"]``: quasi-static
energy minimization, or the seed paper's adaptive slew-rate LLG with slaved pinning cells, as
``dataset.simulate`` runs it) for given parameters on one disorder realisation drawn from a given
generator. ``resimulate`` averages it over several disorder profiles (same N_pin, σ_θ, σ_K; new
grains and pinning sites), as the seed paper does for measured data. ``observation_error`` is the
RMS difference of ⟨m_z⟩ over every FORC point the two families share (H ≥ H_r), and per curve.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.streams import stream_rng
from ..forc.adaptive import SlewRate, adaptive_family
from ..forc.protocol import quasistatic_family
from ..micromag.build import build_film

DISORDER_STREAM = "closed_loop_disorder"
"""Named stream of every re-simulation's disorder (keys: sample id or a label, realisation); never a
dataset sample's own disorder stream."""


def protocol_name(cfg: dict) -> str:
    """The dataset's FORC protocol: "quasistatic" (default) or "llg"."""
    name = cfg.get("protocol", {}).get("name", "quasistatic")
    if name not in ("quasistatic", "llg"):
        raise ConfigError(f"unknown FORC protocol {name!r} (quasistatic or llg)")
    return name


def simulate_family(cfg: dict, params: dict, rng: np.random.Generator) -> np.ndarray:
    """One FORC family of ``params`` (SI) on the config's field grid, disorder drawn from ``rng``, with
    the dataset's protocol: ⟨m_z⟩ (n_fields × n_fields, row = reversal field, NaN below the diagonal)."""
    n_fields, B_max_T = cfg["field"]["n_fields"], cfg["field"]["B_max_T"]
    if protocol_name(cfg) == "llg":
        p = cfg["protocol"]
        film, m0, _ = build_film(cfg, params, rng=rng, pinning="slaved")
        settings = SlewRate(alpha=p["alpha"], safety=p["safety"], rate_min_T_per_s=p["rate_min_T_per_s"],
                            rate_max_T_per_s=p["rate_max_T_per_s"])
        family = adaptive_family(film, m0, n_fields=n_fields, B_max_T=B_max_T, settings=settings)
    else:
        film, m0, _ = build_film(cfg, params, rng=rng)
        family = quasistatic_family(film, m0, n_fields=n_fields, B_max_T=B_max_T,
                                    torque_tol_T=cfg["minimizer"]["torque_tol_T"],
                                    max_iterations=cfg["minimizer"]["max_iterations"])
    return family.curves_mz


def resimulate(cfg: dict, params: dict, n_profiles: int = 1, first_profile: int = 0, progress=None,
               key: int | str = "measured") -> np.ndarray:
    """Grid family (n_fields × n_fields, NaN below the diagonal) averaged over ``n_profiles``
    disorder profiles; profile p draws its disorder from stream ``closed_loop_disorder`` with keys
    (``key``, ``first_profile + p``) of the config seed."""
    if n_profiles < 1:
        raise ValueError("n_profiles must be >= 1")
    total = None
    for p in range(n_profiles):
        curves = simulate_family(cfg, params, stream_rng(cfg["seed"], DISORDER_STREAM, key, first_profile + p))
        total = curves if total is None else total + curves
        if progress is not None:
            progress(p + 1, n_profiles)
    return total / n_profiles


def observation_error(reference: np.ndarray, candidate: np.ndarray) -> dict:
    """RMS of ⟨m_z⟩ differences over all shared FORC points, and per curve (rows)."""
    reference = np.asarray(reference, dtype=float)
    candidate = np.asarray(candidate, dtype=float)
    if reference.shape != candidate.shape:
        raise ValueError(f"families have shapes {reference.shape} and {candidate.shape}")
    shared = np.isfinite(reference) & np.isfinite(candidate)
    if not shared.any():
        raise ValueError("the families share no FORC point")
    diff = np.where(shared, candidate - reference, 0.0)
    counts = shared.sum(axis=1)
    per_curve = np.where(counts > 0, np.sqrt((diff**2).sum(axis=1) / np.maximum(counts, 1)), np.nan)
    return {"rms": float(np.sqrt((diff[shared] ** 2).mean())), "per_curve": per_curve, "n_points": int(shared.sum())}
