"""Adapter to magnum.np (https://gitlab.com/magnum.np/magnum.np, PyPI ``magnumnp``), an independent
finite-difference micromagnetic code written in PyTorch, for a film that is periodic in x, y and
open in z. Used to cross-check our numba engine (``forcdecode.micromag``) and to benchmark it.

magnum.np is an optional extra (``pip install -e .[reference]``) and is imported lazily, inside
:class:`MagnumFilm`. Before the import the adapter sets ``CUDA_DEVICE=-1`` (``os.environ.setdefault``)
so that magnum.np runs on the CPU unless the caller chose a GPU explicitly.

Conventions (ours, in and out)
------------------------------
* ``m`` is float64 of shape (3, nz, ny, nx) (component, z, y, x), unit vectors. magnum.np stores
  (nx, ny, nz, 3); reversing the axis order (``transpose(3, 2, 1, 0)``) converts either way.
* Fields are returned as flux density B = μ0 H in tesla, shape (3, nz, ny, nx); energies in joules.
* ``B_ext_T``: a scalar (along z) or a 3-vector, in tesla (converted to H = B/μ0 for magnum.np).
* Energy densities: exchange A|∇m|², anisotropy −K_u (u·m)², Zeeman −M_s m·B_ext,
  demag −(μ0/2) M_s m·H_demag, interfacial DMI ε = D [m_z ∇·m − (m·∇) m_z] (mumax3 ``Dind``), field
  B_DMI = (2D/M_s)(∂x m_z, ∂y m_z, −∂x m_x − ∂y m_y).

magnum.np's ``InterfaceDMIField`` (DMI vectors e_x = ŷ, e_y = −x̂, h = 2D/(μ0 M_s) Σ_k e_k × ∂_k m)
gives exactly that field, so our D is passed unchanged (``DMI_SIGN = +1``). Verified numerically on
a cycloid m = (sin qx, 0, cos qx): magnum.np's DMI energy density is +D sin(q dx)/dx, as ours.
magnum.np 2.2.0 has a bug in the periodic y-direction of its DMI (it averages D with ``dx`` where it
means ``dy``: the y part of the field is scaled by 2 dy/(dx + dy)); for dx ≠ dy the adapter
compensates by splitting the DMI into an x and a y term with a rescaled D for y.

Demag: ``DemagField`` on a ``Mesh(pbc=(P, P, 0))`` - Newell near field (within p = 20 cell
diagonals), dipole far field, and a truncated sum over the (2P+1)² periodic images in x and y. The
images beyond P are missing: for a uniform perpendicular film of thickness t and period L the
outside of the (2P+1)L square contributes N_zz deficit ≈ √2 t / (π (P + ½) L) (measured 0.99731 for
32×32×1 cells of 2×2×4 nm, P = 10; the formula gives 0.99732), and uniform in-plane m gets
N_xx ≈ half of that instead of 0. Our engine's film kernel is the exact infinite-periodic one, so
comparisons must allow for this (or use larger P / L). The kernel build costs ∝ (2P+1)² - on 2 CPU
cores 64×64×1: P=1 0.9 s, 2 1.9 s, 5 8 s, 10 30 s; 256×256×2: P=1 1.6 s, 2 4 s, 5 15 s, 10 65 s;
``cache_dir`` stores it. Note magnum.np's ``pbc=0`` means an open, isolated film, so P ≥ 1 is required.

Constants differ slightly from ours: magnum.np uses μ0 = 1.2566370614e-6 (relative difference to
4π·1e-7 is 3e-11) and γ = 2.21276157e5 m/(A·s), i.e. γ/μ0 = 1.76086e11 rad/(T·s) versus mumax3's
1.7595e11 used by our LLG (0.08 % difference in precession frequency and time scale).
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TERMS = ("exchange", "anisotropy", "dmi", "demag", "zeeman")
"""Energy terms the adapter knows (same names as ``forcdecode.micromag.film.TERMS``)."""

DMI_SIGN = +1.0
"""magnum.np's ``Di`` = DMI_SIGN × our D (mumax3 ``Dind`` convention); checked numerically."""

_INSTALL_HINT = (
    "magnum.np is needed for the reference cross-checks/benchmarks but is not installed; "
    "install the optional extra with: pip install -e .[reference]"
)


def _import_magnumnp():
    """Import magnum.np (on CPU unless CUDA_DEVICE was set) and return the module."""
    os.environ.setdefault("CUDA_DEVICE", "-1")
    try:
        import magnumnp  # noqa: PLC0415  (lazy on purpose: optional dependency)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(_INSTALL_HINT) from exc
    except SystemExit as exc:  # pragma: no cover - magnum.np calls exit() if a submodule fails
        raise ImportError("magnum.np is installed but failed to import (see its log above); "
                          "reinstall with: pip install -e .[reference]") from exc
    return magnumnp


def magnumnp_available() -> bool:
    """True if magnum.np can be imported (without importing it)."""
    import importlib.util

    return importlib.util.find_spec("magnumnp") is not None


@dataclass(frozen=True)
class MagnumGrid:
    """The film's finite-difference grid for :class:`MagnumFilm`: ``nx`` × ``ny`` × ``nz`` cells (x, y
    periodic, z open) of ``dx`` × ``dy`` × ``dz`` metres. Any object with these six attributes will do
    (``forcdecode.micromag.Mesh`` has them)."""

    nx: int
    ny: int
    nz: int
    dx: float
    dy: float
    dz: float


@dataclass(frozen=True)
class MagnumMaterial:
    """The film's material for :class:`MagnumFilm` (SI).

    - ``Ms``: saturation magnetization (A/m, scalar, > 0);
    - ``A_ex``: exchange stiffness (J/m, scalar);
    - ``K_u``: uniaxial anisotropy (J/m³), scalar or per-cell array (nz, ny, nx);
    - ``easy_axis``: anisotropy axis, 3-vector or per-cell array (3, nz, ny, nx); normalized by the film;
    - ``D``: interfacial DMI (J/m²) in mumax3's ``Dind`` convention (see the module docstring);
    - ``alpha``: Gilbert damping (dimensionless), used by :meth:`MagnumFilm.time_llg_step`.
    """

    Ms: float
    A_ex: float
    K_u: float | np.ndarray = 0.0
    easy_axis: tuple | np.ndarray = (0.0, 0.0, 1.0)
    D: float = 0.0
    alpha: float = 1.0


class MagnumFilm:
    """magnum.np model of a film periodic in x, y (pseudo-PBC images) and open in z.

    The magnum.np mesh, state, field terms and the demag kernel are built once in the constructor
    (the kernel build is the expensive part; with ``cache_dir`` it is saved to / loaded from disk).

    Parameters
    ----------
    grid : :class:`MagnumGrid` (cells nx, ny, nz; cell size dx, dy, dz in m), or any object with those
        attributes (``forcdecode.micromag.Mesh``).
    material : :class:`MagnumMaterial` (Ms A/m, A_ex J/m, K_u J/m³ scalar or (nz, ny, nx), easy_axis
        3-vector or (3, nz, ny, nx), D J/m², Gilbert damping alpha).
    terms : subset of :data:`TERMS`.
    pbc_images : number P ≥ 1 of periodic images on each side in x and y for the demag sum
        (magnum.np ``Mesh(pbc=(P, P, 0))``; any P ≥ 1 makes exchange/DMI periodic in x, y). The
        kernel build costs ∝ (2P+1)² (see module docstring); the field evaluation does not depend on P.
    cache_dir : directory for the demag kernel (magnum.np's own ``DemagField(cache_dir=...)``
        mechanism; the adapter uses the subfolder ``magnumnp-<version>-p<near>`` because magnum.np's
        file name ``N_<mesh>.pt`` only encodes n, dx (6 digits) and pbc, not p or the version).
    compile : let magnum.np use ``torch.compile`` for exchange/anisotropy/DMI (needs a C compiler;
        the first call in a fresh process costs ~30 s of compilation, ~3-5 s when TorchInductor's
        on-disk cache is warm, and again for every new grid shape; afterwards the total field is
        ~1.7-2× faster on CPU). ``False`` (default) runs them eagerly: the adapter wraps each of its
        calls in ``torch.compiler.set_stance("force_eager")`` (per call, so compiled and eager
        instances can coexist in one process; ``torch._dynamo.config.patch(disable=True)`` does
        not work for this - a function first run disabled stays uncompiled for the process).
        Results agree to rounding.
    demag_near_p : magnum.np's near-field radius ``p`` (in cell diagonals) for Newell's formulas.
    log_level : level for magnum.np's logger (``logging.WARNING`` silences its INFO chatter).
    """

    def __init__(self, grid: MagnumGrid, material: MagnumMaterial, *, terms=TERMS, pbc_images=10, cache_dir=None,
                 compile=False, demag_near_p=20, log_level=30):
        mnp = _import_magnumnp()
        import torch  # noqa: PLC0415

        self._mnp = mnp
        self._torch = torch
        mnp.set_log_level(log_level)

        self.nx, self.ny, self.nz = int(grid.nx), int(grid.ny), int(grid.nz)
        self.dx, self.dy, self.dz = float(grid.dx), float(grid.dy), float(grid.dz)
        self.Ms, self.A_ex = float(material.Ms), float(material.A_ex)
        self.D, self.alpha = float(material.D), float(material.alpha)
        self.pbc_images = int(pbc_images)
        self.compile = bool(compile)
        unknown = set(terms) - set(TERMS)
        if unknown:
            raise ValueError(f"unknown energy terms {sorted(unknown)}; known: {TERMS}")
        self.terms = tuple(t for t in TERMS if t in terms)
        if not (self.Ms > 0):
            raise ValueError("Ms must be positive")
        if self.pbc_images < 1:
            # magnum.np's pbc=0 means *open* in that direction (exchange/DMI boundaries and a
            # zero-padded demag of an isolated slab), not "periodic without images".
            raise ValueError("pbc_images must be >= 1 (magnum.np's pbc=0 means a non-periodic, isolated film)")

        self.mu0 = float(mnp.constants.mu_0)
        self.gamma_T = float(mnp.constants.gamma) / self.mu0  # rad/(T s)
        self.cell_volume = self.dx * self.dy * self.dz
        self.dtype = torch.float64
        shape_zyx = (self.nz, self.ny, self.nx)

        with self._dynamo():
            mesh = mnp.Mesh((self.nx, self.ny, self.nz), (self.dx, self.dy, self.dz),
                            pbc=(self.pbc_images, self.pbc_images, 0))
            state = mnp.State(mesh)
            self.device = state.device

            K_u = np.broadcast_to(np.asarray(material.K_u, dtype=np.float64), shape_zyx)
            axis = np.asarray(material.easy_axis, dtype=np.float64)
            if axis.shape == (3,):
                axis = axis[:, None, None, None]
            axis = np.broadcast_to(axis, (3,) + shape_zyx)
            norm = np.linalg.norm(axis, axis=0)
            if np.any(norm == 0):
                raise ValueError("easy_axis has zero-length vectors")
            axis = axis / norm

            mnp_material = {
                "Ms": self.Ms,
                "A": self.A_ex,
                "Ku": self._to_mnp_scalar_field(K_u),
                "Ku_axis": self._to_mnp(axis),
                "Di": DMI_SIGN * self.D,
                "alpha": self.alpha,
            }
            split_dmi = self.dx != self.dy
            if split_dmi:
                # magnum.np 2.2.0 averages D over the periodic y link with dx instead of dy
                # (D_avg = 2D/(dy + dx)); a rescaled D makes the y part come out as D/dy.
                mnp_material["Di_y"] = DMI_SIGN * self.D * (self.dx + self.dy) / (2.0 * self.dy)
            state.material = mnp_material
            state.m = state.Constant([0.0, 0.0, 1.0])
            self._state = state

            self._fields = {}
            if "exchange" in self.terms:
                self._fields["exchange"] = [mnp.ExchangeField()]
            if "anisotropy" in self.terms:
                self._fields["anisotropy"] = [mnp.UniaxialAnisotropyField()]
            if "dmi" in self.terms:
                if split_dmi:
                    self._fields["dmi"] = [
                        mnp.DMIField([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], D="Di"),
                        mnp.DMIField([[0.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], D="Di_y"),
                    ]
                else:
                    self._fields["dmi"] = [mnp.InterfaceDMIField()]
            if "zeeman" in self.terms:
                self._zeeman = mnp.ExternalField(state.Constant([0.0, 0.0, 0.0]))
                self._fields["zeeman"] = [self._zeeman]
            self._B_ext_current = None

            self.kernel_build_s = 0.0
            self.kernel_from_cache = False
            self.cache_dir = None
            if "demag" in self.terms:
                if cache_dir is not None:
                    version = getattr(mnp, "__version__", "unknown")
                    self.cache_dir = str(Path(cache_dir) / f"magnumnp-{version}-p{int(demag_near_p)}")
                demag = mnp.DemagField(p=int(demag_near_p), cache_dir=self.cache_dir)
                if self.cache_dir is not None:
                    name = "N_%s.pt" % str(mesh).replace(" ", "")
                    self.kernel_from_cache = os.path.isfile(os.path.join(self.cache_dir, name))
                t0 = time.perf_counter()
                demag._N = demag._init_N(state)  # build (or load) the kernel now, once
                self.kernel_build_s = time.perf_counter() - t0
                self._fields["demag"] = [demag]

    # ------------------------------------------------------------------ helpers
    @contextmanager
    def _dynamo(self):
        """Honour ``self.compile`` for the duration of an adapter call (torch.compiler stance)."""
        stance = "default" if self.compile else "force_eager"
        with self._torch.compiler.set_stance(stance):
            yield

    def _to_mnp(self, a):
        """(3, nz, ny, nx) numpy → (nx, ny, nz, 3) torch float64 on magnum.np's device."""
        a = np.ascontiguousarray(np.transpose(np.asarray(a, dtype=np.float64), (3, 2, 1, 0)))
        return self._torch.tensor(a, dtype=self.dtype, device=self.device)

    def _to_mnp_scalar_field(self, a):
        """(nz, ny, nx) numpy → (nx, ny, nz, 1) torch float64."""
        a = np.ascontiguousarray(np.transpose(np.asarray(a, dtype=np.float64), (2, 1, 0)))[..., None]
        return self._torch.tensor(a, dtype=self.dtype, device=self.device)

    @staticmethod
    def _from_mnp(t):
        """(nx, ny, nz, 3) torch → (3, nz, ny, nx) C-contiguous numpy float64."""
        a = t.detach().to("cpu").numpy()
        return np.ascontiguousarray(np.transpose(a, (3, 2, 1, 0)), dtype=np.float64)

    @staticmethod
    def _field_vector(B_ext_T):
        b = np.asarray(B_ext_T, dtype=np.float64)
        if b.shape == ():
            b = np.array([0.0, 0.0, float(b)])
        if b.shape != (3,):
            raise ValueError("B_ext_T must be a scalar (along z) or a 3-vector in tesla")
        return b

    def _set_m(self, m):
        m = np.asarray(m, dtype=np.float64)
        if m.shape != (3, self.nz, self.ny, self.nx):
            raise ValueError(f"m must have shape (3, nz, ny, nx) = {(3, self.nz, self.ny, self.nx)}, got {m.shape}")
        self._state.m = self._to_mnp(m)
        self._state.t = 0.0

    def _set_B_ext(self, B_ext_T):
        if "zeeman" not in self.terms:
            return
        b = self._field_vector(B_ext_T)
        if self._B_ext_current is None or not np.array_equal(b, self._B_ext_current):
            H = self._torch.tensor(b / self.mu0, dtype=self.dtype, device=self.device)
            self._zeeman.h = self._state.Constant(H)  # full (nx, ny, nz, 3) tensor field
            self._B_ext_current = b.copy()

    def _all_fields(self):
        return [f for name in self.terms for f in self._fields[name]]

    def _h_total(self):
        return sum(f.h(self._state) for f in self._all_fields())

    # ------------------------------------------------------------------ physics
    def effective_field_T(self, m, B_ext_T=0.0) -> np.ndarray:
        """Effective flux density B_eff = μ0 H_eff (T) of all enabled terms, shape (3, nz, ny, nx).

        ``B_ext_T`` (scalar along z, or 3-vector, tesla) only enters if "zeeman" is in ``terms``.
        """
        with self._dynamo():
            self._set_m(m)
            self._set_B_ext(B_ext_T)
            return self._from_mnp(self.mu0 * self._h_total())

    def term_fields_T(self, m, B_ext_T=0.0) -> dict[str, np.ndarray]:
        """B (T) of each enabled term separately, shape (3, nz, ny, nx) each."""
        with self._dynamo():
            self._set_m(m)
            self._set_B_ext(B_ext_T)
            return {name: self._from_mnp(self.mu0 * sum(f.h(self._state) for f in self._fields[name]))
                    for name in self.terms}

    def energies_J(self, m, B_ext_T=0.0) -> dict[str, float]:
        """Energy (J) of each enabled term and ``"total"``.

        Computed from magnum.np's fields as magnum.np's own ``E`` does: −(μ0/2) Σ M_s m·h V for the
        terms linear in m (exchange, anisotropy, DMI, demag) and −μ0 Σ M_s m·h V for Zeeman.
        """
        with self._dynamo():
            self._set_m(m)
            self._set_B_ext(B_ext_T)
            state = self._state
            out = {}
            for name in self.terms:
                h = sum(f.h(state) for f in self._fields[name])
                factor = 1.0 if name == "zeeman" else 0.5
                e = -factor * self.mu0 * (state.material["Ms"] * state.m * h).sum() * self.cell_volume
                out[name] = float(e)
            out["total"] = float(sum(out.values()))
            return out

    # ------------------------------------------------------------------ timings
    def time_field_evaluation(self, m, repeats=20, B_ext_T=0.0) -> float:
        """Wall seconds per evaluation of the total effective field (magnum.np side only).

        One untimed warm-up call first (it triggers torch.compile when ``compile=True``). The
        ``repeats`` evaluations are timed in up to 5 blocks and the fastest block is reported
        (robust against other processes on a shared machine); all block times are kept in
        ``self.last_field_timing``.
        """
        repeats = max(1, int(repeats))
        n_blocks = min(5, repeats)
        sizes = [repeats // n_blocks + (1 if i < repeats % n_blocks else 0) for i in range(n_blocks)]
        with self._dynamo():
            self._set_m(m)
            self._set_B_ext(B_ext_T)
            self._h_total()
            per_eval = []
            for size in sizes:
                t0 = time.perf_counter()
                for _ in range(size):
                    h = self._h_total()
                h.sum().item()  # make sure the work is done (matters on a GPU)
                per_eval.append((time.perf_counter() - t0) / size)
        self.last_field_timing = {"per_eval_s_by_block": per_eval, "evaluations": repeats}
        return min(per_eval)

    def time_llg_step(self, m, n_steps=20, B_ext_T=0.0) -> float:
        """Wall seconds per accepted step of magnum.np's ``LLGSolver`` (damping ``alpha``).

        magnum.np's default integrator is ``RKF45``: adaptive Runge–Kutta–Fehlberg 4(5), 6 field
        evaluations per attempt, advancing with the 5th-order solution, step control on
        max|err|/(atol + rtol|m|) with atol = rtol = 1e-5, initial dt 1e-15 s, max dt 1e-10 s;
        m is renormalized after each ``LLGSolver.step`` call. Here every call advances by the
        solver's current adaptive step (so normally one RK attempt per accepted step; rejected
        attempts are included in the time). A few untimed warm-up steps let dt settle first; the
        ``n_steps`` steps are timed in up to 5 blocks and the fastest block's time per step is
        returned. Details (mean, blocks, field evaluations per step, dt) are in ``self.last_llg_stats``.
        """
        mnp = self._mnp
        with self._dynamo():
            self._set_m(m)
            self._set_B_ext(B_ext_T)
            state = self._state
            llg = mnp.LLGSolver(self._all_fields())
            solver = llg._solver
            counter = {"n": 0}
            f = solver._f

            def counted(*args, **kwargs):
                counter["n"] += 1
                return f(*args, **kwargs)

            solver._f = counted
            for _ in range(5):  # warm-up: compile, let dt grow from 1e-15
                llg.step(state, solver._dt)
            n_steps = max(1, int(n_steps))
            n_blocks = min(5, n_steps)
            block_target = [n_steps // n_blocks + (1 if i < n_steps % n_blocks else 0) for i in range(n_blocks)]
            counter["n"] = 0
            t_start = float(state.t)
            per_step, total_steps, total_time = [], 0, 0.0
            for target in block_target:
                steps0 = state._step
                t0 = time.perf_counter()
                while state._step - steps0 < target:
                    llg.step(state, solver._dt)
                elapsed = time.perf_counter() - t0
                steps = state._step - steps0
                per_step.append(elapsed / steps)
                total_steps += steps
                total_time += elapsed
            self.last_llg_stats = {
                "accepted_steps": total_steps,
                "rhs_evaluations": counter["n"],
                "simulated_time_s": float(state.t) - t_start,
                "last_dt_s": float(solver._dt),
                "mean_seconds_per_step": total_time / total_steps,
                "seconds_per_step_by_block": per_step,
            }
            state.t = 0.0
        return min(per_step)

    # ------------------------------------------------------------------ relaxation
    def minimize(self, m, B_ext_T=0.0, torque_tol_T=None, max_iterations=2000,
                 tau_min=1e-13, tau_max=1e-5) -> np.ndarray:
        """Relax ``m`` with magnum.np's ``MinimizerBB`` (Barzilai–Borwein, semi-implicit midpoint).

        Convergence: max over cells and components of |m × (m × h)| < dm_tol with h in A/m;
        ``torque_tol_T`` is that bound in tesla (default: magnum.np's dm_tol = 1 A/m, ≈1.26e-6 T).
        Returns the relaxed m, shape (3, nz, ny, nx); ``self.last_minimize_converged`` tells
        whether it converged within ``max_iterations``.
        """
        mnp = self._mnp
        dm_tol = 1.0 if torque_tol_T is None else float(torque_tol_T) / self.mu0
        with self._dynamo():
            self._set_m(m)
            self._set_B_ext(B_ext_T)
            minimizer = mnp.MinimizerBB(self._all_fields())
            self.last_minimize_converged = bool(minimizer.minimize(
                self._state, maxiter=int(max_iterations), dm_tol=dm_tol, tau_min=tau_min, tau_max=tau_max))
            return self._from_mnp(self._state.m)
