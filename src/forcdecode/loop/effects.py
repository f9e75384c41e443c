"""Measured-side effects the micromagnetic model lacks, alone and in small combinations, and their
selection on held-out whole curves.

Each effect maps the re-simulated grid family m_sim(H_r, H) (NaN below the diagonal, m normalized
to the film's saturation moment) to a model of the measurement. Components (μ0H in tesla):

- ``scale``:           a·m_sim                      (volume / M_s error; a dimensionless)
- ``background``:      a·m_sim + χ·μ0H              (para/diamagnetic substrate, χ per tesla)
- ``field_offset``:    m_sim(H_r − δ, H − δ)        (reported field off by δ (T): the sample feels
                       μ0H − δ; on the grid, whole rows in H_r, see ``_offset_family``)
- ``additive_drift``:  a·m_sim + d·τ                (τ ∈ [0, 1]: measurement clock)
- ``multiplicative_drift``: a·m_sim·(1 + d·τ)

A combination composes them as m = a·S_δ[m_sim]·(1 + d_m·τ) + χ·μ0(H − δ) + d_a·τ with the absent
parameters at their neutral values; its name joins the components with "+" (``scale`` is dropped
where another component already carries a scale: background+additive_drift, field_offset+scale).

Selection: fit every candidate on all curves but every k-th, score it on the held-out curves (mean
square misfit per curve; optionally cross-fitted, every curve held out once). Stepwise in the number
of fitted parameters, starting from the base model (``none``, m = m_sim): at each level the
candidate with the lowest held-out error among those that beat the current choice replaces it (a
tie in the mean does not hide a candidate whose gain is consistent behind a noisier one); beating
means by more than its own noise: held-out mean-square error lower by more than ``equivalence`` (5 %) and the 5 %
bound of a paired bootstrap over held-out curves of the relative reduction of that error above
``min_relative_gain`` (5 %). A combination must therefore earn the parameters it adds over the
best simpler candidate; a single effect stays named as the single effect.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy.optimize import least_squares

from ..core.streams import stream_rng

COMPONENTS = ("background", "field_offset", "additive_drift", "multiplicative_drift", "scale")
"""Measured-side components, in the order they are named in a combination."""

_CARRY_SCALE = {"scale", "background", "additive_drift", "multiplicative_drift"}
_PARAMETER_ORDER = ("scale", "offset_T", "chi_per_T", "additive_drift", "multiplicative_drift")
_INITIAL = {"scale": 1.0, "offset_T": 0.0, "chi_per_T": 0.0, "additive_drift": 0.0, "multiplicative_drift": 0.0}

COMBINATIONS = ("background+field_offset", "background+additive_drift", "background+multiplicative_drift",
                "field_offset+scale", "field_offset+additive_drift", "field_offset+multiplicative_drift")
"""Combinations offered by default: pairs a real measurement plausibly has together (the two drifts
together are left out: on one clock they are nearly collinear)."""


@lru_cache(maxsize=8)
def _grid_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """0 … n − 1 and the n × n mask of the FORC triangle (H ≥ H_r), read-only."""
    index = np.arange(n)
    upper = index[None, :] >= index[:, None]
    index.setflags(write=False)
    upper.setflags(write=False)
    return index, upper


def _offset_family(sim, fields, delta):
    """The family an instrument whose reported fields are off by δ (T) records, as rasterized.

    The sample feels μ0H − δ when μ0H is reported. Along a curve the shift is continuous (linear
    interpolation in H, as ``forc.raster.resample_curves`` does); a curve is placed on the grid row
    nearest to its reported reversal field, so in H_r the shift is whole rows, round(δ/ΔH): an
    offset below half a row moves no curve to another row (exact when the curves were reversed at
    the grid fields; where the instrument's reported reversal fields sit on the grid instead, a
    sub-row part δ·∂m/∂H_r stays in the residual). Beyond the simulated window the film is taken to
    stay where the window leaves it (the edge value along a curve, the edge curve in H_r: saturated
    ends), so the model is defined at every measured point and a candidate cannot shrink its misfit by
    shifting points out of the comparison.

    Vectorized over the curves (every curve is read at the same shifted fields), and bit for bit
    ``np.interp`` curve by curve, its rules at a node and around a NaN included
    (``tests/loop/test_effects.py``): this family is evaluated some 10⁵ times per file."""
    n = len(fields)
    step = fields[1] - fields[0]
    rows = int(np.rint(delta / step))
    index, upper = _grid_indices(n)
    source = np.clip(index - rows, 0, n - 1)  # the simulated curve whose reversal field is the true one of row i
    # below its reversal point a curve holds m(H_r, H_r)
    curves = np.where(index[None, :] < source[:, None], sim[source, source][:, None], sim[source])
    h = np.clip(fields - delta, fields[0], fields[-1])
    j = np.clip(np.searchsorted(fields, h, side="right") - 1, 0, n - 2)  # fields[j] <= h < fields[j + 1]
    left, right = curves[:, j], curves[:, j + 1]
    slope = (right - left) / (fields[j + 1] - fields[j])
    with np.errstate(invalid="ignore"):
        out = slope * (h - fields[j]) + left
        lost = np.isnan(out)
        if lost.any():  # np.interp's second try from the right node, then a flat interval's value
            out = np.where(lost, slope * (h - fields[j + 1]) + right, out)
            out = np.where(np.isnan(out) & (left == right), left, out)
    out = np.where(h == fields[j], left, out)  # on a node: its value
    at_end = h == fields[-1]
    if at_end.any():
        out[:, at_end] = curves[:, -1:]
    return np.where(upper & np.isfinite(sim), out, np.nan)


def _clock(order):
    """Measurement clock τ broadcast to the family: per curve (n,) or per point (n, n)."""
    order = np.asarray(order, dtype=float)
    return order[:, None] if order.ndim == 1 else order


def measurement_clock(n: int) -> np.ndarray:
    """Normalized time τ ∈ [0, 1] at which each point of an n × n grid family is measured in the
    MicroMag order: curves from the highest reversal field down, each preceded by one calibration
    point and swept from H_r up (time ∝ points measured). NaN below the diagonal."""
    clock = np.full((n, n), np.nan)
    t = 0
    for i in range(n - 1, -1, -1):
        t += 1  # the calibration point before the curve
        clock[i, i:] = t + np.arange(n - i)
        t += n - i
    return (clock - 1) / (t - 1)


def effect_name(components) -> str:
    """Canonical name of a set of components ("none" for the empty set)."""
    components = set(components)
    unknown = components - set(COMPONENTS)
    if unknown:
        raise ValueError(f"unknown measured-side components {sorted(unknown)}; known: {COMPONENTS}")
    if len(components & _CARRY_SCALE) > 1:
        components.discard("scale")
    return "+".join(c for c in COMPONENTS if c in components) or "none"


@dataclass(frozen=True)
class Effect:
    """A measured-side model with its fitted parameters (names in ``parameters``, SI/tesla)."""

    name: str
    components: tuple[str, ...]

    @property
    def parameters(self) -> tuple[str, ...]:
        present = set()
        if set(self.components) & _CARRY_SCALE:
            present.add("scale")
        if "field_offset" in self.components:
            present.add("offset_T")
        if "background" in self.components:
            present.add("chi_per_T")
        for drift in ("additive_drift", "multiplicative_drift"):
            if drift in self.components:
                present.add(drift)
        return tuple(p for p in _PARAMETER_ORDER if p in present)

    @property
    def initial(self) -> tuple[float, ...]:
        return tuple(_INITIAL[p] for p in self.parameters)

    def model(self, sim, fields, order, theta):
        """The measurement predicted from ``sim`` with parameters ``theta`` (order of ``parameters``)."""
        values = {**_INITIAL, **dict(zip(self.parameters, theta))}
        delta = values["offset_T"]
        film = _offset_family(sim, fields, delta) if "field_offset" in self.components else sim
        tau = _clock(order)
        if "multiplicative_drift" in self.components:
            film = film * (1 + values["multiplicative_drift"] * tau)
        out = values["scale"] * film
        if "background" in self.components:
            out = out + values["chi_per_T"] * (fields[None, :] - delta)
        if "additive_drift" in self.components:
            out = out + values["additive_drift"] * tau
        return out


def correct_measurement(measured, fields, order, effect: Effect, parameters: dict):
    """The film's own family from a measurement with the measured-side ``effect`` (``parameters`` by
    name, as fitted): the inverse of ``Effect.model``, m_film = S_−δ[(m − χ(μ0H − δ) − d_a τ) /
    (a (1 + d_m τ))], so that the networks see the film, not the instrument. NaN where the inverse
    field shift leaves the window."""
    values = {**_INITIAL, **{k: float(v) for k, v in (parameters or {}).items() if k in _INITIAL}}
    delta = values["offset_T"]
    tau = _clock(order if order is not None else measurement_clock(len(fields)))
    film = np.asarray(measured, dtype=float)
    if "additive_drift" in effect.components:
        film = film - values["additive_drift"] * tau
    if "background" in effect.components:
        film = film - values["chi_per_T"] * (fields[None, :] - delta)
    film = film / values["scale"]
    if "multiplicative_drift" in effect.components:
        film = film / (1 + values["multiplicative_drift"] * tau)
    if "field_offset" in effect.components:
        film = _offset_family(film, fields, -delta)
    return film


def _effect(components) -> Effect:
    return Effect(effect_name(components), tuple(c for c in COMPONENTS if c in set(components)))


EFFECTS = {"none": Effect("none", ())}
EFFECTS.update({c: _effect([c]) for c in ("scale", "background", "field_offset", "additive_drift",
                                          "multiplicative_drift")})
EFFECTS.update({name: _effect(name.split("+")) for name in COMBINATIONS})
SINGLE_EFFECTS = ("scale", "background", "field_offset", "additive_drift", "multiplicative_drift")


def fit_effect(effect: Effect, measured, sim, fields, order, rows):
    """Least-squares fit of ``effect`` on the curves ``rows``; returns (theta, standard errors).

    The standard error is the larger of the ordinary one (independent residuals) and the one robust
    to correlated residuals along a curve (sandwich estimator with curves as clusters)."""
    if not effect.parameters:
        return np.array([]), np.array([])
    mask = np.zeros(measured.shape, dtype=bool)
    mask[rows] = True
    mask &= np.isfinite(measured) & np.isfinite(sim)
    curve_of_point = np.nonzero(mask)[0]

    def residual(theta):
        model = effect.model(sim, fields, order, theta)
        r = np.where(mask & np.isfinite(model), model - measured, 0.0)
        return r[mask]

    starts = [np.array(effect.initial, dtype=float)]
    if "offset_T" in effect.parameters:
        # the shifted family is piecewise bilinear in δ: start on both sides of a grid node too
        step = float(np.median(np.diff(fields)))
        k = effect.parameters.index("offset_T")
        for d in (-0.25 * step, 0.25 * step):
            start = starts[0].copy()
            start[k] = d
            starts.append(start)
    result = min((least_squares(residual, s, x_scale="jac") for s in starts), key=lambda r: r.cost)
    dof = max(1, mask.sum() - len(effect.parameters))
    sigma2 = 2 * result.cost / dof
    J, r = result.jac, result.fun
    try:
        bread = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return result.x, np.full(len(effect.parameters), np.nan)
    per_curve_score = np.zeros((curve_of_point.max() + 1, J.shape[1]))
    np.add.at(per_curve_score, curve_of_point, J * r[:, None])
    clustered = bread @ (per_curve_score.T @ per_curve_score) @ bread
    errors = np.sqrt(np.clip(np.maximum(np.diag(bread) * sigma2, np.diag(clustered)), 0, None))
    return result.x, errors


def _per_curve_mse(measured, model, rows):
    """Mean-square misfit of each curve in ``rows`` (aligned with rows; NaN where nothing to compare)."""
    out = np.full(len(rows), np.nan)
    for k, i in enumerate(rows):
        ok = np.isfinite(measured[i]) & np.isfinite(model[i])
        if ok.any():
            out[k] = np.mean((model[i, ok] - measured[i, ok]) ** 2)
    return out


def bootstrap_resamples(rng, n_boot: int, n_curves: int) -> np.ndarray:
    """Bootstrap resamples of ``n_curves`` held-out curves, (n_boot, n_curves) indices, drawn from a
    copy of ``rng``: common random numbers. Every comparison made with one generator resamples the same
    curves, so its outcome depends on the two candidates' errors alone, never on which comparisons ran
    before it. (With the generator consumed call by call, a last-bit tie between two candidates' mean
    errors reordered the comparisons, reshuffled every later resample and could flip a verdict from
    one CPU to another.)"""
    return copy.deepcopy(rng).integers(0, n_curves, size=(n_boot, n_curves))


def _bootstrap_gain(base_mse, mse, rng, n_boot):
    """Paired bootstrap over the curves both can score (resampled as whole curves). Returns
    (mean gain base − candidate, [5 %, 95 %] of the mean gain, [5 %, 95 %] of the relative gain
    1 − Σ mse / Σ base_mse). The relative bound is the one to test: it stays meaningful when one
    curve carries most of the base error and is missing from a resample."""
    both = np.isfinite(base_mse) & np.isfinite(mse)
    base, candidate = base_mse[both], mse[both]
    if base.size == 0:
        return float("nan"), [float("-inf")] * 2, [float("-inf")] * 2
    pick = bootstrap_resamples(rng, n_boot, base.size)
    base_sum, candidate_sum = base[pick].sum(axis=1), candidate[pick].sum(axis=1)
    gain = (base_sum - candidate_sum) / base.size
    relative = np.where(base_sum > 0, 1 - candidate_sum / np.where(base_sum > 0, base_sum, 1.0), 0.0)
    return (float((base - candidate).mean()), [float(np.quantile(gain, 0.05)), float(np.quantile(gain, 0.95))],
            [float(np.quantile(relative, 0.05)), float(np.quantile(relative, 0.95))])


def _heldout_split(measured, every_k):
    """Curves with at least two points; every ``every_k``-th of them held out. (train, held)."""
    n = measured.shape[0]
    usable = [i for i in range(n) if np.isfinite(measured[i]).sum() >= 2]
    held = usable[every_k // 2::every_k]
    return [i for i in usable if i not in held], held


def heldout_folds(measured, every_k: int, cross_fit: bool):
    """(train, held) splits of the usable curves: the single split of ``_heldout_split``, or with
    ``cross_fit`` all ``every_k`` of them (fold r holds out usable curves r, r + k, ...), so that
    every curve is held out once."""
    train, held = _heldout_split(measured, every_k)
    if not cross_fit:
        return [(train, held)]
    usable = sorted(train + held)
    return [([i for i in usable if i not in usable[r::every_k]], usable[r::every_k]) for r in range(every_k)
            if usable[r::every_k]]


def heldout_mse(measured, fit, folds):
    """Per-curve held-out mean-square misfit of a candidate over ``folds``: ``fit(train_rows)``
    returns the model family fitted on those rows. Aligned with the concatenated held-out rows."""
    return np.concatenate([_per_curve_mse(measured, fit(train), held) for train, held in folds])


def _beats(challenger_mse, current_mse, rng, n_boot, min_relative_gain, equivalence, evidenced: bool = False,
           decisive: bool = False) -> bool:
    """The challenger's held-out error is lower than the current one's by more than ``equivalence``
    and the 5 % bound of the paired bootstrap of the relative reduction of the held-out
    mean-square error exceeds ``min_relative_gain``. ``evidenced``: the challenger's effect is shown
    by a test apart from the held-out curves (``choose_candidate``): the first condition only.
    ``decisive``: that test is where the effect lives (a background in the saturated film): a held-out
    error not above the current one's beyond ``equivalence`` (the held-out curves do not contradict it)."""
    current = float(np.nanmean(current_mse))
    if decisive:
        return float(np.nanmean(challenger_mse)) <= current * (1 + equivalence)
    if not float(np.nanmean(challenger_mse)) * (1 + equivalence) < current:
        return False
    if evidenced:
        return True
    _, _, relative = _bootstrap_gain(current_mse, challenger_mse, rng, n_boot)
    return relative[0] > min_relative_gain


def choose_candidate(heldout_mse: dict, n_parameters: dict, rng, n_boot: int = 2000,
                     min_relative_gain: float = 0.05, equivalence: float = 0.05, evidenced=(), decisive=()):
    """The selection rule shared by every candidate kind (see the module docstring).

    ``heldout_mse[name]``: per-held-out-curve mean-square misfit (aligned arrays; ``"none"`` is the
    base model). Stepwise from ``none``: at each number of fitted parameters, in increasing order,
    the candidate with the lowest held-out error among those that ``_beats`` the current choice
    replaces it.
    Returns (chosen name, {name: {"heldout_rms", "gain_mse", "gain_ci90", "relative_gain_ci90",
    "accepted"}}): the mean per-curve gain over ``none`` in mean-square error, its paired-bootstrap
    90 % interval, that of the relative gain, and whether the candidate alone would beat ``none``.

    ``evidenced``: candidates whose effect a test apart from the held-out curves has shown (a field
    shift seen in the major loop's own symmetry, calibrated by simulation, or a drift of the end
    moments in saturation: ``signatures``). Their
    significance comes from that test, so against the current choice they need only a held-out
    error lower by more than ``equivalence``, not the bootstrap bound: a shift shows on the few
    held-out curves that cross the switching region (on a 24-curve file 1–3 of 6), where a bootstrap
    over curves cannot bound a gain however large.

    ``decisive``: evidenced candidates whose effect lives where the held-out curves hardly look (a
    linear background, shown by the saturated film's slope: ``signatures.background_evidence``); they
    need only a held-out error not above the current choice's beyond ``equivalence``: a background of a
    few per cent beside a switching misfit of 10–40 % of M_sat moves the held-out error by less than
    that misfit's own noise, either way."""
    base_mse = heldout_mse["none"]
    base = float(np.nanmean(base_mse))
    scores = {}
    for name, mse in heldout_mse.items():
        if name == "none":
            gain, ci, relative = 0.0, [0.0, 0.0], [0.0, 0.0]
        else:
            gain, ci, relative = _bootstrap_gain(base_mse, mse, rng, n_boot)
        scores[name] = {"heldout_rms": float(np.sqrt(np.nanmean(mse))), "gain_mse": gain, "gain_ci90": ci,
                        "relative_gain_ci90": relative,
                        "accepted": name != "none" and (
                            float(np.nanmean(mse)) <= base * (1 + equivalence) if name in decisive else
                            float(np.nanmean(mse)) * (1 + equivalence) < base
                            and (relative[0] > min_relative_gain or name in evidenced))}
    mean_mse = {k: float(np.nanmean(v)) for k, v in heldout_mse.items()}
    chosen = "none"
    for level in sorted({n_parameters[k] for k in heldout_mse} - {0}):
        # the lowest held-out error among this level's candidates that beat the current choice: a
        # candidate whose mean ties the best but whose gain is consistent is not hidden behind a
        # noisier one
        for challenger in sorted((k for k in heldout_mse if n_parameters[k] == level), key=mean_mse.get):
            if _beats(heldout_mse[challenger], heldout_mse[chosen], rng, n_boot, min_relative_gain, equivalence,
                      evidenced=challenger in evidenced, decisive=challenger in decisive):
                chosen = challenger
                break
    return chosen, scores


HAMILTONIAN_CHANGE = "K_u change"
"""The name an ambiguous set gives the Hamiltonian's own neighbourhood (K_u moved along its
re-simulated families, ``analyse_residual(hamiltonian_families=)``): a change of the decoded
Hamiltonian, not an effect the model lacks."""

REALISATION_NOISE = "realisation noise"
"""The member an ambiguous set gives the difference between two disorder realisations of the decoded
Hamiltonian (``physics_effects.realisation_ambiguity``): no effect, the film's own switching statistics."""

SWITCHING_FIELD_DISTRIBUTION = "switching-field distribution"
"""The member an ambiguous set gives a switching-field distribution the model draws differently from the
film (realisation noise, disorder statistics): what a Sharrock shift is told from only by a second sweep
rate (``physics_effects.realisation_ambiguity``)."""

NO_EFFECT_MEMBERS = frozenset({REALISATION_NOISE, SWITCHING_FIELD_DISTRIBUTION})
"""Members of an ambiguous set that say the residual may be no effect at all: an ambiguous answer holding
one of them is not an attribution of an effect."""

SEPARATING_MEASUREMENTS = {
    REALISATION_NOISE: "the same film measured again after re-saturation, or a larger area (more patches): "
                       "realisation noise changes between patches and repeats, an effect does not",
    SWITCHING_FIELD_DISTRIBUTION: "a FORC family at another sweep rate (a Sharrock shift of the switching fields "
                                  "moves with the logarithm of the rate; a switching-field distribution does not)",
    "field_tilt": "a loop with the field at another angle to the film normal (a misalignment moves the "
                  "switching field with the angle; a K_u change does not)",
    "K_2": "a hard-axis (in-plane) loop: K_2 and K_u enter its curvature differently, while on an easy-axis "
           "FORC family both move the switching field",
    "thermal_activation": "FORC families at two sweep rates or temperatures (thermal activation moves "
                          "the switching field with the rate; a Hamiltonian change does not)",
    "second_phase": "a FORC diagram at finer field steps, or a minor loop of the soft phase alone",
    "bias_field": "loops after field cooling in opposite fields (an exchange bias reverses; a K_u change "
                  "does not)",
    "field_offset": "the field calibration against a paramagnetic standard (an offset of the reported field "
                    "moves with the instrument, not with the sample)",
    "background": "a loop to higher fields (a background keeps its slope where the film is saturated)",
    "scale": "the sample's volume or M_s measured apart (a scale is a normalization error)",
    "additive_drift": "the measurement repeated in the reverse order of reversal fields (a drift follows "
                      "the clock, the film does not)",
    "multiplicative_drift": "the measurement repeated in the reverse order of reversal fields (a drift "
                            "follows the clock, the film does not)",
    HAMILTONIAN_CHANGE: "a hard-axis loop (its saturation field gives K_eff independently of the switching field)",
}
"""For each candidate, a measurement apart from the FORC family that tells it from the others it is
ambiguous with (``separating_measurements``)."""


def _components(name: str) -> frozenset:
    return frozenset(name.split("+"))


def nested(a: str, b: str) -> bool:
    """Is one candidate a combination containing the other (e.g. background, background+additive_drift)?
    Nested candidates are told apart by parsimony (the stepwise rule), not reported as ambiguous."""
    ca, cb = _components(a), _components(b)
    return ca <= cb or cb <= ca


def beats_null_gain(relative_gain: float, gain_mse: float, none_mse: float, null: dict, margin: float) -> bool:
    """Whether a candidate's held-out gain beats its realisation floor ``null`` (``null_gains``): relative
    gain above the null's by ``margin``, and mean-square gain above the null's by the factor 1 + ``margin``,
    the null's mean-square gain scaled down by none_mse / null["none_mse"] where the measured residual is
    smaller than the null films' (``none_mse``: the measured held-out mean-square residual of "none").
    Why the scaling: a file that happens to lie close to the re-simulation (its realisation near the mean)
    leaves a smaller residual than a typical effect-free film, and a candidate's absolute gain on the null
    films grows with their residual; unscaled, a 10 % background on a one-patch film (relative gain 0.985
    against a null 0.07) failed the floor because effect-free single realisations, whose residual is 13
    times larger, gave it more absolute gain. Where the measured residual is the larger, the absolute
    criterion stands as it was."""
    null_mse = max(null["mse"], 0.0)
    reference = null.get("none_mse")
    if reference is not None and np.isfinite(reference) and reference > 0 and none_mse < reference:
        null_mse *= none_mse / reference
    return bool(relative_gain > max(null["relative"], 0.0) + margin and gain_mse > null_mse * (1 + margin))


def beats_floor(challenger_mse, none_mse, floor: dict | None, margin: float = 0.05) -> bool:
    """The challenger's held-out gain over "none" exceeds its null gain ``floor`` ({"relative": 1 −
    MSE_c/MSE_none, "mse": MSE_none − MSE_c}, m² in units of the saturation moment; what it reaches on
    films without an effect) in both senses, by ``margin`` (``beats_null_gain``): the realisation floor of
    ``physics_effects.analyse_residual(null_gain=)``. No floor: True."""
    if floor is None:
        return True
    none = float(np.nanmean(none_mse))
    gain = none - float(np.nanmean(challenger_mse))
    relative = gain / none if none > 0 else 0.0
    return beats_null_gain(relative, gain, none, floor, margin)


def _beats_beyond_floors(challenger_mse, current_mse, floors: list, rng, n_boot, min_relative_gain, equivalence,
                         margin: float) -> bool:
    """``_beats``, and by a mean-square margin larger than the larger of the two candidates' null gains
    (``floors``: their {"relative", "mse"} or None): a difference no larger than what films without an
    effect give either of them does not tell them apart."""
    if not _beats(challenger_mse, current_mse, rng, n_boot, min_relative_gain, equivalence):
        return False
    floor = max([f["mse"] for f in floors if f is not None] + [0.0])
    return float(np.nanmean(current_mse)) - float(np.nanmean(challenger_mse)) > floor * (1 + margin)


@dataclass(frozen=True)
class SelectionRule:
    """When one candidate beats another on held-out curves (``_beats``, ``choose_candidate``): a held-out error
    lower by more than ``equivalence`` (relative, dimensionless) and a paired-bootstrap 5 % bound of the relative
    reduction above ``min_relative_gain`` (dimensionless), from ``n_boot`` resamples of the held-out curves."""

    n_boot: int = 2000
    min_relative_gain: float = 0.05
    equivalence: float = 0.05


def equivalent_candidates(heldout_mse: dict, chosen: str, rng, rule: SelectionRule | None = None, *,
                          same_observable=(), floors: dict | None = None, floor_margin: float = 0.05,
                          **rule_values) -> list[str]:
    """The candidates that explain the held-out residual as well as ``chosen``, by the ``rule`` (a
    ``SelectionRule``, its defaults where None; keyword ``rule_values`` set single fields).

    ``heldout_mse``: {name: per-held-out-curve mean-square misfit} of the candidates still offered
    (after every gate), ``"none"`` included, and optionally ``HAMILTONIAN_CHANGE`` (the Hamiltonian's
    own neighbourhood). A candidate c is equivalent to ``chosen`` when c alone beats ``none`` and
    neither of the two beats the other (``_beats``: a held-out error lower by more than
    ``equivalence`` and a paired-bootstrap 5 % bound of the relative reduction above
    ``min_relative_gain``; common random numbers, ``bootstrap_resamples``). Nested candidates (one a
    combination containing the other) and candidates that are one observable with ``chosen``
    (``same_observable``: groups of names) are not counted: the first are told apart by parsimony,
    the second by no FORC measurement at all. Returns the sorted names (empty: ``chosen`` stands
    alone).

    ``floors`` ({name: null gain {"relative", "mse"}}, ``physics_effects.null_gains``): equal within
    their null gains. A candidate must then also beat "none" beyond its own floor (``beats_floor``, by
    ``floor_margin``), and one of the two beats the other only by a mean-square difference above the
    larger of their floors (``refit.refit_ambiguity``). None: as before."""
    rule = replace(rule or SelectionRule(), **rule_values)
    n_boot, min_relative_gain, equivalence = rule.n_boot, rule.min_relative_gain, rule.equivalence
    if chosen == "none" or chosen not in heldout_mse:
        return []
    same = set().union(*[set(g) for g in same_observable if chosen in g]) if same_observable else set()
    floors = floors or {}
    options = dict(rng=rng, n_boot=n_boot, min_relative_gain=min_relative_gain, equivalence=equivalence,
                   margin=floor_margin)
    out = []
    for name, mse in heldout_mse.items():
        if name in ("none", chosen) or name in same or nested(name, chosen):
            continue
        if not (_beats(mse, heldout_mse["none"], rng, n_boot, min_relative_gain, equivalence)
                and beats_floor(mse, heldout_mse["none"], floors.get(name), floor_margin)):
            continue
        pair = [floors.get(name), floors.get(chosen)]
        if _beats_beyond_floors(heldout_mse[chosen], mse, pair, **options):
            continue
        if _beats_beyond_floors(mse, heldout_mse[chosen], pair, **options):
            continue
        out.append(name)
    return sorted(out)


def separating_measurements(names) -> dict:
    """{candidate: the measurement apart from the FORC family that tells it from the others}."""
    generic = "a measurement whose prediction differs between these candidates (they are equal on this FORC family)"
    return {name: SEPARATING_MEASUREMENTS.get(name, SEPARATING_MEASUREMENTS.get(name.split("+")[0], generic))
            for name in names}


def _grid_resolution(values, best) -> float:
    """Half the local spacing of the grid at ``best``: the resolution of a gridded size."""
    values = sorted(values)
    if len(values) < 2:
        return 0.0
    k = values.index(best)
    lo, hi = max(k - 1, 0), min(k + 1, len(values) - 1)
    return abs(values[hi] - values[lo]) / (hi - lo) / 2


@dataclass(frozen=True)
class EffectSelection:
    """How ``select_effect`` chooses among the measured-side candidates.

    ``every_k``: every k-th curve held out; ``cross_fit``: each of the ``every_k`` such splits in turn (every
    curve held out once); ``seed``: the seed of the bootstrap stream (``core.streams``); ``candidates``: names in
    ``EFFECTS`` offered (None: all); ``n_boot``, ``min_relative_gain``, ``equivalence``: the rule
    (``SelectionRule``)."""

    every_k: int = 4
    n_boot: int = 2000
    seed: int = 0
    candidates: object = None
    min_relative_gain: float = 0.05
    equivalence: float = 0.05
    cross_fit: bool = False


def select_effect(measured, sim, fields, order=None, settings: EffectSelection | None = None, **options) -> dict:
    """Fit measured-side candidates (singles and ``COMBINATIONS``; ``candidates`` restricts them) on
    training curves, compare them on held-out curves (every ``every_k``-th; with ``cross_fit`` each
    of the ``every_k`` such splits in turn, so every curve is held out once), choose (module rule). The
    settings are those of ``settings`` (an ``EffectSelection``, its defaults where None), keyword ``options``
    setting single ones.

    ``order``: measurement clock τ ∈ [0, 1] per curve (n,) or per point (n, n); default per curve
    0 → 1 in ascending H_r. Parameters and uncertainties are those of the fit on the training curves
    (all usable curves with ``cross_fit``). Returns {"chosen", "candidates": {name: {"parameters",
    "uncertainties", "n_parameters", "heldout_rms", "gain_mse", "gain_ci90", "accepted"}},
    "heldout_curves", "heldout_rms_before", "heldout_rms_after"}."""
    o = replace(settings or EffectSelection(), **options)
    every_k, n_boot, seed, candidates = o.every_k, o.n_boot, o.seed, o.candidates
    min_relative_gain, equivalence, cross_fit = o.min_relative_gain, o.equivalence, o.cross_fit
    measured = np.asarray(measured, dtype=float)
    sim = np.asarray(sim, dtype=float)
    fields = np.asarray(fields, dtype=float)
    order = np.linspace(0.0, 1.0, measured.shape[0]) if order is None else np.asarray(order, dtype=float)
    folds = heldout_folds(measured, every_k, cross_fit)
    all_train = sorted(folds[0][0] + folds[0][1]) if cross_fit else folds[0][0]
    names = ["none"] + [k for k in (candidates or EFFECTS) if k != "none"]
    fits, mse = {}, {}
    for name in names:
        effect = EFFECTS[name]

        def fit(train, effect=effect):
            return effect.model(sim, fields, order, fit_effect(effect, measured, sim, fields, order, train)[0])

        mse[name] = heldout_mse(measured, fit, folds)
        theta, errors = fit_effect(effect, measured, sim, fields, order, all_train)
        fits[name] = {"parameters": dict(zip(effect.parameters, map(float, theta))),
                      "uncertainties": dict(zip(effect.parameters, map(float, errors))),
                      "n_parameters": len(effect.parameters)}
    chosen, scores = choose_candidate(mse, {k: v["n_parameters"] for k, v in fits.items()},
                                      stream_rng(seed, "bootstrap", "select_effect"), n_boot, min_relative_gain,
                                      equivalence)
    results = {k: {**fits[k], **scores[k]} for k in names}
    return {"chosen": chosen, "candidates": results, "heldout_curves": [i for _, held in folds for i in held],
            "heldout_rms_before": results["none"]["heldout_rms"], "heldout_rms_after": results[chosen]["heldout_rms"]}
