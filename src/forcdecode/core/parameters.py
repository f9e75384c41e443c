"""The parameter table: every Hamiltonian parameter once, with its SI unit, its default draw bounds
(the seed paper's Table I), its scale and whether a network learns it. The draw, the learning, the
loop and the schema's bounds all read this table.

Normalization maps a value to u ∈ [0, 1] by the configured bounds (on a log scale for log-scale
parameters), never by data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import physics
from .physics import MU0


@dataclass(frozen=True)
class Parameter:
    """One Hamiltonian parameter: ``low``/``high`` are the default bounds in ``unit`` (SI unless the
    name says otherwise); ``scale`` is "linear" or "log" (draw and normalization); ``learned``: has
    its own network (M_s is an input of the networks, not a target)."""

    name: str
    unit: str
    low: float
    high: float
    scale: str
    description: str
    learned: bool

    def __post_init__(self):
        if self.scale not in ("linear", "log"):
            raise ValueError(f"scale of {self.name} must be 'linear' or 'log', got {self.scale!r}")
        if not self.low < self.high:
            raise ValueError(f"bounds of {self.name} must satisfy low < high, got {self.low}, {self.high}")

    @property
    def bounds(self) -> list:
        return [self.low, self.high]


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("Ms", "A/m", 2e5, 1.4e6, "linear", "saturation magnetization M_s", False),
    Parameter("A_ex", "J/m", 1e-12, 35e-12, "linear", "exchange stiffness A_ex", True),
    Parameter("K_u", "J/m^3", 1e3, 1.5e6, "log", "uniaxial (perpendicular) anisotropy constant K_u", True),
    Parameter("D", "J/m^2", 0.0, 5e-3, "linear", "interfacial Dzyaloshinskii-Moriya constant D", True),
    Parameter("N_pin", "count", 0, 255, "linear", "pinning sites, counted on the paper's 256x256x2 grid", True),
    Parameter("sigma_theta_deg", "deg", 0.0, 10.0, "linear", "spread of the grains' easy-axis tilt σ_θ", True),
    Parameter("sigma_K", "fraction", 0.0, 0.2, "linear", "relative spread of the grains' K_u σ_K", True),
)
"""Every parameter, M_s first (the column order of the dataset files)."""

NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS)
BY_NAME: dict[str, Parameter] = {p.name: p for p in PARAMETERS}

TARGETS: tuple[str, ...] = ("N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K")
"""The learned parameters, in the order of the networks (one network each)."""

DEFAULT_BOUNDS: dict[str, list] = {p.name: p.bounds for p in PARAMETERS}
"""name -> [low, high] (SI; N_pin a count, σ_θ in degrees, σ_K a fraction)."""

LOG_SCALE: frozenset[str] = frozenset(p.name for p in PARAMETERS if p.scale == "log")
"""Parameters drawn (and normalized) on a log scale."""

UNITS: dict[str, str] = {p.name: p.unit for p in PARAMETERS}


def _bounds(name: str, bounds) -> tuple[float, float]:
    if name not in BY_NAME:
        raise KeyError(f"unknown parameter {name!r} (one of {', '.join(NAMES)})")
    lo, hi = (bounds or {}).get(name, DEFAULT_BOUNDS[name])
    return float(lo), float(hi)


def normalize(name: str, value, bounds=None):
    """Map a value (SI) to u ∈ [0, 1] by ``bounds`` (name -> [low, high]; default the table's), on a
    log scale for log-scale parameters."""
    lo, hi = _bounds(name, bounds)
    value = np.asarray(value, dtype=float)
    if name in LOG_SCALE:
        return (np.log(value) - np.log(lo)) / (np.log(hi) - np.log(lo))
    return (value - lo) / (hi - lo)


def denormalize(name: str, unit_value, bounds=None):
    """Inverse of :func:`normalize`: u ∈ [0, 1] back to the value (SI)."""
    lo, hi = _bounds(name, bounds)
    unit_value = np.asarray(unit_value, dtype=float)
    if name in LOG_SCALE:
        return np.exp(np.log(lo) + unit_value * (np.log(hi) - np.log(lo)))
    return lo + unit_value * (hi - lo)


# ---------------------------------------------------------------- derived combinations


# ---------------------------------------------------------------- prior classes
PRIOR_CLASSES: dict[str, str] = {
    "paper": "the seed paper's draw (Table I): every film of the bounds, in-plane (K_eff < 0) ones included",
    "perpendicular": "the paper's draw with K_u restricted to K_eff = K_u − μ0 M_s²/2 > 0 given M_s "
                     "(perpendicular films, what a thin-film lab measures); the other parameters as in paper",
}
"""The named prior classes a dataset can be drawn from (config key ``prior``; the schema's enum lists the
same names). The draw of each is ``dataset.params.draw_parameters``; a model records the class it was
trained on (``prior_class`` of its file; a file without one was trained on ``paper``)."""

DEFAULT_PRIOR_CLASS = "paper"
"""The class of a config or model that names none (every dataset and model made before the key)."""


def prior_class(source=None) -> str:
    """The prior class named by ``source``: a config or model metadata dict (its ``prior`` or
    ``prior_class`` key), a class name, or None; absent → ``DEFAULT_PRIOR_CLASS``. ValueError for a
    name that is not a class."""
    if isinstance(source, dict):
        source = source.get("prior_class", source.get("prior"))
    name = DEFAULT_PRIOR_CLASS if source is None else str(source)
    if name not in PRIOR_CLASSES:
        raise ValueError(f"unknown prior class {name!r} (one of {', '.join(PRIOR_CLASSES)})")
    return name


def k_u_floor(Ms, prior: str = DEFAULT_PRIOR_CLASS, bounds=None) -> np.ndarray:
    """The smallest K_u (J/m³) the prior class allows at M_s (A/m): the K_u bound for ``paper``;
    for ``perpendicular`` max(bound, μ0 M_s²/2), where K_eff = 0 (the draw stays strictly above it).
    ValueError where that floor reaches the K_u upper bound (no perpendicular film of that M_s in
    the bounds)."""
    lo, hi = _bounds("K_u", bounds)
    Ms = np.asarray(Ms, dtype=float)
    if prior_class(prior) == "paper":
        return np.full(Ms.shape, lo) if Ms.ndim else lo
    floor = np.maximum(lo, MU0 * Ms**2 / 2)
    if np.any(floor >= hi):
        worst = float(np.max(Ms))
        raise ValueError(f"prior 'perpendicular': no K_u ≤ {hi:g} J/m³ gives K_eff > 0 at M_s = {worst:g} A/m "
                         f"(μ0 M_s²/2 = {MU0 * worst**2 / 2:g} J/m³); lower the M_s bound or raise the K_u bound")
    return floor if floor.ndim else float(floor)


def _si(values: dict, name: str) -> np.ndarray:
    if name not in values:
        raise KeyError(f"the combination needs {name!r} (SI), got {', '.join(values) or 'nothing'}")
    return np.asarray(values[name], dtype=float)


def k_eff(values: dict) -> np.ndarray:
    """Effective perpendicular anisotropy K_eff = K_u − μ0 M_s²/2 (J/m³), thin-film shape anisotropy;
    ``values``: name -> SI array (``K_u``, ``Ms``), broadcast together."""
    return physics.k_eff(_si(values, "K_u"), _si(values, "Ms"))


def _where_keff_positive(values: dict, fn) -> np.ndarray:
    """fn(K_eff > 0 part) where K_eff > 0, NaN elsewhere (no √ of a negative is ever taken)."""
    keff = k_eff(values)
    a = _si(values, "A_ex")
    d = np.abs(_si(values, "D")) if "D" in values else np.zeros(())
    keff, a, d = np.broadcast_arrays(keff, a, d)
    out = np.full(keff.shape, np.nan)
    ok = keff > 0
    out[ok] = fn(a[ok], keff[ok], d[ok])
    return out if out.ndim else float(out)


def wall_energy(values: dict) -> np.ndarray:
    """σ_w = 4√(A_ex K_eff) − π|D| (J/m²); NaN where K_eff ≤ 0."""
    return physics.wall_energy(_si(values, "A_ex"), k_eff(values), _si(values, "D") if "D" in values else 0.0)


def wall_width(values: dict) -> np.ndarray:
    """δ_w = π√(A_ex/K_eff) (m); NaN where K_eff ≤ 0."""
    return physics.wall_width(_si(values, "A_ex"), k_eff(values))


def critical_dmi(values: dict) -> np.ndarray:
    """D_c = 4√(A_ex K_eff)/π (J/m²), the |D| at which σ_w = 0; NaN where K_eff ≤ 0."""
    return physics.critical_dmi(_si(values, "A_ex"), k_eff(values))


def dmi_ratio(values: dict) -> np.ndarray:
    """|D|/D_c (dimensionless); NaN where K_eff ≤ 0."""
    return _where_keff_positive(values, lambda a, k, d: d * np.pi / (4.0 * np.sqrt(a * k)))


def quality_factor(values: dict) -> np.ndarray:
    """Q = 2K_u/(μ0 M_s²) (dimensionless), defined everywhere (M_s > 0); Q > 1 ⇔ K_eff > 0."""
    return physics.quality_factor(_si(values, "K_u"), _si(values, "Ms"))


@dataclass(frozen=True)
class Combination:
    """A derived combination of the Hamiltonian's parameters (M_s given), reported like a parameter.

    ``formula``: the definition, in words; ``needs``: the parameters it reads (SI); ``function``:
    name -> SI array dict → array (vectorized, broadcast), NaN where ``undefined`` says;
    ``scale``: "log" (positive wherever defined: normalized on a log scale) or "linear"; the
    normalization's range is not a fixed bound but a reference set of values (see
    :func:`combination_reference`)."""

    name: str
    unit: str
    formula: str
    needs: tuple
    function: object
    scale: str
    undefined: str
    description: str

    def __post_init__(self):
        if self.scale not in ("linear", "log"):
            raise ValueError(f"scale of {self.name} must be 'linear' or 'log', got {self.scale!r}")

    def __call__(self, values: dict):
        return self.function(values)


COMBINATIONS: tuple[Combination, ...] = (
    Combination("sigma_w", "J/m^2", "σ_w = 4√(A_ex K_eff) − π|D|, K_eff = K_u − μ0 M_s²/2", ("A_ex", "K_u", "D", "Ms"),
                wall_energy, "linear", "NaN where K_eff ≤ 0 (no perpendicular wall; the √ is not extended)",
                "energy per area of a Néel wall (negative: spirals are favoured)"),
    Combination("delta_w", "m", "δ_w = π√(A_ex/K_eff)", ("A_ex", "K_u", "Ms"), wall_width, "log",
                "NaN where K_eff ≤ 0 (the wall width diverges as K_eff → 0⁺)", "domain-wall width"),
    Combination("D_over_Dc", "1", "|D|/D_c, D_c = 4√(A_ex K_eff)/π", ("A_ex", "K_u", "D", "Ms"), dmi_ratio, "linear",
                "NaN where K_eff ≤ 0 (D_c undefined)", "DMI relative to the critical DMI (σ_w = 0 at 1)"),
    Combination("Q", "1", "Q = 2K_u/(μ0 M_s²)", ("K_u", "Ms"), quality_factor, "log",
                "defined everywhere", "quality factor (Q > 1 ⇔ K_eff > 0)"),
)
"""The derived combinations, one source of truth for Alice's and the posterior's metrics.

Undefined region: σ_w, δ_w and D/D_c are NaN where K_eff ≤ 0 (in-plane films have no perpendicular
Néel wall); metrics skip a family whose true value is NaN and condition a posterior on the draws
where the combination is defined (``learn.combinations``). Q is defined everywhere.

Normalization for MAE tables (:func:`normalize_combination`): u_c = (g(c) − g(lo))/(g(hi) − g(lo)) with
g = log for the positive-definite combinations (δ_w, Q: they span decades over the prior) and the
identity for the signed or zero-touching ones (σ_w, D/D_c); [lo, hi] is the central 98 % (1st to 99th
percentile) of the combination over a reference set of true values: the training split's families,
i.e. screened draws of the prior, never test. So an MAE of a combination reads on the same scale as a
parameter's normalized MAE (≈ 1 spans the prior); values outside [lo, hi] map outside [0, 1] (not
clipped). Coverage and SBC do not depend on the normalization (monotone), skill ratios only on g."""

COMBINATION_NAMES: tuple[str, ...] = tuple(c.name for c in COMBINATIONS)
COMBINATION_BY_NAME: dict[str, Combination] = {c.name: c for c in COMBINATIONS}
REFERENCE_PERCENTILES = (1.0, 99.0)


def combination_values(values: dict, names=None) -> dict:
    """name -> SI array of each combination in ``names`` (default all) whose parameters ``values`` holds."""
    names = COMBINATION_NAMES if names is None else tuple(names)
    return {n: COMBINATION_BY_NAME[n](values) for n in names if set(COMBINATION_BY_NAME[n].needs) <= set(values)}


def combination_reference(name: str, values) -> list:
    """[lo, hi] of the normalization of combination ``name``: the 1st and 99th percentiles of its finite
    ``values`` (SI; positive ones only for a log-scale combination); NaN where fewer than two."""
    c = COMBINATION_BY_NAME[name]
    values = np.asarray(values, dtype=float).ravel()
    values = values[np.isfinite(values) & ((values > 0) if c.scale == "log" else True)]
    if values.size < 2:
        return [float("nan"), float("nan")]
    lo, hi = np.percentile(values, REFERENCE_PERCENTILES)
    if not hi > lo:  # a degenerate reference: one unit around the value
        lo, hi = (lo / np.e, hi * np.e) if c.scale == "log" else (lo - 0.5, hi + 0.5)
    return [float(lo), float(hi)]


def normalize_combination(name: str, value, reference) -> np.ndarray:
    """Combination value (SI) → u_c by the ``reference`` [lo, hi] (log scale for log-scale combinations;
    a non-positive value of a log-scale one → NaN); NaN stays NaN."""
    c = COMBINATION_BY_NAME[name]
    lo, hi = (float(v) for v in reference)
    value = np.asarray(value, dtype=float)
    if c.scale == "log":
        with np.errstate(divide="ignore", invalid="ignore"):
            logged = np.where(value > 0, np.log(np.where(value > 0, value, 1.0)), np.nan)
        return (logged - np.log(lo)) / (np.log(hi) - np.log(lo))
    return (value - lo) / (hi - lo)


__all__ = ["Parameter", "PARAMETERS", "NAMES", "BY_NAME", "TARGETS", "DEFAULT_BOUNDS", "LOG_SCALE", "UNITS",
           "normalize", "denormalize", "MU0", "PRIOR_CLASSES", "DEFAULT_PRIOR_CLASS", "prior_class", "k_u_floor", "k_eff", "wall_energy", "wall_width", "critical_dmi", "dmi_ratio",
           "quality_factor", "Combination", "COMBINATIONS", "COMBINATION_NAMES", "COMBINATION_BY_NAME",
           "combination_values", "combination_reference", "normalize_combination"]
