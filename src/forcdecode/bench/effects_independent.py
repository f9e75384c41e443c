"""The residual analysis judged on data our model did not make (``forcdecode bench effects --independent``).

Samples: FORC families computed by magnum.np (``reference.independent``: 58 × 58 cells of 2.2 nm, its
own tessellation and draws; one control with a uniform grain-anisotropy distribution, which our model lacks) on a protocol off the fitting
grid (24 curves over ±1 T, reversal fields shifted by 0.37 of a step, points every half step), recorded by an
instrument model written apart from the loop's candidates (exponential gain warm-up, a drift ∝ t^1.5,
Langevin paramagnet, detector lag) and written as MicroMag 0015 and Lake Shore 8600 CSV files.

Fitting model: our engine on the laptop film (64 × 64 cells of 2 nm, Gaussian grain anisotropy, 24
grid fields over ±1 T), started from a Hamiltonian that is off (the truth with K_u × 1.08,
A_ex × 0.85, D × 1.2: a network's typical error), refitted on training curves without the candidate
(``loop.refit.analyse_with_refit``, K_u, A_ex and D free), then every candidate (measured-side and
physics-side, re-simulated around the refit) judged on held-out curves. Effect sizes lie off the
candidate grids. Cases: each library effect alone, two combinations, controls without an effect
(three disorder realisations × two Hamiltonians, and a gain drift the calibration points see, which
the reader's drift correction removes), and two effects outside the library (a saturating
paramagnetic background, a first-order detector lag). A case is correct when the verdict names the
injected effect (or one no FORC measurement can tell from it); on a control when it is "none" or
"unexplained structured residual"; an outside-the-library case is a forced attribution when a library
candidate is named.

This module holds that oracle path (``--oracle``), the generator of the committed cluster case file
(``effects_cases.yaml``) and the store of magnum.np samples (``stored_sample``) every path shares; the
loop as a user runs it on the committed cases is ``effects_user``.
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import physics as phys
from ..core.errors import ConfigError
from ..core.io import append_jsonl, atomic_path
from ..core.streams import stream_rng
from ..dataset.params import draw_parameters
from ..forc.raster import measured_image
from ..loop.physics_effects import NULL_REALISATIONS, ResidualOptions
from ..loop.refit import analyse_with_refit, joint_generalises
from ..loop.signatures import drift_evidence_of, field_shift_of, measured_point_arrays
from ..measured import read_forc
from ..reference.independent import (IndependentFilm, InstrumentModel, SampleFamily, average_families,
                                     magnumnp_family, measurement_protocol, mix_phases,
                                     write_measurement)

CONFIG = {"seed": 11, "n_grains": 255, "mesh": {"nx": 64, "ny": 64, "nz": 1, "dx_nm": 2.0, "dy_nm": 2.0, "dz_nm": 4.0},
          "field": {"B_max_T": 1.0, "n_fields": 24}, "minimizer": {"torque_tol_T": 0.001, "max_iterations": 20000},
          "pinning": {"treatment": "full", "scale_to_reference": False}}
"""The fitting film (our engine): the laptop film (128 nm box, 255 grains of ≈ 8 nm), 24 grid fields.
A 32 nm box (16 × 16 cells) was tried first: one disorder realisation then decides the family (two
films of one Hamiltonian differ by 0.13–0.29 RMS after the refit) and no effect of a realistic size
could be told from that (results in the README)."""

HAMILTONIANS = (
    {"Ms": 6e5, "A_ex": 1e-11, "K_u": 2.6e5, "D": 1.5e-3, "N_pin": 0, "sigma_theta_deg": 15.0, "sigma_K": 0.3},
    {"Ms": 6e5, "A_ex": 1e-11, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 15.0, "sigma_K": 0.3},
)
"""True Hamiltonians of the independent samples (SI). H0 (Q = 2K_u/μ0M_s² = 1.15) switches over a range of
fields (two realisations of our laptop film differ by 0.037 RMS on 24 fields); H1 (Q = 1.77) is a square,
single-avalanche film (0.09 RMS between realisations), a control only. Walls √(A_ex/K_u) ≈ 5–6 nm,
resolved by both grids: with A_ex = 2e-12 J/m (walls of 2.2 nm, about one cell) the refit against
2.5 nm-cell samples ran to K_u + 35 % on both a 32 nm and a 128 nm box (wall pinning on the coarser
lattice is the likely cause; not separated from the box and disorder here)."""

SAMPLE_CURVES = 48
"""FORCs in each sample file (reversal fields every 2 B_max/48 = 42 mT over ±1 T, points every 21 mT;
the fitting grid stays at 24 fields). The real files in ``shared/data/measured`` hold 120–297 curves;
the first bench used 24, which left the descending major branch known only every 83 mT, so the
model-free shift test could not resolve a loop centre to better than ±8 mT on the H0 film (results
in the README). 48 is what the bench's time allows (the magnum.np cost grows with the number of
curves; samples are shared between cases that differ by the instrument only)."""

PREDICTION_ERROR = {"K_u": 1.08, "A_ex": 0.85, "D": 1.2}
"""The Hamiltonian handed to the loop: the truth times these factors."""

SAMPLE = dict(nx=58, ny=58, cell_nm=2.2, n_grains=254, sweep_step_T=0.005)
"""The magnum.np sample: 127.6 nm box of 2.2 nm cells (ours: 128 nm of 2 nm), grains ≈ 8 nm as the
fitting film's, drawn by another tessellation; the field ramped on 5 mT nodes, the points snapshots
(``IndependentFilm.sweep_step_T``). Before 2026-11-26 the sample stepped through the measured points
(≤ 50 mT steps), which made an unbiased film's loop look shifted: on the H0 film with 48 curves
+21 mT (seed 4) where the ramped sweep gives +3.0 ± 3.1 mT."""

REFIT = ("K_u", "A_ex", "D")
REFIT_BOUNDS = 0.3
"""Refitted parameters, each within ×(1 ± 0.3) of the handed Hamiltonian (24 re-simulations, pattern
search). Measured on the H0 sample without an effect: the handed Hamiltonian misses it by 0.151 RMS,
the truth on our film by 0.037 (our own realisation floor: 0.039), the refit of (K_u, A_ex, D) by 0.032
on held-out curves; refitting (K_u, A_ex, σ_K) instead left the D error in and stayed at 0.11."""

# name -> (physics of the magnum.np sample, instrument settings); sizes off the candidate grids
CASES = {
    "background": ({}, {"chi_per_T": 0.06}),
    "field_offset": ({}, {"field_offset_T": 0.031}),
    "additive_drift": ({}, {"additive_drift": 0.045}),
    "multiplicative_drift": ({}, {"gain_drift": 0.05, "gain_drift_time_s": 200.0}),
    "scale": ({}, {"scale": 0.91}),
    "background+additive_drift": ({}, {"chi_per_T": 0.05, "additive_drift": 0.04}),
    "background+field_offset": ({}, {"chi_per_T": 0.05, "field_offset_T": 0.028}),
    "K_2": ({"K_2_over_K_u": -0.1}, {}),
    "bias_field": ({"B_bias_T": 0.033}, {}),
    "field_tilt": ({"tilt_deg": 8.0}, {}),
    "second_phase": ({"K_u_soft_over_K_u": 0.15, "fraction": 0.2}, {}),
    "none": ({}, {}),
    "none (uniform grain anisotropy)": ({"anisotropy_distribution": "uniform"}, {}),
    "none (drift seen by calibration)": ({}, {"gain_drift": 0.05, "gain_drift_time_s": 200.0,
                                              "calibration_sees_drift": True}),
    "outside: Langevin paramagnet": ({}, {"langevin_amplitude": 0.05, "langevin_field_T": 0.08}),
    "outside: detector lag": ({}, {"lag_points": 1.5}),
}

VALIDATION_CASES = (
    # (case, Hamiltonian, disorder seed, physics of the sample, instrument): seeds 3-6 and sizes the
    # bench's cases do not use; the films of SIGNATURE_VALIDATION where they exist (stored samples shared)
    ("none", 0, 3, {}, {}),
    ("none", 0, 4, {}, {}),
    ("none", 1, 3, {}, {}),
    ("field_offset", 0, 3, {}, {"field_offset_T": 0.024}),
    ("bias_field", 0, 5, {"B_bias_T": 0.04}, {}),
    ("background", 0, 4, {}, {"chi_per_T": 0.04}),
    ("scale", 0, 5, {}, {"scale": 1.06}),
    ("background+additive_drift", 0, 6, {}, {"chi_per_T": 0.045, "additive_drift": 0.035}),
    ("field_tilt", 0, 3, {"tilt_deg": 6.0}, {}),
    ("K_2", 0, 4, {"K_2_over_K_u": -0.12}, {}),
    ("outside: detector lag", 0, 5, {}, {"lag_points": 1.0}),
    ("outside: Langevin paramagnet", 0, 3, {}, {"langevin_amplitude": 0.04, "langevin_field_T": 0.12}),
)
"""Cases on which choices about the selection are made (``forcdecode bench effects --independent
--validation``): other disorder realisations and other effect sizes than ``CASES``, so the bench's
own cases stay a test that is only reported."""


def validation_plan() -> list[dict]:
    """The rows of ``VALIDATION_CASES`` (each carries its physics and instrument)."""
    return [{"case": name, "hamiltonian": h, "seed": seed, "physics": dict(physics), "instrument": dict(settings)}
            for name, h, seed, physics, settings in VALIDATION_CASES]


SAME_OBSERVABLE = ({"field_offset", "bias_field"},)
NO_EFFECT_VERDICTS = ("none", "unexplained structured residual")


def case_kind(name: str) -> str:
    """"control", "outside" or "library"."""
    return "control" if name.startswith("none") else "outside" if name.startswith("outside") else "library"


def is_correct(name: str, verdict: str, chosen: str) -> bool:
    kind = case_kind(name)
    if kind in ("control", "outside"):
        return verdict in NO_EFFECT_VERDICTS
    return chosen == name or any({name, chosen} <= group for group in SAME_OBSERVABLE)


def _sample_key(params, physics, seed, protocol, film, patches) -> str:
    """A digest of everything the magnum.np sample depends on (the instrument does not enter)."""
    import hashlib
    from dataclasses import asdict

    reversal, curves = protocol
    text = json.dumps({"params": params, "physics": physics, "seed": seed, "patches": patches,
                       "film": asdict(film), "reversal": np.round(np.asarray(reversal, float), 12).tolist(),
                       "curves": [np.round(np.asarray(c, float), 12).tolist() for c in curves]}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _sample_path(samples_dir, params, physics, seed, protocol, film, patches) -> Path:
    """Where ``stored_sample`` keeps a sample: ``samples_dir``/<``_sample_key``>.npz."""
    return Path(samples_dir) / f"{_sample_key(params, physics, seed, protocol, film, patches)}.npz"


def stored_sample(samples_dir, params, physics, seed, cache_dir, protocol, film, patches: int = 1):
    """``_sample``, kept in ``samples_dir`` (one .npz per distinct sample, written atomically) so that the
    cases that differ by the instrument only share one magnum.np run; None: always computed. A sample of
    several patches is made patch by patch, each kept in ``samples_dir``/patches until their mean is
    written (then removed), so a run stopped half-way resumes from the patches it finished."""
    if samples_dir is None:
        return _sample(params, physics, seed, cache_dir, protocol, film, patches=patches)
    path = _sample_path(samples_dir, params, physics, seed, protocol, film, patches)
    if path.exists():
        return _load_sample(path)
    parts = []
    if patches > 1:  # _sample's patches: disorder seeds seed, seed + 100, ...
        patch_dir = Path(samples_dir) / "patches"
        singles = [stored_sample(patch_dir, params, physics, seed + 100 * k, cache_dir, protocol, film)
                   for k in range(patches)]
        parts = [_sample_path(patch_dir, params, physics, seed + 100 * k, protocol, film, 1) for k in range(patches)]
        for single in singles:
            single.stats.pop("stored", None)
        sample = average_families(singles)
    else:
        sample = _sample(params, physics, seed, cache_dir, protocol, film)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, reversal_fields_T=np.asarray(sample.reversal_fields_T, float),
                     lengths=np.array([len(c) for c in sample.curves]),
                     fields_T=np.concatenate(sample.curve_fields_T), m=np.concatenate(sample.curves),
                     stats=json.dumps(sample.stats, default=str))
    for part in parts:
        part.unlink(missing_ok=True)
    return sample


def _load_sample(path) -> SampleFamily:
    """A ``stored_sample`` file back as a ``SampleFamily`` (its stats say where it was stored)."""
    with np.load(path) as data:
        lengths = np.cumsum(data["lengths"])[:-1]
        return SampleFamily(data["reversal_fields_T"], np.split(data["fields_T"], lengths),
                            np.split(data["m"], lengths), json.loads(str(data["stats"])) | {"stored": str(path)})


def _sample(params, physics, seed, cache_dir, protocol, film, patches: int = 1):
    """The magnum.np sample; with ``patches`` > 1 the mean of that many independent patches (disorder
    seeds seed, seed + 100, ...): a macroscopic film averages many patches."""

    if patches > 1:
        return average_families([_sample(params, physics, seed + 100 * k, cache_dir, protocol, film)
                                 for k in range(patches)])

    physics = dict(physics)
    if "K_u_soft_over_K_u" in physics:
        main = magnumnp_family(params, *protocol, film=film, seed=seed, cache_dir=cache_dir)
        soft = magnumnp_family(params, *protocol, film=film, seed=seed + 1000, cache_dir=cache_dir,
                               K_u=physics["K_u_soft_over_K_u"] * params["K_u"])
        return mix_phases(main, soft, physics["fraction"])
    kwargs = {}
    if "K_2_over_K_u" in physics:
        kwargs["K_2"] = physics["K_2_over_K_u"] * params["K_u"]
    if "B_bias_T" in physics:
        kwargs["B_bias_T"] = physics["B_bias_T"]
    if "tilt_deg" in physics:
        kwargs["tilt_deg"] = physics["tilt_deg"]
    return magnumnp_family(params, *protocol, film=film, seed=seed, cache_dir=cache_dir, **kwargs)


def plan(hamiltonians=(0,), control_hamiltonians=(0, 1), control_seeds=(1, 2), cases=None) -> list[dict]:
    """Every case run: each effect on each of ``hamiltonians`` (disorder realisation 1), the plain
    control on each of ``control_hamiltonians`` × ``control_seeds``."""
    rows = []
    for name in (cases or CASES):
        for h in (control_hamiltonians if name == "none" else hamiltonians):
            for seed in (control_seeds if name == "none" else (1,)):
                rows.append({"case": name, "hamiltonian": h, "seed": seed})
    return rows


@dataclass(frozen=True)
class CaseSettings:
    """How every independent case is run.

    - ``budget``: evaluations of the Hamiltonian refit;
    - ``noise``: the instrument's noise σ, a fraction of the saturation moment;
    - ``null_realisations``: null realisations of the selection (None: ``NULL_REALISATIONS``);
    - ``patches``: magnum.np patches averaged in the sample;
    - ``profiles``: disorder profiles averaged in every re-simulation of the model (the realisation
      floor falls as 1/√n on each side);
    - ``sample_curves``: FORCs in the instrument file;
    - ``analysis``: options of the selection passed to ``loop.refit.analyse_with_refit`` (e.g.
      ``cross_fit``, ``evidence_suffices``), kept in the row; None: the defaults;
    - ``sample_film``: keys of ``SAMPLE`` replaced (a smaller magnum.np film for a test of the wiring)."""

    budget: int = 24
    noise: float = 0.002
    null_realisations: int | None = None
    patches: int = 1
    profiles: int = 1
    sample_curves: int = SAMPLE_CURVES
    analysis: dict | None = None
    sample_film: dict | None = None


def run_case(row: dict, work_dir, settings: CaseSettings = CaseSettings(), *, cache_dir=None,
             samples_dir=None) -> dict:
    """One case end to end: magnum.np sample, instrument file, read back, put on the grid by the
    measured rule, Hamiltonian refitted, candidates judged. ``row``: {"case", "hamiltonian", "seed"}
    and, for a case apart from ``CASES`` (``VALIDATION_CASES``), its "physics" and "instrument";
    ``settings``: how the case is run (:class:`CaseSettings`); ``samples_dir``: where magnum.np samples
    are kept and reused (``stored_sample``). Returns the JSON-ready row."""
    budget, noise, null_realisations = settings.budget, settings.noise, settings.null_realisations
    patches, profiles, sample_curves = settings.patches, settings.profiles, settings.sample_curves
    analysis, sample_film = settings.analysis, settings.sample_film
    name, h, seed = row["case"], row["hamiltonian"], row["seed"]
    physics, settings = (row["physics"], row["instrument"]) if "physics" in row else CASES[name]
    analysis = selection_options(analysis)
    truth = dict(HAMILTONIANS[h])
    physics = dict(physics)
    film = IndependentFilm(**{**SAMPLE, **(sample_film or {})},
                           anisotropy_distribution=physics.pop("anisotropy_distribution", "gaussian"))
    start = time.perf_counter()
    sample = stored_sample(samples_dir, truth, physics, seed, cache_dir, measurement_protocol(sample_curves), film,
                           patches=patches)
    sample_s = time.perf_counter() - start
    fmt = ["micromag0015", "lakeshore_csv"][(sum(map(ord, name)) + h + seed) % 2]
    stem = "".join(c if c.isalnum() else "_" for c in name).strip("_")
    if "physics" in row:  # a validation film: its sizes in the name, so two of one case do not collide
        stem += "".join(f"_{k}{v:g}" for k, v in {**physics, **settings}.items()
                        if not isinstance(v, str))
    suffix = {"micromag0015": "frc", "lakeshore_csv": "csv"}[fmt]
    path = write_measurement(Path(work_dir) / f"{stem}_H{h}_s{seed}.{suffix}", sample,
                             truth["Ms"] * film.moment_Am2, InstrumentModel(noise=noise, **settings), seed=seed, fmt=fmt)
    data = read_forc(path)
    B_max, n = CONFIG["field"]["B_max_T"], CONFIG["field"]["n_fields"]
    moment = truth["Ms"] * film.moment_Am2  # the sample's saturation moment is known, as in a calibrated bench
    _, family, note = measured_image(data.reversal_fields_T,
                                     [(c.field_T, c.moment_Am2) for c in data.curves], moment, B_max, n)
    prediction = {**truth, **{k: truth[k] * f for k, f in PREDICTION_ERROR.items()}}
    fields = np.linspace(-B_max, B_max, n)
    shift = field_shift_of(data, moment, noise)
    drift = drift_evidence_of(data, moment, noise)
    result = analyse_with_refit(CONFIG, prediction, family, fields, names=REFIT, budget=budget, physics=True,
                                relative_bounds=REFIT_BOUNDS, n_profiles=profiles, noise_sigma=noise,
                                null_realisations=NULL_REALISATIONS if null_realisations is None else null_realisations,
                                field_shift=shift, drift=drift, measured_points=measured_point_arrays(data, moment),
                                shift_protocol=(data.reversal_fields_T,
                                                [c.field_T for c in data.curves]), **analysis)
    refit, joint = result["hamiltonian"]["refit_without_effect"], result["hamiltonian"]["refit_with_effect"]
    return {**row, "kind": case_kind(name), "analysis": analysis, "patches": patches, "profiles": profiles,
            "sample_curves": sample_curves, "file": str(path),
            "format": data.format, "in_domain": note is None, "chosen": result["chosen"], "verdict": result["verdict"],
            "correct": is_correct(name, result["verdict"], result["chosen"]),
            "parameters": result["parameters"], "heldout_rms_before": result["heldout_rms_before"],
            "heldout_rms_after": result["heldout_rms_after"],
            "heldout_ratio": result["heldout_rms_after"] / result["heldout_rms_before"]
            if result["heldout_rms_before"] else None,
            "heldout_rms_after_joint": result["heldout_rms_after_joint"],
            "heldout_ratio_joint": result["heldout_rms_after_joint"] / result["heldout_rms_before"]
            if result["heldout_rms_before"] else None,
            "heldout_rms_prediction": result["refit"]["heldout_rms_prediction"],
            "refit_relative_error": {k: refit[k] / truth[k] - 1 for k in REFIT},
            "refit_with_effect_relative_error": {k: joint["params"][k] / truth[k] - 1 for k in REFIT} if joint else None,
            "prediction_relative_error": {k: prediction[k] / truth[k] - 1 for k in REFIT},
            "field_shift": {k: result["field_shift"].get(k) for k in ("offset_T", "se_T", "z", "chi2", "consistent",
                                                                      "significant", "raw_offset_T", "analytic_se_T",
                                                                      "null_offsets_T")},
            "drift": drift, "saturation": result.get("saturation"),
            "hamiltonian_neighbourhood": result.get("hamiltonian_neighbourhood"),
            "structure_after": {k: result["structure"].get(k) for k in _STRUCTURE},
            "sample_s": sample_s, "case_s": time.perf_counter() - start,
            "candidates": {k: {key: v.get(key) for key in _EVIDENCE} for k, v in result["candidates"].items()}}


_EVIDENCE = ("heldout_rms", "heldout_mse_per_curve", "accepted", "kind", "n_parameters", "parameters", "uncertainties",
             "relative_gain", "gain_mse_mean", "null_gain",
             "beats_null", "within_moment_tolerance", "beats_normalization", "beats_hamiltonian", "shift_evidence",
             "drift_evidence", "saturation_evidence", "at_grid_edge")
"""What each candidate's row keeps: the selection's evidence, so a decision can be re-read from the file."""

_STRUCTURE = ("structured", "chi2_ratio", "chi2_p", "runs_z", "lag1_z", "n_points", "where")
"""What a row keeps of the structure test of the chosen model's residual (``loop.structure``)."""


LEGACY_SELECTION = {"cross_fit": False, "evidence_suffices": False}
"""The selection options of rows written before rows kept them (before 2026-11-26, fourth round)."""


def selection_options(analysis: dict | None = None) -> dict:
    """The selection options a case runs with: ``analysis`` over the defaults of
    ``loop.refit.analyse_with_refit`` (``cross_fit``) and ``loop.physics_effects.analyse_residual``
    (``evidence_suffices``), read from their signatures (the one place they are declared), so a row
    records what it ran with even after a default changes."""
    import inspect

    defaults = {"cross_fit": inspect.signature(analyse_with_refit).parameters["cross_fit"].default,
                "evidence_suffices": ResidualOptions().evidence_suffices}
    unknown = set(analysis or {}) - set(defaults)
    if unknown:
        raise ValueError(f"unknown selection options {sorted(unknown)}; known: {sorted(defaults)}")
    return {**defaults, **(analysis or {})}


def _row_key(row: dict) -> tuple:
    """What makes a case the same case on resuming: its name, Hamiltonian, seed and (validation cases)
    its physics and instrument."""
    return (row["case"], row["hamiltonian"], row["seed"],
            json.dumps([row.get("physics"), row.get("instrument")], sort_keys=True))


def independent_confusion(rows=None, settings: CaseSettings = CaseSettings(), *, cache_dir=None, samples_dir=None,
                          files_dir=None, done=None, out_jsonl=None, progress=None) -> dict:
    """Run the planned cases with ``settings`` (:class:`CaseSettings`; ``done``: rows already run are
    kept; ``out_jsonl``: each finished case is appended there and the ones already in it are not run
    again, so a killed run resumes; ``files_dir``: the instrument files are kept there, one per case, for
    ``forcdecode loop``; ``samples_dir``: the magnum.np samples, shared by cases that differ by the
    instrument only); returns {"cases", "confusion", "correct_fraction", "false_attribution_controls",
    "false_attribution_outside_library", "median_heldout_reduction", "n_cases", "wall_s"}."""
    sample_curves, analysis = settings.sample_curves, settings.analysis
    rows = plan() if rows is None else rows
    finished = list(done or [])
    if out_jsonl is not None and Path(out_jsonl).exists():
        earlier = [json.loads(line) for line in Path(out_jsonl).read_text().splitlines() if line.strip()]
        # a row of another protocol is not this run's (rows before the key existed had 24 curves)
        # (and of other selection options: rows before the key existed used the defaults)
        options = selection_options(analysis)
        finished += [r for r in earlier if r.get("sample_curves", 24) == sample_curves
                     and {**LEGACY_SELECTION, **r.get("analysis", {})} == options]
    seen = {_row_key(r) for r in finished}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        where = tmp if files_dir is None else Path(files_dir)
        Path(where).mkdir(parents=True, exist_ok=True)
        for row in rows:
            if _row_key(row) in seen:
                continue
            finished.append(run_case(row, where, settings, cache_dir=cache_dir, samples_dir=samples_dir))
            if out_jsonl is not None:
                append_jsonl(out_jsonl, finished[-1])
            if progress is not None:
                progress(finished[-1])
    return summarize(finished, wall_s=time.perf_counter() - start)


def summarize(cases: list[dict], wall_s: float = float("nan")) -> dict:
    confusion = {}
    for r in cases:
        confusion.setdefault(r["case"], {}).setdefault(r["verdict"], 0)
        confusion[r["case"]][r["verdict"]] += 1
    library = [r for r in cases if r["kind"] == "library"]
    controls = [r for r in cases if r["kind"] == "control"]
    outside = [r for r in cases if r["kind"] == "outside"]
    chosen_ratios = [r["heldout_ratio"] for r in cases if r["chosen"] != "none" and r["heldout_ratio"] is not None]
    # Hamiltonian and effect refitted together (rows before 2026-11-26 lack it), and the model the loop
    # uses: the joint refit where it generalises to the held-out curves (``loop.refit.joint_generalises``)
    joint_rows = [r for r in cases if r["chosen"] != "none" and r.get("heldout_ratio_joint") is not None]
    joint_ratios = [r["heldout_ratio_joint"] for r in joint_rows]
    used_ratios = [r["heldout_ratio_joint"] if joint_generalises(r["heldout_rms_after_joint"], r["heldout_rms_after"])
                   else r["heldout_ratio"] for r in joint_rows]

    def fraction(rows, test):
        return float(np.mean([test(r) for r in rows])) if rows else None

    return {"cases": cases, "confusion": confusion, "n_cases": len(cases), "oracle_inputs": True,
            "correct_fraction": fraction(library, lambda r: r["correct"]),
            "false_attribution_controls": fraction(controls, lambda r: not r["correct"]),
            "false_attribution_outside_library": fraction(outside, lambda r: not r["correct"]),
            "median_heldout_reduction": float(1 - np.median(chosen_ratios)) if chosen_ratios else None,
            "median_heldout_ratio_where_chosen": float(np.median(chosen_ratios)) if chosen_ratios else None,
            "median_heldout_ratio_joint_where_chosen": float(np.median(joint_ratios)) if joint_ratios else None,
            "median_heldout_ratio_used_where_chosen": float(np.median(used_ratios)) if used_ratios else None,
            "wall_s": wall_s}


def summary_lines(result: dict) -> list[str]:
    lines = [f"residual analysis on independent (magnum.np) samples, {result['n_cases']} cases: in-library correct "
             f"{_pct(result['correct_fraction'])}, false attributions on controls {_pct(result['false_attribution_controls'])}, "
             f"forced attributions outside the library {_pct(result['false_attribution_outside_library'])}, median "
             f"held-out RMS after/before where an effect is chosen {_num(result['median_heldout_ratio_where_chosen'])}"
             f" (Hamiltonian refitted with the effect: {_num(result.get('median_heldout_ratio_joint_where_chosen'))}; "
             f"the joint refit where it generalises: {_num(result.get('median_heldout_ratio_used_where_chosen'))})",
             "", "case".ljust(34) + "H  seed  verdict".ljust(45) + "held-out before → after   K_u, A_ex, D refit error"]
    for r in result["cases"]:
        refit = ", ".join(f"{v:+.1%}" for v in r["refit_relative_error"].values())
        lines.append(r["case"][:33].ljust(34) + f"{r['hamiltonian']}  {r['seed']}     " + r["verdict"][:34].ljust(36)
                     + f"{r['heldout_rms_before']:.4f} → {r['heldout_rms_after']:.4f}".ljust(26) + refit
                     + ("" if r["correct"] else "   ✗"))
    return lines


def _pct(v):
    return "—" if v is None else f"{v:.0%}"


def _num(v):
    return "—" if v is None else f"{v:.2f}"


SIGNATURE_VALIDATION = (
    # (Hamiltonian, disorder seed, physics, instrument): seeds and sizes apart from the bench's cases
    *[(h, seed, {}, {}) for h in (0, 1) for seed in (3, 4, 5)],
    (0, 3, {}, {"field_offset_T": 0.024}),
    (0, 4, {}, {"field_offset_T": 0.045}),
    (0, 5, {"B_bias_T": 0.04}, {}),
    (1, 3, {}, {"field_offset_T": 0.05}),
    (0, 6, {}, {"chi_per_T": 0.05, "additive_drift": 0.04}),
)
"""Films the model-free field-shift test is validated on (``signature_validation``): six without
any shift (two Hamiltonians × seeds 3–5), four shifted (offsets 24, 45, 50 mT and a 40 mT bias,
sizes and seeds the bench does not use) and one with a background and an additive drift (a vertical
asymmetry that must not be taken for a shift)."""


def signature_validation(cache_dir=None, noise: float = 0.002, out_dir=None, progress=None,
                         sample_curves: int = SAMPLE_CURVES, samples_dir=None) -> dict:
    """The model-free field-shift test (``loop.signatures.field_shift_of``) on the magnum.np films of
    ``SIGNATURE_VALIDATION``, recorded by the instrument model and read back from MicroMag files:
    its false claims on films without a shift and what it shows of the shifted ones. Choices about
    the test are made here, not on the bench's cases. Returns {"films": [...], "false_shift_claims",
    "effect_free", "shown", "shifted", "wall_s"}."""
    start = time.perf_counter()
    films = []
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(tmp if out_dir is None else out_dir)
        where.mkdir(parents=True, exist_ok=True)
        for h, seed, physics, settings in SIGNATURE_VALIDATION:
            truth = dict(HAMILTONIANS[h])
            film = IndependentFilm(**SAMPLE)
            sample = stored_sample(samples_dir, truth, physics, seed, cache_dir, measurement_protocol(sample_curves),
                                   film)
            moment = truth["Ms"] * film.moment_Am2
            label = "_".join([f"H{h}", f"s{seed}", *(f"{k}{v:g}" for k, v in {**physics, **settings}.items())])
            path = write_measurement(where / f"{label}.frc", sample, moment, InstrumentModel(noise=noise, **settings),
                                     seed=seed)
            shift = field_shift_of(read_forc(path), moment, noise)
            true_shift = settings.get("field_offset_T", 0.0) - physics.get("B_bias_T", 0.0)
            films.append({"hamiltonian": h, "seed": seed, "physics": physics, "instrument": settings,
                          "true_shift_T": true_shift, **{k: shift[k] for k in ("offset_T", "se_T", "z", "consistent",
                                                                               "significant")}})
            if progress is not None:
                progress(films[-1])
    free = [f for f in films if f["true_shift_T"] == 0.0]
    shifted = [f for f in films if f["true_shift_T"] != 0.0]
    return {"films": films, "false_shift_claims": sum(f["significant"] for f in free), "effect_free": len(free),
            "shown": sum(f["significant"] for f in shifted), "shifted": len(shifted),
            "wall_s": time.perf_counter() - start}


def signature_lines(result: dict) -> list[str]:
    lines = [f"model-free field-shift test on {len(result['films'])} magnum.np films: false claims "
             f"{result['false_shift_claims']}/{result['effect_free']} without a shift, shown {result['shown']}/"
             f"{result['shifted']} shifted", "", "film".ljust(44) + "true mT  found mT     z   consistent  claimed"]
    for f in result["films"]:
        label = f"H{f['hamiltonian']} seed {f['seed']} " + " ".join(f"{k}={v:g}" for k, v in {**f['physics'],
                                                                                             **f['instrument']}.items())
        found = "—" if f["offset_T"] is None else f"{1e3 * f['offset_T']:+.1f} ± {1e3 * f['se_T']:.1f}"
        z = "—" if f["z"] is None else f"{f['z']:.1f}"
        lines.append(label[:43].ljust(44) + f"{1e3 * f['true_shift_T']:+6.1f}  {found:>14}  {z:>5}   "
                     f"{str(f['consistent']):10}  {f['significant']}")
    return lines


# ------------------------------------------------------------------------------------------------
# The user path (issue 45): `forcdecode loop FILE` run as a user runs it, on cases fixed in advance
# in a committed file (a development set and an evaluation set), beside two trivial rules.
# ------------------------------------------------------------------------------------------------

CASES_FILE = Path(__file__).with_name("effects_cases.yaml")
"""The committed cases (``generate_cases()`` written by ``write_cases_file``; a test regenerates it)."""

CASES_SEED = 45
"""Seed of every draw of the case file: Hamiltonians from the dataset's ``parameters`` stream
(``dataset.params.draw_parameters(CASES_SEED, id)``, ids 0.. for dev and 100000.. for eval: never the
training set's seed), everything else from ``core.streams`` stream ``bench_film`` with keys
("effects_cases", split, what)."""

CASE_COUNTS = {"dev": {"controls": 6, "per_library_class": 3, "per_outside_class": 1},
               "eval": {"controls": 30, "per_library_class": 12, "per_outside_class": 8}}
"""Cases per split. Eval: 30 controls, 12 per in-library class, 4 outside classes × 8 = 32: a rate of
0 in n has the two-sided 90 % Clopper–Pearson upper bound 1 − 0.05^{1/n}, ≤ 0.1 from n = 29 on, so
30 controls and 32 outside cases can show a false-attribution rate ≤ 0.1 (with one false attribution
they cannot: 1 of 30 reaches 0.15); 12 per class only read detection against size."""

LIBRARY_CLASSES = {
    # class -> (side, the size's key, |size| range, signed, the candidate's grid (physics) or None)
    "background": ("instrument", "chi_per_T", (0.004, 0.08), True, None),
    "field_offset": ("instrument", "field_offset_T", (0.003, 0.05), True, None),
    "additive_drift": ("instrument", "additive_drift", (0.004, 0.06), True, None),
    "multiplicative_drift": ("instrument", "gain_drift", (0.005, 0.08), True, None),
    "scale": ("instrument", "scale", (0.01, 0.12), True, None),
    "K_2": ("physics", "K_2_over_K_u", (0.03, 0.5), True, (-0.15, 0.15, 0.3, 0.45)),
    "bias_field": ("physics", "B_bias_T", (0.004, 0.05), True, (-0.04, -0.02, 0.02, 0.04)),
    "field_tilt": ("physics", "tilt_deg", (1.0, 18.0), False, (3.0, 6.0, 10.0, 15.0)),
    "second_phase": ("physics", "fraction", (0.03, 0.35), False, None),
}
"""The in-library effect classes the magnum.np generator makes (``thermal_activation`` needs a
temperature the generator lacks; the library's combinations are left to the singles). The size is
|value| (scale: |scale − 1|; second phase: the moment fraction, K_u,soft/K_u drawn beside it);
sizes are drawn log-uniformly, stratified over the range; for a gridded physics candidate two of
the eval sizes are put on its grid (``physics_effects.physics_candidate_families``), the rest lie off it.
Measured-side candidates are fitted continuously: any size is off a grid."""

OUTSIDE_CLASSES = {
    # class -> (the size's key, |size| range, signed, companion parameter and its range)
    "outside: Langevin paramagnet": ("langevin_amplitude", (0.01, 0.08), False, ("langevin_field_T", (0.03, 0.3))),
    "outside: detector lag": ("lag_points", (0.3, 3.0), False, None),
    "outside: training exchange bias": ("training_bias_T", (0.01, 0.06), True, ("training_curves", (2.0, 12.0))),
    "outside: correlated noise": ("correlated_noise", (0.002, 0.02), False, ("correlation_points", (3.0, 15.0))),
}
"""What the library lacks (``reference.independent.InstrumentModel``). An interlayer-coupled second
layer is not made: ``MagnumFilm`` is one layer of cells, and two coupled layers would double the
magnum.np cost of every such case; an exchange bias that trains away (a per-curve decaying shift of
the film's response) and noise correlated along the curves stand in for it."""

GRIDS = ({"nx": 58, "cell_nm": 2.2}, {"nx": 52, "cell_nm": 2.5}, {"nx": 60, "cell_nm": 2.1}, {"nx": 54, "cell_nm": 2.4})
"""magnum.np sample grids (square, periodic, 4 nm thick): boxes of 121–130 nm, none our 64 × 64 × 2 nm."""

N_GRAINS = (12, 32)
"""Grains per sample, drawn uniformly (the shipped film: 16 grains of ≈ 32 nm in 128 nm)."""

NOISE = (0.001, 0.005)
"""Noise σ per point in units of the film moment, drawn log-uniformly."""

MS_ERROR = 0.05
"""M_s handed to the loop: the truth × a factor drawn uniformly within ±5 %."""

SCREEN = {"Q_min": 1.1, "B_K_eff_T": (0.05, 0.8), "wall_nm_min": 3.5, "D_over_D_c_max": 0.9}
"""The draws kept (a cheap screen in place of the dataset's simulated one, which would need our
engine): perpendicular (Q = 2K_u/μ0M_s² ≥ 1.1), an effective anisotropy field 2K_u/M_s − μ0M_s of
0.05–0.8 T (the major loop saturates inside ±1 T), walls √(A_ex/K_u) ≥ 3.5 nm (resolved by the
2.1–2.5 nm cells), and D ≤ 0.9 D_c, D_c = 4√(A_ex K_eff)/π with K_eff = K_u − μ0M_s²/2 (a uniform
perpendicular ground state: above D_c the film relaxes to spirals, loses its hysteresis, which the
dataset's screening asks for, and magnum.np spent over 7 CPU-minutes on a 20 × 20 film of 16 curves
without finishing; measured on the first draft's dev-006, D/D_c = 1.15). N_pin is set to 0: the magnum.np film has no pinning cells (0 lies in the prior)."""

SAMPLE_PROTOCOL = {"curves": SAMPLE_CURVES, "shift": (0.2, 0.8), "sweep_step_T": 0.005}


def _sig(x: float, digits: int = 4) -> float:
    return float(f"{float(x):.{digits}g}")


def _screened(h: dict) -> bool:
    Q = phys.quality_factor(h["K_u"], h["Ms"])
    b_k = phys.effective_anisotropy_field(h["K_u"], h["Ms"])
    lo, hi = SCREEN["B_K_eff_T"]
    d_c = 4 * np.sqrt(h["A_ex"] * max(phys.k_eff(h["K_u"], h["Ms"]), 0.0)) / np.pi
    return (Q >= SCREEN["Q_min"] and lo <= b_k <= hi and np.sqrt(h["A_ex"] / h["K_u"]) * 1e9 >= SCREEN["wall_nm_min"]
            and h["D"] <= SCREEN["D_over_D_c_max"] * d_c)


def draw_hamiltonians(first_id: int, count: int, seed: int = CASES_SEED, keep_pinning: bool = False,
                      wall_nm_min: float | None = None) -> list[tuple[int, dict]]:
    """``count`` in-prior Hamiltonians passing ``SCREEN``: (dataset sample id, SI dict rounded to 4
    significant digits, N_pin = 0 unless ``keep_pinning``: then the drawn N_pin), ids from ``first_id`` on,
    drawn under ``seed``; ``wall_nm_min`` overrides the screen's wall width."""

    out, k = [], first_id
    while len(out) < count:
        h = draw_parameters(seed, k)
        wall_ok = wall_nm_min is None or np.sqrt(h["A_ex"] / h["K_u"]) * 1e9 >= wall_nm_min
        if _screened(h) and wall_ok:
            pins = int(h["N_pin"]) if keep_pinning else 0
            out.append((k, {**{n: _sig(v) for n, v in h.items() if n != "N_pin"}, "N_pin": pins}))
        k += 1
    return out


def _sizes(rng, n: int, bounds, signed: bool, grid=None, on_grid: int = 0) -> list[float]:
    """``n`` sizes, log-uniform stratified over ``bounds`` in random order; ``on_grid`` of them replaced
    by values of ``grid`` (inside the bounds, by |value|); signed: a random sign each (kept for grid values)."""
    lo, hi = bounds
    u = (np.arange(n) + rng.uniform(size=n)) / n
    values = [_sig(lo * (hi / lo) ** x, 3) for x in rng.permutation(u)]
    signs = rng.choice([-1.0, 1.0], size=n) if signed else np.ones(n)
    values = [float(v * s) for v, s in zip(values, signs)]
    if grid and on_grid:
        usable = [g for g in grid if lo <= abs(g) <= hi]
        for i, g in enumerate(rng.choice(usable, size=min(on_grid, n), replace=len(usable) < on_grid)):
            values[i] = float(g)
    return values


def fresh_seed(rng, used: set) -> int:
    """A realisation seed drawn from ``rng`` that no case in ``used`` has (added to it)."""
    seed = int(rng.integers(1, 2**31 - 1))
    while seed in used:
        seed = int(rng.integers(1, 2**31 - 1))
    used.add(seed)
    return seed


def case_stem(name: str) -> str:
    """A case class as it appears in a case's name ("outside: detector lag" → "detector_lag")."""
    return "".join(c if c.isalnum() else "_" for c in name.removeprefix("outside: ")).strip("_")


def library_case(name: str, v: float, rng) -> tuple:
    """(kind, class, physics, instrument, size) of an in-library case of size ``v`` (``LIBRARY_CLASSES``);
    the companion settings a class needs are drawn from ``rng`` (a multiplicative drift's time constant, a
    second phase's K_u,soft/K_u)."""
    side, key = LIBRARY_CLASSES[name][:2]
    if name == "scale":
        settings = {"scale": _sig(1 + v, 4)}
    elif name == "multiplicative_drift":
        settings = {"gain_drift": v, "gain_drift_time_s": _sig(rng.uniform(100.0, 600.0), 3)}
    elif name == "second_phase":
        settings = {"fraction": v, "K_u_soft_over_K_u": _sig(rng.uniform(0.03, 0.35), 3)}
    else:
        settings = {key: v}
    physics, instrument = (settings, {}) if side == "physics" else ({}, settings)
    return ("library", name, physics, instrument, abs(v))


def outside_cases(rng, per_class: int) -> list[tuple]:
    """``per_class`` cases of each class outside the library (``OUTSIDE_CLASSES``), sizes from ``_sizes``."""
    plan = []
    for name, (key, bounds, signed, companion) in OUTSIDE_CLASSES.items():
        for v in _sizes(rng, per_class, bounds, signed):
            settings = {key: v}
            if companion:
                settings[companion[0]] = _sig(rng.uniform(*companion[1]), 3)
            plan.append(("outside", name, {}, settings, abs(v)))
    return plan


def generate_cases() -> dict:
    """The dev and eval cases (deterministic: everything from ``CASES_SEED``); see ``write_cases_file``."""

    sets, seeds_used = {}, set()
    for split, first_id in (("dev", 0), ("eval", 100000)):
        counts = CASE_COUNTS[split]
        rng = stream_rng(CASES_SEED, "bench_film", "effects_cases", split)
        plan_ = []  # (kind, class, physics, instrument, size)
        for i in range(counts["controls"]):
            variant = i % 6
            if variant == 4:
                plan_.append(("control", "none (uniform grain anisotropy)", {"anisotropy_distribution": "uniform"},
                              {}, None))
            elif variant == 5:
                plan_.append(("control", "none (drift seen by calibration)", {},
                              {"gain_drift": _sig(rng.uniform(0.01, 0.06), 3), "gain_drift_time_s": 200.0,
                               "calibration_sees_drift": True}, None))
            else:
                plan_.append(("control", "none", {}, {}, None))
        for name, (_, _, bounds, signed, grid) in LIBRARY_CLASSES.items():
            n = counts["per_library_class"]
            if name == "K_2":  # negative K_2 only down to −0.2 K_u (the candidate's grid reaches −0.15)
                sizes = _sizes(rng, n, bounds, True, grid, on_grid=2 if split == "eval" else 0)
                sizes = [max(v, -0.2) if v < 0 else v for v in sizes]
            else:
                sizes = _sizes(rng, n, bounds, signed, grid, on_grid=2 if split == "eval" and grid else 0)
            plan_ += [library_case(name, v, rng) for v in sizes]
        plan_ += outside_cases(rng, counts["per_outside_class"])
        hamiltonians = draw_hamiltonians(first_id, len(plan_))
        cases = []
        for i, ((kind, name, physics, instrument, size), (h_id, h)) in enumerate(zip(plan_, hamiltonians)):
            seed = fresh_seed(rng, seeds_used)
            grid = GRIDS[int(rng.integers(len(GRIDS)))]
            physics = dict(physics)
            distribution = physics.pop("anisotropy_distribution", "gaussian")
            stem = case_stem(name)
            cases.append({
                "name": f"{split}-{i:03d}-{stem}", "split": split, "kind": kind, "class": name,
                "hamiltonian_id": h_id, "hamiltonian": h, "in_prior": True,
                "sample": {"nx": grid["nx"], "ny": grid["nx"], "cell_nm": grid["cell_nm"],
                           "n_grains": int(rng.integers(N_GRAINS[0], N_GRAINS[1] + 1)),
                           "anisotropy_distribution": distribution},
                "protocol": {"curves": SAMPLE_PROTOCOL["curves"],
                             "shift": _sig(rng.uniform(*SAMPLE_PROTOCOL["shift"]), 3),
                             "sweep_step_T": SAMPLE_PROTOCOL["sweep_step_T"]},
                "realisation_seed": seed, "noise": _sig(NOISE[0] * (NOISE[1] / NOISE[0]) ** rng.uniform(), 3),
                "format": ["micromag0015", "lakeshore_csv"][int(rng.integers(2))],
                "physics": physics, "instrument": instrument, "size": None if size is None else _sig(size, 3),
                "Ms_error_factor": _sig(1 + rng.uniform(-MS_ERROR, MS_ERROR), 4)})
        sets[split] = cases
    return {"seed": CASES_SEED, "generator": "forcdecode.bench.effects_independent.generate_cases",
            "screen": SCREEN, "dev": sets["dev"], "eval": sets["eval"]}


CASES_HEADER = ("# The effects bench's cases (issue 45), fixed before any run: written by\n"
                "#   python -c 'from forcdecode.bench.effects_independent import write_cases_file; write_cases_file()'\n"
                "# and checked against the generator by tests/bench/test_effects_cases.py. Choices are made on `dev`;\n"
                "# `eval` is only reported. Do not edit by hand.\n")


def write_cases_file(path=CASES_FILE, cases: dict | None = None, header: str = CASES_HEADER) -> Path:
    """Write ``cases`` (default ``generate_cases()``) as YAML under ``header`` (atomically)."""
    import yaml


    with atomic_path(path) as tmp:
        tmp.write_text(header + yaml.safe_dump(generate_cases() if cases is None else cases, sort_keys=False,
                                               width=120))
    return Path(path)


def load_cases(split: str = "eval", path=CASES_FILE) -> list[dict]:
    """The cases of ``split`` ("dev" or "eval") of the case file; ConfigError for another split or a
    missing file."""
    import yaml


    if split not in ("dev", "eval"):
        raise ConfigError(f"case set {split!r}: dev or eval")
    if not Path(path).exists():
        raise ConfigError(f"no case file {path}")
    return yaml.safe_load(Path(path).read_text())[split]
