"""Measured-side effects the micromagnetic model lacks, their signatures on the raw curves, and
selection by held-out whole curves.

Each effect maps the re-simulated grid family m_sim(H_r, H) (NaN below the diagonal) to a model of
the measurement with a few parameters:

- ``scale``:       m = a·m_sim                      (volume / M_s error)
- ``background``:  m = a·m_sim + χ·μ0H              (para/diamagnetic substrate, χ per tesla)
- ``field_offset``: m = m_sim(H_r − δ, H − δ)        (remanent field of the magnet, δ in tesla)
- ``additive_drift``: m = a·m_sim + d·τ              (τ ∈ [0, 1]: measurement order of the curve)
- ``multiplicative_drift``: m = a·m_sim·(1 + d·τ)

Selection: fit every candidate on all curves but every k-th, score it on the held-out curves (RMS),
and accept it only if it beats the base model (``none``, m = m_sim) on those curves by more than
its own noise: the 5 % lower bound of a paired bootstrap over held-out curves of the per-curve
mean-square improvement must exceed 5 % of the base error. Among accepted candidates that are
equivalent to the best (within 5 % in held-out MSE) the simplest wins; else ``none``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import least_squares


def _shift_field(sim, fields, delta):
    """m_sim evaluated at (H_r − δ, H − δ) (bilinear on the grid; NaN outside or below diagonal)."""
    filled = np.where(np.isfinite(sim), sim, np.nan)
    # fill below the diagonal by the reversal-point value so interpolation near the diagonal works
    for i in range(filled.shape[0]):
        filled[i, :i] = filled[i, i]
    interp = RegularGridInterpolator((fields, fields), filled, bounds_error=False, fill_value=np.nan)
    HR, H = np.meshgrid(fields, fields, indexing="ij")
    out = interp(np.stack([HR - delta, H - delta], axis=-1))
    return np.where(np.isfinite(sim), out, np.nan)


@dataclass(frozen=True)
class Effect:
    name: str
    parameters: tuple[str, ...]
    initial: tuple[float, ...]

    def model(self, sim, fields, order, theta):
        H = fields[None, :]
        tau = order[:, None]
        if self.name == "none":
            return sim
        if self.name == "scale":
            return theta[0] * sim
        if self.name == "background":
            return theta[0] * sim + theta[1] * H
        if self.name == "field_offset":
            return _shift_field(sim, fields, theta[0])
        if self.name == "additive_drift":
            return theta[0] * sim + theta[1] * tau
        if self.name == "multiplicative_drift":
            return theta[0] * sim * (1 + theta[1] * tau)
        raise ValueError(self.name)


EFFECTS = {
    "none": Effect("none", (), ()),
    "scale": Effect("scale", ("scale",), (1.0,)),
    "background": Effect("background", ("scale", "chi_per_T"), (1.0, 0.0)),
    "field_offset": Effect("field_offset", ("offset_T",), (0.0,)),
    "additive_drift": Effect("additive_drift", ("scale", "drift"), (1.0, 0.0)),
    "multiplicative_drift": Effect("multiplicative_drift", ("scale", "drift"), (1.0, 0.0)),
}


def fit_effect(effect: Effect, measured, sim, fields, order, rows):
    """Least-squares fit of ``effect`` on the curves ``rows``; returns (theta, standard errors)."""
    if not effect.parameters:
        return np.array([]), np.array([])
    mask = np.zeros(measured.shape, dtype=bool)
    mask[rows] = True
    mask &= np.isfinite(measured) & np.isfinite(sim)

    def residual(theta):
        model = effect.model(sim, fields, order, theta)
        r = np.where(mask & np.isfinite(model), model - measured, 0.0)
        return r[mask]

    result = least_squares(residual, np.array(effect.initial, dtype=float), x_scale="jac")
    dof = max(1, mask.sum() - len(effect.parameters))
    sigma2 = 2 * result.cost / dof
    try:
        covariance = np.linalg.inv(result.jac.T @ result.jac) * sigma2
        errors = np.sqrt(np.clip(np.diag(covariance), 0, None))
    except np.linalg.LinAlgError:
        errors = np.full(len(effect.parameters), np.nan)
    return result.x, errors


def _per_curve_mse(measured, model, rows):
    """Mean-square misfit of each curve in ``rows`` (aligned with rows; NaN where nothing to compare)."""
    out = np.full(len(rows), np.nan)
    for k, i in enumerate(rows):
        ok = np.isfinite(measured[i]) & np.isfinite(model[i])
        if ok.any():
            out[k] = np.mean((model[i, ok] - measured[i, ok]) ** 2)
    return out


def _bootstrap_gain(base_mse, mse, rng, n_boot):
    """Paired gain base − candidate over the curves both can score; (mean, 5 %, 95 %)."""
    both = np.isfinite(base_mse) & np.isfinite(mse)
    gain = (base_mse - mse)[both]
    if gain.size == 0:
        return float("nan"), float("-inf"), float("-inf")
    boots = gain[rng.integers(0, gain.size, size=(n_boot, gain.size))].mean(axis=1)
    return float(gain.mean()), float(np.quantile(boots, 0.05)), float(np.quantile(boots, 0.95))


def _heldout_split(measured, every_k):
    """Curves with at least two points; every ``every_k``-th of them held out. (train, held)."""
    n = measured.shape[0]
    usable = [i for i in range(n) if np.isfinite(measured[i]).sum() >= 2]
    held = usable[every_k // 2::every_k]
    return [i for i in usable if i not in held], held


def select_effect(measured, sim, fields, order=None, every_k: int = 4, n_boot: int = 2000, seed: int = 0,
                  candidates=None, min_relative_gain: float = 0.05, equivalence: float = 0.05) -> dict:
    """Fit candidates on training curves, compare on held-out curves (every ``every_k``-th), choose.

    A candidate is accepted when the 5 % bound of its bootstrapped held-out gain exceeds
    ``min_relative_gain`` of the base model's held-out mean-square error (noise and triviality
    guard); among accepted candidates within ``equivalence`` of the best held-out MSE, the one with
    the fewest parameters wins (nested models: scale ⊂ background, drift)."""
    measured = np.asarray(measured, dtype=float)
    sim = np.asarray(sim, dtype=float)
    order = np.linspace(0.0, 1.0, measured.shape[0]) if order is None else np.asarray(order, dtype=float)
    train, held = _heldout_split(measured, every_k)
    rng = np.random.default_rng(seed)
    base_model = EFFECTS["none"].model(sim, fields, order, ())
    base_mse = _per_curve_mse(measured, base_model, held)
    results = {}
    for name in candidates or EFFECTS:
        effect = EFFECTS[name]
        theta, errors = fit_effect(effect, measured, sim, fields, order, train)
        model = effect.model(sim, fields, order, theta)
        mse = _per_curve_mse(measured, model, held)
        gain, low, high = _bootstrap_gain(base_mse, mse, rng, n_boot)
        results[name] = {
            "parameters": dict(zip(effect.parameters, map(float, theta))),
            "uncertainties": dict(zip(effect.parameters, map(float, errors))),
            "heldout_rms": float(np.sqrt(np.nanmean(mse))),
            "gain_mse": gain,
            "gain_ci90": [low, high],
        }
    base = float(np.nanmean(base_mse))
    accepted = [k for k, v in results.items()
                if k != "none" and v["gain_ci90"][0] > max(0.0, min_relative_gain * base)]
    chosen = "none"
    if accepted:
        best = min(results[k]["heldout_rms"] for k in accepted) ** 2
        # parsimony: the fewest parameters among candidates within ``equivalence`` of the best
        equivalent = [k for k in accepted if results[k]["heldout_rms"] ** 2 <= best * (1 + equivalence)]
        chosen = min(equivalent, key=lambda k: (len(EFFECTS[k].parameters), results[k]["heldout_rms"]))
    return {"chosen": chosen, "candidates": results, "heldout_curves": held,
            "heldout_rms_before": results["none"]["heldout_rms"], "heldout_rms_after": results[chosen]["heldout_rms"]}


def select_physics_effect(measured, base_family, candidate_families: dict, every_k: int = 4, n_boot: int = 2000,
                          seed: int = 0, min_relative_gain: float = 0.05) -> dict:
    """Physics-side candidates: for each effect, re-simulated families over a grid of its size
    (``candidate_families[name] = {value: family}``). The size is chosen on the training curves, the
    effect judged on the held-out curves against ``base_family`` (paired bootstrap, as above)."""
    train, held = _heldout_split(np.asarray(measured, float), every_k)
    rng = np.random.default_rng(seed)
    base_mse = _per_curve_mse(measured, base_family, held)
    results = {"none": {"value": None, "heldout_rms": float(np.sqrt(np.nanmean(base_mse))), "gain_ci90": [0.0, 0.0]}}
    for name, families in candidate_families.items():
        train_error = {v: np.nanmean(_per_curve_mse(measured, fam, train)) for v, fam in families.items()}
        best_value = min(train_error, key=train_error.get)
        values = sorted(families)
        k = values.index(best_value)
        step = (values[min(k + 1, len(values) - 1)] - values[max(k - 1, 0)]) / 2 if len(values) > 1 else 0.0
        mse = _per_curve_mse(measured, families[best_value], held)
        gain, low, high = _bootstrap_gain(base_mse, mse, rng, n_boot)
        results[name] = {"value": float(best_value), "uncertainty": float(abs(step)),
                         "heldout_rms": float(np.sqrt(np.nanmean(mse))), "gain_mse": gain, "gain_ci90": [low, high]}
    base = float(np.nanmean(base_mse))
    accepted = [k for k, v in results.items() if k != "none" and v["gain_ci90"][0] > min_relative_gain * base]
    chosen = min(accepted, key=lambda k: results[k]["heldout_rms"]) if accepted else "none"
    return {"chosen": chosen, "candidates": results, "heldout_curves": held,
            "heldout_rms_before": results["none"]["heldout_rms"], "heldout_rms_after": results[chosen]["heldout_rms"]}
