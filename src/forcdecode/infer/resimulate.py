"""Re-simulation of a (predicted) Hamiltonian and the observation-space error.

``simulate_family`` runs the dataset's FORC protocol (``cfg["protocol"]["name"]``: quasi-static
energy minimization, or the seed paper's adaptive slew-rate LLG with slaved pinning cells, as
``dataset.simulate`` runs it) for given parameters on one disorder realisation drawn from a given
generator. ``resimulate`` averages it over several disorder profiles (same N_pin, σ_θ, σ_K; new
grains and pinning sites), as the seed paper does for measured data (``resimulate_with_spread`` also
returns the variance between profiles). ``simulate_measured``/``resimulate_measured`` run a measured
file's own protocol (its reversal fields and field points, ``forc.measured_protocol``), and a
parameter ``field_tilt_deg`` applies the field at that angle from the normal (a misaligned sample).
``observation_error`` is the RMS difference of ⟨m_z⟩ over every FORC point the two families share
(H ≥ H_r), and per curve.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.errors import ConfigError
from ..core.parallel import map_in_order, using_workers
from ..core.streams import stream_rng
from ..forc.measured_protocol import field_direction, grid_protocol, measured_protocol_family, protocol_to_grid
from ..forc.simulate import protocol_name, simulate_family as simulate_grid_family
from ..micromag.build import build_film, sweep_options

DISORDER_STREAM = "closed_loop_disorder"
"""Named stream of every re-simulation's disorder (keys: sample id or a label, realisation); never a
dataset sample's own disorder stream."""


def _tilt(params: dict) -> float:
    """The applied field's tilt from the film normal (degrees, ``params["field_tilt_deg"]``; 0 if absent)."""
    value = params.get("field_tilt_deg", 0.0)
    return 0.0 if value is None or not np.isfinite(value) else float(value)


def simulate_family(cfg: dict, params: dict, rng: np.random.Generator) -> np.ndarray:
    """One FORC family of ``params`` (SI) on the config's field grid, disorder drawn from ``rng``, with
    the dataset's protocol: ⟨m_z⟩ (n_fields × n_fields, row = reversal field, NaN below the diagonal).
    With ``params["field_tilt_deg"]`` ≠ 0 (a misaligned sample, quasi-static protocol only) the field
    is applied at that angle from the normal and ⟨m⟩·ĥ is recorded (``forc.measured_protocol``)."""
    n_fields, B_max_T = cfg["field"]["n_fields"], cfg["field"]["B_max_T"]
    if _tilt(params) != 0.0:
        reversal, fields = grid_protocol(n_fields, B_max_T)
        return protocol_to_grid(simulate_measured(cfg, params, rng, reversal, fields), n_fields)
    return simulate_grid_family(cfg, params, rng=rng).curves_mz


def grid_single(cfg: dict, params: dict, key: int | str, profile: int) -> np.ndarray:
    """One grid family of ``params`` on disorder profile ``profile`` of ``key`` (stream
    ``closed_loop_disorder``, keys (``key``, ``profile``) of the config seed): a module-level worker of
    ``core.parallel.map_in_order``."""
    return simulate_family(cfg, params, stream_rng(cfg["seed"], DISORDER_STREAM, key, profile))


def _profiles(cfg: dict, params: dict, n_profiles: int, first_profile: int, key, progress) -> list:
    """The grid families of profiles ``first_profile`` … ``first_profile + n_profiles − 1``, in order (on
    the active ``core.parallel`` workers, if any)."""
    if n_profiles < 1:
        raise ValueError("n_profiles must be >= 1")
    return map_in_order(grid_single, [(cfg, params, key, first_profile + p) for p in range(n_profiles)],
                        progress=progress)


def resimulate(cfg: dict, params: dict, n_profiles: int = 1, first_profile: int = 0, progress=None,
               key: int | str = "measured") -> np.ndarray:
    """Grid family (n_fields × n_fields, NaN below the diagonal) averaged over ``n_profiles``
    disorder profiles; profile p draws its disorder from stream ``closed_loop_disorder`` with keys
    (``key``, ``first_profile + p``) of the config seed."""
    total = None
    for curves in _profiles(cfg, params, n_profiles, first_profile, key, progress):
        total = curves if total is None else total + curves
    return total / n_profiles


def resimulate_with_spread(cfg: dict, params: dict, n_profiles: int = 2, first_profile: int = 0, progress=None,
                           key: int | str = "measured") -> tuple[np.ndarray, np.ndarray]:
    """``resimulate`` (same streams, same mean) and the variance of m between the profiles at every
    point (ddof 1; zeros for one profile): the disorder floor of an observation error."""
    total = squares = None
    for curves in _profiles(cfg, params, n_profiles, first_profile, key, progress):
        total = curves if total is None else total + curves
        squares = curves**2 if squares is None else squares + curves**2
    mean = total / n_profiles
    variance = (squares - n_profiles * mean**2) / (n_profiles - 1) if n_profiles > 1 else np.zeros_like(mean)
    return mean, np.clip(variance, 0, None)


def simulate_measured(cfg: dict, params: dict, rng: np.random.Generator, reversal_fields_T, curve_fields_T,
                      max_step_T: float | None = None, field_tol_T: float = 1e-12):
    """One family of ``params`` on a measured protocol (``forc.measured_protocol``: the file's reversal
    fields and per-curve fields in measurement order), disorder from ``rng``, field tilted by
    ``params["field_tilt_deg"]``. Returns a ``ProtocolFamily`` (⟨m⟩·ĥ at every point). The
    quasi-static protocol only: ConfigError for "llg"."""
    if protocol_name(cfg) != "quasistatic":
        raise ConfigError("the measured protocol is re-simulated quasi-statically only (protocol: quasistatic)")
    film, m0, _ = build_film(cfg, params, rng=rng)
    options = sweep_options(cfg)
    return measured_protocol_family(film, m0, reversal_fields_T, curve_fields_T,
                                    direction=field_direction(_tilt(params)),
                                    torque_tol_T=options["torque_tol_T"], max_iterations=options["max_iterations"],
                                    same_state_tol=options["same_state_tol"], merge_curves=options["merge_curves"],
                                    merge_memory_MB=options["merge_memory_MB"], max_step_T=max_step_T,
                                    field_tol_T=field_tol_T)


@dataclass(frozen=True)
class DisorderProfiles:
    """Which disorder profiles a re-simulation averages: ``n_profiles`` profiles (≥ 1) from ``first_profile``
    on, of the stream ``closed_loop_disorder`` under ``key`` (the streams of ``resimulate``)."""

    n_profiles: int = 1
    first_profile: int = 0
    key: int | str = "measured"


def resimulate_measured(cfg: dict, params: dict, reversal_fields_T, curve_fields_T,
                        profiles: DisorderProfiles | None = None, *, max_step_T: float | None = None, progress=None,
                        **profile_options) -> list:
    """``simulate_measured`` averaged over the disorder ``profiles`` (a ``DisorderProfiles``, its defaults where
    None; keyword ``profile_options`` set single fields: ``n_profiles``, ``first_profile``, ``key``) — the same
    disorder as the grid re-simulation of the same key. ``max_step_T``: the sweep's largest field step (T; None:
    the protocol's own fields); ``progress(done, total)``: per profile. Returns per curve the mean ⟨m⟩·ĥ at its
    fields (input order)."""
    profiles = replace(profiles or DisorderProfiles(), **profile_options)
    n_profiles, first_profile, key = profiles.n_profiles, profiles.first_profile, profiles.key
    if n_profiles < 1:
        raise ValueError("n_profiles must be >= 1")
    families = map_in_order(measured_single, [(cfg, params, key, first_profile + p, reversal_fields_T, curve_fields_T,
                                               max_step_T) for p in range(n_profiles)], progress=progress)
    total = None
    for family in families:
        total = family.curves if total is None else [a + b for a, b in zip(total, family.curves)]
    return [c / n_profiles for c in total]


def measured_single(cfg: dict, params: dict, key: int | str, profile: int, reversal_fields_T, curve_fields_T,
                    max_step_T: float | None = None):
    """``simulate_measured`` on disorder profile ``profile`` of ``key`` (the streams of ``grid_single``):
    a module-level worker of ``core.parallel.map_in_order``."""
    return simulate_measured(cfg, params, stream_rng(cfg["seed"], DISORDER_STREAM, key, profile), reversal_fields_T,
                             curve_fields_T, max_step_T=max_step_T)


def major_loop_branches(cfg: dict, params: dict, top_T: float, step_T: float = 0.01, n_profiles: int = 1,
                        key: int | str = "major_loop") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The major hysteresis loop of ``params``: the descending branch from saturation at +``top_T`` and
    the ascending branch from −``top_T``, both at the fields of one lattice of ``step_T`` (T) over
    ±``top_T`` (the measured protocol with every lattice field a reversal point and the lowest curve
    swept back up: ``resimulate_measured``), ⟨m⟩·ĥ averaged over ``n_profiles`` disorder profiles
    (streams of ``resimulate`` under ``key``). Returns (fields ascending, descending m, ascending m). Past the loop's closure the
    two branches coincide: the reversible, saturated film."""
    if not (top_T > 0 and step_T > 0):
        raise ValueError(f"top_T and step_T must be > 0 (got {top_T!r}, {step_T!r})")
    count = int(np.ceil(top_T / step_T))
    fields = np.round(np.linspace(-count * step_T, count * step_T, 2 * count + 1), 12)
    reversal = fields[::-1].copy()
    # every curve but the last is its reversal point alone (a point of the descending branch); the last,
    # reversed at −top_T, is swept back up
    curves = resimulate_measured(cfg, params, reversal, [np.array([h]) for h in reversal[:-1]] + [fields],
                                 n_profiles=n_profiles, key=key)
    descending = np.array([float(c[0]) for c in curves])[::-1]
    return fields, descending, np.asarray(curves[-1], float)


def _simulate_task(cfg: dict, params: dict, sample_id: int, realisation: int):
    """Worker: one family of ``params`` on realisation ``realisation`` of ``sample_id``'s disorder;
    (curves, "") or (None, reason): a failed or non-finite simulation is a result, not an exception."""
    try:
        rng = stream_rng(cfg["seed"], DISORDER_STREAM, int(sample_id), int(realisation))
        curves = simulate_family(cfg, params, rng)
    except Exception as error:  # recorded per task, never fatal for the stage
        return None, f"{type(error).__name__}: {error}"
    if not np.isfinite(np.diag(curves)).all():
        return None, "non-finite magnetization on the diagonal"
    return curves, ""


def run_tasks(cfg: dict, tasks: list, workers: int = 1, progress=None) -> list:
    """Run ``_simulate_task`` for each (params, sample_id, realisation) on ``workers`` processes
    (``core.parallel``: spawned, so a calling script needs the ``if __name__ == "__main__":`` guard; inside
    an open ``using_workers`` block its pool serves). Results in task order; the outcome does not depend
    on ``workers``."""
    if workers < 1:
        raise ValueError("workers must be >= 1")
    with using_workers(min(workers, max(len(tasks), 1))):
        return map_in_order(_simulate_task, [(cfg, *task) for task in tasks], progress=progress)


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
