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

Shared work without ``max_step_T`` (as ``quasistatic_family``): where a curve reaches a field within ``field_tol_T`` of an
already simulated curve's reversal field with a state equal to that curve's starting state (max cell
|Δm| < ``same_state_tol``), its remaining points are that curve's values at the same fields (linear
interpolation between them; exact where the fields coincide, as on a grid); with ``merge_curves``
also where it meets, at a field within ``field_tol_T``, the state of any curve simulated before it
(``forc.protocol.StateMemory``), its remaining points are that curve's from there on. With the defaults and
the grid protocol (reversal fields = grid, curve k = grid[k:]) the numbers are those of
``quasistatic_family``. Time (averaging, pauses, rate) does not enter a quasi-static protocol.

**A continuous sweep sampled by the instrument** (with ``max_step_T``): the field moves on a lattice
of nodes at the multiples of ``max_step_T`` (the same fields for every curve), relaxing at each node;
a measured point between nodes is a snapshot, relaxed at its field from the state of the last node
passed, and does not enter the sweep's path. So where the instrument takes its points does not change
the path, as in a real sweep. A sweep whose state at a node equals (max cell |Δm| < ``same_state_tol``,
far below the difference of two distinct minima) the state of a sweep already simulated through that
node in the same direction continues on that sweep's path: the same minimum under the same field
history has the same future. Without this, the energy minimizer's numerical noise (states equal to its
convergence tolerance) decides between the branches of an avalanche, and two curves reversed from
saturation could part by tens of per cent of the loop (measured on a 32-grain film, curves reversed at
−0.798 and −0.770 T: 0.4 of the half-loop height apart at +0.6 T). Node states are kept in single
precision, so a sweep that joins a path continues from exactly the states that path continued from.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field, replace

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


def _saturation_and_levels(reversal, curve_fields, saturation_field_T):
    """The field the protocol saturates at (its largest field unless given) and the reversal fields
    in decreasing order (the descending branch's stops)."""
    top = max(float(reversal.max()), max(float(f.max()) for f in curve_fields))
    return (top if saturation_field_T is None else float(saturation_field_T)), np.unique(reversal)[::-1]


@dataclass(frozen=True)
class ProtocolSettings:
    """How the measured protocol is simulated (module docstring).

    - ``saturation_field_T``: the field the film is saturated at before the descending branch (T);
      None: the largest field of the protocol;
    - ``torque_tol_T``: a relaxation has converged when the largest cell torque |m × B_eff| is below
      it (T);
    - ``max_iterations``: the cap on the minimizer's iterations per relaxation;
    - ``same_state_tol``: two states closer than this (max cell |Δm|, dimensionless) are the same
      state (the work is shared); 0 shares nothing;
    - ``field_tol_T``: fields closer than this are the same field (T);
    - ``max_step_T``: None relaxes at the measured points themselves; a step (T) sweeps the field
      on a lattice of nodes that far apart, the measured points being snapshots;
    - ``merge_curves``: a curve may continue as any curve simulated before it (without
      ``max_step_T``) or a sweep join a path already simulated (with it);
    - ``merge_memory_MB``: memory for the states kept to merge into (MiB, float32 states).
    """

    saturation_field_T: float | None = None
    torque_tol_T: float = 1e-3
    max_iterations: int = 20_000
    same_state_tol: float = 0.02
    field_tol_T: float = 1e-12
    max_step_T: float | None = None
    merge_curves: bool = True
    merge_memory_MB: float = 256.0


@dataclass(frozen=True)
class _Protocol:
    """A measured protocol: one reversal field per curve (T, any order) and per curve its fields (T)
    in measurement order."""

    reversal: np.ndarray
    curve_fields: list

    @classmethod
    def of(cls, reversal_fields_T, curve_fields_T) -> _Protocol:
        """The protocol as arrays; ValueError when it is malformed."""
        reversal = np.asarray(reversal_fields_T, dtype=float)
        curve_fields = [np.asarray(f, dtype=float) for f in curve_fields_T]
        if reversal.ndim != 1 or len(curve_fields) != reversal.size or reversal.size == 0:
            raise ValueError("need one reversal field per curve")
        if any(f.ndim != 1 or f.size == 0 for f in curve_fields):
            raise ValueError("every curve needs at least one field")
        return cls(reversal, curve_fields)

    def highest_first(self):
        """The curves' indices from the highest reversal field down (the order they are simulated in)."""
        return np.argsort(-self.reversal, kind="stable")


class _Relaxation:
    """Relaxations of a film at the applied field B·ĥ (``vector(B)``, T) to a local energy minimum
    (torque criterion), counted in ``stats``."""

    def __init__(self, film: Film, vector, settings: ProtocolSettings, stats: dict):
        self.film, self.vector, self.stats = film, vector, stats
        self.torque_tol_T, self.max_iterations = settings.torque_tol_T, settings.max_iterations

    def __call__(self, m, B):
        """Relax ``m`` in place at the field B (T along ĥ)."""
        result = self.film.minimize(m, self.vector(B), torque_tol_T=self.torque_tol_T,
                                    max_iterations=self.max_iterations)
        self.stats["iterations"] += result.iterations
        self.stats["relaxations"] += 1
        self.stats["unconverged"] += not result.converged


def measured_protocol_family(film: Film, m0: np.ndarray, reversal_fields_T, curve_fields_T, *, direction=Z,
                             progress=None, settings: ProtocolSettings | None = None,
                             **overrides) -> ProtocolFamily:
    """Simulate the protocol of the module docstring. ``reversal_fields_T``: one per curve (any
    order); ``curve_fields_T``: per curve, its fields (T) in measurement order; ``direction``: of the
    applied field. ``m0`` is not modified. ``settings`` (default ``ProtocolSettings()``): how it is
    simulated; ``overrides`` replace single fields of it by keyword (``torque_tol_T=...``,
    ``max_step_T=...``). With ``max_step_T`` the field sweeps on a lattice of that step and the points
    are its snapshots (module docstring; ``merge_curves`` then lets sweeps join a path already
    simulated). ``progress(done, total)`` is called per curve.
    Raises SimulationError on a non-finite magnetization, ValueError on a malformed protocol."""
    settings = replace(settings if settings is not None else ProtocolSettings(), **overrides)
    protocol = _Protocol.of(reversal_fields_T, curve_fields_T)
    if settings.max_step_T is not None:
        if not settings.max_step_T > 0:
            raise ValueError(f"max_step_T must be > 0 (got {settings.max_step_T!r})")
        return _sweep_family(film, m0, protocol, direction, settings, progress)
    return _point_family(film, m0, protocol, direction, settings, progress)


class _PointByPoint:
    """The protocol relaxed at its own points, a curve's remainder copied where it meets a state
    already simulated (module docstring, shared work without ``max_step_T``)."""

    def __init__(self, relax: _Relaxation, record, protocol: _Protocol, settings: ProtocolSettings):
        self.relax, self.record, self.protocol, self.settings = relax, record, protocol, settings
        self.stats = relax.stats
        self.memory = (StateMemory(settings.merge_memory_MB * 2**20)
                       if settings.merge_curves and settings.same_state_tol > 0 else None)
        self.quantum = max(float(settings.field_tol_T), 1e-12)  # fields within field_tol_T fall into neighbouring bins
        self.out = [None] * protocol.reversal.size
        self.done = []  # (reversal field, curve index) of finished curves
        self.m = None  # the state being relaxed
        self.states, self.descending, self.level_of = {}, None, {}  # the descending branch (``descend``)

    def descend(self, m0, top, levels):
        """Saturate at ``top`` and descend through ``levels`` (T, decreasing), keeping the state and
        the recorded value at each."""
        relax, max_step_T = self.relax, self.settings.max_step_T
        self.m = m = np.array(m0, dtype=np.float64, order="C", copy=True)
        relax(m, top)
        self.states, self.descending = {}, np.empty(levels.size)
        previous = top
        for j, B in enumerate(levels):
            for b in _steps(previous, B, max_step_T):
                relax(m, b)
            previous = B
            if not np.all(np.isfinite(m)):
                raise SimulationError(f"non-finite magnetization on the descending branch at {B:+.4f} T")
            self.states[j] = m.copy()
            self.descending[j] = self.record(m)
        self.level_of = {float(B): j for j, B in enumerate(levels)}

    def curve(self, k) -> np.ndarray:
        """The values of curve ``k`` from its reversal field's kept state, remainder copied where possible."""
        H_r, fields = float(self.protocol.reversal[k]), self.protocol.curve_fields[k]
        j0 = self.level_of[H_r]
        m = self.m
        m[...] = self.states[j0]
        values = np.full(fields.size, np.nan)
        previous = H_r
        for p, B in enumerate(fields):
            if p == 0 and abs(B - H_r) <= self.settings.field_tol_T:
                values[0] = self.descending[j0]  # the reversal point is the descending state
                continue
            for b in _steps(previous, B, self.settings.max_step_T):
                self.relax(m, b)
            previous = B
            if self._copied_from_reversal(k, p, B, values) or self._merged(k, p, B, values):
                break
            values[p] = self.record(m)
        return values

    def finish(self, k, values):
        """Curve ``k`` is simulated: its values can be copied from now on."""
        self.out[k] = values
        self.done.append((float(self.protocol.reversal[k]), k))

    def _copied_from_reversal(self, k, p, B, values) -> bool:
        """At the reversal field B of a curve already simulated (reversed above this one's), with the
        state it started from: this curve's remainder is that curve's (True when copied)."""
        field_tol_T, curve_fields = self.settings.field_tol_T, self.protocol.curve_fields
        H_r = float(self.protocol.reversal[k])
        for H_other, other in self.done:
            if abs(H_other - B) > field_tol_T or H_other <= H_r:
                continue
            if np.abs(self.m - self.states[self.level_of[H_other]]).max() < self.settings.same_state_tol:
                rest = curve_fields[k][p:]
                if _covers(curve_fields[other], rest, field_tol_T):
                    values[p:] = _along(rest, curve_fields[other], self.out[other])
                    self.stats["curves_shortened"] += 1
                    return True
            return False
        return False

    def _merged(self, k, p, B, values) -> bool:
        """With ``merge_curves``: where the state equals one that a curve simulated before reached at
        B, this curve's remainder is that curve's (True when copied); else the state is kept."""
        if self.memory is None:
            return False
        field_tol_T, curve_fields = self.settings.field_tol_T, self.protocol.curve_fields
        rest, bin_ = curve_fields[k][p:], int(round(B / self.quantum))

        def joins(token):
            other, p_other, B_other = token
            return (other != k and abs(B_other - B) <= field_tol_T
                    and _covers(curve_fields[other][p_other:], rest, field_tol_T))

        twin = self.memory.find((bin_, bin_ - 1, bin_ + 1), self.m, self.settings.same_state_tol, accept=joins)
        if twin is not None:
            other, p_other, _ = twin
            values[p:] = _along(rest, curve_fields[other][p_other:], self.out[other][p_other:])
            self.stats["curves_shortened"] += 1
            self.stats["curves_merged"] += 1
            return True
        self.memory.add(bin_, k, self.m, token=(k, p, B))
        return False


def _point_family(film: Film, m0, protocol: _Protocol, direction, settings: ProtocolSettings,
                  progress) -> ProtocolFamily:
    """The protocol relaxed at its own points (no ``max_step_T``)."""
    start = time.perf_counter()
    _, vector, record = _projector(direction)
    stats = {"iterations": 0, "relaxations": 0, "unconverged": 0, "curves_shortened": 0, "curves_merged": 0}
    simulation = _PointByPoint(_Relaxation(film, vector, settings, stats), record, protocol, settings)
    top, levels = _saturation_and_levels(protocol.reversal, protocol.curve_fields, settings.saturation_field_T)
    simulation.descend(m0, top, levels)
    for count, k in enumerate(protocol.highest_first()):
        values = simulation.curve(k)
        _check_curve(values, protocol.reversal[k])
        simulation.finish(k, values)
        if progress is not None:
            progress(count + 1, protocol.reversal.size)
    stats["wall_s"] = time.perf_counter() - start
    return ProtocolFamily(simulation.out, levels, simulation.descending, stats)


def _check_curve(values, H_r):
    """SimulationError if a curve's values (reversed at ``H_r``, T) are not all finite."""
    if not np.all(np.isfinite(values)):
        raise SimulationError(f"non-finite magnetization on the curve reversed at {float(H_r):+.4f} T")


class PathMemory:
    """Node states of the sweeps already simulated, in single precision, filed by (direction, node),
    to let a sweep that reaches one of them continue on that sweep's path. At most ``budget_bytes``
    are kept; when full, the sweep filed first is forgotten."""

    def __init__(self, budget_bytes: float):
        self.budget_bytes = float(budget_bytes)
        self.states: dict = {}  # (direction, node, path) -> state
        self.at: dict = {}  # (direction, node) -> [(path, <m_z>)]
        self.paths: dict = {}  # path -> [(direction, node)], in filing order
        self.aliases: dict = {}  # (direction, node, path) -> the path it followed there
        self.nbytes = 0

    def add(self, direction: int, node: int, path: int, state: np.ndarray):
        if state.nbytes > self.budget_bytes:
            return
        while self.nbytes + state.nbytes > self.budget_bytes and self.paths:
            self._forget(next(iter(self.paths)))
        self.states[(direction, node, path)] = state
        self.at.setdefault((direction, node), []).append((path, float(state[2].mean())))
        self.paths.setdefault(path, []).append((direction, node))
        self.nbytes += state.nbytes

    def _forget(self, path: int):
        for direction, node in self.paths.pop(path):
            self.nbytes -= self.states.pop((direction, node, path)).nbytes
            self.at[(direction, node)] = [entry for entry in self.at[(direction, node)] if entry[0] != path]

    def follow(self, direction: int, node: int, path: int, joined: int):
        """Record that ``path`` passed ``node`` on ``joined``'s path (its state there is that path's)."""
        self.aliases[(direction, node, path)] = joined

    def owner(self, direction: int, node: int, path):
        """The path whose own state ``path`` has at ``node`` (through the paths it joined), or None."""
        for _ in range(64):
            if path is None or (direction, node, path) in self.states:
                return path
            path = self.aliases.get((direction, node, path))
        return None

    def get(self, direction: int, node: int, path):
        """The state of ``path`` at ``node`` (through the paths it joined), or None."""
        owner = self.owner(direction, node, path)
        return None if owner is None else self.states[(direction, node, owner)]

    def find(self, direction: int, node: int, m: np.ndarray, tol: float):
        """A path whose state at this node is within ``tol`` (max cell |Δm|) of ``m``, or None."""
        mz = float(m[2].mean())
        for path, stored_mz in self.at.get((direction, node), ()):
            if abs(stored_mz - mz) < tol and float(np.abs(m - self.states[(direction, node, path)]).max()) < tol:
                return path
        return None


class _Lattice:
    """What the sweeps of one family share: the lattice of nodes at the multiples of ``step`` (T),
    the relaxation, the recorded projection, the paths already simulated (``PathMemory``, None when
    sweeps may not join) and the snapshots taken from them."""

    def __init__(self, relax: _Relaxation, record, settings: ProtocolSettings):
        self.relax, self.record, self.stats = relax, record, relax.stats
        self.step = float(settings.max_step_T)
        self.same_state_tol = settings.same_state_tol
        memory_MB = settings.merge_memory_MB if settings.merge_curves else 0.0
        self.memory = PathMemory(memory_MB * 2**20) if memory_MB > 0 and settings.same_state_tol > 0 else None
        self.snapshots: dict = {}  # (direction, node, path owning the node's state, field quantum) -> recorded value
        self.quantum = max(float(settings.field_tol_T), 1e-12)  # fields within it are one field
        self.new_path = itertools.count()

    def on_node(self, B):
        """The index of the node at field B (T), or None when B is not a node."""
        s = self.step
        n = round(B / s)
        return n if abs(B - n * s) <= 1e-9 * s else None


class _Sweep:
    """A sweep at ``field`` (on node ``node``, or None) on path ``path``; its state is ``m``, or,
    while it follows a path already simulated, that path's stored state at the node (``shared``)."""

    def __init__(self, lattice: _Lattice, m, B):
        self.lattice = lattice
        self.m, self.field, self.node, self.dir = m, float(B), lattice.on_node(B), 0
        self.path, self.own, self.shared = None, None, None

    def state(self) -> np.ndarray:
        """The state now (in double precision; do not modify)."""
        if self.shared is not None:
            self.m[...] = self.shared
            self.shared = None
        return self.m

    def advance(self, B) -> bool:
        """Sweep over the nodes towards B (B itself included if it is a node); True if B is a node."""
        s = self.lattice.step
        d = 1 if B > self.field else -1
        if d != self.dir:
            self.state()
            self.dir, self.path, self.own = d, None, next(self.lattice.new_path)
        first = np.floor(self.field / s + 1e-9) + 1 if d > 0 else np.ceil(self.field / s - 1e-9) - 1
        target = self.lattice.on_node(B)
        last = target if target is not None else (np.ceil(B / s) - 1 if d > 0 else np.floor(B / s) + 1)
        for n in range(int(first), int(last) + d, d):
            self.step(n)
        return target is not None

    def snapshot(self, B) -> np.ndarray:
        """The state relaxed at B from the sweep's state (which stays where it is)."""
        snap = self.state().copy()
        self.lattice.relax(snap, B)
        self.lattice.stats["snapshots"] += 1
        return snap

    def to(self, B) -> np.ndarray:
        """The state at the measured field B: the sweep's own on a node, else a snapshot."""
        if B == self.field or self.advance(B):
            return self.state().copy()
        return self.snapshot(B)

    def value(self, B) -> float:
        """The recorded value at B; a snapshot taken before from the same node state is reused."""
        lattice = self.lattice
        if B == self.field or self.advance(B):
            return lattice.record(self.state())
        memory, snapshots = lattice.memory, lattice.snapshots
        owner = memory.owner(self.dir, self.node, self.path) if memory is not None and self.node is not None else None
        key = (self.dir, self.node, owner, round(B / lattice.quantum)) if owner is not None else None
        if key is not None and key in snapshots:
            lattice.stats["snapshots_reused"] += 1
            return snapshots[key]
        snap = self.snapshot(B)
        if not np.all(np.isfinite(snap)):
            raise SimulationError(f"non-finite magnetization at {B:+.4f} T")
        value = lattice.record(snap)
        if key is not None:
            snapshots[key] = value
        return value

    def step(self, n):
        """Move to node ``n``: on a path already simulated take its state there, else relax and
        join a path whose state there is the same, or file this one's."""
        d, lattice = self.dir, self.lattice
        memory, stats = lattice.memory, lattice.stats
        owner = memory.owner(d, n, self.path) if memory is not None and self.path is not None else None
        if owner is not None:  # on a path already simulated: its state, without relaxing
            self.shared = memory.states[(d, n, owner)]
            memory.follow(d, n, self.own, owner)
            stats["nodes_followed"] += 1
        else:
            m = self.state()
            lattice.relax(m, n * lattice.step)
            single = m.astype(np.float32)
            m[...] = single
            stats["nodes_relaxed"] += 1
            if not np.all(np.isfinite(m)):
                raise SimulationError(f"non-finite magnetization at {n * lattice.step:+.4f} T")
            joined = memory.find(d, n, m, lattice.same_state_tol) if memory is not None else None
            if joined is not None:
                stats["curves_merged"] += 1
                self.shared = memory.states[(d, n, joined)]
                memory.follow(d, n, self.own, joined)
                self.path = joined
            else:
                self.path = self.own
                if memory is not None:
                    memory.add(d, n, self.own, single)
        self.field, self.node = n * lattice.step, n


def _swept_descending(lattice: _Lattice, m0, top, levels):
    """Saturate at ``top`` and sweep down through ``levels`` (T, decreasing): the state and the
    recorded value at each."""
    m = np.array(m0, dtype=np.float64, order="C", copy=True)
    lattice.relax(m, top)
    sweep = _Sweep(lattice, m, top)
    states, descending = {}, np.empty(levels.size)
    for j, B in enumerate(levels):
        states[j] = sweep.to(float(B))
        if not np.all(np.isfinite(states[j])):
            raise SimulationError(f"non-finite magnetization on the descending branch at {B:+.4f} T")
        descending[j] = lattice.record(states[j])
    return states, descending


def _swept_curve(lattice: _Lattice, start_state, H_r, fields, reversal_value, field_tol_T) -> np.ndarray:
    """The values of a curve swept up from ``start_state`` at its reversal field ``H_r`` and sampled
    at ``fields`` (T); its first point, at H_r, is ``reversal_value`` (the descending branch's)."""
    sweep = _Sweep(lattice, start_state.copy(), H_r)
    values = np.full(fields.size, np.nan)
    for p, B in enumerate(fields):
        if p == 0 and abs(B - H_r) <= field_tol_T:
            values[0] = reversal_value  # the reversal point is the descending state
            continue
        values[p] = sweep.value(float(B))
    return values


def _sweep_family(film: Film, m0, protocol: _Protocol, direction, settings: ProtocolSettings,
                  progress) -> ProtocolFamily:
    """The protocol as a sweep on the lattice of ``settings.max_step_T`` sampled at the measured
    points (module docstring)."""
    start = time.perf_counter()
    _, vector, record = _projector(direction)
    stats = {"iterations": 0, "relaxations": 0, "unconverged": 0, "curves_shortened": 0, "curves_merged": 0,
             "nodes_relaxed": 0, "nodes_followed": 0, "snapshots": 0, "snapshots_reused": 0}
    lattice = _Lattice(_Relaxation(film, vector, settings, stats), record, settings)
    top, levels = _saturation_and_levels(protocol.reversal, protocol.curve_fields, settings.saturation_field_T)
    states, descending = _swept_descending(lattice, m0, top, levels)
    level_of = {float(B): j for j, B in enumerate(levels)}
    out = [None] * protocol.reversal.size
    for count, k in enumerate(protocol.highest_first()):
        H_r = float(protocol.reversal[k])
        j0 = level_of[H_r]
        values = _swept_curve(lattice, states[j0], H_r, protocol.curve_fields[k], descending[j0],
                              settings.field_tol_T)
        _check_curve(values, H_r)
        out[k] = values
        if progress is not None:
            progress(count + 1, protocol.reversal.size)
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


__all__ = ["ProtocolFamily", "ProtocolSettings", "field_direction", "grid_protocol", "measured_protocol_family",
           "protocol_to_grid"]
