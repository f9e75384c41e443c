"""The prior class a model was trained on, checked against the measured loop before anything is decoded.

A model trained on the ``perpendicular`` class (``core.parameters.PRIOR_CLASSES``: every training film
has K_eff = K_u − μ0 M_s²/2 > 0) has never seen an in-plane film; given one, it still answers, with a
Hamiltonian it could not have learnt. The check reads one observable of the measured major loop that
the sign of K_eff decides: its remanence (squareness) m_r = M_r/M_s. The FORC image on the training grid
holds both branches of the major loop: the descending branch is its diagonal (the reversal points
m(H_r, H_r)), the ascending one its first row (the curve reversed at −B_max); the image is normalized by
the saturation. m_r is the larger of the two branches' remanences, m(H=0) on the descending branch and
−m(H=0) on the ascending one (pinning sites and DMI break the ±H symmetry of a simulated film, and a
perpendicular film may keep its saturation to H = 0 on one branch only). A perpendicular film stays
saturated down to H = 0 (m_r ≈ 1); an in-plane film, swept along its hard axis, has m_r ≈ 0 on both
branches. The file is refused when m_r < ``PERPENDICULAR_MIN_REMANENCE``.

Measured on the simulated families of a laptop run (``forcdecode bench prior-class``; docs/inference.md):
the fraction of K_eff > 0 families the rule refuses and the fraction of K_eff < 0 families it catches.
The K_eff > 0 films it refuses are those whose ground state is not uniform: DMI above the critical
value (|D| > D_c, spirals) close to K_eff = 0, whose loop is an in-plane film's.
A ``paper``-class model covers both regimes: nothing to contradict, the remanence is only reported.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import PriorClassError
from ..core.parameters import PRIOR_CLASSES, prior_class

PERPENDICULAR_MIN_REMANENCE = 0.5
"""m_r below which a loop contradicts K_eff > 0 (``perpendicular`` class). Chosen between the two
clusters of simulated laptop families (K_eff < 0: m_r ≤ 0.15; K_eff > 0: m_r ≥ 0.9 but for films close
to K_eff = 0 or with |D| > D_c); its rates are those of ``forcdecode bench prior-class`` (docs/inference.md)."""

OBSERVABLE = "major-loop remanence m_r = max(m_desc(H=0), -m_asc(H=0)) / m_s"


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


def prior_class_line(name: str, check: dict | None = None) -> str:
    """One line saying which prior class the model was trained on (and the measured m_r when checked)."""
    line = f"model trained on prior class: {name} ({PRIOR_CLASSES.get(name, 'unknown class')})"
    if check and check.get("m_r") is not None:
        line += f"; measured m_r = {check['m_r']:.3f}"
        if check.get("threshold") is not None:
            line += f" (the class needs m_r >= {check['threshold']:g})"
    return line


def check_prior_class(model_class, image, force: bool = False, source: str = "the file") -> dict:
    """Does the loop of ``image`` agree with the prior class ``model_class`` of the model? Returns the check
    (``prior_class``, ``observable``, ``m_r``, ``threshold`` (None for paper), ``consistent``, ``reason``,
    ``forced``); a contradiction raises PriorClassError with the reason and the measured numbers unless
    ``force`` (then ``forced`` is True and the check says so)."""
    name = prior_class(model_class)
    m_desc, m_asc = descending_remanence(image), ascending_remanence(image)
    m_r = max(m_desc, m_asc)
    check = {"prior_class": name, "observable": OBSERVABLE, "m_r": m_r, "m_r_descending": m_desc,
             "m_r_ascending": m_asc, "threshold": None, "consistent": True, "reason": None, "forced": False}
    if name == "perpendicular":
        check["threshold"] = PERPENDICULAR_MIN_REMANENCE
        if not m_r >= PERPENDICULAR_MIN_REMANENCE:
            check["consistent"] = False
            check["reason"] = (f"{source}: the major loop's remanence m_r = M_r/M_s = {m_r:.3f} (descending branch "
                               f"{m_desc:.3f}, ascending {m_asc:.3f}) is below {PERPENDICULAR_MIN_REMANENCE:g}, "
                               f"the loop of an in-plane film (K_eff = K_u - mu0 M_s^2/2 < 0), "
                               f"but the model was trained on the prior class 'perpendicular' (K_eff > 0 for every "
                               f"training film); use a model of the 'paper' class (or --force to decode anyway)")
            if not force:
                raise PriorClassError(check["reason"], check)
            check["forced"] = True
    return check


__all__ = ["PERPENDICULAR_MIN_REMANENCE", "OBSERVABLE", "descending_branch", "ascending_branch",
           "descending_remanence", "ascending_remanence", "loop_remanence", "prior_class_line", "check_prior_class"]
