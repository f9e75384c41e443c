"""FORCs of a simulated film on an arbitrary protocol: the measured file's own reversal fields and
field points, in the order the instrument visited them, with the applied field along any direction.

Protocol (quasi-static, the relaxation machinery of ``forc.protocol``): saturate at the largest field
(``saturation_field_T``, default the largest field of the protocol); descend through the reversal
fields in decreasing order, keeping the state at each (the instrument ramps from saturation to H_r
before each curve, visiting the same quasi-static path); for each curve, from the highest reversal
field down, start from the kept state and relax at each of its fields in the given order (the sweep
direction as measured). A relaxation minimizes the energy (``Film.minimize``, torque criterion) in
the field B·ĥ; the value recorded is ⟨m⟩·ĥ (a vector magnetometer's coils along the applied field).
With ``max_step_T`` a step larger than it is made in equal sub-steps.

Shared work (as ``quasistatic_family``): where a curve reaches a field within ``field_tol_T`` of an
already simulated curve's reversal field with a state equal to that curve's starting state (max cell
|Δm| < ``same_state_tol``), its remaining points are that curve's values at the same fields (linear
interpolation between them; exact where the fields coincide, as on a grid); with ``merge_curves``
also where it meets, at a field within ``field_tol_T``, the state of any curve simulated before it
(``forc.protocol.StateMemory``), its remaining points are that curve's from there on. With the defaults and
the grid protocol (reversal fields = grid, curve k = grid[k:]) the numbers are those of
``quasistatic_family``. Time (averaging, pauses, rate) does not enter a quasi-static protocol.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..micromag.film import Film, SimulationError
from .protocol import StateMemory

Z = (0.0, 0.0, 1.0)


def field_direction(tilt_deg: float = 0.0, azimuth_deg: float = 0.0) -> np.ndarray:
    """Unit vector of an applied field tilted by ``tilt_deg`` from the film normal z towards the
    in-plane azimuth ``azimuth_deg`` (from x)."""
    t, a = np.radians(tilt_deg), np.radians(azimuth_deg)
    return np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])


@dataclass
class ProtocolFamily:
    """⟨m⟩·ĥ of every point of the protocol: ``curves[k]`` aligned with the k-th curve's fields (input
    order); ``descending`` at the sorted-decreasing reversal fields ``descending_fields_T``."""

    curves: list
    descending_fields_T: np.ndarray
    descending: np.ndarray
    stats: dict = field(default_factory=dict)


def _projector(direction):
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    if np.array_equal(d, np.asarray(Z)):
        return d, (lambda B: B), (lambda m: m[2].mean())
    return d, (lambda B: B * d), (lambda m: float((d[0] * m[0] + d[1] * m[1] + d[2] * m[2]).mean()))


def _steps(start, stop, max_step):
    if max_step is None or abs(stop - start) <= max_step:
        return [stop]
    k = int(np.ceil(abs(stop - start) / max_step))
    return list(np.linspace(start, stop, k + 1)[1:])


def _covers(curve_fields, rest, field_tol_T) -> bool:
    """Whether a curve's fields span the ``rest`` of another curve (so its values can be copied)."""
    return rest.min() >= curve_fields.min() - field_tol_T and rest.max() <= curve_fields.max() + field_tol_T


def _along(rest, curve_fields, curve_values):
    """A curve's values at the fields ``rest`` (linear interpolation; exact where the fields coincide)."""
    order = np.argsort(curve_fields, kind="stable")
    return np.interp(rest, curve_fields[order], curve_values[order])


def measured_protocol_family(film: Film, m0: np.ndarray, reversal_fields_T, curve_fields_T, *,
                             direction=Z, saturation_field_T: float | None = None, torque_tol_T: float = 1e-3,
                             max_iterations: int = 20_000, same_state_tol: float = 0.02, field_tol_T: float = 1e-12,
                             max_step_T: float | None = None, merge_curves: bool = True,
                             merge_memory_MB: float = 256.0, progress=None) -> ProtocolFamily:
    """Simulate the protocol of the module docstring. ``reversal_fields_T``: one per curve (any
    order); ``curve_fields_T``: per curve, its fields (T) in measurement order. ``m0`` is not modified.
    Raises SimulationError on a non-finite magnetization, ValueError on a malformed protocol."""
    reversal = np.asarray(reversal_fields_T, dtype=float)
    curve_fields = [np.asarray(f, dtype=float) for f in curve_fields_T]
    if reversal.ndim != 1 or len(curve_fields) != reversal.size or reversal.size == 0:
        raise ValueError("need one reversal field per curve")
    if any(f.ndim != 1 or f.size == 0 for f in curve_fields):
        raise ValueError("every curve needs at least one field")
    start = time.perf_counter()
    _, vector, record = _projector(direction)
    stats = {"iterations": 0, "relaxations": 0, "unconverged": 0, "curves_shortened": 0, "curves_merged": 0}
    memory = StateMemory(merge_memory_MB * 2**20) if merge_curves and same_state_tol > 0 else None
    quantum = max(float(field_tol_T), 1e-12)  # fields within field_tol_T fall into neighbouring bins

    def relax(m, B):
        result = film.minimize(m, vector(B), torque_tol_T=torque_tol_T, max_iterations=max_iterations)
        stats["iterations"] += result.iterations
        stats["relaxations"] += 1
        stats["unconverged"] += not result.converged

    top = max(float(reversal.max()), max(float(f.max()) for f in curve_fields))
    top = top if saturation_field_T is None else float(saturation_field_T)
    levels = np.unique(reversal)[::-1]  # decreasing
    m = np.array(m0, dtype=np.float64, order="C", copy=True)
    relax(m, top)
    states, descending = {}, np.empty(levels.size)
    previous = top
    for j, B in enumerate(levels):
        for b in _steps(previous, B, max_step_T):
            relax(m, b)
        previous = B
        if not np.all(np.isfinite(m)):
            raise SimulationError(f"non-finite magnetization on the descending branch at {B:+.4f} T")
        states[j] = m.copy()
        descending[j] = record(m)
    level_of = {float(B): j for j, B in enumerate(levels)}
    out = [None] * reversal.size
    done = []  # (reversal field, curve index) of finished curves
    for count, k in enumerate(np.argsort(-reversal, kind="stable")):
        H_r, fields = float(reversal[k]), curve_fields[k]
        j0 = level_of[H_r]
        m[...] = states[j0]
        values = np.full(fields.size, np.nan)
        previous = H_r
        for p, B in enumerate(fields):
            if p == 0 and abs(B - H_r) <= field_tol_T:
                values[0] = descending[j0]  # the reversal point is the descending state
                continue
            for b in _steps(previous, B, max_step_T):
                relax(m, b)
            previous = B
            copied = False
            for H_other, other in done:
                if abs(H_other - B) > field_tol_T or H_other <= H_r:
                    continue
                if np.abs(m - states[level_of[H_other]]).max() < same_state_tol:
                    rest = fields[p:]
                    if _covers(curve_fields[other], rest, field_tol_T):
                        values[p:] = _along(rest, curve_fields[other], out[other])
                        stats["curves_shortened"] += 1
                        copied = True
                break
            if copied:
                break
            if memory is not None:
                rest, bin_ = fields[p:], int(round(B / quantum))

                def joins(token, rest=rest, B=B, k=k):
                    other, p_other, B_other = token
                    return (other != k and abs(B_other - B) <= field_tol_T
                            and _covers(curve_fields[other][p_other:], rest, field_tol_T))

                twin = memory.find((bin_, bin_ - 1, bin_ + 1), m, same_state_tol, accept=joins)
                if twin is not None:
                    other, p_other, _ = twin
                    values[p:] = _along(rest, curve_fields[other][p_other:], out[other][p_other:])
                    stats["curves_shortened"] += 1
                    stats["curves_merged"] += 1
                    break
                memory.add(bin_, k, m, token=(k, p, B))
            values[p] = record(m)
        if not np.all(np.isfinite(values)):
            raise SimulationError(f"non-finite magnetization on the curve reversed at {H_r:+.4f} T")
        out[k] = values
        done.append((H_r, k))
        if progress is not None:
            progress(count + 1, reversal.size)
    stats["wall_s"] = time.perf_counter() - start
    return ProtocolFamily(out, levels, descending, stats)


def grid_protocol(n_fields: int, B_max_T: float):
    """The training grid as a protocol: (reversal fields, per-curve fields)."""
    grid = np.linspace(-B_max_T, B_max_T, n_fields)
    return grid, [grid[i:] for i in range(n_fields)]


def protocol_to_grid(family: ProtocolFamily, n_fields: int) -> np.ndarray:
    """A grid-protocol family as the n × n array of ``ForcFamily.curves_mz`` (NaN below the diagonal)."""
    out = np.full((n_fields, n_fields), np.nan)
    for i, values in enumerate(family.curves):
        out[i, i:] = values
    return out


__all__ = ["ProtocolFamily", "field_direction", "grid_protocol", "measured_protocol_family", "protocol_to_grid"]
