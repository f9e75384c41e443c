"""How many independent patches a measured family averages, read from the family's own steps, and the
effect-free films (null films) of the decoded Hamiltonian drawn at that number.

A FORC measurement averages the moment of the whole sample. A millimetre film averages millions of
independent patches of the size of our simulation box and its curves are smooth; a small element, or a
film with a handful of nucleation sites, averages a few, and each of its curves reverses in a few jumps.
The re-simulation averages ``profiles`` disorder realisations (20 by default), so it is smooth whatever
the file. How far a file may lie from that smooth mean without any effect (the realisation floor)
depends on the number of patches P the file averages: the variance between two P-patch films of one
Hamiltonian is v·(1/P + 1/profiles), v the variance between single realisations.

The estimate uses the family's **effective step height** (``step_height``): Σ Δm² / Σ |Δm| over the
increments Δm between successive grid fields of every curve (m in units of the saturation moment, so a
full reversal is 2). A curve that reverses in one jump gives the jump (≈ 2); P patches reversing apart
give ≈ 2/P; a smooth family gives its largest per-step change, which the grid and the film's
switching-field distribution set. Because that smooth limit depends on the Hamiltonian, the file's value
is compared with the same statistic of P-averages of single realisations of the decoded Hamiltonian
(disjoint groups of a pool of ``POOL_SIZE`` singles, the file's noise added), for P in
``PATCH_CHOICES``, and not with 2/P (``estimate_patches``). The floor is drawn at the smallest P the
file is consistent with (the most realisation noise it may hold: a bound, conservative for the
verdict), and the null films are P-averages of the pool (``null_films``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.streams import stream_rng
from ..forc.raster import measurement_on_grid
from ..core.parallel import map_in_order
from ..core.progress import counter
from ..infer.resimulate import grid_single, measured_single

PATCH_CHOICES = (1, 2, 4, 8)
"""Patch numbers the estimate tells apart; a family smoother than 8-patch averages of the decoded
Hamiltonian is reported as averaging "more than 8" and its floor drawn at 8 (conservative)."""

POOL_SIZE = 16
"""Single disorder realisations simulated for the estimate and the null films (two disjoint 8-patch
groups). Cost: 16 families of the decoded Hamiltonian (on the laptop film ≈ 30 s on one core)."""

NULL_FILMS = 6
"""Effect-free P-patch films whose gains make the default path's realisation floor; each is also
mirrored (``physics_effects.null_gains``), so the floor is the largest gain over 12 films: a candidate
gaining no more than effect-free films do passes with probability ≤ 1/13."""

CONSISTENCY_MARGIN = 1.25
"""A P is consistent with the file when the file's step height lies within the range of the P-groups'
values widened by this factor each way (the groups are few: 16/P of them)."""


def step_height(family) -> float:
    """The effective step height Σ Δm² / Σ |Δm| of a grid family (rows: reversal fields, columns: fields,
    NaN below the diagonal; m in units of the saturation moment), over the increments between successive
    fields along every curve. 0 for a family without increments."""
    family = np.asarray(family, float)
    increments = np.diff(family, axis=1)
    increments = increments[np.isfinite(increments)]
    total = float(np.sum(np.abs(increments)))
    return float(np.sum(increments**2) / total) if total > 0 else 0.0


def single_realisations(cfg: dict, params: dict, count: int = POOL_SIZE, key: str = "loop_null",
                        progress=None) -> list[np.ndarray]:
    """``count`` single-realisation grid families of ``params`` (SI), realisation k drawing its disorder
    from stream ``closed_loop_disorder`` with keys (``key``, k): independent of the re-simulation's own
    profiles (key "measured")."""
    return map_in_order(grid_single, [(cfg, params, key, k) for k in range(count)], progress=progress)


RASTERIZED_MAX_POINTS = 4000
"""Files of at most this many points get their pool simulated on their own protocol and put on the grid
as the file is (``rasterized_singles``); larger files (a real MicroMag file holds 10⁴–10⁵ points, whose
sweep would cost minutes per single) get grid singles, and the report says the rasterization is then
not in the floor."""


class _Pool(list):
    """A list of single realisations that counts those made on the grid instead (``fallbacks``) and, where
    they were simulated on the file's own protocol, keeps that simulation (``on_protocol``: per curve the
    mean ⟨m⟩·ĥ over every single at the file's points, in the simulation's units; ``protocol``: a dict with
    its ``params``, ``max_step_T`` and ``singles``), so that the report's residual at the measured points
    costs no second simulation of the same protocol (``measured_loop.measured_points_residual``)."""

    fallbacks = 0
    on_protocol = None
    protocol = None


PROBE_SINGLES = 2
"""Singles simulated on the file's protocol first (``rasterized_singles``): where none of them saturates in the
file's window, the rest of the pool goes to the grid at once. A decoded film harder than the sample does not
re-saturate where the file does, and its sweep of the file's protocol is slow (laptop bench dev 005: 24 s a
single, 13 of 16 not saturated, 6.4 min for the protocol and 3 min more for the grid stand-ins)."""


def _on_file_grid(data, family, moment_saturation_Am2, moment_offset_Am2, B_max, n):
    """A single simulated on the file's protocol, put on the training grid exactly as the file is, in the
    simulation's units (m = (M − M_0)/M_sat with the file's M_0 and M_sat); None where it does not saturate
    in the file's window (its own normalization would mean nothing)."""
    pseudo = replace(data, curves=[replace(c, moment_Am2=moment_offset_Am2 + moment_saturation_Am2 * np.asarray(v))
                                   for c, v in zip(data.curves, family.curves)])
    _, grid, note, saturation, domain = measurement_on_grid(pseudo, B_max, n, with_domain=True)
    if note is not None or not saturation > 0:
        return None
    return (grid * (saturation / moment_saturation_Am2)
            + (domain.moment_offset_Am2 - moment_offset_Am2) / moment_saturation_Am2)


def rasterized_singles(cfg: dict, params: dict, data, moment_saturation_Am2: float, moment_offset_Am2: float,
                       count: int = POOL_SIZE, key: str = "loop_null", max_step_T: float = 0.002,
                       progress=None, probe: int = PROBE_SINGLES) -> list[np.ndarray]:
    """``count`` single realisations of ``params`` simulated on the file's own protocol (``data``: its
    reversal fields and field points, swept on ``max_step_T`` nodes, ``infer.resimulate.simulate_measured``;
    disorder from stream ``closed_loop_disorder`` with keys (``key``, k), the same as ``single_realisations``)
    and put on the training grid exactly as the file is (``forc.raster.measurement_on_grid`` of the file
    with its moments replaced by M_0 + M_sat·m): an off-grid file's interpolation between its curves is
    then in the null films too. Measured on the example control (40 curves off the grid, 8 patches): the
    film on the grid and the file put on the grid differ by 0.075 RMS at the same disorder
    (``scripts/check_rasterization.py``). A realisation whose rasterization is out of the domain (it does
    not saturate in the file's window) is replaced by its grid family; the list's ``fallbacks`` counts
    them. The first ``probe`` singles are simulated on the protocol first: where none of them saturates,
    the others go to the grid without it (``PROBE_SINGLES``). Each family is returned in the simulation's
    units (m = (M − M_0)/M_sat with the file's M_0 and M_sat), not re-normalized by its own saturated
    branches."""
    B_max, n = cfg["field"]["B_max_T"], cfg["field"]["n_fields"]
    reversal = [float(c.reversal_field_T) for c in data.curves]
    fields = [np.concatenate([[h], np.asarray(c.field_T, float)[1:]]) if abs(float(c.field_T[0]) - h) < 1e-9
              else np.asarray(c.field_T, float) for h, c in zip(reversal, data.curves)]
    tasks = [(cfg, params, key, k, reversal, fields, max_step_T) for k in range(count)]
    # the probe, then the rest on the protocol unless no probe saturated in the file's window
    first = max(1, min(int(probe), count))
    families = map_in_order(measured_single, tasks[:first], progress=_offset_progress(progress, 0, count))
    on_grid = {k: g for k, g in enumerate(_on_file_grid(data, f, moment_saturation_Am2, moment_offset_Am2, B_max, n)
                                          for f in families) if g is not None}
    if on_grid:
        rest = map_in_order(measured_single, tasks[first:], progress=_offset_progress(progress, first, count))
        for k, family in enumerate(rest, start=first):
            grid = _on_file_grid(data, family, moment_saturation_Am2, moment_offset_Am2, B_max, n)
            if grid is not None:
                on_grid[k] = grid
        families += rest
    # a realisation that does not saturate in the file's window: the grid family of the same disorder stands
    # in (``fallbacks``), simulated on the workers as the rest
    missing = [k for k in range(count) if k not in on_grid]
    grids = map_in_order(grid_single, [(cfg, params, key, k) for k in missing],
                         progress=counter("singles on the grid (not saturated in the file's window)", "families")
                         if missing else None)
    on_grid.update(zip(missing, grids))
    singles = _Pool(on_grid[k] for k in range(count))
    singles.fallbacks = len(missing)
    singles.on_protocol = [np.mean([family.curves[i] for family in families], axis=0) for i in range(len(reversal))]
    singles.protocol = {"params": dict(params), "max_step_T": max_step_T, "singles": len(families)}
    return singles


def _offset_progress(progress, done_before: int, total: int):
    """``progress(done, total)`` of a whole made of batches: this batch's counts shifted by ``done_before``."""
    if progress is None:
        return None
    return lambda done, _total: progress(done_before + done, total)


@dataclass(frozen=True)
class PatchEstimate:
    """The file's effective step height, the same statistic over P-averages of the pool (per P: median,
    range), the P closest to the file (``estimate``; ``None`` when the file is smoother than every P),
    the P it is consistent with, and the P the floor is drawn at (``floor_patches``)."""

    step_height: float
    by_patches: dict
    estimate: int | None
    consistent: tuple
    floor_patches: int

    def label(self) -> str:
        """The estimate as the report prints it: "1", "2", …, or "more than 8"."""
        return str(self.estimate) if self.estimate is not None else f"more than {PATCH_CHOICES[-1]}"

    def report(self) -> dict:
        return {"step_height": self.step_height, "estimate": self.label(), "consistent": list(self.consistent),
                "floor_patches": self.floor_patches,
                "by_patches": {str(p): v for p, v in self.by_patches.items()},
                "rule": ("effective step height Σ Δm²/Σ|Δm| of the file against P-averages of single "
                         "realisations of the decoded Hamiltonian (the file's noise added); the floor is "
                         "drawn at the smallest consistent P (loop.patches)")}


def _with_noise(family, noise_sigma, rng):
    family = np.asarray(family, float)
    return family if not noise_sigma else family + float(noise_sigma) * rng.normal(size=family.shape)


def estimate_patches(measured, singles, noise_sigma: float | None = None, seed: int = 0) -> PatchEstimate:
    """How many patches the measured family averages (module docstring), from its step height against
    disjoint P-averages of ``singles`` (each with Gaussian noise of ``noise_sigma``, m units, from stream
    ``patch_estimate``). ValueError for fewer singles than the largest P needs (one group)."""
    singles = [np.asarray(s, float) for s in singles]
    if len(singles) < PATCH_CHOICES[-1]:
        raise ValueError(f"the patch estimate needs >= {PATCH_CHOICES[-1]} single realisations, got {len(singles)}")
    rng = stream_rng(seed, "patch_estimate", "step_height")
    measured_height = step_height(measured)
    by_patches = {}
    for p in PATCH_CHOICES:
        groups = [np.mean(singles[i:i + p], axis=0) for i in range(0, len(singles) - p + 1, p)]
        heights = [step_height(_with_noise(g, noise_sigma, rng)) for g in groups]
        by_patches[p] = {"median": float(np.median(heights)), "min": float(np.min(heights)),
                         "max": float(np.max(heights)), "groups": len(heights)}
    consistent = tuple(p for p, v in by_patches.items()
                       if v["min"] / CONSISTENCY_MARGIN <= measured_height <= v["max"] * CONSISTENCY_MARGIN)
    smoothest = by_patches[PATCH_CHOICES[-1]]
    if measured_height < smoothest["min"] / CONSISTENCY_MARGIN:
        estimate = None  # smoother than every P the pool can form
    else:
        estimate = min(PATCH_CHOICES, key=lambda p: abs(np.log(max(measured_height, 1e-12))
                                                         - np.log(max(by_patches[p]["median"], 1e-12))))
    floor = min(consistent) if consistent else (estimate if estimate is not None else PATCH_CHOICES[-1])
    return PatchEstimate(measured_height, by_patches, estimate, consistent, int(floor))


def null_films(singles, patches: int, count: int = NULL_FILMS, seed: int = 0) -> list[np.ndarray]:
    """``count`` effect-free films, each the average of ``patches`` singles: disjoint groups of a random
    order of the pool where it holds ``patches``·``count`` of them, else subsets drawn without
    replacement inside each film (films then share singles: their gains are correlated, so the largest
    of them is a somewhat lower quantile than with independent films). Stream ``patch_estimate``."""
    singles = [np.asarray(s, float) for s in singles]
    if not 1 <= patches <= len(singles):
        raise ValueError(f"{patches} patches need 1..{len(singles)} singles in the pool")
    rng = stream_rng(seed, "patch_estimate", "null_films")
    if patches * count <= len(singles):
        order = rng.permutation(len(singles))
        return [np.mean([singles[i] for i in order[k * patches:(k + 1) * patches]], axis=0) for k in range(count)]
    return [np.mean([singles[i] for i in rng.choice(len(singles), size=patches, replace=False)], axis=0)
            for _ in range(count)]


__all__ = ["CONSISTENCY_MARGIN", "NULL_FILMS", "PATCH_CHOICES", "POOL_SIZE", "PROBE_SINGLES", "RASTERIZED_MAX_POINTS", "PatchEstimate",
           "estimate_patches", "null_films", "rasterized_singles", "single_realisations", "step_height"]
