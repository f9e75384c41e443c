"""Could any film inside the prior have made this family? A calibrated posterior-predictive check.

The training-data check (``learn/ood.py``) compares the image with the training images. A film
outside the prior whose family moves *along* the manifold of training images (measured: pinning three
times denser than the prior allows) passes it. The question that can catch such a film is asked in
observation space: among the Hamiltonians the refinement simulated (its first ``budget`` candidates,
drawn from the amortized posterior and then from the refined proposal, all on one disorder
realisation), how close does the best one come to the observed family, relative to the realisation
floor (the RMS difference two disorder realisations of one Hamiltonian make)?

    T = min over the first b candidates of RMS(candidate − observation) / √σ²,

σ² measured by the refinement itself (``infer.fit``: the amortized median on 4 realisations). A family
our film can make has a candidate near T ≈ 1 or below; a family no in-prior film makes keeps T
above. The threshold is not guessed: T is computed the same way (same budget b, same round size,
same prior) for held-out validation families, which our film made and the posterior never trained on,
and the check is conformal: p = (1 + #{validation T ≥ T_obs}) / (n + 1), flagged at p < α. Under
exchangeability with the validation families the false-alarm rate is at most α; with n validation
families nothing below 1/(n + 1) can be resolved (n ≥ 20 for α = 0.05).

The statistic is the minimum over the first b candidates, not the weighted median of the particles:
it depends on the first b simulations only, so a refinement run to any budget ≥ b gives the same T
as the calibration run (and the weights of a tempered run do not enter). What it flags is measured
(``forcdecode bench ood --predictive-budget``, README).

The extension check asks the same question of a refinement run in a box extended beyond the prior's
bound (``fit --extend-prior``, ``infer.fit.beyond_prior``): does a film beyond the bound reproduce the
family better than every film inside? Its statistic is the generalized log-likelihood ratio

    Λ = max log L over the first b candidates − max log L over those of them inside the prior's box

(≥ 0, and 0 when the best candidate lies inside), calibrated the same way on validation families
refined in the same extended box (``bench fit --extend-prior --split validation`` writes the
reference). A reference says which statistic it holds (``statistic``, and ``extend``: {name: factor}
of its box, empty for T), and is refused for a refinement whose box differs.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError, InputFileError
from ..core.io import atomic_path, read_json

ALPHA = 0.05
STATISTIC = "min over the first b candidates of observation RMS / realisation floor"
EXTENSION_STATISTIC = ("log-likelihood ratio of the best of the first b candidates anywhere in the extended box "
                       "over the best of them inside the prior's box")


def _best_by_budget(fit_result: dict) -> dict:
    """The fit result's T per round boundary ({"b": T}); its keys are the multiples of the round size."""
    by_budget = fit_result.get("observation_rms", {}).get("best_over_floor_by_budget")
    if not by_budget:
        raise ConfigError("the fit result has no best_over_floor_by_budget (a refinement from before the check: run it again)")
    return by_budget


def _ratio_by_budget(fit_result: dict) -> dict:
    """The fit result's Λ per round boundary ({"b": Λ}, ``infer.fit.beyond_prior``)."""
    by_budget = (fit_result.get("beyond_prior") or {}).get("log_likelihood_ratio_by_budget")
    if not by_budget:
        raise ConfigError("the fit result has no beyond_prior.log_likelihood_ratio_by_budget: the extension check "
                          "needs a refinement with --extend-prior (made by this version: run it again)")
    return by_budget


def is_extension(reference: dict) -> bool:
    """Whether a reference holds the extension check's Λ (else the predictive check's T)."""
    return bool(reference.get("extend"))


def predictive_statistic(fit_result: dict, budget: int, extension: bool = False) -> float:
    """T (or, with ``extension``, Λ) at ``budget`` from a fit result (``infer.refine.finish_fit``'s dict)."""
    by_budget = _ratio_by_budget(fit_result) if extension else _best_by_budget(fit_result)
    if str(int(budget)) not in by_budget:
        raise ConfigError(f"the refinement ran {max(int(b) for b in by_budget)} simulations in rounds "
                          f"{sorted(int(b) for b in by_budget)}; the check needs the first {budget}")
    return float(by_budget[str(int(budget))])


def make_reference(statistics, *, budget: int, round_size: int, prior: str, sample_ids, split: str = "validation",
                   alpha: float = ALPHA, extend: dict | None = None) -> dict:
    """The check's reference: T (or, with ``extend`` = {name: factor} of the extended box, Λ) of held-out
    in-distribution families and the settings that made them."""
    values = np.asarray(statistics, dtype=float)
    if values.size < 1 or not np.all(np.isfinite(values)):
        raise ConfigError(f"the predictive reference needs finite statistics (got {values.tolist()})")
    if budget % round_size:
        raise ConfigError(f"budget {budget} is not a multiple of the round size {round_size}")
    return {"statistic": EXTENSION_STATISTIC if extend else STATISTIC,
            "extend": {str(k): float(v) for k, v in (extend or {}).items()},
            "budget": int(budget), "round_size": int(round_size), "prior": str(prior), "split": split,
            "sample_ids": [int(s) for s in sample_ids], "values": sorted(float(v) for v in values),
            "alpha": float(alpha), "resolvable_p": 1.0 / (values.size + 1.0)}


def _check_box(ref_extend: dict | None, extend: dict | None) -> None:
    """Raise unless the refinement's box ({name: factor}; {} or None: the prior's) is the reference's."""
    extend = {str(k): float(v) for k, v in (extend or {}).items()}
    ref_extend = {str(k): float(v) for k, v in (ref_extend or {}).items()}
    if ref_extend == extend:
        return

    def box(e):
        return ("the prior's box" if not e else
                "a box extended beyond the prior (" + ", ".join(f"{k}={v:g}" for k, v in sorted(e.items())) + ")")

    raise ConfigError(f"the check's reference was refined in {box(ref_extend)}; this refinement ran in {box(extend)}: "
                      + ("refine with the same --extend-prior" if ref_extend else
                         "the predictive reference is for refinements inside the prior's box (for an extended one, "
                         "use the extension_reference.json of `forcdecode bench fit --extend-prior --split validation`)"))


def check_reference(reference: dict, *, round_size: int, prior: str, budget_run: int, extend: dict | None = None) -> None:
    """Raise if a refinement's settings (``extend``: {name: factor} of its box, {} or None in the prior's
    box) cannot be compared with the reference's."""
    try:
        ref_budget, ref_round, ref_prior = int(reference["budget"]), int(reference["round_size"]), reference["prior"]
        _ = reference["values"]
        ref_extend = {str(k): float(v) for k, v in (reference.get("extend") or {}).items()}
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise InputFileError(f"the predictive-check reference is damaged: {error}") from None
    _check_box(ref_extend, extend)
    if ref_round != int(round_size) or ref_prior != prior:
        raise ConfigError(f"the predictive-check reference was made with rounds of {ref_round} and the {ref_prior} "
                          f"prior; this refinement has rounds of {round_size} and the {prior} prior")
    if int(budget_run) < ref_budget:
        raise ConfigError(f"the predictive check needs a refinement of at least {ref_budget} simulations "
                          f"(its reference's budget); this one ran {budget_run}")


def read_reference(path, *, round_size: int, prior: str, budget_run: int, extend: dict | None = None,
                   what: str = "predictive-check reference") -> dict:
    """The reference JSON at ``path``, refused (ConfigError, InputFileError) unless it can judge a refinement
    with these settings (``check_reference``): every entry point calls this before any simulation."""

    reference = read_json(path, what=what)
    check_reference(reference, round_size=round_size, prior=prior, budget_run=budget_run, extend=extend)
    return reference


def predictive_p_value(statistic: float, reference_values) -> float:
    """Conformal p-value of the statistic (T or Λ) against the reference families' (large = the films inside
    the prior fit worse)."""
    ref = np.asarray(reference_values, dtype=float)
    return float((1.0 + (ref >= statistic).sum()) / (ref.size + 1.0))


def check_flag_threshold(reference: dict) -> float | None:
    """The statistic above which the conformal check flags a film at the reference's α: with p = (1 +
    #{reference ≥ t}) / (n + 1), p < α iff fewer than k = ⌈α (n + 1)⌉ − 1 reference values reach t, i.e. t
    above the k-th largest; None when k = 0 (too few reference families to flag anything at α)."""
    values = np.sort(np.asarray(reference["values"], dtype=float))
    k = int(np.ceil(float(reference.get("alpha", ALPHA)) * (values.size + 1))) - 1
    return float(values[values.size - k]) if k >= 1 else None


def predictive_check(fit_result: dict, reference: dict, alpha: float | None = None) -> dict:
    """Verdict of the check for one refined family (module docstring): the predictive check (T) or, for a
    reference made in an extended box, the extension check (Λ)."""
    budget = int(reference["budget"])
    extension = is_extension(reference)
    _check_box(reference.get("extend"), fit_result.get("extend"))
    by_budget = _ratio_by_budget(fit_result) if extension else _best_by_budget(fit_result)
    boundaries = [int(b) for b in by_budget]  # round_size, 2·round_size, …
    check_reference(reference, round_size=min(boundaries), prior=fit_result.get("prior", "uniform"),
                    budget_run=max(boundaries), extend=fit_result.get("extend"))
    alpha = float(reference.get("alpha", ALPHA) if alpha is None else alpha)
    t = predictive_statistic(fit_result, budget, extension)
    values = np.asarray(reference["values"], float)
    out = {"check": "extension" if extension else "predictive", "budget": budget, "alpha": alpha,
           "n_reference": int(values.size), "reference_median": float(np.median(values)),
           "reference_max": float(values.max())}
    if np.isnan(t):  # Λ with no successful simulation among the first b: nothing to judge, nothing flagged
        return {**out, "statistic": None, "p_value": None, "misspecified": False,
                "verdict": f"undetermined: none of the first {budget} simulations of the refinement succeeded"}
    p = predictive_p_value(t, values)
    flagged = p < alpha
    out.update(statistic=t, p_value=p, misspecified=bool(flagged))
    if extension:
        names = ", ".join(sorted(reference["extend"]))
        out["verdict"] = (f"a film beyond the prior's bound of {names} reproduces this family better than any film "
                          f"inside: log-likelihood ratio {t:.3g} over the best of {budget} candidates inside, above "
                          f"the held-out validation families (max {values.max():.3g}; p = {p:.3f} < {alpha}); the "
                          f"film lies outside the training prior" if flagged else
                          f"no film beyond the prior's bound of {names} fits better than the films inside, beyond "
                          f"what the held-out validation families show (log-likelihood ratio {t:.3g}; validation "
                          f"max {values.max():.3g}; p = {p:.2f})")
        return out
    return {**out,
            "verdict": (f"no film inside the prior reproduces this family: the best of {budget} simulated "
                        f"Hamiltonians misses it by {t:.2f}× the realisation floor, more than for the held-out "
                        f"validation families (max {values.max():.2f}×; p = {p:.3f} < {alpha})" if flagged else
                        f"reproduced by a film inside the prior: best of {budget} at {t:.2f}× the floor "
                        f"(validation families: median {np.median(values):.2f}×; p = {p:.2f})")}


def check_figure(path, reference: dict, judged: dict, *, title: str) -> None:
    """The conformal check on one axis: the reference families' statistic (T or Λ, grey), the value above
    which a film is flagged at the reference's α (the dashed line), and each judged film (label → its
    ``predictive_check`` verdict; red if flagged, blue if not, hollow if undetermined). A symmetric-log
    axis, since Λ is 0 for most in-distribution films and hundreds for a clearly beyond-prior one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = np.sort(np.asarray(reference["values"], dtype=float))
    alpha = float(reference.get("alpha", ALPHA))
    threshold = check_flag_threshold(reference)
    fig, ax = plt.subplots(figsize=(8.5, 1.2 + 0.28 * (len(judged) + 1)))
    ax.scatter(values, np.zeros_like(values), color="0.5", s=22, label=f"reference ({reference.get('split', '')}, "
               f"n = {values.size})")
    if (values == 0).sum() > 1:  # Λ = 0 (the best fit inside the prior) is common: say how many lie there
        ax.annotate(f"{int((values == 0).sum())} at 0", (0.0, 0.0), xytext=(6, 5), textcoords="offset points",
                    fontsize=7, color="0.4")
    for i, (label, check) in enumerate(judged.items(), start=1):
        value, flagged = check["statistic"], check["misspecified"]
        if value is None or not np.isfinite(value):
            ax.scatter([0.0], [i], facecolors="none", edgecolors="k", s=30)
            ax.annotate("undetermined", (0.0, i), xytext=(6, -3), textcoords="offset points", fontsize=7)
            continue
        ax.scatter([value], [i], color="C3" if flagged else "C0", s=30)
    if threshold is not None:
        ax.axvline(threshold, color="k", ls="--", lw=1, label=f"flag above (p < {alpha:g})")
    ax.set_yticks(range(len(judged) + 1), ["reference"] + [str(label) for label in judged], fontsize=7)
    ax.set_ylim(-0.7, len(judged) + 0.7)
    ax.set_xscale("symlog", linthresh=1e-2)
    shown = [c["statistic"] for c in judged.values() if c["statistic"] is not None and np.isfinite(c["statistic"])]
    shown += values.tolist()
    ax.set_xlim(-5e-3, 3.0 * max(max(shown), threshold or 0.0, 1e-2))
    name = "Λ (log-likelihood ratio, extended box)" if reference.get("extend") else "T (best RMS / floor)"
    ax.set_xlabel(f"{name} at {reference['budget']} simulations")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


__all__ = ["ALPHA", "EXTENSION_STATISTIC", "STATISTIC", "check_figure", "check_flag_threshold", "check_reference", "is_extension",
           "make_reference", "predictive_check", "predictive_p_value", "predictive_statistic", "read_reference"]
