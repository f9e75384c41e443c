"""``Film``: one magnetic film (mesh + Hamiltonian) with its field, energy, minimizer and LLG.

All quantities are SI: M_s in A/m, A_ex in J/m, K_u in J/m³, D in J/m², fields as flux density
μ0H in tesla, energies in joules, times in seconds. Magnetization arrays are unit vectors of
shape (3, nz, ny, nx).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import SimulationError
from .demag import periodic_film_kernel
from .effective_field import FieldModel, compute_effective_field, torque_and_max, total_energy
from .llg import StepControl, run_llg_rk45
from .mesh import Mesh
from .minimize import fourier_preconditioner, minimize_bb, minimize_bb_fourier

FOURIER_STIFFNESS_T = 3.0
"""S of the Fourier preconditioner (T): the stiffness all modes share, of the order of the
anisotropy field; chosen on the benchmark film (13 relaxations: iterations 2756 → 1064 at S = 3; 1898 at
0.3, 1157 at 10)."""

TERMS = ("exchange", "anisotropy", "dmi", "demag", "zeeman")


@dataclass
class MinimizeResult:
    iterations: int
    max_torque_T: float
    converged: bool
    last_step: float = 0.0  # the last Barzilai–Borwein step h; pass as ``initial_step`` to a nearby relaxation


@dataclass
class LLGResult:
    t_s: float
    next_dt_s: float
    accepted_steps: int
    rejected_steps: int
    ok: bool


def _as_cell_array(value, shape, name):
    array = np.broadcast_to(np.asarray(value, dtype=np.float64), shape)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains non-finite values")
    return np.ascontiguousarray(array)


@dataclass
class Film:
    """A periodic perpendicular film: mesh, material parameters and which energy terms are on.

    ``K_u`` may be a scalar or a per-cell array (nz, ny, nx); ``easy_axis`` a 3-vector or a per-cell
    array (3, nz, ny, nx) (normalized here). ``frozen`` marks cells that are held fixed; ``slaved``
    marks cells kept at their local equilibrium in the field of their neighbours (pinning sites,
    see ``forcdecode.micromag.disorder`` and ``effective_field.relax_slaved_cells``). ``terms`` is a subset of ``TERMS``.

    ``spacer_after_layer = k`` (0 ≤ k < nz − 1) puts a non-magnetic spacer between layers k and
    k + 1: their direct exchange is cut and replaced by the interlayer coupling
    E = −J ∫ m_k·m_{k+1} dA with J = ``interlayer_coupling_J_m2`` (J/m², > 0 ferromagnetic; 0:
    decoupled layers). It belongs to the "exchange" term (see ``interlayer``). Default: no spacer.
    """

    mesh: Mesh
    Ms: float
    A_ex: float
    K_u: float | np.ndarray = 0.0
    easy_axis: tuple | np.ndarray = (0.0, 0.0, 1.0)
    D: float = 0.0
    frozen: np.ndarray | None = None
    slaved: np.ndarray | None = None
    terms: tuple[str, ...] = TERMS
    n_alias: int = 20
    kernel_cache_dir: str | Path | None = None
    K_2: float = 0.0
    B_bias_T: tuple = (0.0, 0.0, 0.0)
    interlayer_coupling_J_m2: float = 0.0
    spacer_after_layer: int | None = None
    preconditioner: str = "diagonal"
    """Minimizer preconditioner: "diagonal" (cell-local, ``minimize.diagonal_preconditioner``) or
    "fourier" (that times the in-plane exchange filter, ``minimize.minimize_bb_fourier``: ~4× fewer
    iterations, but avalanches can end in other minima than plain descent reaches: an option)."""
    fourier_guard_dm: float = 0.0
    """With "fourier": a relaxation in which some cell turned by more than this (|Δm|) is redone with
    the diagonal preconditioner (0: never)."""
    model: FieldModel = field(init=False, repr=False)

    def __post_init__(self):
        mesh = self.mesh
        if not (self.Ms > 0 and np.isfinite(self.Ms)):
            raise ValueError(f"Ms must be positive (A/m), got {self.Ms!r}")
        if not (self.A_ex >= 0 and np.isfinite(self.A_ex)):
            raise ValueError(f"A_ex must be non-negative (J/m), got {self.A_ex!r}")
        unknown = set(self.terms) - set(TERMS)
        if unknown:
            raise ValueError(f"unknown energy terms {sorted(unknown)}; known: {TERMS}")
        J = float(self.interlayer_coupling_J_m2)
        if not np.isfinite(J):
            raise ValueError(f"interlayer_coupling_J_m2 must be finite (J/m²), got {self.interlayer_coupling_J_m2!r}")
        if self.spacer_after_layer is None:
            if J != 0.0:
                raise ValueError("interlayer_coupling_J_m2 needs spacer_after_layer (the layer below the spacer)")
            spacer = -1
        else:
            spacer = int(self.spacer_after_layer)
            if not 0 <= spacer < mesh.nz - 1:
                raise ValueError(f"spacer_after_layer must be in 0..nz-2 = {mesh.nz - 2} "
                                 f"(nz = {mesh.nz}), got {self.spacer_after_layer!r}")
        K_u = _as_cell_array(self.K_u, mesh.shape, "K_u")
        axis = np.asarray(self.easy_axis, dtype=np.float64)
        if axis.shape == (3,):
            axis = axis[:, None, None, None]
        axis = _as_cell_array(axis, mesh.vector_shape, "easy_axis")
        norm = np.linalg.norm(axis, axis=0)
        if np.any(norm == 0):
            raise ValueError("easy_axis has zero-length vectors")
        axis = np.ascontiguousarray(axis / norm)
        frozen = np.zeros(mesh.shape, dtype=np.bool_) if self.frozen is None else np.ascontiguousarray(self.frozen, dtype=np.bool_)
        if frozen.shape != mesh.shape:
            raise ValueError(f"frozen mask has shape {frozen.shape}, expected {mesh.shape}")
        slaved = np.zeros(mesh.shape, dtype=np.bool_) if self.slaved is None else np.ascontiguousarray(self.slaved, dtype=np.bool_)
        if slaved.shape != mesh.shape:
            raise ValueError(f"slaved mask has shape {slaved.shape}, expected {mesh.shape}")
        slaved_cells = np.ascontiguousarray(np.argwhere(slaved & ~frozen).astype(np.int64).reshape(-1, 3))
        self.K_u, self.easy_axis, self.frozen, self.slaved = K_u, axis, frozen, slaved
        # cells the integrators do not move themselves: fixed ones and slaved ones
        immobile = np.ascontiguousarray(frozen | slaved)
        if "demag" in self.terms:
            kernel = periodic_film_kernel(mesh, self.n_alias, self.kernel_cache_dir).arrays()
        else:
            empty = np.zeros((1, 1, 1))
            kernel = (empty,) * 6
        self.model = FieldModel(
            float(self.Ms), float(self.A_ex), float(self.D), mesh.dx, mesh.dy, mesh.dz, float(self.K_2),
            np.asarray(self.B_bias_T, dtype=np.float64).reshape(3),
            K_u, axis, immobile, slaved_cells, spacer, J, *kernel,
            "exchange" in self.terms, "anisotropy" in self.terms, "dmi" in self.terms,
            "demag" in self.terms, "zeeman" in self.terms,
        )

    # ------------------------------------------------------------------ helpers
    def _check_m(self, m):
        if m.shape != self.mesh.vector_shape or m.dtype != np.float64 or not m.flags.c_contiguous:
            raise ValueError(f"m must be a C-contiguous float64 array of shape {self.mesh.vector_shape}")
        if not m.flags.writeable:
            raise ValueError("m must be writeable (it is updated in place)")
        return m

    @staticmethod
    def _field_vector(B_ext_T):
        b = np.asarray(B_ext_T, dtype=np.float64)
        if b.shape == ():
            b = np.array([0.0, 0.0, float(b)])
        if b.shape != (3,):
            raise ValueError("B_ext_T must be a scalar (along z) or a 3-vector in tesla")
        return b

    def uniform(self, direction=(0.0, 0.0, 1.0)) -> np.ndarray:
        """A uniform magnetization array along ``direction``."""
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        m = np.empty(self.mesh.vector_shape)
        m[...] = d[:, None, None, None]
        return m

    # ------------------------------------------------------------------ physics
    def effective_field(self, m, B_ext_T=0.0) -> np.ndarray:
        """B_eff (T), shape (3, nz, ny, nx)."""
        out = np.empty_like(self._check_m(m))
        compute_effective_field(m, self.model, self._field_vector(B_ext_T), out)
        return out

    def energy(self, m, B_ext_T=0.0) -> float:
        """Total energy (J)."""
        buffer = np.empty_like(self._check_m(m))
        return float(total_energy(m, self.model, self._field_vector(B_ext_T), buffer, self.mesh.cell_volume))

    def energies(self, m, B_ext_T=0.0) -> dict[str, float]:
        """Energy of each enabled term and the total (J)."""
        out = {}
        for term in self.terms:
            single = self.with_terms((term,))
            out[term] = single.energy(m, B_ext_T)
        out["total"] = self.energy(m, B_ext_T)
        return out

    def with_terms(self, terms) -> "Film":
        """A copy with another set of terms (shares arrays and the cached demag kernel)."""
        return Film(self.mesh, self.Ms, self.A_ex, self.K_u, self.easy_axis, self.D, self.frozen,
                    self.slaved, tuple(terms), self.n_alias, self.kernel_cache_dir, self.K_2,
                    self.B_bias_T if "zeeman" in terms else (0.0, 0.0, 0.0),
                    interlayer_coupling_J_m2=self.interlayer_coupling_J_m2,
                    spacer_after_layer=self.spacer_after_layer)

    def max_torque(self, m, B_ext_T=0.0) -> float:
        """max_i |m_i × B_eff,i| (T) over non-frozen cells."""
        field_ = self.effective_field(m, B_ext_T)
        return float(torque_and_max(m, field_, self.frozen, np.empty_like(m)))  # slaved cells count

    def minimize(self, m, B_ext_T=0.0, torque_tol_T=1e-4, max_iterations=50_000,
                 max_rotation_rad=0.5, require_convergence=False, initial_step=0.0) -> MinimizeResult:
        """Relax ``m`` in place to a local energy minimum (quasi-static path, see ``minimize``);
        ``initial_step``: the first BB step (e.g. the ``last_step`` of the previous field step)."""
        self._check_m(m)
        redone = False
        if self.preconditioner == "fourier":
            start = m.copy() if self.fourier_guard_dm > 0 else None
            it, torque, ok, h = minimize_bb_fourier(m, self.model, self._field_vector(B_ext_T), float(torque_tol_T),
                                                    int(max_iterations), float(max_rotation_rad), float(initial_step),
                                                    self._fourier_preconditioner())
            if start is not None and np.abs(m - start).max() > self.fourier_guard_dm:
                # an irreversible event: its path (and so the minimum reached) belongs to plain descent
                m[...] = start
                it2, torque, ok, h = minimize_bb(m, self.model, self._field_vector(B_ext_T), float(torque_tol_T),
                                                 int(max_iterations), float(max_rotation_rad), 0.0)
                it += it2
                redone = True
        else:
            it, torque, ok, h = minimize_bb(m, self.model, self._field_vector(B_ext_T), float(torque_tol_T),
                                            int(max_iterations), float(max_rotation_rad), float(initial_step))
        if not np.isfinite(torque) or not np.all(np.isfinite(m)):
            raise SimulationError(f"minimizer diverged after {it} iterations (non-finite torque)")
        if require_convergence and not ok:
            raise SimulationError(f"minimizer did not reach max torque {torque_tol_T:g} T in {it} iterations "
                                  f"(max torque {torque:.3g} T)")
        return MinimizeResult(int(it), float(torque), bool(ok), float(h))

    def _fourier_preconditioner(self):
        cached = getattr(self, "_fourier_cache", None)
        if cached is None:
            cached = fourier_preconditioner(self.model, FOURIER_STIFFNESS_T)
            object.__setattr__(self, "_fourier_cache", cached)
        return cached

    def run_llg(self, m, duration_s, B_ext_T=0.0, alpha=0.02, ramp_T_per_s=0.0, dt_s=1e-14,
                tol=1e-5, max_steps=10_000_000) -> LLGResult:
        """Integrate LLG in place for ``duration_s`` (adaptive Dormand–Prince RK45)."""
        self._check_m(m)
        t, dt, acc, rej, ok = run_llg_rk45(m, self.model, self._field_vector(B_ext_T), float(ramp_T_per_s),
                                           float(alpha), 0.0, float(duration_s),
                                           StepControl(float(dt_s), float(tol), int(max_steps)))
        if not np.all(np.isfinite(m)):
            raise SimulationError(f"LLG diverged at t = {t:.3e} s (non-finite magnetization)")
        return LLGResult(float(t), float(dt), int(acc), int(rej), bool(ok))
