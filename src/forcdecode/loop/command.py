"""The `forcdecode loop FILE --out DIR` command (``loop.cli`` is its entry; the bench runs it from here):
close the loop on a measured (or simulated-as-measured) file
(``loop.measured_loop.close_loop_on_file``: domain check by physics, prediction or given
Hamiltonian, re-simulation on the grid and on the file's own protocol, residual effects, optional
Hamiltonian refit, structured-residual verdict). Writes DIR/report.json, DIR/report.md and figures;
prints the decoded Hamiltonian (each parameter and derived combination with its intervals, or "not read
from the image: prior only", ``learn.answer``) and the verdict, or with ``--json`` the report itself.
"""

from __future__ import annotations

import argparse
import json

from ..config import film_thickness_nm, load_config as load, shipped_config, with_thickness
from ..core.io import read_json
from ..core.parallel import available_cores
from ..infer.refine import METHODS
from ..learn.estimator_choice import add_estimator_arguments, choose_estimator, default_posterior_path
from ..learn.prior_class import prior_class_line
from ..learn.shipped import check_thickness, resolve_models
from .measured_loop import _json_ready, close_loop_on_file
from .physics_effects import NULL_REALISATIONS

MAX_DEFAULT_WORKERS = 8
"""``--workers``'s default: the cores this process may use, at most this many (a workstation's loop gains
little beyond it: its largest batch is the 21 physics-side candidates)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:

    parser.add_argument("file", help="measured FORC file (any format `forcdecode read` knows)")
    parser.add_argument("--out", required=True, help="output directory")
    add_estimator_arguments(parser, auto_note="; the posterior with --refine",
                            after_note="; either after a training-data (out-of-distribution) check")
    parser.add_argument("--dataset", help="the dataset the Alice networks were trained on, for their training-data "
                                          "check (default: dataset.h5 beside the --models directory)")
    parser.add_argument("--refine", type=int, default=0, metavar="N",
                        help="with --estimator posterior: refine the posterior of this file by N simulations of the "
                             "film (forcdecode fit) and analyse the residual of the refined medians")
    parser.add_argument("--refine-round-size", type=int, default=25, help="simulations per refinement round (default 25)")
    parser.add_argument("--refine-workers", type=int, default=1, help="processes simulating the refinement")
    parser.add_argument("--refine-method", choices=METHODS, default="pmc",
                        help="with --refine: pmc (tempered population Monte Carlo) or adjusted (the amortized draws "
                             "simulated on their own realisations, regression-adjusted; forcdecode fit --method)")
    parser.add_argument("--predictive-reference", help="with --refine: the misspecification check's reference, "
                        "made with B <= --refine simulations: predictive_reference.json of `forcdecode bench ood "
                        "--predictive-budget B` flags a family no film inside the prior reproduces; with "
                        "--refine-extend-prior, extension_reference.json of `forcdecode bench fit --extend-prior "
                        "--split validation` flags one that a film beyond the bound fits better")
    parser.add_argument("--refine-extend-prior", nargs="+", metavar="NAME[=FACTOR]",
                        help="with --refine (pmc): refine in a box reaching FACTOR (default 4) times the prior's range "
                             "for these parameters and report the posterior mass beyond the bound (e.g. N_pin: is the "
                             "film pinned more densely than any training film?)")
    parser.add_argument("--params", help="JSON file with a Hamiltonian to re-simulate (SI) instead of predicting one")
    parser.add_argument("--Ms-kA-m", dest="ms_kA_m", type=float, help="known M_s (kA/m): no sweep")
    parser.add_argument("--thickness-nm", type=float, default=None,
                        help="your film's thickness (nm): checked against the range the models' thickness study "
                             "shows safe (refused outside it without --force) and used by every re-simulation "
                             "(default: the models' own film, 4 nm for the shipped laptop models)")
    parser.add_argument("--Ms-sweep-kA-m", dest="ms_sweep", type=float, nargs=3, default=[470.0, 1400.0, 6],
                        metavar=("LOW", "HIGH", "N"), help="M_s values swept when M_s is not known (default 470 1400 6)")
    parser.add_argument("--config", help="simulation config (grid, field window, minimizer; default: the shipped "
                                         "config.yaml)")
    parser.add_argument("--profiles", type=int, default=20, help="pinning profiles averaged in the final re-simulation")
    parser.add_argument("--sweep-profiles", type=int, default=2, help="pinning profiles per M_s during the sweep")
    parser.add_argument("--every-k", type=int, default=4, help="hold out every k-th curve")
    parser.add_argument("--no-physics", action="store_true", help="skip the physics-side candidates (K_2, bias, second phase)")
    parser.add_argument("--force", action="store_true", help="analyse even when the file is out of domain, or its loop "
                        "contradicts the prior class the model was trained on")
    parser.add_argument("--refit", metavar="NAMES", help="refit these Hamiltonian parameters around the prediction "
                                                          "before the effect selection, comma-separated (e.g. K_u,A_ex)")
    parser.add_argument("--refit-budget", type=int, default=20, help="re-simulations of the refit (default 20)")
    parser.add_argument("--null-realisations", type=int, default=None,
                        help="effect-free films of the decoded (with --refit: the refitted) Hamiltonian at the file's "
                             "patch number; an effect must gain more than it gains on them (the realisation floor; "
                             f"default: the config's loop.null_films, {NULL_REALISATIONS} in the shipped configs)")
    parser.add_argument("--moment-tolerance", type=float, default=None, metavar="FRACTION",
                        help="relative uncertainty of the moment normalization (M_s·V, calibration) inside which a "
                             "fitted scale is not named an effect (default 0.02; 0: name every scale that earns it)")
    parser.add_argument("--fixed-point", action="store_true",
                        help="needs --refit (and a prediction, not --params): after a measured-side effect is chosen, "
                             "predict the Hamiltonian again from the family with the effect removed and iterate to a "
                             "fixed point (loop.fixed_point)")
    parser.add_argument("--no-measured-protocol", action="store_true",
                        help="skip the re-simulation of the file's own protocol (residual at the measured points)")
    parser.add_argument("--measured-profiles", type=int, default=None,
                        help="re-simulate the file's own protocol for the residual at the measured points with this "
                             "many pinning profiles (default: the patch pool's single realisations, already "
                             "simulated on that protocol, where they hold the final Hamiltonian; else 2)")
    parser.add_argument("--max-measured-points", type=int, default=5000,
                        help="thin the measured protocol to about this many points (default 5000)")
    parser.add_argument("--measured-max-step-mT", type=float, default=2.0,
                        help="largest field sub-step of the measured-protocol re-simulation, mT (default 2)")
    parser.add_argument("--workers", type=int, default=None,
                        help="processes simulating the loop's independent families (the re-simulation's profiles, the "
                             "patch pool, the physics-side candidates); the answer does not depend on it (default: "
                             f"the cores this process may use, at most {MAX_DEFAULT_WORKERS})")
    parser.add_argument("--json", action="store_true",
                        help="print the report (report.json's content: the decoded Hamiltonian with each parameter's "
                             "and combination's read_from_image flag and basis, the verdict) instead of the summary")


def load_config(path=None) -> dict:
    """The validated config at ``path`` (default: the shipped config.yaml); ConfigError if invalid."""

    return load(shipped_config("config") if path is None else path)


def resolve_estimator(args) -> dict | None:
    """``--estimator auto`` resolved in place (``learn.estimator_choice``): the posterior where --refine asks
    for it, else whichever validation shows better; returns the choice's record (None when the user chose),
    and fills in the default models (``learn.shipped.resolve_models``: the shipped set unless --models;
    ``args.models_line`` says which) and posterior path (beside the models directory)."""
    if not getattr(args, "models_line", None):
        models_dir, args.models_line = resolve_models(args.models)
        args.models = str(models_dir)
    args.posterior = args.posterior or default_posterior_path(args.models)
    if args.estimator != "auto":
        return None
    if args.refine:
        args.estimator = "posterior"
        return {"estimator": "posterior", "basis": "--refine refines the posterior"}
    if args.params:
        args.estimator = "alice"
        return {"estimator": "alice", "basis": "--params gives the Hamiltonian: no estimator is used"}
    choice = choose_estimator(args.models, args.posterior)
    args.estimator = choice["estimator"]
    return choice


def run(args) -> int:
    import numpy as np

    cfg = load_config(args.config)
    params = read_json(args.params, what="Hamiltonian file") if args.params else None
    choice = resolve_estimator(args)
    if not args.json and not params:
        print(args.models_line)
    if params:  # no model decodes the file: its thickness only sets the re-simulated film
        thickness = film_thickness_nm(cfg) if args.thickness_nm is None else args.thickness_nm
        thickness_line = (f"film thickness: {thickness:g} nm (--params gives the Hamiltonian, no model decodes the "
                          "file; the re-simulation uses this thickness)")
    else:
        thickness_line = check_thickness(args.models, args.thickness_nm, film_thickness_nm(cfg), force=args.force)
    if args.thickness_nm is not None:
        cfg = with_thickness(cfg, args.thickness_nm)
    if not args.json:
        print(thickness_line)
    if args.ms_kA_m is not None:
        ms_values = [args.ms_kA_m * 1e3]
    else:
        low, high, count = args.ms_sweep
        ms_values = list(np.linspace(low * 1e3, high * 1e3, max(1, int(count))))
    # the report on disk says the film's thickness and, where auto chose, which estimator answered and why
    extras = {"film_thickness_nm": film_thickness_nm(cfg), "thickness": thickness_line}
    if choice is not None:
        extras.update(estimator_choice=choice, models=args.models_line)
    report = close_loop_on_file(args.file, args.out, cfg, params=params, models_dir=args.models,
                                ms_values_A_per_m=ms_values, profiles=args.profiles,
                                sweep_profiles=args.sweep_profiles, every_k=args.every_k,
                                physics=not args.no_physics, force=args.force,
                                refit=[n.strip() for n in args.refit.split(",") if n.strip()] if args.refit else None,
                                refit_budget=args.refit_budget, null_realisations=args.null_realisations,
                                measured_protocol=not args.no_measured_protocol,
                                measured_profiles=args.measured_profiles, max_measured_points=args.max_measured_points,
                                measured_max_step_T=args.measured_max_step_mT * 1e-3, estimator=args.estimator,
                                posterior_path=args.posterior, fixed_point=args.fixed_point,
                                refine_budget=args.refine, refine_round_size=args.refine_round_size,
                                refine_workers=args.refine_workers, refine_method=args.refine_method,
                                predictive_reference=args.predictive_reference, refine_extend=args.refine_extend_prior,
                                training_dataset=args.dataset,
                                workers=min(available_cores(), MAX_DEFAULT_WORKERS) if args.workers is None else args.workers,
                                report_extras=extras,
                                **({} if args.moment_tolerance is None else {"moment_tolerance": args.moment_tolerance}))
    if choice is not None and not args.json:
        print(f"estimator: {choice['estimator']} (auto: {choice['basis']})")
    if args.json:
        print(json.dumps(_json_ready(report), indent=2))
        return 0
    if report.get("prior_class"):
        print(prior_class_line(report["prior_class"], report.get("prior_check")))
    prediction = report.get("prediction")
    if prediction:  # the decoded Hamiltonian: intervals, read from the image or prior only, combinations
        from ..learn.predictor import prediction_lines  # local: the predictor imports torch

        ms = report.get("Ms_chosen_A_per_m", prediction.get("Ms"))
        swept = report.get("Ms_source") == "swept"
        for line in prediction_lines(prediction, f"{args.file}: decoded Hamiltonian", ms / 1e3,
                                     "swept: the value whose re-simulation is closest" if swept else "given"):
            print(line)
        if report.get("refined"):
            print(f"(the amortized prediction; refined by {report['refined']['budget']} simulations of this film, "
                  "whose medians were re-simulated: see report.md)")
    if report["status"] == "out of domain":
        print(f"{args.file}: out of domain ({report['out_of_domain_reason']}); report in {args.out}")
    elif report["status"] == "out of distribution":
        print(f"{args.file}: not decoded, {report['ood']['verdict']}; report in {args.out}")
    else:
        print(f"verdict: {report['verdict']}; effect: {report['effect']}; held-out RMS "
              f"{report['heldout_rms_before']:.4f} -> {report['heldout_rms_after']:.4f}; report in {args.out}")
    return 0
