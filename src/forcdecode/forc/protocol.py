"""First-order reversal curves of a simulated film, quasi-static path.

Protocol (μ0H along z, in tesla, on a uniform grid of ``n_fields`` values from −B_max to +B_max):
saturate at +B_max; descend the major loop point by point, keeping the state at every grid field;
for each reversal field H_r (a grid point) start from the kept descending state and sweep up to
+B_max. At every field the film is relaxed to a local energy minimum (``Film.minimize``, torque
criterion). The magnetization recorded is the film average ⟨m_z⟩ (pinning cells included, as an
instrument sees them).

Work is shared. The relaxation is deterministic: two sweeps that hold the same state at the same
field and then visit the same fields reach the same states. So a curve that reaches a state equal
(max cell |Δm| < ``same_state_tol``) to one already known at that field continues as the curve that
holds it, and its remainder is copied:
- the descending state at that field (the start of the FORC reversed there): above the nucleation
  field this ends a curve one step after it starts, and a curve that has rejoined saturation costs
  nothing more;
- (``merge_curves``) the state of any FORC computed before it at that field (curves are computed
  from the highest reversal field down): two curves whose reversals differ only in domains that the
  rising field has wiped out again merge long before saturation (return-point memory). Those states
  are kept in float32 (the test is at 0.02), within ``merge_memory_MB``; beyond it the curves farthest
  from the current one are forgotten first.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..micromag.film import Film, SimulationError


@dataclass
class ForcFamily:
    """A family of FORCs on a field grid.

    ``curves_mz[i, j]`` is ⟨m_z⟩ on the curve reversed at ``fields_T[i]`` when the field is
    ``fields_T[j]`` (j ≥ i); entries with j < i (H < H_r) are NaN. ``descending_mz`` is the
    descending major-loop branch; ``curves_mz[i, i] == descending_mz[i]``.
    """

    fields_T: np.ndarray
    curves_mz: np.ndarray
    descending_mz: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def reversal_fields_T(self) -> np.ndarray:
        return self.fields_T


@dataclass(frozen=True)
class SweepSettings:
    """How a quasi-static sweep relaxes the film at each field, and which work it shares.

    - ``torque_tol_T``: a relaxation has converged when the largest cell torque |m × B_eff| is below
      it (T);
    - ``max_iterations``: the cap on the minimizer's iterations per relaxation;
    - ``substeps``: relaxations per grid step, at evenly spaced intermediate fields (≥ 1);
    - ``extrapolate``: start each relaxation from the last step's linear response (``Continuation``);
    - ``warm_step``: start each relaxation with the previous one's last Barzilai–Borwein step;
    - ``same_state_tol``: two states closer than this (max cell |Δm|, dimensionless) are the same
      state and a curve reaching one continues as the curve that holds it; 0 disables every
      remainder copy (the reference);
    - ``merge_curves``: also copy remainders from earlier FORCs, not only from the descending branch;
    - ``merge_memory_MB``: memory for the FORC states kept to merge into (MiB, float32 states).

    The fields are the keywords ``micromag.build.sweep_options`` reads from a config.
    """

    torque_tol_T: float = 1e-3
    max_iterations: int = 20_000
    substeps: int = 1
    extrapolate: bool = False
    warm_step: bool = False
    same_state_tol: float = 0.02
    merge_curves: bool = True
    merge_memory_MB: float = 256.0


def _relax(film: Film, m, B, settings: SweepSettings, stats, initial_step=0.0):
    """Relax ``m`` (in place) at the field ``B`` (T, along z) and count the work in ``stats``."""
    result = film.minimize(m, B, torque_tol_T=settings.torque_tol_T, max_iterations=settings.max_iterations,
                           initial_step=initial_step)
    stats["iterations"] += result.iterations
    stats["relaxations"] += 1
    if not result.converged:
        stats["unconverged"] += 1
    return result


class Continuation:
    """Relaxations along one field sweep, each started from a prediction of its answer.

    Predictor (``extrapolate``): where the last field step changed the state reversibly (max cell
    |Δm| below ``reversible_dm``), the next state is first moved by the same linear response,
    m ← normalize(m + (ΔB_next/ΔB_last)·Δm_last), the first-order continuation of the equilibrium
    branch m(B); after a jump (an avalanche) no extrapolation is made. Step memory (``warm_step``):
    the first Barzilai–Borwein step is the last one of the previous relaxation (the curvature of the
    energy barely changes between neighbouring fields), not a blind 0.01 rad. Neither changes the
    equilibrium reached when it is unique; both are checked against the plain protocol on the same
    films (``tests/forc/test_protocol_shortcuts.py``).
    """

    def __init__(self, film: Film, settings: SweepSettings, stats, reversible_dm: float = 0.1):
        self.film, self.settings, self.stats = film, settings, stats
        self.extrapolate, self.warm_step, self.reversible_dm = settings.extrapolate, settings.warm_step, reversible_dm
        self.step = 0.0
        self.start(None, None)

    def start(self, m, B):
        """A new sweep starts from the relaxed state ``m`` at field ``B`` (no linear response known yet)."""
        self.last_m = None if (m is None or not self.extrapolate) else m.copy()
        self.last_B = B
        self.prev_m = None
        self.prev_B = None

    def relax(self, m, B):
        """Relax ``m`` (in place; the relaxed state at the last field) at field ``B`` (T)."""
        if self.extrapolate and self.prev_m is not None and self.last_B != self.prev_B:
            delta = self.last_m - self.prev_m
            if np.abs(delta).max() < self.reversible_dm:
                m += delta * ((B - self.last_B) / (self.last_B - self.prev_B))
                m /= np.sqrt((m * m).sum(axis=0))
                self.stats["predicted"] = self.stats.get("predicted", 0) + 1
        result = _relax(self.film, m, B, self.settings, self.stats, self.step if self.warm_step else 0.0)
        if result.converged and result.last_step > 0.0:
            self.step = result.last_step
        if self.extrapolate:
            self.prev_m, self.prev_B = self.last_m, self.last_B
            self.last_m, self.last_B = m.copy(), B
        return result


def descending_branch(film: Film, m0: np.ndarray, fields_T: np.ndarray, torque_tol_T: float = 1e-3,
                      max_iterations: int = 20_000, *, stats=None, keep_states=False, **settings):
    """Saturate at ``fields_T[-1]`` (the largest) and descend through ``fields_T`` (increasing grid)
    to its first value. Returns (⟨m_z⟩ per field, states, final m): ``states`` holds the state at
    every field (``keep_states=True``), at the given indices only (a dict index → state, for a
    sequence of indices), or is None. ``settings``: the other ``SweepSettings`` fields by keyword
    (``substeps``, ``extrapolate``, ``warm_step``); ``stats`` counts the work (a new dict if None)."""
    sweep_settings = SweepSettings(torque_tol_T=torque_tol_T, max_iterations=max_iterations, **settings)
    return _descend(film, m0, fields_T, sweep_settings, stats, keep_states)


def _descend(film: Film, m0: np.ndarray, fields_T: np.ndarray, settings: SweepSettings, stats, keep_states):
    """``descending_branch`` with its settings as one ``SweepSettings``."""
    stats = stats if stats is not None else {"iterations": 0, "relaxations": 0, "unconverged": 0}
    n = len(fields_T)
    m = np.array(m0, dtype=np.float64, order="C", copy=True)
    sweep = Continuation(film, settings, stats)
    _relax(film, m, fields_T[-1], settings, stats)
    sweep.start(m, fields_T[-1])
    if keep_states is True:
        states = np.empty((n,) + m.shape, dtype=np.float64)
        wanted = range(n)
    else:
        wanted = {j % n for j in keep_states} if keep_states else set()
        states = {} if keep_states else None
    descending = np.empty(n)
    previous = fields_T[-1]
    for j in range(n - 1, -1, -1):
        for B in np.linspace(previous, fields_T[j], settings.substeps + 1)[1:]:
            sweep.relax(m, B)
        previous = fields_T[j]
        if not np.all(np.isfinite(m)):
            raise SimulationError(f"non-finite magnetization on the descending branch at {fields_T[j]:+.3f} T")
        if j in wanted:
            states[j] = m.copy() if isinstance(states, dict) else m
        descending[j] = m[2].mean()
    return descending, states, m


class StateMemory:
    """States that FORCs already reached, filed by field (float32), to find a curve to merge into.

    ``add(key, curve, m, token)`` files the state ``m`` of curve ``curve`` under ``key`` (a grid
    index, or a quantized field); ``find(keys, m, tol, accept)`` returns the ``token`` of a state filed
    under one of ``keys`` within ``tol`` (max cell |Δm|) of ``m`` (and that ``accept(token)`` takes),
    or None. A stored state whose ⟨m_z⟩ differs by ``tol`` or more cannot match (|Δ⟨m_z⟩| ≤
    max |Δm_z|) and is skipped without the cell-wise test. At most ``budget_bytes`` are kept; when
    full, the states of the curve filed first (the farthest from the current one: curves are computed
    from the highest reversal field down) are dropped.
    """

    def __init__(self, budget_bytes: float):
        self.budget_bytes = float(budget_bytes)
        self.filed: dict = {}
        self.curves: dict = {}  # curve -> keys, in the order curves were first filed
        self.nbytes = 0

    def add(self, key, curve, m: np.ndarray, token=None):
        state = m.astype(np.float32)
        if state.nbytes > self.budget_bytes:
            return
        while self.nbytes + state.nbytes > self.budget_bytes and self.curves:
            self._forget(next(iter(self.curves)))
        self.filed.setdefault(key, []).append((curve, curve if token is None else token, float(m[2].mean()), state))
        self.curves.setdefault(curve, []).append(key)
        self.nbytes += state.nbytes

    def _forget(self, curve):
        for key in set(self.curves.pop(curve)):
            self.nbytes -= sum(entry[3].nbytes for entry in self.filed[key] if entry[0] == curve)
            self.filed[key] = [entry for entry in self.filed[key] if entry[0] != curve]

    def find(self, keys, m: np.ndarray, tol: float, accept=None):
        mz = float(m[2].mean())
        for key in keys:
            for _, token, stored_mz, state in self.filed.get(key, ()):
                if abs(stored_mz - mz) < tol and (accept is None or accept(token)) \
                        and float(np.abs(m - state).max()) < tol:
                    return token
        return None


def quasistatic_family(film: Film, m0: np.ndarray, n_fields: int = 64, B_max_T: float = 1.0, *, progress=None,
                       settings: SweepSettings | None = None, **overrides) -> ForcFamily:
    """Simulate a FORC family with the quasi-static path on ``n_fields`` fields over ±``B_max_T``
    (T). ``m0`` is not modified.

    ``settings`` (default ``SweepSettings()``) says how each field is relaxed and which work is shared
    (module docstring); ``overrides`` replace single fields of it by keyword (``torque_tol_T=...``,
    ``same_state_tol=...``, or ``**micromag.build.sweep_options(cfg)``). ``progress(done, total)`` is
    called per curve. Raises ``SimulationError`` if the magnetization becomes non-finite.
    """
    settings = replace(settings if settings is not None else SweepSettings(), **overrides)
    if n_fields < 2:
        raise ValueError("n_fields must be at least 2")
    if settings.substeps < 1:
        raise ValueError("substeps must be >= 1")
    start = time.perf_counter()
    fields = np.linspace(-B_max_T, B_max_T, n_fields)
    stats = {"iterations": 0, "relaxations": 0, "unconverged": 0, "curves_shortened": 0, "curves_merged": 0}
    descending, states, m = _descend(film, m0, fields, settings, stats, keep_states=True)
    sweep = Continuation(film, settings, stats)
    curves = np.full((n_fields, n_fields), np.nan)
    same_state_tol = settings.same_state_tol
    memory = StateMemory(settings.merge_memory_MB * 2**20) if settings.merge_curves and same_state_tol > 0 else None
    for i in range(n_fields - 1, -1, -1):
        curves[i, i] = descending[i]
        m[...] = states[i]
        sweep.start(m, fields[i])
        for j in range(i + 1, n_fields):
            for B in np.linspace(fields[j - 1], fields[j], settings.substeps + 1)[1:]:
                sweep.relax(m, B)
            if np.abs(m - states[j]).max() < same_state_tol:
                curves[i, j:] = curves[j, j:]
                stats["curves_shortened"] += 1
                break
            if memory is not None:
                twin = memory.find((j,), m, same_state_tol)
                if twin is not None:
                    curves[i, j:] = curves[twin, j:]
                    stats["curves_shortened"] += 1
                    stats["curves_merged"] += 1
                    break
                memory.add(j, i, m)
            curves[i, j] = m[2].mean()
        if not np.all(np.isfinite(curves[i, i:])):
            raise SimulationError(f"non-finite magnetization on the FORC with H_r = {fields[i]:+.3f} T")
        if progress is not None:
            progress(n_fields - i, n_fields)
    stats["wall_s"] = time.perf_counter() - start
    return ForcFamily(fields, curves, descending, stats)
