"""The closed loop on one measured (or simulated-as-measured) FORC file.

Reads the file, decides whether it is usable by physics (``forc.saturation``: the major loop saturates
inside the measured window) and puts the family on the training grid (normalized by the saturated
branches, completed where the state is known), takes the given Hamiltonian (SI) or
predicts it with the trained Alice networks, sweeping M_s when it is not given and keeping the M_s
whose re-simulation is closest to the measurement; re-simulates it averaged over pinning profiles,
and traces the residual on the raw curves to an effect the model lacks (measured-side and
physics-side candidates, chosen on held-out curves: ``physics_effects.analyse_residual``;
optionally against the Hamiltonian refitted without the candidate, ``loop.refit``), says
"unexplained structured residual" where nothing explains a structured residual, and re-simulates the file's own protocol for the residual at the measured
points in A·m². Writes OUT/report.json, OUT/report.md and figures (fields μ0H in T, m normalized).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError, ModelFileError, PriorClassError
from ..core.io import atomic_path, write_json, write_text
from ..core.parallel import map_in_order, using_workers
from ..core.parameters import TARGETS, denormalize, normalize
from ..core.progress import counter, progress, say
from ..core.streams import stream_rng
from ..forc.raster import measurement_on_grid
from ..forc.simulate import protocol_name
from ..infer.posterior_predictive import draws_as_hamiltonians
from ..infer.predictive_check import check_figure, predictive_check, read_reference
from ..infer.refine import DEFAULT_PRIOR, RefineRun, beyond_prior_lines, family_key, fit_function, parse_extension
from ..infer.resimulate import observation_error, resimulate_measured, resimulate_with_spread
from ..learn.answer import alice_answer
from ..learn.prediction import Prediction, answer_table, basis_lines
from ..learn.prior_class import check_prior_class, prior_class_line
from ..measured import read_forc
from .fixed_point import image_of_family, predict_correct_iterate
from .patches import (POOL_SIZE, RASTERIZED_MAX_POINTS, estimate_patches, null_films, rasterized_singles,
                      single_realisations)
from .physics_effects import (MOMENT_TOLERANCE, NULL_REALISATIONS, analyse_residual, decode_neighbourhood,
                              merge_null_gains, null_gains, physics_candidate_families)
from .refit import RefitSettings, analyse_with_refit, measured_saturation, realisation_floor
from .report_page import diagrams_figure, write_report_page
from .signatures import drift_evidence_of, field_shift_of, measured_point_arrays
from .structure import null_structure_floor


def _progress(text):
    say(text)  # timestamped on stderr; on a terminal, above the progress bar


def _json_ready(obj):
    if isinstance(obj, dict):
        return {str(k): _json_ready(v) for k, v in obj.items() if k != "arrays"}
    if isinstance(obj, (list, tuple)):
        return [_json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_ready(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _hamiltonian_of(prediction: dict) -> dict:
    """The simulator's parameter dict (SI) of a prediction (``predict_parameters`` format)."""

    return Prediction.from_dict(prediction).hamiltonian()


def family_predictor(models, Ms_A_per_m: float):
    """family → Hamiltonian (SI): the prediction path of ``predict_and_sweep`` at one M_s applied to
    the networks' image of a grid family (``loop.fixed_point.image_of_family``)."""
    from ..learn.predictor import predict_parameters  # local: the predictor imports torch

    predict = models if callable(models) else (lambda img, ms: predict_parameters(models, img, ms))
    return lambda family: _hamiltonian_of(predict(image_of_family(family), Ms_A_per_m))


def predict_and_sweep(cfg, models, image, family, ms_values, n_profiles, log=_progress):
    """Predict the Hamiltonian at each M_s (``models``: Alice's models, or a callable (image, M_s) →
    prediction such as the posterior's), re-simulate it, keep the M_s whose family is closest to
    the measured one (observation-space RMS). Returns (best, sweep rows); each row keeps its
    re-simulated ``family``, the variance between its profiles ``spread`` and ``n_profiles``."""
    from ..learn.predictor import predict_parameters  # local: the predictor imports torch

    predict = models if callable(models) else (lambda img, ms: predict_parameters(models, img, ms))
    rows = []
    for k, ms in enumerate(progress(ms_values, desc="M_s sweep", unit="values")):
        prediction = predict(image, ms)
        params = _hamiltonian_of(prediction)
        resim, spread = resimulate_with_spread(cfg, params, n_profiles=n_profiles)
        rms = observation_error(family, resim)["rms"]
        rows.append({"Ms": float(ms), "prediction": prediction, "params": params, "observation_rms": rms,
                     "family": resim, "spread": spread, "n_profiles": n_profiles})
        log(f"M_s {ms / 1e3:.0f} kA/m ({k + 1}/{len(ms_values)}): observation RMS {rms:.4f}")
    best = min(rows, key=lambda r: r["observation_rms"])
    return best, rows


def _refine(cfg, est, m: Measurement, Ms, path, s: LoopSettings, setup: RefineSetup, log):
    """(report entry, Hamiltonian SI) of the refined posterior of the measured family ``m.family`` at M_s
    ``Ms`` (A/m; ``infer.fit``, ``s.refine_budget`` simulations in rounds of ``s.refine_round_size`` on
    ``s.refine_workers`` processes): medians and 68/90 % intervals per parameter (normalized and SI),
    effective sample size, whether the tempering reached the full likelihood; with ``setup.reference`` (a
    dict of ``infer.predictive_check.make_reference``) the posterior-predictive misspecification check.
    ``s.refine_method``: "pmc" (``refine.fit_one``) or "adjusted" (``refine.fit_adjusted``: no tempering, no
    particles' observation RMS). ``setup.extend`` ({name: factor}, pmc only): the refinement's box reaches
    beyond the prior's bound (``refine.parse_extension``); the entry then carries ``beyond_prior``
    (``infer.fit.beyond_prior``) and the medians may lie past the bound."""
    budget, method, extend, predictive_reference = s.refine_budget, s.refine_method, setup.extend, setup.reference
    key = family_key(f"{Path(path).name}:refine")
    run = RefineRun(budget=budget, round_size=s.refine_round_size, workers=s.refine_workers,
                    seed=int(cfg.get("seed", 0)), key=key, prior=DEFAULT_PRIOR, extend=extend)
    result = fit_function(method)(cfg, est, m.image, m.family, Ms, run, log=log)
    final = result["refined_by_budget"][str(max(int(b) for b in result["refined_by_budget"]))]
    names = result["names"]
    medians = np.array([[final["parameters"][n]["median"] for n in names]])
    params = draws_as_hamiltonians(medians, names, Ms, est.bounds)[0]
    entry = {"budget": int(budget), "method": method, "ess": final["ess"],
             "reached_full_likelihood": result["reached_full_likelihood"], "betas": result.get("betas"),
             "wall_s": result["wall_s"], "note": final.get("note"), "parameters": {}}
    for n in names:
        row = dict(final["parameters"][n])
        row["value"] = float(denormalize(n, row["median"], est.bounds))
        for tag in ("68", "90"):
            row[f"value_{tag}"] = [float(denormalize(n, v, est.bounds)) for v in row[f"interval_{tag}"]]
        row["amortized_median"] = result["amortized"]["parameters"][n]["median"]
        entry["parameters"][n] = row
    log(f"refined by {budget} simulations: ESS {final['ess']:.1f}"
        + ("" if result["reached_full_likelihood"] else " (tempered: not the full posterior)"))
    if "observation_rms" in result:  # pmc: the particles' own posterior-predictive RMS
        entry["observation_rms"] = result["observation_rms"]
    if extend:
        entry["extend"], entry["beyond_prior"] = result["extend"], result["beyond_prior"]
        for line in beyond_prior_lines(result["beyond_prior"]):
            log(line)
    if predictive_reference is not None:
        entry["predictive_check"] = predictive_check(result, predictive_reference)
        log(f"{entry['predictive_check'].get('check', 'predictive')} check: {entry['predictive_check']['verdict']}")
    return entry, params


def _drift_note(data) -> str:
    if not data.calibration:
        return "none (the file has no calibration points)"
    if not data.drift_corrected:
        return "none (not applied)"
    timed = data.curves and data.curves[0].time_s is not None and data.calibration[0].time_s is not None
    return ("multiplicative, calibration moment interpolated in time" if timed
            else "multiplicative, one factor per curve from its calibration point")


def thin_protocol(data, max_points: int):
    """(indices of the curves kept, per kept curve the indices of its points kept): every k-th curve and
    every l-th point (ends kept) so that at most about ``max_points`` points remain."""
    n_points = sum(len(c) for c in data.curves)
    if n_points <= max_points:
        return list(range(len(data.curves))), [np.arange(len(c)) for c in data.curves]
    ratio = n_points / max_points
    k = max(1, int(np.floor(np.sqrt(ratio))))
    curves = list(range(0, len(data.curves), k))
    kept = sum(len(data.curves[i]) for i in curves)
    l = max(1, int(np.ceil(kept / max_points)))
    points = [np.unique(np.append(np.arange(0, len(data.curves[i]), l), len(data.curves[i]) - 1)) for i in curves]
    return curves, points


MEASURED_PROFILES = 2
"""Disorder profiles of the measured-protocol re-simulation made for the report where the patch pool does not
already hold one (``_measured_points``)."""

MEASURED_MAX_STEP_T = 0.002
"""Largest field step of the measured-protocol re-simulation: a continuous sweep is followed in
sub-steps, because a quasi-static relaxation that steps over an instability by a large field step lets
an avalanche run further than a continuous sweep does (at 5 mT steps curves reversed from saturation
still took different paths on the 16×16 test film; at 2 mT they coincide)."""


def _simulated_saturation(domain, reversal, fields, m):
    """(m_sat, m_0) of the simulated points by the measurement's rule: the medians U of the points at
    H ≥ H_+ and L of the points of curves reversed at or below H_− at H ≤ H_−, m_sat = (U − L)/2,
    m_0 = (U + L)/2; without saturated branches the median of the curves' last values, m_0 = 0."""
    if domain.lower_saturated and domain.upper_saturated:
        upper = np.concatenate([v[f >= domain.H_plus_T - 1e-12] for f, v in zip(fields, m)])
        lower = np.concatenate([v[f <= domain.H_minus_T + 1e-12] for h, f, v in zip(reversal, fields, m)
                                if h <= domain.H_minus_T + 1e-12])
        if upper.size and lower.size:
            U, L = float(np.median(upper)), float(np.median(lower))
            if U > L:
                return (U - L) / 2, (U + L) / 2
    return float(np.median([v[-1] for v in m])), 0.0


def measured_points_residual(cfg, params, data, domain, n_profiles: int = 2, max_points: int = 5000,
                             max_step_T: float | None = MEASURED_MAX_STEP_T, progress=None,
                             simulated: list | None = None) -> dict:
    """The re-simulation on the file's own protocol (its reversal fields and field points, sweep as
    measured; thinned to about ``max_points``) and the residual at the measured points in A·m²:
    model moment = M_0 + M_sat·(m − m_0)/m_sat, M_sat, M_0 of the measurement (``forc.saturation``:
    its saturated branches) and m_sat, m_0 of the simulated ⟨m⟩·ĥ by the same rule at the same points
    (explicit normalization of both, no fitted scale), measured moments after the drift
    correction the file supports. Returns a JSON-ready dict (``per_curve`` rows: H_r, RMS A·m²).

    ``simulated``: per curve of the file, ⟨m⟩·ĥ at every one of its points already simulated on this protocol
    (the patch pool's mean, ``patches.rasterized_singles``; ``n_profiles`` and ``max_step_T`` then say what it
    averaged and how it was swept): nothing is simulated."""

    curves, points = thin_protocol(data, max_points if simulated is None else sum(len(c) for c in data.curves))
    reversal = [data.curves[i].reversal_field_T for i in curves]
    fields = [data.curves[i].field_T[p] for i, p in zip(curves, points)]
    # the reversal point is measured at the reversal field: pass it as such (exact descending state)
    fields = [np.concatenate([[h], f[1:]]) if abs(f[0] - h) < 1e-9 else f for h, f in zip(reversal, fields)]
    if simulated is None:
        m = resimulate_measured(cfg, params, reversal, fields, n_profiles=n_profiles, max_step_T=max_step_T,
                                progress=progress)
    else:
        m = [np.asarray(v, float) for v in simulated]
        if [len(v) for v in m] != [len(f) for f in fields]:
            raise ValueError("simulated: one value per measured point of every curve expected")
    M_sat, M_0 = domain.moment_saturation_Am2, domain.moment_offset_Am2
    s_sat, s_0 = _simulated_saturation(domain, reversal, fields, m)
    residuals, per_curve = [], []
    for i, p, values in zip(curves, points, m):
        r = data.curves[i].moment_Am2[p] - (M_0 + M_sat * (values - s_0) / s_sat)
        residuals.append(r)
        per_curve.append([float(data.curves[i].reversal_field_T), float(np.sqrt(np.mean(r**2)))])
    r = np.concatenate(residuals)
    rms = float(np.sqrt(np.mean(r**2)))
    sigma = domain.noise_Am2
    return {"rms_Am2": rms, "rms_over_noise": rms / sigma if sigma > 0 else None,
            "rms_over_moment_saturation": rms / M_sat if M_sat > 0 else None, "noise_Am2": sigma,
            "n_points": int(r.size), "n_points_file": int(sum(len(c) for c in data.curves)),
            "n_curves": len(curves), "n_profiles": n_profiles, "max_step_T": max_step_T,
            "normalization": (f"model = M_0 + M_sat (m_sim - m_0)/m_sat, the measurement's M_sat, M_0 and the "
                              f"simulation's m_sat = {s_sat:.4f}, m_0 = {s_0:.4f} by one rule "
                              f"({domain.summary.get('normalization', '')})"),
            "per_curve": per_curve}


@dataclass(frozen=True)
class LoopSettings:
    """What ``close_loop_on_file`` runs (each field's default is the command line's).

    ``params``: a Hamiltonian (SI) to re-simulate instead of predicting one with the models of ``models_dir``;
    ``ms_values_A_per_m``: M_s values tried (one: known M_s; several: swept, each re-simulated with
    ``sweep_profiles`` profiles; None: the default sweep). ``profiles``: profiles of the final re-simulation
    (their spread is the structure test's disorder floor). ``every_k``: every k-th curve held out.
    ``physics``: try the physics-side candidates (K_2, bias, second phase, tilt). ``force``: analyse a file
    out of the domain or unlike the training data. ``refit``: names of Hamiltonian parameters refitted around
    the prediction before the effect selection (``loop.refit.analyse_with_refit``, ``refit_budget``
    re-simulations). ``measured_protocol``: also report the residual at the measured points in A·m² (the file's own
    protocol: the patch pool's simulation of it where it serves, or with ``measured_profiles`` given
    re-simulated with that many profiles, at most ``max_measured_points`` points, field sub-steps of at most
    ``measured_max_step_T``: ``_measured_points``). ``estimator``: "alice" (Alice + Bob's conformal
    intervals) or "posterior" (the joint neural posterior at ``posterior_path``: medians re-simulated, 68/90 %
    intervals and correlations, after its out-of-distribution check). ``fixed_point`` (needs ``refit`` and a
    prediction): after a measured-side effect is chosen, predict again from the family with the effect removed
    and repeat to a fixed point (``loop.fixed_point.predict_correct_iterate``). ``null_realisations``:
    effect-free films of the decoded (with ``refit``: the refitted) Hamiltonian whose gains a candidate must
    beat (the realisation floor; None: the config's ``loop.null_films``; 0 with ``refit``: off).
    ``refine_budget`` (the posterior estimator): refine the amortized posterior of this family by that many
    simulations (``infer.fit``, rounds of ``refine_round_size``, ``refine_workers`` processes,
    ``refine_method`` "pmc" or "adjusted"); the refined medians are re-simulated. ``predictive_reference`` (a
    JSON path, with the pmc refinement): the calibrated posterior-predictive check of the refinement.
    ``refine_extend`` (["N_pin", "D=3", …]): refine in a box beyond the prior's bound and report the mass past
    it. ``moment_tolerance``: relative uncertainty of the moment normalization inside which a fitted scale is
    not named an effect; ConfigError outside [0, 1). ``training_dataset``: the dataset of Alice's image-only
    training-data check (default ``models_dir``/../dataset.h5). ``workers``: processes simulating the independent
    families (``core.parallel``; the answer does not depend on it). ``report_extras``: entries the caller adds
    to every report this run writes (the command line's film thickness and estimator choice)."""

    params: dict | None = None
    models_dir: object = "results/models"
    ms_values_A_per_m: object = None
    profiles: int = 20
    sweep_profiles: int = 2
    every_k: int = 4
    physics: bool = True
    force: bool = False
    refit: object = None
    refit_budget: int = 20
    measured_protocol: bool = True
    measured_profiles: int | None = None
    max_measured_points: int = 5000
    measured_max_step_T: float | None = MEASURED_MAX_STEP_T
    estimator: str = "alice"
    posterior_path: object = "results/posterior/model.pt"
    fixed_point: bool = False
    null_realisations: int | None = None
    refine_budget: int = 0
    refine_round_size: int = 25
    refine_workers: int = 1
    refine_method: str = "pmc"
    predictive_reference: object = None
    refine_extend: object = None
    moment_tolerance: float = MOMENT_TOLERANCE
    training_dataset: object = None
    workers: int = 1
    report_extras: dict | None = None


@dataclass
class RefineSetup:
    """The refinement's box beyond the prior's bound ({name: factor}, ``refine.parse_extension``) and the
    reference of its posterior-predictive check (None without ``predictive_reference``)."""

    extend: dict | None
    reference: dict | None


@dataclass
class Measurement:
    """The file (``read_forc``) on the training grid ``fields``: its image and family, the domain
    (``forc.saturation``) and why it is out of it (None: in the domain)."""

    data: object
    image: np.ndarray
    family: np.ndarray
    domain_note: str | None
    moment_saturation: float
    domain: object
    fields: np.ndarray


@dataclass
class Estimate:
    """The Hamiltonian to re-simulate (SI); the family and profile spread when the M_s sweep already
    re-simulated it with the final number of profiles (else None); ``predictor`` (fixed point only):
    family → Hamiltonian at the chosen M_s."""

    params: dict
    resim: np.ndarray | None = None
    spread: object = None
    predictor: object = None


@dataclass
class Residual:
    """The observation error of the re-simulation, and the model-free evidence the candidates need: the
    noise (m units), the field-shift and drift evidence, the measured points for the saturation test; and
    the re-simulated grid family (n × n, m normalized) the residual is of."""

    error: dict
    noise: float | None
    shift: dict | None
    drift: dict | None
    points: object
    resim: np.ndarray | None = None


@dataclass
class FileFloor:
    """The realisation floor of this file: how many patches it averages (``patches.PatchEstimate``), the
    pool of single realisations of the decoded Hamiltonian it was read against, and the null gains of
    every candidate on effect-free films at that patch number (None where not computed here: the refit
    path computes its own on the refitted Hamiltonian)."""

    patches: object
    pool: list
    null_gain: dict | None = None
    null_squares: list = field(default_factory=list)
    null_residuals: list = field(default_factory=list)
    null_gain_per_film: list = field(default_factory=list)
    """Each null film's own gains (mirrored), in the films' order: ``null_gain`` is their maximum, and the
    floor of the first k films is the maximum of the first k (the floor size can be studied on the bench's
    rows without re-running the loop)."""


@dataclass
class Judgement:
    """The residual analysis (``analyse_residual``'s dict, or the refit's) and the Hamiltonian it ends on."""

    analysis: dict
    final_params: dict


def check_options(s: LoopSettings) -> RefineSetup:
    """ConfigError for options that contradict each other or lie outside their range, before any work;
    the refinement's extended box and its predictive check's reference (read here)."""
    fixed_point, refit, refine_budget, estimator = s.fixed_point, s.refit, s.refine_budget, s.estimator
    refine_round_size, refine_workers, refine_method = s.refine_round_size, s.refine_workers, s.refine_method
    predictive_reference, moment_tolerance, measured_max_step_T = (s.predictive_reference, s.moment_tolerance,
                                                                   s.measured_max_step_T)
    if s.workers < 1:
        raise ConfigError(f"--workers {s.workers}: the loop needs at least one process")
    if fixed_point and not refit:
        raise ConfigError("the fixed-point iteration needs a Hamiltonian refit (refit names, --refit)")
    if refine_budget and (estimator != "posterior" or s.params is not None):
        raise ConfigError("refinement by simulation (--refine) starts from the joint posterior: it needs "
                          "--estimator posterior and a prediction, not --params")
    if refine_budget and (refine_round_size < 2 or refine_budget < refine_round_size or refine_workers < 1):
        raise ConfigError(f"--refine {refine_budget} needs at least one round of >= 2 simulations "
                          f"(round size {refine_round_size}) and >= 1 worker")
    fit_function(refine_method)  # an unknown method: ConfigError before any simulation
    if predictive_reference is not None and refine_method != "pmc":
        raise ConfigError("the posterior-predictive check (--predictive-reference) reads the pmc particles' observation "
                          "RMS: it needs --refine-method pmc")
    if s.refine_extend and (not refine_budget or refine_method != "pmc"):
        raise ConfigError("--refine-extend-prior needs --refine with --refine-method pmc")
    extend = parse_extension(s.refine_extend, TARGETS)  # an unknown or non-extensible name: before any simulation
    reference = None
    if predictive_reference is not None:
        if not refine_budget:
            raise ConfigError("the posterior-predictive check (--predictive-reference) judges a refinement: it needs --refine")
        reference = read_reference(predictive_reference, round_size=refine_round_size, prior=DEFAULT_PRIOR,
                                   budget_run=refine_budget, extend=extend)
    if fixed_point and s.params is not None:
        raise ConfigError("the fixed-point iteration predicts again from the corrected family: it needs the "
                          "networks, not a given Hamiltonian (--params)")
    if not 0.0 <= moment_tolerance < 1.0:
        raise ConfigError(f"moment tolerance {moment_tolerance!r} (--moment-tolerance) must lie in [0, 1): a relative "
                          "uncertainty of the moment normalization, e.g. 0.02 for ±2 %")
    if measured_max_step_T is not None and not measured_max_step_T > 0:
        raise ConfigError(f"measured-protocol field step {measured_max_step_T!r} T (--measured-max-step-mT) must be "
                          "> 0: the re-simulation sweeps on a lattice of that step")
    return RefineSetup(extend, reference)


def read_domain(path, cfg: dict) -> tuple[Measurement, dict]:
    """The file read and put on the training grid, its domain decided by physics; the report's first
    entries."""
    data = read_forc(path)
    B_max, n = cfg["field"]["B_max_T"], cfg["field"]["n_fields"]
    image, family, domain_note, moment_saturation, domain = measurement_on_grid(data, B_max, n, with_domain=True)
    report = {"file": str(path), "format": data.format, "n_curves": len(data.curves),
              "drift_percent": data.drift_percent, "drift_correction": _drift_note(data),
              "moment_saturation_Am2": moment_saturation, "moment_offset_Am2": domain.moment_offset_Am2,
              "in_domain": domain_note is None, "out_of_domain_reason": domain_note, "domain": domain.report()}
    fields = np.linspace(-B_max, B_max, n)
    return Measurement(data, image, family, domain_note, moment_saturation, domain, fields), report


def stop(out: Path, path, report: dict, status: str, note: str) -> dict:
    """A file not analysed (``status``): the report, its Markdown (the domain, then ``note``) and page."""
    report["status"] = status
    write_json(out / "report.json", _json_ready(report))
    text = _markdown_domain(path, report) + note
    write_text(out / "report.md", text)
    write_report_page(out, _json_ready(report), text, figures=())
    return report


OOD_SWEPT_NOTE = "M_s unknown: the most favourable p over the sweep"
"""How the report names the posterior's check when M_s is swept: the M_s of the largest p is kept."""


def posterior_ood(est, image, ms_values) -> dict:
    """The posterior's training-data check (``learn.ood.ood_check``): at the given M_s alone (one value),
    or, M_s unknown (several), at each M_s of the sweep keeping the most favourable p, and saying so."""
    from ..learn.ood import ood_check  # local: the check imports torch

    checks = [ood_check(est, image, [float(normalize("Ms", ms, est.bounds))]) for ms in ms_values]
    if not checks[0].get("available"):
        return dict(checks[0])
    if len(ms_values) == 1:
        ood = dict(checks[0])
        ood.update(Ms_A_per_m=float(ms_values[0]), Ms_mode="given",
                   Ms_note=f"at the given M_s ({ms_values[0] / 1e3:.0f} kA/m) alone")
        return ood
    k = int(np.argmax([c["p_value"] for c in checks]))
    ood = dict(checks[k])
    ood.update(Ms_A_per_m=float(ms_values[k]), Ms_mode="swept",
               Ms_note=(f"{OOD_SWEPT_NOTE} (at {ms_values[k] / 1e3:.0f} kA/m, of {len(ms_values)} values from "
                        f"{min(ms_values) / 1e3:.0f} to {max(ms_values) / 1e3:.0f} kA/m)"),
               p_by_Ms=[{"Ms": float(ms), "p_value": c["p_value"]} for ms, c in zip(ms_values, checks)])
    return ood


def alice_ood(models_dir, models, image, dataset=None, log=_progress) -> dict:
    """Alice's training-data check: the image-only conformal check (``learn.ood.image_ood_check``) against
    the train split of the networks' own dataset (``training_image_reference``); M_s plays no part. Not
    available, with the reason, when that dataset cannot be found or is another configuration's."""
    from ..learn.ood import image_ood_check, training_image_reference  # local: the check imports torch

    check = "image only (no posterior)"
    hashes = ([str(m.payload["config_hash"]) for m in models.values()
               if getattr(m, "payload", {}).get("config_hash") is not None] if isinstance(models, dict) else None)
    reference, note = training_image_reference(models_dir, dataset, hashes, log=log)
    if reference is None:
        return {"available": False, "check": check, "verdict": f"could not run: {note}"}
    try:
        ood = image_ood_check(reference, image)
    except (ValueError, ModelFileError) as error:
        return {"available": False, "check": check, "verdict": f"could not run: {error}"}
    ood.update(reference=note, Ms_mode="not used", Ms_note="image only: M_s plays no part in it")
    return ood


def _log_ood(ood: dict, log) -> None:
    log(f"training-data check ({ood.get('check', 'posterior')}): {ood['verdict']}"
        + (f"; {ood['Ms_note']}" if ood.get("Ms_note") else ""))
    if ood.get("warning"):
        log(f"WARNING training-data check: {ood['warning']}")


def prior_check(report: dict, trained_on: str, m: Measurement, s: LoopSettings, out: Path, path, log) -> None:
    """The prior-class check (``learn.prior_class``) of the model's class against the measured loop; report
    keys ``prior_class`` and ``prior_check``. A loop that contradicts the class stops the file: the report
    is written (status "contradicts the prior class") and PriorClassError raised, unless ``force``."""
    report["prior_class"] = trained_on
    try:
        report["prior_check"] = check_prior_class(trained_on, m.image, force=s.force, source=str(path),
                                                  B_max_T=float(m.fields[-1]))
    except PriorClassError as error:
        report["prior_check"] = error.check
        stop(out, path, report, "contradicts the prior class", "\n".join(_prior_lines(report)))
        raise
    log(prior_class_line(trained_on, report["prior_check"]))
    if report["prior_check"].get("forced"):
        log(f"WARNING (--force): {report['prior_check']['reason']}")


def estimate(cfg: dict, s: LoopSettings, m: Measurement, setup: RefineSetup, report: dict, out: Path, path,
             log) -> Estimate | None:
    """The Hamiltonian: given, or predicted (Alice or the posterior) at each M_s and the M_s whose
    re-simulation is closest kept, then optionally refined by simulation (``_refine``); its report
    entries. First, whatever the estimator, the training-data check (report key ``ood``: the posterior's
    ``posterior_ood``, Alice's image-only ``alice_ood``); None when it stops the file (its report
    written; ``force`` decodes it anyway). Before it, the prior-class check (``prior_check``): a loop that
    contradicts the class the model was trained on raises PriorClassError (report written) unless ``force``."""
    if s.params is not None:
        report.update(parameters=s.params, Ms_source="given (--params)",
                      ood={"available": False, "verdict": "not run: the Hamiltonian is given (--params), nothing is decoded"})
        return Estimate(s.params)
    profiles = s.profiles
    ms_values = list(s.ms_values_A_per_m if s.ms_values_A_per_m is not None else np.linspace(470e3, 1400e3, 6))
    est = None
    if s.estimator == "posterior":
        from ..learn.posterior import PosteriorEstimator, posterior_prediction  # local: imports torch

        est = PosteriorEstimator.load(s.posterior_path)
        prior_check(report, est.prior_class, m, s, out, path, log)
        ood = posterior_ood(est, m.image, ms_values)
        models = lambda img, ms: posterior_prediction(est, img, ms)  # noqa: E731
        trained = "The posterior was trained on"
    elif s.estimator == "alice":
        from ..learn.predictor import load_models, models_prior_class  # local: imports torch

        models = load_models(s.models_dir)
        prior_check(report, models_prior_class(models), m, s, out, path, log)
        ood = alice_ood(s.models_dir, models, m.image, s.training_dataset, log=log)
        trained = "Alice's networks were trained on"
    else:
        raise ConfigError(f"unknown estimator {s.estimator!r} (alice or posterior)")
    report["ood"] = ood
    _log_ood(ood, log)
    if ood.get("out_of_distribution") and not s.force:
        stop(out, path, report, "out of distribution",
             "\n".join(_ood_lines(report)) + f"\n\n**Not decoded**: {ood['verdict']}. {trained} "
             "families that do not look like this one (`--force` decodes it anyway).\n")
        return None
    best, sweep = predict_and_sweep(cfg, models, m.image, m.family, ms_values,
                                    s.sweep_profiles if len(ms_values) > 1 else profiles, log=log)
    result = Estimate(best["params"])
    if s.fixed_point:
        result.predictor = family_predictor(models, best["Ms"])
    prediction = best["prediction"]
    if s.estimator == "alice":  # the posterior's prediction carries its flags and combinations already
        prediction = alice_answer(models, prediction, seed=int(cfg.get("seed", 0)))
    report.update(parameters=result.params, prediction=prediction, Ms_chosen_A_per_m=best["Ms"],
                  Ms_source="given" if len(ms_values) == 1 else "swept",
                  Ms_sweep=[{"Ms": r["Ms"], "observation_rms": r["observation_rms"]} for r in sweep])
    if best["n_profiles"] == profiles:
        result.resim, result.spread = best["family"], best["spread"]
    if s.refine_budget:
        report["refined"], result.params = _refine(cfg, est, m, best["Ms"], path, s, setup, log)
        report["parameters"] = result.params
        result.resim = None  # re-simulate the refined Hamiltonian
        check = report["refined"].get("predictive_check")
        if check is not None:  # where this film lies among the reference's validation families
            check_figure(out / "predictive_check.png", setup.reference, {Path(str(path)).name: check},
                         title=f"{check['check']} check")
    return result


def resimulate_estimate(cfg: dict, s: LoopSettings, e: Estimate) -> tuple[np.ndarray, object]:
    """The re-simulated family of the estimate (``profiles`` pinning profiles) and the variance between
    its profiles; the sweep's own when it already has them."""
    if e.resim is not None:
        return e.resim, e.spread

    return resimulate_with_spread(cfg, e.params, n_profiles=s.profiles, progress=counter("re-simulation", "profiles"))


def residual_evidence(cfg: dict, m: Measurement, resim: np.ndarray, report: dict) -> Residual:
    """The observation error of the re-simulation and the model-free evidence of the measured curves
    (field shift, drift; report entries), and the measured points for the saturation test."""
    data, domain, moment_saturation = m.data, m.domain, m.moment_saturation
    error = observation_error(m.family, resim)
    noise = domain.noise_Am2 / moment_saturation if moment_saturation > 0 else None
    # the model-free evidence field-shift and drift candidates need: is the major loop symmetric, do
    # the saturated end points drift?
    shift = drift = None
    if noise:
        shift = field_shift_of(data, moment_saturation, noise, domain.moment_offset_Am2)
        drift = drift_evidence_of(data, moment_saturation, noise, domain.moment_offset_Am2)
        report["field_shift"], report["drift_evidence"] = shift, drift
    # the measured points themselves for the saturation test (the re-simulated major loop tells where the
    # film is saturated; the measured protocol is re-simulated quasi-statically only)
    points = None
    if protocol_name(cfg) == "quasistatic" and moment_saturation > 0:
        points = measured_point_arrays(data, moment_saturation, domain.moment_offset_Am2)
    return Residual(error, noise, shift, drift, points, resim)


def physics_candidates(cfg: dict, s: LoopSettings, params: dict, prediction: dict | None = None) -> dict:
    """The physics-side candidate families around ``params`` (none without ``physics``), with the
    Hamiltonian's neighbourhood as the decode leaves it open (``physics_effects.decode_neighbourhood`` of
    ``prediction``: each parameter moved to the edges of its own intervals for this file) where the
    Hamiltonian was decoded, K_u's ±6 % where it was given."""
    if not s.physics:
        return {}
    neighbourhood = decode_neighbourhood(prediction or {}, params)
    return physics_candidate_families(cfg, params, progress=counter("physics-side candidates", "families"),
                                      hamiltonian_values=neighbourhood)


def file_patches(cfg: dict, s: LoopSettings, m: Measurement, params: dict, r: Residual, report: dict,
                 log) -> FileFloor:
    """How many patches the file averages (``loop.patches.estimate_patches``: its step heights against
    P-averages of the config's ``loop.patch_pool`` single realisations of ``params``, the file's noise added); report
    key ``patches``. The pool is simulated on the file's own protocol and put on the grid as the file is
    (``patches.rasterized_singles``) where the file holds at most ``patches.RASTERIZED_MAX_POINTS`` points
    and the protocol is quasi-static, else on the training grid (``pool`` says which)."""
    pool_size = int(cfg.get("loop", {}).get("patch_pool", POOL_SIZE))

    points = sum(len(c) for c in m.data.curves)
    progress = counter("single realisations", "families")
    if points <= RASTERIZED_MAX_POINTS and protocol_name(cfg) == "quasistatic" and m.moment_saturation > 0:
        pool_step_T = float(cfg.get("loop", {}).get("pool_max_step_T", 0.0)) or None  # 0: the file's own points
        pool = rasterized_singles(cfg, params, m.data, m.moment_saturation, m.domain.moment_offset_Am2, pool_size,
                                  max_step_T=pool_step_T, progress=progress)
        where = "the file's own protocol, put on the grid as the file is"
        if pool.fallbacks:
            where += f" ({pool.fallbacks} of {len(pool)} on the grid: they do not saturate in the file's window)"
    else:
        pool = single_realisations(cfg, params, pool_size, progress=progress)
        where = (f"the training grid (the file's {points} points exceed {RASTERIZED_MAX_POINTS}, or its protocol is "
                 "not re-simulated: its rasterization is not in the floor)")
    estimate = estimate_patches(m.family, pool, noise_sigma=r.noise, seed=cfg["seed"])
    report["patches"] = {**estimate.report(), "pool": where, "null_films": s.null_realisations}
    log(f"patches averaged by the file: {estimate.label()} (step height {estimate.step_height:.3f}; consistent with "
        f"{', '.join(map(str, estimate.consistent)) or 'none of 1-8'}); the realisation floor is drawn at "
        f"{estimate.floor_patches}")
    return FileFloor(estimate, pool)


def null_floor(cfg: dict, s: LoopSettings, m: Measurement, resim: np.ndarray, r: Residual, floor: FileFloor,
               candidates: dict) -> FileFloor:
    """The realisation floor of every candidate (``physics_effects.null_gains``, K_u's neighbourhood
    included): its largest held-out gain on ``s.null_realisations`` effect-free films of the decoded
    Hamiltonian averaging the file's patch number (``patches.null_films``, each also mirrored, with the
    file's noise), analysed against the same re-simulation with the same candidates."""
    films = null_films(floor.pool, floor.patches.floor_patches, count=max(s.null_realisations, 1), seed=cfg["seed"])
    # each film with its own noise (seed + k), as the refit path's; merged in the films' order
    gains = map_in_order(_null_film_gains, [(film, resim, m.fields, r.noise, cfg["seed"] + k, s, candidates)
                                            for k, film in enumerate(films)],
                         progress=counter("realisation floor", "effect-free films"))
    null = {}
    for film_gains in gains:
        null = merge_null_gains(null, film_gains)
    noise = stream_rng(cfg["seed"], "null_noise", "structure_floor")
    residuals = [film - resim + (r.noise or 0.0) * noise.normal(size=film.shape) for film in films]
    return FileFloor(floor.patches, floor.pool, null, [(film - resim) ** 2 for film in films], residuals, gains)


def _null_film_gains(film, resim, fields, noise_sigma, seed: int, s: LoopSettings, candidates: dict) -> dict:
    """One null film's gains (``physics_effects.null_gains``, mirrored): a module-level worker of
    ``core.parallel.map_in_order``."""
    return null_gains([film], resim, fields, noise_sigma=noise_sigma, seed=seed, hamiltonian_floor=True,
                      every_k=s.every_k, n_profiles=s.profiles, **candidates)


def judge_residual(cfg: dict, s: LoopSettings, m: Measurement, params: dict, spread, r: Residual, candidates: dict,
                   floor: FileFloor) -> Judgement:
    """The residual traced to an effect against the re-simulation ``r.resim`` of ``params`` (``analyse_residual``),
    every candidate judged against its realisation floor at the file's patch number; ``spread``: the variance of
    m between the re-simulation's profiles."""
    resim = r.resim
    saturated = measured_saturation(cfg, params, r.points) if r.points is not None else None
    # the disorder floor of the structure test: the re-simulation's profile spread pooled with the null
    # films' (P-patch films against the re-simulation: their tails, where every profile happened to agree)
    variance = realisation_floor(spread, s.profiles, floor.null_squares, null_patches=floor.patches.floor_patches)
    # and the structure test's own floor: what it finds on those films (each with the file's noise)
    null_structure = null_structure_floor(floor.null_residuals, m.fields, r.noise, variance, s.profiles,
                                          measured_patches=floor.patches.floor_patches)
    analysis = analyse_residual(m.family, resim, m.fields, every_k=s.every_k, seed=cfg["seed"], noise_sigma=r.noise,
                                floor_variance=variance, n_profiles=s.profiles, field_shift=r.shift, drift=r.drift,
                                moment_tolerance=s.moment_tolerance, saturation_points=saturated,
                                null_gain=floor.null_gain, measured_patches=floor.patches.floor_patches,
                                null_structure=null_structure,
                                **candidates)
    return Judgement(analysis, params)


def judge_with_refit(cfg: dict, s: LoopSettings, m: Measurement, e: Estimate, r: Residual, report: dict,
                     log, floor: FileFloor) -> Judgement:
    """The residual traced to an effect against the Hamiltonian refitted without it
    (``refit.analyse_with_refit``), or iterated to a fixed point (``fixed_point``); report entries."""

    data, fields, refit = m.data, m.fields, s.refit
    if s.fixed_point:
        analysis = predict_correct_iterate(cfg, e.predictor, m.family, fields, names=tuple(refit),
                                           budget=s.refit_budget, noise_sigma=r.noise, every_k=s.every_k,
                                           n_profiles=s.sweep_profiles, physics=s.physics, log=log,
                                           null_realisations=s.null_realisations, field_shift=r.shift, drift=r.drift,
                                           moment_tolerance=s.moment_tolerance, measured_points=r.points,
                                           progress=counter("Hamiltonian refit", "re-simulations"))
        report["fixed_point"] = {k: analysis.pop(k) for k in ("converged", "n_iterations", "tolerance", "iterations")}
        analysis["arrays"] = {**analysis.get("arrays", {}), "corrected_family": analysis.pop("corrected_family")}
    else:
        shift_protocol = ((data.reversal_fields_T, [c.field_T for c in data.curves])
                          if r.shift is not None and protocol_name(cfg) == "quasistatic" else None)
        settings = RefitSettings(names=tuple(refit), every_k=s.every_k, null_realisations=s.null_realisations,
                                 null_patches=floor.patches.floor_patches, n_profiles=s.sweep_profiles,
                                 budget=s.refit_budget, physics=s.physics, noise_sigma=r.noise, field_shift=r.shift,
                                 drift=r.drift, measured_points=r.points, shift_protocol=shift_protocol)
        analysis = analyse_with_refit(cfg, e.params, m.family, fields, settings,
                                      measured_patches=floor.patches.floor_patches, moment_tolerance=s.moment_tolerance,
                                      progress=counter("Hamiltonian refit", "re-simulations"))
    final_params = analysis["hamiltonian"]["refit_without_effect"]
    report["hamiltonian"] = analysis["hamiltonian"]
    if analysis.get("field_shift") is not None:
        report["field_shift"] = analysis["field_shift"]  # calibrated by simulation when the refit ran
    report["refit"] = analysis["refit"]
    return Judgement(analysis, final_params)


def _same_hamiltonian(a: dict, b: dict) -> bool:
    """Whether two Hamiltonians (SI dicts) hold the same values."""
    return a.keys() == b.keys() and all(np.array_equal(np.asarray(a[k]), np.asarray(b[k])) for k in a)


def _measured_points(cfg: dict, s: LoopSettings, m: Measurement, j: Judgement, pool) -> dict:
    """The residual at the measured points (``measured_points_residual``) of the final Hamiltonian. Without
    ``s.measured_profiles``: the patch ``pool``'s own simulation of this protocol where it holds that
    Hamiltonian and every point (its mean over all its singles, on its sweep step ``loop.pool_max_step_T``:
    the same simulation is not run twice), else ``MEASURED_PROFILES`` profiles swept at
    ``s.measured_max_step_T`` (the refit path, a file over ``patches.RASTERIZED_MAX_POINTS`` points or over
    ``s.max_measured_points``); with it, that many profiles of the protocol's own disorder stream. Report
    key ``source`` says which."""
    points = sum(len(c) for c in m.data.curves)
    protocol = getattr(pool, "protocol", None)
    if (s.measured_profiles is None and protocol is not None and _same_hamiltonian(protocol["params"], j.final_params)
            and points <= s.max_measured_points):
        result = measured_points_residual(cfg, j.final_params, m.data, m.domain, n_profiles=protocol["singles"],
                                          max_step_T=protocol["max_step_T"], simulated=pool.on_protocol)
        return {**result, "source": "the patch pool's single realisations (the same protocol, simulated once)"}
    result = measured_points_residual(
        cfg, j.final_params, m.data, m.domain, n_profiles=s.measured_profiles or MEASURED_PROFILES,
        max_points=s.max_measured_points,
        max_step_T=s.measured_max_step_T, progress=counter("measured protocol", "profiles"))
    return {**result, "source": "re-simulated for the report"}


def write_report(out: Path, path, cfg: dict, s: LoopSettings, m: Measurement, r: Residual, j: Judgement,
                 report: dict, pool=None) -> dict:
    """The analysed file's report: its entries, the residual at the measured points (the file's own
    protocol re-simulated, or the patch ``pool``'s simulation of it: ``_measured_points``), the figures
    (against the re-simulation ``r.resim``), report.json, report.md and report.html."""
    analysis, fields, family, resim = j.analysis, m.fields, m.family, r.resim
    error = r.error
    residual = family - resim
    report.update(status="analysed", observation_rms=error["rms"],
                  per_curve_rms=[None if not np.isfinite(v) else float(v) for v in error["per_curve"]],
                  effect=analysis["chosen"], verdict=analysis["verdict"], verdict_text=analysis["verdict_text"],
                  analysis=_json_ready(analysis),
                  heldout_rms_before=analysis["heldout_rms_before"], heldout_rms_after=analysis["heldout_rms_after"])
    if s.measured_protocol and protocol_name(cfg) == "quasistatic":
        report["measured_points"] = _measured_points(cfg, s, m, j, pool)
    _figures(out, fields, family, resim, residual, analysis.get("arrays", {}).get("residual_after"))
    report["diagram_peaks"] = diagrams_figure(out / "diagrams.png", fields, family, resim)
    write_json(out / "report.json", _json_ready(report))
    text = _markdown(path, report, analysis)
    write_text(out / "report.md", text)
    write_report_page(out, _json_ready(report), text)
    return report


def close_loop_on_file(path, out, cfg: dict, settings: "LoopSettings | None" = None, *, log=_progress,
                       **options) -> dict:
    """Run the closed loop on the measured file ``path`` with the validated config ``cfg``; writes
    ``out``/report.json, report.md and figures and returns the report.

    ``settings`` (a ``LoopSettings``; its defaults where None) says what to run, and keyword ``options`` set
    single fields of it (``close_loop_on_file(path, out, cfg, refit=["K_u"])``; a TypeError names an unknown
    one). ``log``: progress lines. Domain (``forc.saturation``): the family is usable when its major loop
    saturates inside the measured window; the training image is completed where the state is known. A file
    out of the domain is reported with the specific reason and not analysed unless ``force``. Whatever the
    estimator, a training-data check runs before any decoding (report key ``ood``). Raises InputFileError for
    an unreadable file, ModelFileError for missing models, ConfigError for inconsistent settings."""
    s = replace(settings or LoopSettings(), **options)
    if s.null_realisations is None:  # the config's floor size (loop.null_films)
        s = replace(s, null_realisations=int(cfg.get("loop", {}).get("null_films", NULL_REALISATIONS)))
    setup = check_options(s)
    with using_workers(s.workers):
        return _close_loop(path, Path(out), cfg, s, setup, log)


def _close_loop(path, out: Path, cfg: dict, s: LoopSettings, setup: RefineSetup, log) -> dict:
    """``close_loop_on_file``'s stages (its settings checked, inside its workers' block)."""
    out.mkdir(parents=True, exist_ok=True)
    measurement, report = read_domain(path, cfg)  # domain
    report.update(s.report_extras or {})
    if measurement.domain_note is not None and not s.force:
        return stop(out, path, report, "out of domain", "\nNo prediction is made (`--force` analyses it anyway).\n")
    hamiltonian = estimate(cfg, s, measurement, setup, report, out, path, log)  # estimate
    if hamiltonian is None:  # not decoded: unlike the posterior's training data
        return report
    resim, spread = resimulate_estimate(cfg, s, hamiltonian)  # re-simulate
    residual = residual_evidence(cfg, measurement, resim, report)  # residual
    floor = file_patches(cfg, s, measurement, hamiltonian.params, residual, report, log)  # patches averaged
    if s.refit:  # candidates and judge, against the Hamiltonian refitted without each candidate
        judgement = judge_with_refit(cfg, s, measurement, hamiltonian, residual, report, log, floor)
    else:  # candidates, the realisation floor, judge
        candidates = physics_candidates(cfg, s, hamiltonian.params, report.get("prediction"))
        floor = null_floor(cfg, s, measurement, resim, residual, floor, candidates)
        report["patches"]["null_gain_per_film"] = floor.null_gain_per_film
        judgement = judge_residual(cfg, s, measurement, hamiltonian.params, spread, residual, candidates, floor)
    return write_report(out, path, cfg, s, measurement, residual, judgement, report, floor.pool)  # report


def _markdown_domain(path, report) -> str:
    d = report["domain"]

    def t(v):
        return "—" if v is None else f"{v:+.3f} T"

    lines = [f"# Closed loop: {Path(path).name}", "",
             f"Format {report['format']}, {report['n_curves']} curves; drift {report['drift_percent']:.2f} % "
             f"(correction: {report['drift_correction']}).", "",
             "## Domain (physics, not the window)", "",
             "Usable when the major loop saturates inside the measured window: the curves reversed at the "
             "lowest fields coincide and the ascending branch rejoins the descending one (within τ = max(4σ, one "
             "8-bit image level)), over at least one training-grid step, and both saturated branches change by at "
             "most 10 % of the half loop height per tesla (see `forc.saturation`).", "",
             f"- noise σ = {d['noise_Am2']:.3g} A m² (along the curves)"
             + (f"; {d['calibration_noise_Am2']:.3g} A m² from successive calibration points"
                if d.get("calibration_noise_Am2") else "") + f"; τ = {d['tolerance_Am2']:.3g} A m²",
             f"- loop closes (curves coincide) below {t(d.get('closure_field_lower_T'))} and above "
             f"{t(d.get('closure_field_upper_T'))}; saturated branches: lower {d['lower_saturated']}, upper {d['upper_saturated']}",
             f"- measured: reversal fields {d['measured_reversal_fields_T'][0]:+.3f}..{d['measured_reversal_fields_T'][1]:+.3f} T, "
             f"fields {d['measured_fields_T'][0]:+.3f}..{d['measured_fields_T'][1]:+.3f} T; on the ±{d['grid_B_max_T']:g} T "
             f"training grid: {100 * d['fraction_measured']:.1f} % measured, {100 * d['fraction_completed']:.1f} % "
             f"completed, {100 * d['fraction_unknown']:.1f} % unknown",
             "- completed: " + "; ".join(d["completed"]),
             f"- M_sat = {report['moment_saturation_Am2']:.4g} A m², offset M_0 = {report['moment_offset_Am2']:.3g} A m² "
             f"({d['normalization']})", ""]
    if report["out_of_domain_reason"]:
        lines += [f"**Out of the domain**: {report['out_of_domain_reason']}.", ""]
    else:
        lines += ["**In the domain.**", ""]
    return "\n".join(lines)


def _ood_lines(report) -> list[str]:
    """The training-data check in Markdown (empty without one)."""
    ood = report.get("ood")
    if not ood:
        return []
    lines = ["## Training-data check (out of prior)", "",
             f"Looks like the training data? {ood['verdict']}."]
    details = [f"check: {ood['check']}" if ood.get("check") else None, ood.get("Ms_note"),
               (f"{ood['n_validation']} held-out reference families, smallest p {ood['smallest_p']:.3f}, "
                f"alpha {ood['alpha']:g}") if "smallest_p" in ood else None,
               f"reference {ood['reference']}" if ood.get("reference") else None]
    details = [d for d in details if d]
    if details:
        lines += ["", "(" + "; ".join(details) + ")"]
    if ood.get("warning"):
        lines += ["", f"**Warning: {ood['warning']}.**"]
    return lines + [""]


def _prior_lines(report) -> list[str]:
    """The prior class of the model and its check against the loop, in Markdown (empty without a model)."""
    name = report.get("prior_class")
    if not name:
        return []

    lines = ["## Prior class", "", prior_class_line(name, report.get("prior_check")) + "."]
    check = report.get("prior_check") or {}
    if check.get("reason"):
        lines += ["", f"**{'Decoded with --force although' if check.get('forced') else 'Not decoded'}**: {check['reason']}."]
    return lines + [""]


def _posterior_lines(prediction) -> list[str]:
    """The joint posterior's draws in Markdown: the pairwise correlations (normalized parameters) and the
    conformalized 90 % intervals where the prediction carries them."""
    lines = []
    corr = prediction["posterior_correlation"]
    lines += ["", f"Joint posterior ({prediction['draws']} draws; value = median, central credible intervals). "
              "Pairwise correlations of the draws (normalized parameters):", "",
              "| | " + " | ".join(corr["names"]) + " |", "|---" * (len(corr["names"]) + 1) + "|"]
    for name, row in zip(corr["names"], corr["matrix"]):
        lines.append(f"| {name} | " + " | ".join(f"{v:+.2f}" for v in row) + " |")
    conformal = {n: e["interval_90_conformal"] for n, e in prediction.items()
                 if isinstance(e, dict) and "interval_90_conformal" in e}
    if conformal:
        lines += ["", "90 % intervals conformalized on the calibration split (coverage guaranteed for "
                  "families like the training data): " + "; ".join(
                      f"{n} {lo:.3g}–{hi:.3g}" for n, (lo, hi) in conformal.items())]
    return lines


def _refined_lines(refined) -> list[str]:
    """The refinement by simulation in Markdown: its table (amortized and refined medians, 68/90 % intervals),
    what it found beyond the prior's bound and its predictive check."""
    lines = ["", f"Refined by {refined['budget']} simulations of this film (`loop.fit`; effective sample size "
             f"{refined['ess']:.1f}{'' if refined['reached_full_likelihood'] else '; tempered, not the full posterior'}). "
             "The residual below is that of the refined medians:", "",
             "| parameter | amortized median (normalized) | refined median | refined 68 % | refined 90 % |",
             "|---|---|---|---|---|"]
    for name, row in refined["parameters"].items():
        lines.append(f"| {name} | {row['amortized_median']:.3f} | {row['value']:.4g} ({row['median']:.3f}) | "
                     f"{row['value_68'][0]:.3g}–{row['value_68'][1]:.3g} | {row['value_90'][0]:.3g}–{row['value_90'][1]:.3g} |")
    if refined.get("beyond_prior"):
        lines += ["", *(f"- {line}" for line in beyond_prior_lines(refined["beyond_prior"]))]
    check = refined.get("predictive_check")
    if check:
        extension = check.get("check") == "extension"
        lines += ["", ((f"**Outside the prior ({', '.join(refined.get('extend') or {})}): " if extension
                        else "**Misspecified: ") if check["misspecified"] else
                       ("Extension check: " if extension else "Posterior-predictive check: "))
                  + check["verdict"] + (".**" if check["misspecified"] else "."), "",
                  "![the check against its validation reference](predictive_check.png)"]
    return lines


def _prediction_lines(report) -> list[str]:
    """The decoded Hamiltonian in Markdown: M_s, the answer table, the posterior's correlations, the
    refinement and the M_s sweep (empty without a prediction)."""
    prediction = report.get("prediction")
    if not prediction:
        return []
    typed = Prediction.from_dict(prediction)
    lines = [f"M_s {report['Ms_chosen_A_per_m'] / 1e3:.0f} kA/m ({report['Ms_source']}).", "",
             *answer_table(typed, markdown=True), *basis_lines(typed, markdown=True)]
    if prediction.get("estimator") == "posterior":
        lines += _posterior_lines(prediction)
    refined = report.get("refined")
    if refined:
        lines += _refined_lines(refined)
    if len(report.get("Ms_sweep", [])) > 1:
        lines += ["", "M_s sweep: " + ", ".join(f"{r['Ms'] / 1e3:.0f} kA/m → {r['observation_rms']:.4f}" for r in report["Ms_sweep"])]
    return lines


def _measured_points_lines(report) -> list[str]:
    """The residual at the measured points (the file's own protocol re-simulated, A·m²) in Markdown."""
    points = report.get("measured_points")
    if not points:
        return []
    source = (f"the patch pool's {points['n_profiles']} single realisations" if str(points.get("source", "")).startswith(
        "the patch pool") else f"{points['n_profiles']} profiles")
    return [f"Residual at the measured points (the file's own protocol re-simulated, {points['n_points']} of "
            f"{points['n_points_file']} points, {source}): RMS {points['rms_Am2']:.3g} A m² "
            f"= {points['rms_over_noise']:.1f} σ = {100 * points['rms_over_moment_saturation']:.2f} % of M_sat "
            f"({points['normalization']}).", ""]


def _hamiltonian_lines(report, analysis) -> list[str]:
    """The refitted Hamiltonian in Markdown: prediction, refitted without and with the effect, and the joint
    refit's held-out error (empty without a refit)."""
    hamiltonian = report.get("hamiltonian")
    if not hamiltonian:
        return []
    refit = report["refit"]
    lines = [f"Hamiltonian refitted around the prediction ({', '.join(refit['names'])}; {refit['evaluations']} "
             f"re-simulations): training MSE {refit['training_mse_prediction']:.4g} → {refit['training_mse_refit']:.4g}.", "",
             "| parameter | prediction | refitted without the effect | refitted with the effect |", "|---|---|---|---|"]
    with_effect = (hamiltonian.get("refit_with_effect") or {}).get("params", {})
    for name in refit["names"]:
        lines.append(f"| {name} | {hamiltonian['prediction'][name]:.4g} | {hamiltonian['refit_without_effect'][name]:.4g} | "
                     f"{with_effect.get(name, float('nan')):.4g} |")
    lines.append("")
    joint = hamiltonian.get("refit_with_effect") or {}
    if "heldout_rms" in joint:
        lines += [f"Hamiltonian and effect refitted together: held-out RMS {joint['heldout_rms']:.4f} (the effect on "
                  f"the Hamiltonian refitted without it: {analysis['heldout_rms_after']:.4f})"
                  + ("." if joint.get("generalises", True) else
                     " — the joint refit does not generalise to the held-out curves, so its Hamiltonian and effect "
                     "size are not used; the effect is read on the Hamiltonian refitted without it."), ""]
    return lines


def _fixed_point_lines(report) -> list[str]:
    """The fixed-point iteration in Markdown (empty without one)."""
    fixed = report.get("fixed_point")
    if not fixed:
        return []
    steps = "; ".join(f"{it['chosen']}, " + ", ".join(f"{n} {it['prediction'][n]:.4g} → {it['refitted'][n]:.4g}"
                                                         for n in report["refit"]["names"])
                      for it in fixed["iterations"])
    return [f"Fixed point of (Hamiltonian, measured-side effect), predicted again from the family with the effect "
            f"removed: {'converged' if fixed['converged'] else 'NOT converged'} after {fixed['n_iterations']} "
            f"iteration(s) (tolerance {100 * fixed['tolerance']:.0f} %; per iteration effect, prediction → "
            f"refitted: {steps}).", ""]


def _verdict_lines(report, analysis) -> list[str]:
    """The verdict, the chosen effect, the held-out errors and the candidates' table in Markdown, with the
    realisation floor's explanation where it was drawn."""
    lines = [f"**Verdict: {analysis['verdict']}** — {analysis['verdict_text']}.", "",
             f"Effect chosen on held-out curves: {analysis['chosen']} ({analysis.get('kind', '')}) "
             f"{_json_ready(analysis.get('parameters', {}))} ± {_json_ready(analysis.get('uncertainties', {}))}", "",
             f"Held-out RMS {analysis['heldout_rms_before']:.4f} → {analysis['heldout_rms_after']:.4f}"
             f" (reduction {_json_ready(analysis.get('heldout_reduction'))}, 90 % CI {_json_ready(analysis.get('heldout_reduction_ci90'))}).", "",
             "| candidate | held-out RMS | relative gain | gain on effect-free films (floor) | beats the floor | accepted |",
             "|---|---|---|---|---|---|"]
    for name, c in sorted(analysis["candidates"].items(), key=lambda kv: kv[1]["heldout_rms"]):
        null = c.get("null_gain")
        floor = "—" if null is None else f"{null['relative']:.2f}"
        lines.append(f"| {name} | {c['heldout_rms']:.4f} | {c.get('relative_gain', float('nan')):.2f} | "
                     f"{floor} | {c.get('beats_null', '—')} | "
                     f"{c.get('accepted', '')} |")
    if any("null_gain" in c for c in analysis["candidates"].values()):
        lines += ["", f"Floor: the {'refitted' if report.get('refit') else 'decoded'} Hamiltonian simulated on other "
                  "disorder realisations, each averaging as many patches as this file (below; mirrored, with the "
                  "measurement's noise) and analysed as if measured; a candidate must gain more here than there, "
                  "relatively and in mean-square error (`loop.patches`, `physics_effects.null_gains`). Field-shift "
                  "and drift candidates with model-free evidence are judged by that evidence (their floor is printed, "
                  "not applied)."]
    return lines


def _evidence_lines(report, analysis) -> list[str]:
    """The patches averaged by the file, the model-free evidence (field shift, drift) and the residual's
    structure in Markdown (each where it was computed)."""
    lines = []
    patches = report.get("patches")
    if patches:
        consistent = ", ".join(map(str, patches["consistent"])) or "none of 1–8"
        lines += ["", f"Patches averaged by the file (`loop.patches`): {patches['estimate']} (effective step height "
                  f"{patches['step_height']:.3f}; consistent with {consistent}); the floor is drawn at "
                  f"{patches['floor_patches']} patch(es), the most realisation noise the file may hold. Its single "
                  f"realisations were simulated on {patches.get('pool', 'the training grid')}."]
    shift = analysis.get("field_shift")
    if shift and shift.get("offset_T") is not None:
        lines += ["", f"Symmetry of the major loop (model-free evidence for a field shift, `loop.signatures`): centre "
                  f"{1e3 * shift['offset_T']:+.1f} ± {1e3 * shift['se_T']:.1f} mT ({shift['z']:.1f} se, χ² over "
                  f"{len(shift['levels'])} levels {shift['chi2']:.1f} / limit {shift['chi2_limit']:.1f}"
                  + (f"; {shift['calibration']}, read {1e3 * shift['raw_offset_T']:+.1f} mT" if "calibration" in shift else "")
                  + "): "
                  + ("a shift; field-shift candidates are judged without the realisation floor, and need only a "
                     "held-out error lower by 5 % (their significance is this test's). A lag of the "
                     "swept curves behind the reversal points (a detector time constant, a sweep-rate effect) reads "
                     "the same, as a shift of half its delay: a measurement at another sweep rate tells it from "
                     "an offset or a bias field, which do not depend on the rate."
                     if shift["significant"] else "no shift shown: field-shift candidates (offset, bias) are not offered.")]
    drift = analysis.get("drift")
    if drift and drift.get("trend") is not None:
        lines += ["", f"Drift evidence (model-free, `loop.signatures.drift_evidence`): end moments in positive saturation "
                  f"change by {drift['trend']:+.4f} over the run ({drift['z']:.1f} se)"
                  + (f"; mirror sum m(B_r) + m(−B_r) in saturation {drift['mirror_sum']:+.4f} ± {drift['mirror_se']:.4f} "
                     f"over {drift['mirror_curves']} curves ({'additive' if drift['additive'] else 'not additive'})"
                     if drift.get("mirror_sum") is not None else "")
                  + ("." if drift["significant"] else "; no drift: drift candidates are not offered.")]
    lines += _neighbourhood_lines(report, analysis)
    structure = analysis.get("structure", {})
    if "chi2_ratio" in structure:
        lines += ["", f"Residual structure after the chosen model: mean z² {structure['chi2_ratio']:.2f}, runs z "
                  f"{structure['runs_z']:.1f}, lag-1 z {structure['lag1_z']:.1f} (noise σ {structure['noise_sigma']:.3g}, "
                  f"{structure['noise_source']}); rule: {structure['rule']}."]
    return lines


def _neighbourhood_lines(report, analysis) -> list[str]:
    """The Hamiltonian's neighbourhood the gates used, in Markdown, where it moved along a decoded
    parameter (``physics_effects.decode_neighbourhood``): the direction, the change and the held-out RMS."""
    h = analysis.get("hamiltonian_neighbourhood") or {}
    if not h.get("parameter"):
        return []
    name = h["parameter"]
    decoded = (report.get("parameters") or {}).get(name)
    moved = f" (from {decoded:.4g} to {decoded + h['change']:.4g})" if isinstance(decoded, (int, float)) else ""
    before = analysis.get("heldout_rms_before")
    before = f"{before:.4f}" if isinstance(before, (int, float)) else "—"
    return ["", f"The decoded Hamiltonian moved inside what this file's decode leaves open "
            f"(`physics_effects.decode_neighbourhood`: {', '.join(h.get('directions', []))}, each to the edges of "
            f"its own intervals): best along {name}, by {h['change']:+.4g} ± {h['change_uncertainty']:.2g} SI{moved}, "
            f"held-out RMS {before} → {h['heldout_rms']:.4f}"
            + (" (at its interval's edge)" if h.get("at_interval_edge") else "")
            + ". A physics candidate, or one that shifts the field, is named only where it beats this change."]


def _markdown(path, report, analysis) -> str:
    """report.md: the domain, the prior class and training-data checks, the decoded Hamiltonian, the
    residual, the refit, the verdict and its evidence, the figures."""
    lines = [_markdown_domain(path, report), *_prior_lines(report), *_ood_lines(report), *_prediction_lines(report)]
    lines += ["", f"Observation-space RMS error on the training grid (all FORC points, m normalized): "
              f"{report['observation_rms']:.4f}.", ""]
    lines += [*_measured_points_lines(report), *_hamiltonian_lines(report, analysis), *_fixed_point_lines(report),
              *_verdict_lines(report, analysis), *_evidence_lines(report, analysis)]
    lines += ["", "![families](families.png)", "", "![residual](residual.png)", "",
              "FORC diagrams (measured, re-simulated, difference; one colour scale): `diagrams.png` (in report.html).", ""]
    return "\n".join(lines)


def _figures(out, fields, measured, resim, residual, residual_after=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for i in range(0, fields.size, 4):
        ax.plot(fields[i:], measured[i, i:], color="tab:red", lw=0.8)
        ax.plot(fields[i:], resim[i, i:], color="0.2", lw=0.8, ls="--")
    ax.set_xlabel(r"$\mu_0H$ (T)")
    ax.set_ylabel(r"$m$")
    ax.set_title("measured (red) vs re-simulated (dashed)")
    fig.tight_layout()
    with atomic_path(out / "families.png") as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    vmax = np.nanmax(np.abs(residual)) or 1.0
    im = a.imshow(residual, origin="lower", cmap="RdBu_r", vmin=-vmax, vmax=vmax,
                  extent=[fields[0], fields[-1], fields[0], fields[-1]])
    a.set_xlabel(r"$\mu_0H$ (T)")
    a.set_ylabel(r"$\mu_0H_r$ (T)")
    a.set_title("residual m_measured − m_resimulated")
    fig.colorbar(im, ax=a)
    b.plot(fields, np.sqrt(np.nanmean(residual**2, axis=1)), "o-")
    b.set_xlabel(r"$\mu_0H_r$ (T)")
    b.set_ylabel("per-curve RMS")
    if residual_after is not None:
        b.plot(fields, np.sqrt(np.nanmean(np.asarray(residual_after) ** 2, axis=1)), "s-", label="after the chosen effect")
        b.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(out / "residual.png") as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)
