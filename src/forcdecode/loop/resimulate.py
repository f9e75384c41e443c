"""Re-simulation of a (predicted) Hamiltonian and the observation-space error.

``resimulate`` runs the dataset's FORC protocol for given parameters, averaged over several
pinning-site profiles (different disorder seeds at the same N_pin, σ_θ, σ_K), as the seed paper does
for measured data. ``observation_error`` is the RMS difference of ⟨m_z⟩ over every FORC point the two
families share (H ≥ H_r), and per curve.
"""

from __future__ import annotations

import numpy as np

from ..dataset.simulate import build_film
from ..forc.protocol import quasistatic_family


def resimulate(cfg: dict, params: dict, n_profiles: int = 1, first_profile: int = 0, progress=None) -> np.ndarray:
    """Grid family (n_fields × n_fields, NaN below the diagonal) averaged over ``n_profiles``
    disorder profiles; profile p uses disorder stream ``1_000_000 + first_profile + p`` of the config
    seed (distinct from every dataset sample's stream)."""
    if n_profiles < 1:
        raise ValueError("n_profiles must be >= 1")
    total = None
    for p in range(n_profiles):
        film, m0, _ = build_film(cfg, params, 1_000_000 + first_profile + p)
        family = quasistatic_family(film, m0, n_fields=cfg["field"]["n_fields"], B_max_T=cfg["field"]["B_max_T"],
                                    torque_tol_T=cfg["minimizer"]["torque_tol_T"],
                                    max_iterations=cfg["minimizer"]["max_iterations"])
        total = family.curves_mz if total is None else total + family.curves_mz
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
