"""Independent "measurements": FORC families computed by magnum.np, on another grid and another
disorder model than ours, recorded by an instrument model written apart from the loop's candidates,
and saved in real instrument formats. The test data of the residual analysis
(``forcdecode bench effects --independent``) must not be made by the model under test: nothing here
imports our engine (``micromag``), our protocols (``forc``) or the loop's effect formulas.

Sample (``IndependentFilm``): ``nx`` × ``ny`` × 1 cells of ``cell_nm`` (default 20 × 20 cells of
2.5 nm, 4 nm thick: another discretization and another box than the fitting film), periodic in-plane
(magnum.np pseudo-PBC with ``pbc_images`` images: its missing far images are a demag error of
≈ √2 t / (π (P + ½) L), part of what makes it another code). Disorder: ``n_grains`` columnar grains from
a periodic nearest-seed tessellation drawn here; per grain K_u·(1 + Δ) with Δ of standard deviation
σ_K, Gaussian as ours or **uniform** (a disorder model ours does not have), and the easy axis tilted by |θ| with θ ~ N(0, σ_θ) at uniform azimuth.
Grain sizes: equal seeds (nearest-seed cells, as ours) or **log-normal** (a power diagram: seed k claims
the cells minimizing d² − r_k², r_k log-normal; grain areas then spread far more than ours). Pinning
(``pinning_cells`` > 0): that many cells, drawn here, with K_u = ``PIN_K_U`` along z, whose moment
starts at a random orientation (isotropic, as ours draws it) or along **±z only**
(``pin_orientation="z"``, which ours does not draw) and, with an anisotropy field of ≈ 100 T, keeps it
through the protocol. ``pins_for_density`` converts the Hamiltonian's N_pin (sites on the seed paper's
256 × 256 × 2 grid of 2 × 2 × 4 nm cells) into a count at the same density per volume: a pinning cell
here is one cell of this grid, so its volume differs from ours (another pin size).

Physics of the sample (magnum.np terms): exchange, uniaxial anisotropy, interfacial DMI, demag,
Zeeman, optionally a second-order anisotropy −K_2 (u·m)⁴ (``UniaxialAnisotropyField2``), a bias
field B_bias ẑ felt by the film, the applied field tilted by ψ from the normal (the instrument then
records ⟨m⟩·ĥ, ĥ the field direction), and a second, soft phase (a fraction f of the moment from a film
of the same parameters and disorder model with K_u,soft) that does not interact with the first.

Protocol (quasi-static, magnum.np's ``MinimizerBB`` at every field, torque below ``torque_tol_T``):
saturate at the top field, descend through the reversal fields keeping each state, then for each
reversal field from the highest sweep up through the curve's field points; steps larger than
``max_step_T`` are made in equal sub-steps. Where a curve reaches a field of the curve reversed just
above it with the same state (max cell |Δm| < ``same_state_tol``) the rest of it is that curve's (the
state then follows the same path): exact where the protocol's fields coincide (``measurement_protocol``).

With ``sweep_step_T`` (δ) the field sweeps as a magnet ramps: the path relaxes at the nodes k·δ only,
the same fields going down and up (the lattice is its own mirror), and a measured point is a
snapshot relaxed at its field from the last node, which the path does not continue from; a
reversal field is where the descent to that curve stops (a snapshot of the continuing major
descent) and its curve starts. Stepping through the measured points instead makes the path depend
on where the instrument samples: an avalanche fires at the first visited field past its switching
field, the descending branch visits only the reversal fields and the ascending one the curve's
points, two lattices that are not mirror images, so an unbiased film shows a loop centre off by
up to half a reversal-field spacing (measured on the bench's H0 film, 48 curves: +21 mT at
``max_step_T`` 50 mT, +3 mT with 5 mT steps through the points). Joining the curve above is tested
at the nodes.

Instrument (``InstrumentModel``), applied to the moment M_film·⟨m⟩·ĥ at the field the sample feels,
each point at its time t (s) on the measurement's own clock (``averaging_s`` per point, ``pause_s``
at each calibration and reversal, ``sweep_rate_T_per_s`` between points):

    reported field  = B_true + offset
    recorded moment = gain(t)·M_film·⟨m⟩·ĥ + χ·M_film·B_reported + M_film·[drift_add(t) + σ ε]
                      + M_film·A_L·L(B_reported/B_L)         (a saturating paramagnet, outside the library)

with gain(t) = scale·(1 + g·(1 − e^{−t/t_g})/(1 − e^{−T/t_g})) (an exponential warm-up, not the loop's linear
clock), drift_add(t) = d·(t/T)^{1.5} and the Langevin L(x) = coth x − 1/x; optionally a first-order
lag of the recorded moment (a lock-in time constant ``lag_points`` in averaging times, outside the
library); an exchange bias that trains away (``training_bias_T`` b_0: a curve measured after n curves
whose reversal point had the film reversed (⟨m⟩·ĥ < 0 there: the curves that cycle the film) responds
as in a field B + b_0·e^{−n/n_0}, n_0 = ``training_curves``; the response is the
unbiased curve's read at the shifted field, its reversal state the unbiased descent's: an
approximation, outside the library's constant bias); and noise correlated along each curve (an AR(1)
of stationary amplitude ``correlated_noise`` and correlation length ``correlation_points``, on top of
the white σ; outside the loop's white-noise model). Calibration points (at the top field before each curve) do not see the drift by default (an
undeclared drift, e.g. of the sample's temperature: the reader's calibration-based correction cannot
remove it); with ``calibration_sees_drift`` they carry the same gain and drift as the data, and the
reader's drift correction removes a gain drift. Noise σ in units of the film moment.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..measured.writers import write_lakeshore_csv, write_micromag_0015
from .magnumnp_film import MagnumFilm, MagnumGrid, MagnumMaterial

PIN_K_U = 5e7
"""Anisotropy of a pinning cell (J/m³, along z): the seed paper's 50 MJ/m³."""

REFERENCE_PIN_VOLUME_NM3 = 256 * 256 * 2 * 2.0 * 2.0 * 4.0
"""The volume (nm³) over which the Hamiltonian's N_pin counts pinning sites: the seed paper's grid."""


def pins_for_density(N_pin: float, film: "IndependentFilm") -> int:
    """Pinning cells of ``film`` at the density per volume of N_pin sites on the seed paper's grid."""
    volume = film.nx * film.ny * film.cell_nm**2 * film.thickness_nm
    return int(round(float(N_pin) * volume / REFERENCE_PIN_VOLUME_NM3))


@dataclass(frozen=True)
class IndependentFilm:
    """Grid and disorder model of the independent sample (see the module docstring)."""

    nx: int = 20
    ny: int = 20
    cell_nm: float = 2.5
    thickness_nm: float = 4.0
    n_grains: int = 24
    pbc_images: int = 4
    torque_tol_T: float = 1e-3
    max_iterations: int = 20000
    max_step_T: float = 0.05
    same_state_tol: float = 0.02
    anisotropy_distribution: str = "gaussian"
    sweep_step_T: float | None = None
    grain_sizes: str = "equal"
    pinning_cells: int = 0
    pin_orientation: str = "isotropic"

    @property
    def moment_Am2(self) -> float:
        """Film volume (m³); times M_s the saturation moment (A·m²)."""
        return self.nx * self.ny * (self.cell_nm * 1e-9) ** 2 * self.thickness_nm * 1e-9


def independent_disorder(film: IndependentFilm, sigma_K: float, sigma_theta_deg: float, rng: np.random.Generator):
    """Per-cell anisotropy factor (1 + Δ) and easy axis, shape (ny, nx) and (3, 1, ny, nx): periodic
    nearest-seed grains, Δ of standard deviation σ_K, Gaussian or uniform on [−√3 σ_K, √3 σ_K]
    (``film.anisotropy_distribution``; clipped at −0.95), axis tilted by |N(0, σ_θ)|. With
    ``film.grain_sizes == "lognormal"`` the grains are a power diagram of log-normal radii (drawn after
    everything else, so the other draws are those of equal grains)."""
    if film.grain_sizes not in ("equal", "lognormal"):
        raise ValueError(f"unknown grain sizes {film.grain_sizes!r} (equal or lognormal)")
    n = film.n_grains
    seeds = rng.uniform(0.0, 1.0, size=(n, 2)) * (film.nx, film.ny)
    y, x = np.mgrid[0:film.ny, 0:film.nx] + 0.5
    dx = np.abs(x[..., None] - seeds[:, 0])
    dy = np.abs(y[..., None] - seeds[:, 1])
    dx = np.minimum(dx, film.nx - dx)
    dy = np.minimum(dy, film.ny - dy)
    grain = np.argmin(dx**2 + dy**2, axis=-1)
    if film.anisotropy_distribution == "uniform":
        delta = rng.uniform(-math.sqrt(3.0), math.sqrt(3.0), size=n) * sigma_K
    elif film.anisotropy_distribution == "gaussian":
        delta = rng.normal(0.0, 1.0, size=n) * sigma_K
    else:
        raise ValueError(f"unknown anisotropy distribution {film.anisotropy_distribution!r} (gaussian or uniform)")
    delta = np.clip(delta, -0.95, None)
    theta = np.abs(rng.normal(0.0, math.radians(sigma_theta_deg), size=n))
    phi = rng.uniform(0.0, 2 * math.pi, size=n)
    axes = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    if film.grain_sizes == "lognormal":
        # radii of the mean grain's size, spread log-normally (σ_ln 0.6): big grains swallow small ones
        radius = math.sqrt(film.nx * film.ny / (math.pi * n)) * rng.lognormal(0.0, LOGNORMAL_SIGMA, size=n)
        grain = np.argmin(dx**2 + dy**2 - radius**2, axis=-1)
    return 1.0 + delta[grain], axes[:, grain][:, None, :, :]


LOGNORMAL_SIGMA = 0.6
"""σ of ln(radius) of the log-normal grains (``independent_disorder``)."""


def independent_pins(film: IndependentFilm, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``film.pinning_cells`` distinct cells (flat indices into ny × nx) and their initial unit moments
    (3, n): isotropic directions, or ±z with a random sign (``film.pin_orientation == "z"``)."""
    if film.pin_orientation not in ("isotropic", "z"):
        raise ValueError(f"unknown pin orientation {film.pin_orientation!r} (isotropic or z)")
    n = int(film.pinning_cells)
    if not 0 <= n <= film.nx * film.ny:
        raise ValueError(f"{n} pinning cells on {film.nx} x {film.ny} cells")
    cells = rng.choice(film.nx * film.ny, size=n, replace=False)
    if film.pin_orientation == "z":
        moments = np.zeros((3, n))
        moments[2] = rng.choice([-1.0, 1.0], size=n)
    else:
        moments = rng.normal(size=(3, n))
        moments /= np.linalg.norm(moments, axis=0)
    return cells, moments


@dataclass
class SampleFamily:
    """⟨m⟩·ĥ at every point of the protocol (``curves[k]`` aligned with ``curve_fields_T[k]``, the
    fields the sample felt), the reversal fields, and the cost."""

    reversal_fields_T: np.ndarray
    curve_fields_T: list
    curves: list
    stats: dict = field(default_factory=dict)


def _steps(start: float, stop: float, max_step: float) -> np.ndarray:
    n = max(1, int(math.ceil(abs(stop - start) / max_step - 1e-9)))
    return np.linspace(start, stop, n + 1)[1:]


@dataclass(frozen=True)
class SamplePhysics:
    """The independent sample's physics beyond ``params`` (module docstring, Physics of the sample).

    - ``K_2``: second-order anisotropy −K_2 (u·m)⁴ along the grains' axes (J/m³); 0: off;
    - ``B_bias_T``: a bias field B_bias ẑ felt by the film (T);
    - ``tilt_deg``: the applied field's tilt ψ from the film normal, towards x (degrees); the
      instrument records ⟨m⟩·ĥ;
    - ``K_u``: the uniaxial anisotropy (J/m³) instead of ``params["K_u"]`` (a soft phase); None:
      ``params``'.
    """

    K_2: float = 0.0
    B_bias_T: float = 0.0
    tilt_deg: float = 0.0
    K_u: float | None = None


@dataclass(frozen=True)
class _SampleProtocol:
    """A FORC protocol as the sample feels it: reversal fields (T), per curve its fields (T, from the
    reversal field upward), and the curves' order of simulation (highest reversal field first)."""

    reversal: np.ndarray
    curve_fields_T: list
    order: np.ndarray

    @classmethod
    def of(cls, reversal_fields_T, curve_fields_T) -> _SampleProtocol:
        reversal = np.asarray(reversal_fields_T, float)
        return cls(reversal, curve_fields_T, np.argsort(reversal)[::-1])

    def top(self) -> float:
        """The field the sample is saturated at: the protocol's largest (T)."""
        return max(float(np.max(np.concatenate([np.atleast_1d(f) for f in self.curve_fields_T]))),
                   float(self.reversal.max()))


class _Relaxer:
    """magnum.np relaxations of ``sample`` at B·ĥ + B_bias ẑ (T) to ``film``'s torque criterion,
    counted in ``stats["relaxations"]``; ``project`` is the recorded ⟨m⟩·ĥ."""

    def __init__(self, sample: MagnumFilm, film: IndependentFilm, physics: SamplePhysics, stats: dict):
        psi = math.radians(physics.tilt_deg)
        self.sample, self.film, self.stats = sample, film, stats
        self.direction = np.array([math.sin(psi), 0.0, math.cos(psi)])
        self.bias = np.array([0.0, 0.0, float(physics.B_bias_T)])

    def __call__(self, m, B):
        """The state relaxed from ``m`` at the applied field B (T along ĥ); RuntimeError if it does not converge."""
        film = self.film
        m = self.sample.minimize(m, B_ext_T=B * self.direction + self.bias, torque_tol_T=film.torque_tol_T,
                                 max_iterations=film.max_iterations)
        if not self.sample.last_minimize_converged:
            raise RuntimeError(f"magnum.np relaxation did not converge at {B:+.4f} T within {film.max_iterations} "
                               "iterations")
        self.stats["relaxations"] += 1
        return m

    def project(self, m) -> float:
        """⟨m⟩·ĥ, what the instrument's coils along the applied field see."""
        return float(np.tensordot(self.direction, m.reshape(3, -1).mean(axis=1), axes=1))


def _disordered_sample(params: dict, film: IndependentFilm, seed: int, physics: SamplePhysics, cache_dir):
    """The magnum.np sample of ``params`` with the disorder and pins of realisation ``seed`` (drawn
    here, not from our streams), and its initial state: +z, pinning cells at their own moments."""
    rng = np.random.default_rng([int(seed), 9001])  # our streams are not used: another code, another draw
    factor, axis = independent_disorder(film, float(params["sigma_K"]), float(params["sigma_theta_deg"]), rng)
    K_u = float(params["K_u"] if physics.K_u is None else physics.K_u)
    K_cells = (K_u * factor)[None]
    pins, pin_moments = independent_pins(film, np.random.default_rng([int(seed), 9002]))
    if pins.size:
        j, i = np.unravel_index(pins, (film.ny, film.nx))
        K_cells = K_cells.copy()
        K_cells[0, j, i] = PIN_K_U
        axis = np.array(axis, copy=True)
        axis[:, 0, j, i] = np.array([0.0, 0.0, 1.0])[:, None]
    d = film.cell_nm * 1e-9
    grid = MagnumGrid(film.nx, film.ny, 1, d, d, film.thickness_nm * 1e-9)
    material = MagnumMaterial(float(params["Ms"]), float(params["A_ex"]), K_u=K_cells, easy_axis=axis,
                              D=float(params["D"]), alpha=1.0)
    sample = MagnumFilm(grid, material, pbc_images=film.pbc_images, cache_dir=cache_dir)
    if physics.K_2:
        _add_second_order_anisotropy(sample, physics.K_2)
    m = np.zeros((3, 1, film.ny, film.nx))
    m[2] = 1.0
    if pins.size:
        m[:, 0, j, i] = pin_moments  # a pinning cell keeps (near) its initial pole throughout
    return sample, m


def magnumnp_family(params: dict, reversal_fields_T, curve_fields_T, *, film: IndependentFilm = IndependentFilm(),
                    seed: int = 0, cache_dir=None, progress=None, **physics) -> SampleFamily:
    """The FORC family of ``params`` (SI: Ms, A_ex, K_u, D, sigma_K, sigma_theta_deg) on the sample
    ``film``, computed by magnum.np (module docstring). ``reversal_fields_T``: the curves' reversal
    fields; ``curve_fields_T[k]``: the fields of curve k from its reversal field upward (the field the
    sample feels, before any instrument offset). ``seed``: the disorder realisation. ``physics``: the
    ``SamplePhysics`` fields by keyword (``K_2``, ``B_bias_T``, ``tilt_deg``, ``K_u``: a soft phase).
    ``progress(done, total)`` is called per curve. Raises RuntimeError when a relaxation does not converge."""
    sample_physics = SamplePhysics(**physics)
    sample, m = _disordered_sample(params, film, seed, sample_physics, cache_dir)
    stats = {"relaxations": 0, "points_copied": 0, "wall_s": 0.0}
    start = time.perf_counter()
    relax = _Relaxer(sample, film, sample_physics, stats)
    protocol = _SampleProtocol.of(reversal_fields_T, curve_fields_T)
    top = protocol.top()
    m = relax(m, top)
    if film.sweep_step_T is not None:
        curves = _lattice_sweep(film, relax, m, top, protocol, progress)
    else:
        curves = _stepped_sweep(film, relax, m, top, protocol, progress)
    stats["wall_s"] = time.perf_counter() - start
    return SampleFamily(protocol.reversal, [np.asarray(f, float) for f in curve_fields_T], curves, stats)


def _stepped_sweep(film: IndependentFilm, relax: _Relaxer, m, top: float, protocol: _SampleProtocol, progress) -> list:
    """The stepped protocol of the module docstring (steps of at most ``film.max_step_T`` through the
    measured points; a curve meeting the state of the curve above at one of its fields continues as
    it): per curve the moments at its fields."""
    reversal, curve_fields_T, order = protocol.reversal, protocol.curve_fields_T, protocol.order
    B, kept = top, {}
    for k in order:  # the descending major loop, keeping the state at each reversal field
        for b in _steps(B, float(reversal[k]), film.max_step_T):
            m = relax(m, float(b))
        B = float(reversal[k])
        kept[k] = m.copy()
    curves = [None] * len(reversal)
    above = {}  # states of the curve reversed just above this one, by field (rounded to 1e-9 T)
    for done, k in enumerate(order):
        m, B, values, here = kept[k], float(reversal[k]), [], {}
        fields = np.asarray(curve_fields_T[k], float)
        higher = order[done - 1] if done else None
        for j, h in enumerate(fields):
            if h != B:
                for b in _steps(B, float(h), film.max_step_T):
                    m = relax(m, float(b))
                B = float(h)
            values.append(relax.project(m))
            here[round(B, 9)] = m
            twin = above.get(round(B, 9))
            if twin is not None and float(np.abs(twin - m).max()) < film.same_state_tol:
                # the state equals the higher curve's at this field: the rest of the curve is that curve's
                rest = fields[j + 1:]
                higher_fields = np.asarray(curve_fields_T[higher], float)
                values.extend(np.interp(rest, higher_fields, curves[higher]))
                relax.stats["points_copied"] += rest.size
                break
        curves[k] = np.asarray(values)
        above = here
        if progress is not None:
            progress(done + 1, len(order))
    return curves


def _nodes(start: float, stop: float, step: float) -> list:
    """Lattice fields k·step strictly between ``start`` and ``stop``, in the order a sweep meets them."""
    eps = 1e-9
    if stop > start:
        return [k * step for k in range(math.floor(start / step + eps) + 1, math.ceil(stop / step - eps))]
    return [k * step for k in range(math.ceil(start / step - eps) - 1, math.floor(stop / step + eps), -1)]


def _lattice_sweep(film: IndependentFilm, relax: _Relaxer, m, top: float, protocol: _SampleProtocol, progress) -> list:
    """The ramped protocol of the module docstring (``IndependentFilm.sweep_step_T``): per curve the
    moments at its fields."""
    reversal, curve_fields_T, order, project = protocol.reversal, protocol.curve_fields_T, protocol.order, relax.project
    step = float(film.sweep_step_T)
    if not step > 0:
        raise ValueError(f"sweep_step_T must be > 0 (got {step!r})")
    B, kept = top, {}
    for k in order:  # one continuous descent; each reversal state a snapshot of it
        for b in _nodes(B, float(reversal[k]), step):
            m = relax(m, b)
            B = b
        kept[k] = relax(m.copy(), float(reversal[k]))
    curves = [None] * len(reversal)
    above = {}  # node index -> state of the curve reversed just above this one
    for done, k in enumerate(order):
        m, B = kept[k], float(reversal[k])
        fields = np.asarray(curve_fields_T[k], float)
        values, here, joined = [], {}, None
        higher = order[done - 1] if done else None
        for j, h in enumerate(fields):
            for b in _nodes(B, float(h), step):
                m = relax(m, b)
                B = b
                node = int(round(b / step))
                here[node] = m
                twin = above.get(node)
                if twin is not None and float(np.abs(twin - m).max()) < film.same_state_tol:
                    joined = j
                    break
            if joined is not None:
                break
            values.append(project(m) if h == B else project(relax(m.copy(), float(h))))
        if joined is not None:
            # from this node on the state is the higher curve's: so are the rest of the points
            rest = fields[joined:]
            values.extend(np.interp(rest, np.asarray(curve_fields_T[higher], float), curves[higher]))
            relax.stats["points_copied"] += rest.size
        curves[k] = np.asarray(values)
        above = here
        if progress is not None:
            progress(done + 1, len(order))
    return curves


def _add_second_order_anisotropy(sample, K_2: float) -> None:
    """Add magnum.np's ``UniaxialAnisotropyField2`` (−K_2 (u·m)⁴, the grains' axes) to a ``MagnumFilm``."""
    mnp = sample._mnp
    state = sample._state
    state.material["Ku2"] = float(K_2)
    sample._fields["anisotropy2"] = [mnp.UniaxialAnisotropyField2()]
    sample.terms = sample.terms + ("anisotropy2",)


def average_families(families, weights=None, stats=None) -> SampleFamily:
    """Σ w_i·family_i point by point (weights default equal): non-interacting phases or patches
    measured together. The families must share the protocol; ``stats`` of the result (default: the
    parts' stats)."""
    weights = np.full(len(families), 1.0 / len(families)) if weights is None else np.asarray(weights, float)
    first = families[0]
    curves = [sum(w * f.curves[i] for w, f in zip(weights, families)) for i in range(len(first.curves))]
    return replace(first, curves=curves, stats={"parts": [f.stats for f in families]} if stats is None else stats)


def mix_phases(main: SampleFamily, soft: SampleFamily, fraction: float) -> SampleFamily:
    """(1 − f)·main + f·soft, point by point (two non-interacting phases measured together)."""
    return average_families([main, soft], [1 - fraction, fraction], stats={**main.stats, "soft_phase": soft.stats})


def measurement_protocol(n_curves: int = 24, B_max_T: float = 1.0, shift: float = 0.37) -> tuple[np.ndarray, list]:
    """A FORC protocol off the fitting grid (``n_curves`` fields over ±``B_max_T``): reversal fields
    on the lattice of spacing Δ = 2 B_max/n_curves shifted by ``shift``·Δ, field points every Δ/2 from
    the reversal field up to the lattice point at or below ``B_max_T`` (all curves share field points,
    so a curve can continue as the one above it)."""
    spacing = 2 * B_max_T / n_curves
    reversal = -B_max_T + (np.arange(n_curves) + shift) * spacing
    top = reversal[-1] + np.floor((B_max_T - reversal[-1]) / (spacing / 2) + 1e-9) * spacing / 2
    curves = [h + np.arange(int(np.rint((top - h) / (spacing / 2))) + 1) * spacing / 2 for h in reversal]
    return reversal, curves


@dataclass(frozen=True)
class InstrumentModel:
    """The instrument of the module docstring (all defaults: an ideal magnetometer with noise σ)."""

    noise: float = 0.002
    scale: float = 1.0
    chi_per_T: float = 0.0
    field_offset_T: float = 0.0
    gain_drift: float = 0.0
    gain_drift_time_s: float = 600.0
    additive_drift: float = 0.0
    langevin_amplitude: float = 0.0
    langevin_field_T: float = 0.1
    lag_points: float = 0.0
    training_bias_T: float = 0.0
    training_curves: float = 4.0
    correlated_noise: float = 0.0
    correlation_points: float = 5.0
    averaging_s: float = 0.1
    pause_s: float = 1.0
    sweep_rate_T_per_s: float = 0.05
    calibration_sees_drift: bool = False


def _langevin(x):
    x = np.asarray(x, float)
    small = np.abs(x) < 1e-4
    safe = np.where(small, 1.0, x)
    return np.where(small, x / 3.0, 1.0 / np.tanh(safe) - 1.0 / safe)


def record(family: SampleFamily, moment_Am2: float, instrument: InstrumentModel, rng: np.random.Generator):
    """What the instrument writes: (reported reversal fields, [(reported fields, moments A·m²)],
    calibration moments, calibration field), curves in the order of ``family`` and measured from the
    highest reversal field down, on the clock of the module docstring."""
    ins = instrument
    order = np.argsort(family.reversal_fields_T)[::-1]
    top = max(float(f.max()) for f in family.curve_fields_T)
    times, t = {}, 0.0
    for k in order:  # the clock: pause at calibration, ramp down to H_r, pause, then the points
        f = family.curve_fields_T[k]
        t += ins.pause_s + abs(top - f[0]) / ins.sweep_rate_T_per_s + ins.pause_s
        steps = np.abs(np.diff(f, prepend=f[0])) / ins.sweep_rate_T_per_s + ins.averaging_s
        cal_time = t - abs(top - f[0]) / ins.sweep_rate_T_per_s - ins.pause_s
        times[k] = (cal_time, t + np.cumsum(steps))
        t = times[k][1][-1]
    total = t

    def gain(time_s):
        if ins.gain_drift == 0.0:
            return ins.scale * np.ones_like(np.asarray(time_s, float))
        g = (1 - np.exp(-np.asarray(time_s, float) / ins.gain_drift_time_s)) / (1 - math.exp(-total / ins.gain_drift_time_s))
        return ins.scale * (1 + ins.gain_drift * g)

    def drift(time_s):
        return ins.additive_drift * (np.asarray(time_s, float) / total) ** 1.5

    reported_reversal = family.reversal_fields_T + ins.field_offset_T
    curves, calibration = [None] * len(order), [None] * len(order)
    reversals = 0.0  # curves measured so far whose reversal point had the film reversed (⟨m⟩·ĥ < 0)
    for k in order:
        cal_time, time_s = times[k]
        true_m = family.curves[k]
        if ins.training_bias_T:  # an exchange bias that trains away with each reversal of the film
            b = ins.training_bias_T * math.exp(-reversals / ins.training_curves)
            true_m = np.interp(family.curve_fields_T[k] + b, family.curve_fields_T[k], true_m)
            reversals += float(family.curves[k][0] < 0)
        reported = family.curve_fields_T[k] + ins.field_offset_T
        value = gain(time_s) * true_m + ins.chi_per_T * reported + drift(time_s)
        if ins.langevin_amplitude:
            value = value + ins.langevin_amplitude * _langevin(reported / ins.langevin_field_T)
        if ins.lag_points > 0:  # first-order lag of the detector along the sweep (restarts at each reversal)
            a = math.exp(-1.0 / ins.lag_points)
            lagged = np.empty_like(value)
            lagged[0] = value[0]
            for i in range(1, value.size):
                lagged[i] = a * lagged[i - 1] + (1 - a) * value[i]
            value = lagged
        value = value + ins.noise * rng.normal(size=value.size)
        if ins.correlated_noise:  # AR(1) noise along the curve (1/f-like drift of the detector), stationary
            a = math.exp(-1.0 / ins.correlation_points)
            e = rng.normal(size=value.size) * ins.correlated_noise * math.sqrt(1 - a * a)
            ar = np.empty_like(e)
            ar[0] = ins.correlated_noise * rng.normal()
            for i in range(1, e.size):
                ar[i] = a * ar[i - 1] + e[i]
            value = value + ar
        curves[k] = (reported, moment_Am2 * value)
        reported_top = top + ins.field_offset_T
        cal_at = cal_time if ins.calibration_sees_drift else 0.0  # a saturated film at the top field
        m_cal = float(gain(cal_at)) + ins.chi_per_T * reported_top + float(drift(cal_at))
        if ins.langevin_amplitude:
            m_cal += ins.langevin_amplitude * float(_langevin(reported_top / ins.langevin_field_T))
        calibration[k] = moment_Am2 * (m_cal + ins.noise * rng.normal())
    return reported_reversal, curves, np.asarray(calibration), top + ins.field_offset_T


def write_measurement(path, family: SampleFamily, moment_Am2: float, instrument: InstrumentModel, seed: int,
                      fmt: str = "micromag0015") -> Path:
    """Record ``family`` with ``instrument`` (noise from ``seed``) and write it as a MicroMag 0015
    ("micromag0015") or a Lake Shore 8600 CSV ("lakeshore_csv") file; returns the path."""

    rng = np.random.default_rng([int(seed), 4242])
    reversal, curves, calibration, h_cal = record(family, moment_Am2, instrument, rng)
    if fmt == "micromag0015":
        return write_micromag_0015(path, reversal, curves, calibration_moments_Am2=calibration,
                                   calibration_field_T=h_cal, sample_name="magnum.np independent sample")
    if fmt == "lakeshore_csv":
        return write_lakeshore_csv(path, reversal, curves, calibration_moments_Am2=calibration,
                                   calibration_field_T=h_cal, sample_name="magnum.np independent sample")
    raise ValueError(f"unknown format {fmt!r} (micromag0015 or lakeshore_csv)")


__all__ = ["IndependentFilm", "InstrumentModel", "LOGNORMAL_SIGMA", "PIN_K_U", "SampleFamily", "SamplePhysics",
           "average_families", "independent_disorder", "independent_pins", "magnumnp_family", "pins_for_density",
           "measurement_protocol", "mix_phases", "record", "write_measurement"]
