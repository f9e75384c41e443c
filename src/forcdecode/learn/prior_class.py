"""The prior class a model was trained on, checked against the measured loop before anything is decoded.

A model trained on the ``perpendicular`` class (``core.parameters.PRIOR_CLASSES``: every training film
has K_eff = K_u − μ0 M_s²/2 > 0) has never seen an in-plane film; given one, it still answers, with a
Hamiltonian it could not have learnt. The check reads two observables of the measured major loop, both
off the FORC image on the training grid (normalized by the saturation): the descending branch is its
diagonal (the reversal points m(H_r, H_r)), the ascending one its first row (the curve reversed at
−B_max).

- m_r, the loop's remanence (squareness M_r/M_s): the larger of m(H=0) on the descending branch and
  −m(H=0) on the ascending one (pinning sites and DMI break the ±H symmetry of a simulated film, and a
  perpendicular film may keep its saturation to H = 0 on one branch only).
- H_n, the field (μ0H, T) at which the descending branch leaves saturation: where it first falls below
  m = ``SATURATION_LEVEL`` coming down from +B_max (interpolated between grid fields).

An in-plane film swept along its hard axis turns away from the normal gradually from its effective
anisotropy field 2|K_eff|/M_s on down: it leaves saturation at a high field and has m_r ≈ 0. A
perpendicular film keeps m_r ≈ 1 — except where |D| exceeds the critical DMI D_c (σ_w < 0): a spiral or
skyrmion state nucleates and m_r falls to ≈ 0.1, but only once the field is low. The file is refused
when m_r < ``PERPENDICULAR_MIN_REMANENCE`` **and** H_n > ``PERPENDICULAR_MAX_EXIT_FIELD_T``.

Measured on the 404 simulated families of the laptop film (``forcdecode bench prior-class``, rates in
docs/inference.md): m_r alone refuses 7.7 % of the K_eff > 0 families (every one with |D| > D_c) for
99.6 % of the K_eff < 0 ones caught; with H_n the K_eff > 0 refusals fall below 5 %, and the K_eff < 0
films that pass are those closest to K_eff = 0 (|K_eff| ≲ 60 kJ/m³), whose loops are the least unlike a
perpendicular film's. A ``paper``-class model covers both regimes: nothing to contradict, the
observables are only reported.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import PriorClassError
from ..core.parameters import PRIOR_CLASSES, prior_class

PERPENDICULAR_MIN_REMANENCE = 0.5
"""m_r below which a loop may contradict K_eff > 0: between the two clusters of the simulated laptop
families (K_eff < 0: m_r ≤ 0.17 for 95 % of them; K_eff > 0: m_r ≥ 0.95 but for |D| > D_c)."""

PERPENDICULAR_MAX_EXIT_FIELD_T = 0.15
"""H_n (T) above which an unsaturated remanence contradicts K_eff > 0: chosen on the families of even
sample id of the laptop run (the smallest of 0, 0.05, 0.1, 0.125, 0.15, 0.2 T whose K_eff > 0 refusals
stay ≤ 5 % there), reported on the odd ones (docs/inference.md)."""

SATURATION_LEVEL = 0.9
"""m below which the descending branch has left saturation (the screening's saturation level)."""

OBSERVABLE = ("major-loop remanence m_r = max(m_desc(H=0), -m_asc(H=0)) / m_s, and the field H_n where the "
              f"descending branch first falls below m = {SATURATION_LEVEL:g}")


def _as_m(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2 or image.shape[0] != image.shape[1]:
        raise ValueError(f"a FORC image is square, got shape {image.shape}")
    return image.astype(float) / 127.5 - 1.0 if image.dtype == np.uint8 else image.astype(float)


def descending_branch(image) -> np.ndarray:
    """m(H_r, H_r) along the reversal fields (the descending major branch) of a FORC image on the training
    grid: uint8 (round(127.5 (m + 1))) or m ∈ [−1, 1]."""
    return np.diag(_as_m(image)).copy()


def ascending_branch(image) -> np.ndarray:
    """m(H) of the curve reversed at −B_max (the ascending major branch): the image's first row."""
    return _as_m(image)[0].copy()


def _at_zero(branch) -> float:
    """The branch at H = 0 (the grid is symmetric about H = 0, whatever B_max)."""
    return float(np.interp(0.0, np.linspace(-1.0, 1.0, branch.size), branch))


def descending_remanence(image) -> float:
    """m(H = 0) on the descending major branch."""
    return _at_zero(descending_branch(image))


def ascending_remanence(image) -> float:
    """−m(H = 0) on the ascending major branch (positive for a square loop)."""
    return -_at_zero(ascending_branch(image))


def loop_remanence(image) -> float:
    """m_r: the larger of the two branches' remanences (``OBSERVABLE``)."""
    return max(descending_remanence(image), ascending_remanence(image))


def saturation_exit_field(image, B_max_T: float = 1.0) -> float:
    """H_n (μ0H, T): where the descending branch first falls below ``SATURATION_LEVEL`` coming down from
    +B_max, interpolated between the grid fields (−B_max on a grid of ``B_max_T`` where it never does;
    +B_max where it is below already at +B_max)."""
    branch = descending_branch(image)
    fields = np.linspace(-B_max_T, B_max_T, branch.size)
    below = np.flatnonzero(branch < SATURATION_LEVEL)
    if below.size == 0:
        return float(-B_max_T)
    j = int(below.max())
    if j == branch.size - 1:
        return float(B_max_T)
    step = branch[j + 1] - branch[j]
    return float(fields[j] + (SATURATION_LEVEL - branch[j]) / step * (fields[j + 1] - fields[j]))


def contradicts_perpendicular(m_r, h_n_T) -> np.ndarray:
    """The rule (vectorized): m_r < ``PERPENDICULAR_MIN_REMANENCE`` and H_n > ``PERPENDICULAR_MAX_EXIT_FIELD_T``."""
    return ~(np.asarray(m_r, float) >= PERPENDICULAR_MIN_REMANENCE) & (np.asarray(h_n_T, float) > PERPENDICULAR_MAX_EXIT_FIELD_T)


def prior_class_line(name: str, check: dict | None = None) -> str:
    """One line saying which prior class the model was trained on (and the measured m_r when checked)."""
    line = f"model trained on prior class: {name} ({PRIOR_CLASSES.get(name, 'unknown class')})"
    if check and check.get("m_r") is not None:
        line += f"; measured m_r = {check['m_r']:.3f}, H_n = {check['H_n_T']:.3f} T"
        if check.get("threshold") is not None:
            line += (f" (the class refuses m_r < {check['threshold']:g} with H_n > "
                     f"{check['exit_field_threshold_T']:g} T)")
    return line


def check_prior_class(model_class, image, force: bool = False, source: str = "the file", B_max_T: float = 1.0) -> dict:
    """Does the loop of ``image`` (on the ±``B_max_T`` training grid) agree with the prior class
    ``model_class`` of the model? Returns the check (``prior_class``, ``observable``, ``m_r`` and its two
    branches, ``H_n_T``, ``threshold`` and ``exit_field_threshold_T`` (None for paper), ``consistent``,
    ``reason``, ``forced``); a contradiction raises PriorClassError with the reason and the measured
    numbers unless ``force`` (then ``forced`` is True and the check says so)."""
    name = prior_class(model_class)
    m_desc, m_asc = descending_remanence(image), ascending_remanence(image)
    m_r, h_n = max(m_desc, m_asc), saturation_exit_field(image, B_max_T)
    check = {"prior_class": name, "observable": OBSERVABLE, "m_r": m_r, "m_r_descending": m_desc,
             "m_r_ascending": m_asc, "H_n_T": h_n, "threshold": None, "exit_field_threshold_T": None,
             "consistent": True, "reason": None, "forced": False}
    if name == "perpendicular":
        check["threshold"] = PERPENDICULAR_MIN_REMANENCE
        check["exit_field_threshold_T"] = PERPENDICULAR_MAX_EXIT_FIELD_T
        if contradicts_perpendicular(m_r, h_n):
            check["consistent"] = False
            check["reason"] = (f"{source}: the major loop's remanence m_r = M_r/M_s = {m_r:.3f} (descending branch "
                               f"{m_desc:.3f}, ascending {m_asc:.3f}) is below {PERPENDICULAR_MIN_REMANENCE:g} and the "
                               f"descending branch leaves saturation (m < {SATURATION_LEVEL:g}) already at "
                               f"H_n = {h_n:.3f} T > {PERPENDICULAR_MAX_EXIT_FIELD_T:g} T: the loop of an in-plane film "
                               f"(K_eff = K_u - mu0 M_s^2/2 < 0), but the model was trained on the prior class "
                               f"'perpendicular' (K_eff > 0 for every training film); use a model of the 'paper' class "
                               f"(or --force to decode anyway)")
            if not force:
                raise PriorClassError(check["reason"], check)
            check["forced"] = True
    return check


__all__ = ["PERPENDICULAR_MIN_REMANENCE", "PERPENDICULAR_MAX_EXIT_FIELD_T", "SATURATION_LEVEL", "OBSERVABLE",
           "descending_branch", "ascending_branch", "descending_remanence", "ascending_remanence", "loop_remanence",
           "saturation_exit_field", "contradicts_perpendicular", "prior_class_line", "check_prior_class"]
