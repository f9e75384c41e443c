"""The informative film's FORC family: its cost per prior draw, and a faster minimizer checked
against the reference on the same draws (issue 62 item 1).

For each of the first ``draws`` dataset draws of the main config's prior class that pass the laptop
screening (the Hamiltonians the main job would simulate), on the film of ``information_films.FILMS`` (default ``box128_8nm``:
128 × 128 × 2 cells of 2 × 2 × 4 nm, 64 grains), one disorder realisation, three families:

- **reference**: the film's configured protocol as the information map ran it (float64 fields,
  the diagonal preconditioner, the config's torque criterion);
- **candidate**: the same protocol with other minimizer settings (default: the Fourier
  preconditioner P = D^{1/2} F D^{1/2}, ``micromag.minimize.minimize_bb_fourier``);
- **floor**: the reference again from an initial state perturbed by 1e-9 per component. A film
  whose reversal is chaotic (labyrinth domains: D above D_c = 4√(A K_eff)/π) ends a sweep in other
  metastable states after such a perturbation, so no minimizer can reproduce the reference there
  closer than the reference reproduces itself.

A candidate passes on a draw when its image agrees with the reference (mean |Δm| of the 8-bit image
in m units ≤ ``MEAN_TOL_M``, 99th percentile of |Δ grey level| ≤ ``P99_TOL_LEVELS``, and the
descending branch crossing m_z = 0 in the same field interval), or, where the reference does not
reproduce itself (the floor fails the same test), when its distances are within the floor's.
CPU seconds are this process's (``time.process_time``), compilation excluded (one warm-up family
on a small film first).
"""

from __future__ import annotations

import time

import numpy as np

from ..config import load_config, shipped_config
from ..core.streams import stream_rng
from ..forc.protocol import quasistatic_family
from ..forc.raster import rasterize_grid_family
from ..micromag.build import build_film, sweep_options
from .films import film_config, pick_hamiltonians
from .information_films import FILMS

MEAN_TOL_M = 0.003
"""Largest mean |Δ image| (m_z units, one grey level = 2/255) a speed-up may cause (issue 62)."""
P99_TOL_LEVELS = 1
"""Largest 99th percentile of |Δ grey level| a speed-up may cause (issue 62)."""
PERTURBATION = 1e-9
"""Size of the initial-state perturbation of the floor family (per component, then renormalized)."""
CANDIDATE = {"preconditioner": "fourier"}
"""Default candidate: the Fourier-preconditioned Barzilai–Borwein minimizer."""


def switching_interval(descending_mz: np.ndarray) -> int:
    """Index of the first field interval in which the descending branch (fields increasing, from
    negative saturation upwards in the protocol's grid order) changes sign of m_z; −1 if none."""
    signs = np.sign(np.asarray(descending_mz, dtype=float))
    change = np.flatnonzero(signs[1:] != signs[:-1])
    return int(change[0]) if change.size else -1


def image_distance(curves_a: np.ndarray, curves_b: np.ndarray) -> dict:
    """Distances between two families' 8-bit images: mean |Δ| in m units, the 99th percentile and the
    largest |Δ grey level|."""
    levels = np.abs(rasterize_grid_family(curves_a).astype(int) - rasterize_grid_family(curves_b).astype(int))
    return {"image_mean_abs_m": float(levels.mean() * 2.0 / 255.0),
            "image_p99_levels": float(np.percentile(levels, 99)), "image_max_levels": int(levels.max())}


def _agrees(distance: dict, same_switching: bool) -> bool:
    return (distance["image_mean_abs_m"] <= MEAN_TOL_M and distance["image_p99_levels"] <= P99_TOL_LEVELS
            and same_switching)


def _family(cfg: dict, params: dict, rng_key: tuple, options: dict, perturb: float = 0.0) -> dict:
    """One family of ``params`` on the film of ``cfg`` with minimizer ``options`` (``preconditioner``;
    the rest override ``sweep_options``); CPU seconds, relaxations, iterations, curves."""
    film, m0, _ = build_film(cfg, params, rng=stream_rng(cfg["seed"], *rng_key))
    options = dict(options)
    film.preconditioner = options.pop("preconditioner", film.preconditioner)
    if perturb > 0.0:
        noise = stream_rng(cfg["seed"], "bench_film", "perturbation", *rng_key[2:]).standard_normal(m0.shape)
        m0 = m0 + perturb * noise
        m0 /= np.sqrt((m0 * m0).sum(axis=0))
    cpu = time.process_time()
    family = quasistatic_family(film, m0, n_fields=cfg["field"]["n_fields"], B_max_T=cfg["field"]["B_max_T"],
                                **{**sweep_options(cfg), **options})
    return {"cpu_s": time.process_time() - cpu, "relaxations": int(family.stats["relaxations"]),
            "iterations": int(family.stats["iterations"]), "unconverged": int(family.stats.get("unconverged", 0)),
            "curves": family.curves_mz, "switching": switching_interval(family.descending_mz)}


def _warm_up(base_cfg: dict, candidate: dict) -> None:
    """Compile both minimizers on the small laptop film, outside every timing."""
    cfg = film_config(base_cfg, "laptop", FILMS)
    cfg["field"] = {**cfg["field"], "n_fields": 4}
    params = pick_hamiltonians(cfg, 1, prior=cfg.get("prior"))[0]
    for options in ({}, candidate):
        _family(cfg, _hamiltonian(params), ("bench_film", "film_family", "warm_up"), options)


def _hamiltonian(row: dict) -> dict:
    return {k: v for k, v in row.items() if k != "sample_id"}


def check_draw(cfg: dict, film: str, row: dict, candidate: dict, with_floor: str = "auto") -> dict:
    """Reference, candidate and (``with_floor``: "always", "auto" = only where the candidate misses
    the absolute tolerances, "never") floor families of one draw, their costs and the verdict."""
    key = ("bench_film", "film_family", film, int(row["sample_id"]))
    params = _hamiltonian(row)
    reference = _family(cfg, params, key, {})
    trial = _family(cfg, params, key, candidate)
    distance = image_distance(trial["curves"], reference["curves"])
    same = trial["switching"] == reference["switching"]
    out = {"sample_id": int(row["sample_id"]), "params": params,
           "reference": {k: v for k, v in reference.items() if k != "curves"},
           "candidate": {k: v for k, v in trial.items() if k != "curves"},
           "candidate_vs_reference": {**distance, "same_switching_interval": same},
           "within_tolerance": _agrees(distance, same)}
    passed = out["within_tolerance"]
    if with_floor == "always" or (with_floor == "auto" and not passed):
        floor = _family(cfg, params, key, {}, perturb=PERTURBATION)
        floor_distance = image_distance(floor["curves"], reference["curves"])
        floor_same = floor["switching"] == reference["switching"]
        out["floor"] = {k: v for k, v in floor.items() if k != "curves"}
        out["floor_vs_reference"] = {**floor_distance, "same_switching_interval": floor_same}
        out["reference_reproducible"] = _agrees(floor_distance, floor_same)
        if not passed and not out["reference_reproducible"]:
            passed = (distance["image_mean_abs_m"] <= max(MEAN_TOL_M, floor_distance["image_mean_abs_m"])
                      and distance["image_p99_levels"] <= max(P99_TOL_LEVELS, floor_distance["image_p99_levels"]))
    out["passed"] = bool(passed)
    return out


def film_family_check(draws: int = 8, film: str = "box128_8nm", candidate: dict | None = None,
                      with_floor: str = "auto", say=print) -> dict:
    """The check of ``candidate`` against the reference on the first ``draws`` screened draws of the
    main config on ``film``; the mean CPU seconds per family of each (the main job's cost per draw)."""
    candidate = dict(CANDIDATE if candidate is None else candidate)
    base = load_config(shipped_config("config"))
    cfg = film_config(base, film, FILMS)
    _warm_up(base, candidate)
    rows = []
    for row in pick_hamiltonians(base, draws, prior=base.get("prior")):
        result = check_draw(cfg, film, row, candidate, with_floor)
        rows.append(result)
        say(draw_line(result))
    reference_s = [r["reference"]["cpu_s"] for r in rows]
    candidate_s = [r["candidate"]["cpu_s"] for r in rows]
    return {"film": film, "draws": rows, "candidate_options": candidate,
            "reference_family_mean_s": float(np.mean(reference_s)),
            "candidate_family_mean_s": float(np.mean(candidate_s)),
            "reference_family_median_s": float(np.median(reference_s)),
            "candidate_family_median_s": float(np.median(candidate_s)),
            "speedup_of_mean": float(np.mean(reference_s) / np.mean(candidate_s)),
            "passed": int(sum(r["passed"] for r in rows)), "n": len(rows),
            "tolerances": {"image_mean_abs_m": MEAN_TOL_M, "image_p99_levels": P99_TOL_LEVELS}}


def draw_line(result: dict) -> str:
    """One printed line per draw: costs, distances, verdict."""
    ref, cand, dist = result["reference"], result["candidate"], result["candidate_vs_reference"]
    text = (f"draw {result['sample_id']}: reference {ref['cpu_s']:.1f} CPU-s ({ref['iterations']} iterations, "
            f"{ref['relaxations']} relaxations), candidate {cand['cpu_s']:.1f} CPU-s ({cand['iterations']} iterations); "
            f"image mean {dist['image_mean_abs_m']:.4f} m, p99 {dist['image_p99_levels']:.0f} levels, "
            f"switching {'same' if dist['same_switching_interval'] else 'moved'}")
    if "floor_vs_reference" in result:
        fl = result["floor_vs_reference"]
        text += (f"; floor (1e-9 perturbation) mean {fl['image_mean_abs_m']:.4f} m, p99 {fl['image_p99_levels']:.0f}, "
                 f"switching {'same' if fl['same_switching_interval'] else 'moved'}")
    return text + (" -> pass" if result["passed"] else " -> FAIL")


def summary_line(report: dict) -> str:
    return (f"[film {report['film']}] {report['n']} draws: family mean {report['reference_family_mean_s']:.1f} CPU-s "
            f"(reference) -> {report['candidate_family_mean_s']:.1f} CPU-s (candidate {report['candidate_options']}), "
            f"{report['speedup_of_mean']:.2f}x; medians {report['reference_family_median_s']:.1f} -> "
            f"{report['candidate_family_median_s']:.1f}; check passed on {report['passed']}/{report['n']}")


__all__ = ["film_family_check", "check_draw", "image_distance", "switching_interval", "summary_line", "MEAN_TOL_M",
           "P99_TOL_LEVELS"]
