"""``forcdecode bench TARGET [--json]`` (``TARGETS``: engine, protocols, effects, learn, films, thickness, ...): prints figures; with --json the last
line is one JSON object."""

from __future__ import annotations

import argparse
import json
import os

from ..config import defaults, load_config, shipped_config
from ..core.errors import ConfigError
from ..core.io import read_json, write_json
from ..core.parameters import NAMES, normalize
from ..core.progress import counter, echo, progress
from ..infer.fit import Refinement, beyond_prior
from ..infer.predictive_check import check_figure, make_reference, predictive_check, predictive_statistic, read_reference
from ..infer.refine import add_refinement_arguments, beyond_prior_lines, fit_function, parse_extension
from ..learn.data import load_dataset
from ..learn.shipped import resolve_models
from ..learn.splits import assign_splits
from . import engine, film_family, film_learning, films, prior_learning, realisations
from .effects import effects_confusion, n_cases
from .effects import summary_lines as effects_lines
from .effects_independent import (SAMPLE_CURVES, CaseSettings, independent_confusion, load_cases, signature_lines,
                                  signature_validation, validation_plan)
from .effects_independent import plan as independent_plan
from .effects_independent import summary_lines as independent_lines
from .effects_user import (USER_LOOP_ARGS, check_estimator, check_loop_args, make_samples, user_confusion,
                           user_summary_lines)
from .fit import choice_lines, fit_summary, reading_choice
from .fit import summary_lines as fit_lines
from .information_cli import bench_information
from .laptop_cases import load_cases as load_laptop_cases
from .ood import CASES, CaseFamilies, HeldOutFamilies, bench_ood, carry_over, case_film, ood_lines, predictive_statistics
from .prior_class import prior_class_bench
from .prior_class import summary_lines as prior_class_lines


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Every option of ``forcdecode bench``, one group of targets at a time (in --help order)."""
    parser.add_argument("target", choices=list(TARGETS), help="what to benchmark")
    parser.add_argument("--samples", type=int, default=3, help="protocols: samples compared")
    parser.add_argument("--seeds", type=int, default=3, help="effects: noise seeds per effect and size")
    _add_effects_arguments(parser)
    _add_engine_arguments(parser)
    _add_thickness_arguments(parser)
    _add_films_arguments(parser)
    _add_fit_arguments(parser)
    _add_ood_arguments(parser)
    _add_information_arguments(parser)
    _add_learn_arguments(parser)


def _add_effects_arguments(parser: argparse.ArgumentParser) -> None:
    """effects: the independent-sample bench's options (``--independent`` and what it reads)."""
    parser.add_argument("--independent", action="store_true",
                        help="effects: samples made by magnum.np (another grid and disorder) in instrument files, "
                             "each run through `forcdecode loop` as a user runs it (needs the reference extra and "
                             "the trained estimator)")
    parser.add_argument("--set", dest="case_set", choices=["dev", "eval", "laptop-dev", "laptop-eval"], default="eval",
                        help="effects --independent: the committed cases run: dev for choices, eval only reported "
                             "(default eval): the cluster set (bench/effects_cases.yaml, 207 cases) or the laptop set "
                             "(laptop-dev, laptop-eval: bench/effects_cases_laptop.yaml, pinned and few-patch films "
                             "sized for a 2-core machine)")
    parser.add_argument("--loop-args", default=None,
                        help="effects --independent: the `forcdecode loop` options measured, one string (default: "
                             "the README's first loop command, bench.effects_user.USER_LOOP_ARGS); the "
                             "bench adds --out and --Ms-kA-m; write --loop-args=\"...\" when it starts with --")
    parser.add_argument("--without-estimator", choices=["population-median"], default=None,
                        help="effects --independent: no trained estimator: hand the loop (--params) the median "
                             "film of the screened prior at the given M_s, what a user without one can do "
                             "(reported as such; default: refuse when the estimator is missing)")
    parser.add_argument("--oracle", action="store_true",
                        help="effects --independent: the earlier bench (true moment scale and noise, a start "
                             "near the truth, refit on; oracle_inputs true), kept for comparison")
    parser.add_argument("--effects-out", default="results/bench/effects_independent",
                        help="effects --independent: cases.jsonl (resumable), summary.json and the instrument files")
    parser.add_argument("--cases", nargs="+", help="effects --independent: run only these cases (names as in the "
                        "case file; with --oracle as in the table)")
    parser.add_argument("--shard", metavar="K/N", help="effects --independent (user path): run every N-th case from "
                        "the K-th (1 ≤ K ≤ N), so that N processes share a set; run them with one --effects-out (each "
                        "appends its rows to the same cases.jsonl), then once without --shard: it runs nothing and "
                        "writes the whole set's summary")
    parser.add_argument("--samples-dir", default=None,
                        help="effects --independent (user path): the store of magnum.np samples (one .npz per "
                             "sample; default --effects-out/user/SET/samples); a sample already there is not made "
                             "again, e.g. the committed docs/results/bench_samples/SET")
    parser.add_argument("--summary-only", action="store_true",
                        help="effects --independent (user path): run no case; summarize the rows already in "
                             "--effects-out (a run in progress can be read without stopping it; a partial set "
                             "says so)")
    parser.add_argument("--samples-only", action="store_true",
                        help="effects --independent (user path): make the set's magnum.np samples into "
                             "--samples-dir (resumable; one line per case in its samples.jsonl) and run no loop")
    parser.add_argument("--signatures", action="store_true",
                        help="effects --independent: validate the model-free field-shift test instead, on magnum.np "
                             "films of other seeds and shift sizes than the bench's (writes --effects-out/signatures)")
    parser.add_argument("--validation", action="store_true",
                        help="effects --independent: run the validation cases (other seeds and effect sizes), on "
                             "which choices about the selection are made; the bench's cases are the test")
    parser.add_argument("--cross-fit", action="store_true",
                        help="effects --independent: judge candidates on every curve, each held out once")
    parser.add_argument("--evidence-needs-bootstrap", action="store_true",
                        help="effects --independent: a shift or a drift the model-free tests show must also clear "
                             "the held-out bootstrap bound (analyse_residual(evidence_suffices=False), the rule "
                             "before 2026-11-26)")
    parser.add_argument("--patches", type=int, default=1,
                        help="effects --independent: magnum.np patches averaged in each sample (a macroscopic film)")
    parser.add_argument("--sample-curves", type=int, default=None,
                        help="effects --independent: FORCs in each magnum.np sample file (default: "
                             "bench.effects_independent.SAMPLE_CURVES)")
    parser.add_argument("--model-profiles", type=int, default=1,
                        help="effects --independent: disorder profiles averaged in each re-simulation of the model")


def _add_engine_arguments(parser: argparse.ArgumentParser) -> None:
    """``--json`` (every target) and the engine bench's options (magnum.np peer, grid, timing window)."""
    parser.add_argument("--json", action="store_true", help="end with one JSON line (always printed last)")
    parser.add_argument("--skip-magnumnp", action="store_true", help="do not run the magnum.np peer")
    parser.add_argument("--skip-256", action="store_true", help="skip the 256×256×2 grid")
    parser.add_argument("--cache-dir", default=".cache/magnumnp", help="magnum.np demag-kernel cache")
    parser.add_argument("--seconds", type=float, default=2.0, help="minimum timing window per figure")
    parser.add_argument("--eager-magnumnp", action="store_true",
                        help="run magnum.np without torch.compile (default: compiled, its fastest)")
    parser.add_argument("--film-draws", type=int, default=0,
                        help="engine: also the 128x128x2 film's family on this many screened prior draws, the "
                             "reference minimizer against the Fourier-preconditioned one with the image check "
                             "(family_128x2_s; minutes per labyrinth draw; default 0: skipped)")


def _add_thickness_arguments(parser: argparse.ArgumentParser) -> None:
    """thickness: the models' answer on films of other thicknesses (issue 60)."""
    thickness = parser.add_argument_group("thickness (the models' answer on films of other thicknesses, issue 60)")
    thickness.add_argument("--thickness-models", default=None,
                           help="thickness: the models decoded with (default: the shipped set, else results/models)")
    thickness.add_argument("--thickness-config", default=None,
                           help="thickness: the models' config (default: the shipped config.yaml)")
    thickness.add_argument("--thickness-cases", type=int, default=60, help="thickness: Hamiltonians (screened)")
    thickness.add_argument("--thicknesses-nm", type=float, nargs="+", default=None,
                           help="thickness: film thicknesses simulated (default 2 3 4 5 6 8)")
    thickness.add_argument("--thickness-out", default="results/bench/thickness",
                           help="thickness: rows.jsonl (resumable) and thickness.json")


def _add_films_arguments(parser: argparse.ArgumentParser) -> None:
    """films, film-learning, realisations, prior-learning: the runs compared and where they are."""
    films = parser.add_argument_group("films (the same Hamiltonians on the laptop film and larger ones)")
    films.add_argument("--config", default=None, help="films: base config (default: the shipped laptop config)")
    films.add_argument("--hamiltonians", type=int, default=20, help="films: screened dataset draws compared")
    films.add_argument("--films", nargs="+", default=["laptop:20x2", "laptop_paper_grains:20x2", "box128:20x1",
                                                       "box128:8x2", "paper:5x1"],
                       help="films: FILM:NxR = the first N Hamiltonians with R disorder realisations each")
    films.add_argument("--workers", type=int, default=1, help="films: families simulated at once (one core each)")
    films.add_argument("--out-dir", default="results/bench/films", help="films: one HDF5 per family (resumable)")
    films.add_argument("--summarize-only", action="store_true", help="films: only summarize the families on disk")
    films.add_argument("--runs", nargs="+", default=["laptop_8nm_grains=results/films_learning/laptop/results",
                                                      "laptop=results/films_learning/laptop_paper_grains/results",
                                                      "box128=results/films_learning/box128/results"],
                       help="film-learning: NAME=RESULTS_DIR of workflow runs up to metrics.json (default: the runs of "
                            "config/films/laptop_8nm_grains.yaml, config/config.yaml and config/films/box128.yaml "
                            "named in README); realisations: RUN_A RUN_B, two results folders whose learning stage "
                            "ran (default: those of config/experiments/realisations_R1.yaml and _R4.yaml); prior-learning: RUN_A RUN_C "
                            "(default: those of config/experiments/realisations_R1.yaml and prior_perpendicular.yaml)")
    films.add_argument("--prior-learning-out", default="results/bench/prior_learning", help="prior-learning: summary.json")
    films.add_argument("--cross-reading", action="store_true",
                       help="realisations: also each run's full-set networks on both runs' images of the shared "
                            "validation ids (reads dataset.h5 and models/; reported only)")
    films.add_argument("--realisations-out", default="results/bench/realisations",
                       help="realisations: summary.json and realisations.png")
    films.add_argument("--learning-out", default="results/bench/film_learning",
                       help="film-learning: summary.json and film_learning.png")


def _add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    """fit: refinement by simulation on held-out test families."""
    fit = parser.add_argument_group("fit (refinement by simulation on held-out test families)")
    fit.add_argument("--posterior", default="results/posterior/model.pt", help="fit: the amortized posterior")
    fit.add_argument("--families", type=int, default=5, help="fit: test families refined")
    fit.add_argument("--first-family", type=int, default=0,
                     help="fit: start at this position of the split (runs on disjoint families, e.g. on several "
                          "machines, write files that one later run over all of them reads back)")
    fit.add_argument("--budgets", type=int, nargs="+", default=[50, 200, 500], help="fit: nested budgets (simulations)")
    fit.add_argument("--round-size", type=int, default=25, help="fit: simulations per round")
    fit.add_argument("--fit-workers", type=int, default=2, help="fit: processes simulating in parallel")
    fit.add_argument("--fit-dir", default="results/bench/fit", help="fit: one fit.json per family (resumable)")
    fit.add_argument("--case", help="fit: refine the families of this `bench ood` case instead of the dataset's "
                     "(OOD_DIR/CASE.npz with curves, e.g. magnumnp: another code's films of the held-out "
                     "Hamiltonians; the truth is the case's Hamiltonian)")
    add_refinement_arguments(fit, scope="fit: ")
    fit.add_argument("--extension-reference", metavar="JSON",
                     help="fit, with --extend-prior: judge each family by the extension check against this reference "
                          "(FIT_DIR/extension_reference.json, written by a --split validation run in the same box)")
    fit.add_argument("--split", choices=["validation", "test"], default="test",
                     help="fit: the families refined (choose settings on validation; report on test)")


def _add_ood_arguments(parser: argparse.ArgumentParser) -> None:
    """ood: the posterior's out-of-distribution and predictive checks."""
    ood = parser.add_argument_group("ood (the posterior's out-of-distribution check on films made to be in and out)")
    ood.add_argument("--ood-cases", nargs="+", help="ood: cases (default: all; magnumnp needs the reference extra)")
    ood.add_argument("--ood-dir", default="results/bench/ood", help="ood: images per case (resumable) and summary.json")
    ood.add_argument("--predictive-budget", type=int, default=0,
                     help="ood: also refine every family for this many simulations and apply the posterior-predictive "
                          "check (infer/predictive_check.py), calibrated on --calibration-families validation families "
                          "(0: off; uses --round-size, --fit-workers, --prior)")
    ood.add_argument("--predictive-cases", nargs="+", help="ood: the cases the predictive check runs on (default: "
                     "every case asked for)")
    ood.add_argument("--calibration-families", type=int, default=20,
                     help="ood: validation families the predictive check is calibrated on (>= 20 for alpha 0.05)")


def _add_information_arguments(parser: argparse.ArgumentParser) -> None:
    """information: the Fisher map of the FORC family."""
    info = parser.add_argument_group("information (Fisher map of the FORC family; --films FILM[:NxR], "
                                     "--config, --workers, --summarize-only shared with films)")
    info.add_argument("--fiducials", type=int, default=16, help="information: fiducial Hamiltonians per film")
    info.add_argument("--realisations", type=int, default=8, help="information: disorder realisations R per point")
    info.add_argument("--delta", type=float, nargs="+", default=[0.1, 0.05],
                      help="information: half-steps in normalized units (the first for the map; all of them at the "
                           "first --stability-fiducials fiducials)")
    info.add_argument("--stability-fiducials", type=int, default=2, help="information: fiducials run at every --delta")
    info.add_argument("--pool", type=int, default=200, help="information: draws screened for the regimes' mass")
    info.add_argument("--info-dir", default="results/bench/information", help="information: families, "
                      "fiducials.json, one JSON per fiducial, summary.json (resumable)")
    info.add_argument("--stop-at", default=None, help="information: start no fiducial process after this UTC time (HH:MM)")


def _add_learn_arguments(parser: argparse.ArgumentParser) -> None:
    """learn: the paper network against the laptop head (and prior-class's --dataset, --out)."""
    learn = parser.add_argument_group("learn (paper network vs laptop head, same split and optimizer)")
    learn.add_argument("--dataset", default="results/dataset.h5", help="merged dataset (forcdecode dataset merge); "
                       "prior-class: the families whose rates the prior-class rule is measured on (read only)")
    learn.add_argument("--learning-config", help="the workflow's learning.json (seed, split, lr, batch size; "
                       "default: learning.json beside the dataset)")
    learn.add_argument("--parameters", nargs="+", default=["K_u", "D"], help="targets to train")
    learn.add_argument("--heads", nargs="+", default=["small", "paper"], choices=["small", "paper"])
    learn.add_argument("--epochs", type=int, default=40, help="epoch budget (both heads)")
    learn.add_argument("--patience", type=int, default=10, help="early-stopping patience (both heads)")
    learn.add_argument("--seed", type=int, default=1, help="weight/shuffle seed (both heads; the split is the workflow's)")
    learn.add_argument("--threads", type=int, default=2, help="torch threads")
    learn.add_argument("--out", help="also write the rows and ratios to this JSON file (atomically; prior-class: "
                       "the rates)")


def run(args) -> int:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")


    say = echo  # result lines on stdout; progress on stderr (a bar on a terminal, lines in a log)
    return TARGETS[args.target](args, say)


def _bench_engine(args, say) -> int:
    report = engine.benchmark_engine(["64"] if args.skip_256 else ["64", "256"], args.seconds,
                                     magnumnp=not args.skip_magnumnp, cache_dir=args.cache_dir,
                                     compile=not args.eager_magnumnp, say=say,
                                     progress=counter("family", "curves"))
    if args.film_draws > 0:
        say(f"[film box128_8nm] {args.film_draws} screened draws, reference and candidate families:")
        check = film_family.film_family_check(args.film_draws, "box128_8nm", say=say)
        say(film_family.summary_line(check))
        report["film_128x2"] = check
        report["family_128x2_s"] = check["candidate_family_mean_s"]
        report["family_128x2_reference_s"] = check["reference_family_mean_s"]
        report["family_128x2_check_passed"] = f"{check['passed']}/{check['n']}"
    if args.json:
        print(json.dumps(report))
    return 0


def _bench_protocols(args, say) -> int:
    with progress(total=args.samples, desc="protocols", unit="samples") as bar:
        def row_done(row):
            say(engine.protocol_row_line(row))
            bar.update()

        result = engine.compare_protocols(args.samples, progress=row_done)
    say(engine.protocols_summary(result))
    if args.json:
        print(json.dumps(result))
    return 0


def _bench_effects(args, say) -> int:
    if args.independent:
        return _bench_effects_independent(args, say)
    with progress(total=n_cases(args.seeds), desc="effects", unit="cases") as bar:
        result = effects_confusion(seeds=range(args.seeds), progress=lambda row: bar.update())
    for line in effects_lines(result):
        say(line)
    if args.json:
        print(json.dumps({k: v for k, v in result.items() if k != "cases"}))
    return 0


def _bench_thickness(args, say) -> int:
    # loads torch: imported only when this target runs
    from .thickness import THICKNESSES_NM, run_study, summary_lines

    cfg = load_config(args.thickness_config or shipped_config("config"))
    models_dir, line = resolve_models(args.thickness_models)
    say(line)
    thicknesses = tuple(args.thicknesses_nm or THICKNESSES_NM)
    with progress(total=args.thickness_cases * len(thicknesses), desc="thickness", unit="families") as bar:
        summary = run_study(cfg, models_dir, args.thickness_out, count=args.thickness_cases,
                            thicknesses_nm=thicknesses, progress=lambda row: bar.update())
    for text in summary_lines(summary):
        say(text)
    if args.json:
        print(json.dumps(summary))
    return 0


def _bench_information(args, say) -> int:
    return bench_information(args, say)


def _bench_effects_independent(args, say) -> int:
    from pathlib import Path

    curves = SAMPLE_CURVES if args.sample_curves is None else args.sample_curves
    if curves < 4:
        raise ConfigError(f"--sample-curves ({curves}) must be at least 4")

    if args.signatures:
        out = Path(args.effects_out) / "signatures"
        result = signature_validation(cache_dir=args.cache_dir, out_dir=out / "files", sample_curves=curves,
                                      samples_dir=Path(args.effects_out) / "samples",
                                      progress=lambda f: say(f"H{f['hamiltonian']} seed {f['seed']}: shift "
                                                             f"{f['offset_T']}, claimed {f['significant']}"))
        return _finish(out, result, signature_lines(result), args.json, say, omit="films")
    if args.patches < 1 or args.model_profiles < 1:
        raise ConfigError(f"--patches ({args.patches}) and --model-profiles ({args.model_profiles}) must be at least 1")
    if not (args.oracle or args.validation):
        return _bench_effects_user(args, say)
    rows = validation_plan() if args.validation else independent_plan()
    analysis = {**({"cross_fit": True} if args.cross_fit else {}),
                **({"evidence_suffices": False} if args.evidence_needs_bootstrap else {})}
    if args.cases:
        unknown = set(args.cases) - {r["case"] for r in rows}
        if unknown:
            raise ConfigError(f"--cases: unknown {sorted(unknown)}; known: {sorted({r['case'] for r in rows})}")
        rows = [r for r in rows if r["case"] in args.cases]
    out = Path(args.effects_out)
    with progress(total=len(rows), desc="independent cases", unit="cases") as bar:
        def done(row):
            say(f"{row['case']} (H{row['hamiltonian']}, seed {row['seed']}): {row['verdict']}"
                f"{'' if row['correct'] else '  [wrong]'} ({row['case_s']:.0f} s)")
            bar.update()

        settings = CaseSettings(patches=args.patches, profiles=args.model_profiles, sample_curves=curves,
                                analysis=analysis)
        result = independent_confusion(rows, settings, cache_dir=args.cache_dir, samples_dir=out / "samples",
                                       files_dir=out / "files", out_jsonl=out / "cases.jsonl", progress=done)
    return _finish(out, result, independent_lines(result), args.json, say, omit="cases")


def _bench_effects_user(args, say) -> int:
    """``bench effects --independent``: the committed cases through `forcdecode loop` as a user runs it."""
    import shlex
    from pathlib import Path

    legacy = [flag for flag, on in (("--cross-fit", args.cross_fit), ("--evidence-needs-bootstrap",
                                    args.evidence_needs_bootstrap), ("--patches", args.patches != 1),
                                    ("--model-profiles", args.model_profiles != 1),
                                    ("--sample-curves", args.sample_curves is not None)) if on]
    if legacy:
        raise ConfigError(f"{', '.join(legacy)}: options of the earlier bench (--oracle); the user path runs the "
                          "loop's own options (--loop-args)")
    loop_args = tuple(USER_LOOP_ARGS if args.loop_args is None else shlex.split(args.loop_args))
    check_loop_args(loop_args)
    if args.case_set.startswith("laptop-"):
        cases = load_laptop_cases(args.case_set.removeprefix("laptop-"))
    else:
        cases = load_cases(args.case_set)
    if args.cases:
        unknown = set(args.cases) - {c["name"] for c in cases}
        if unknown:
            raise ConfigError(f"--cases: unknown {sorted(unknown)} in the {args.case_set} set")
        cases = [c for c in cases if c["name"] in args.cases]
    if args.shard:
        cases = cases[_shard(args.shard, len(cases))]
    out = Path(args.effects_out) / "user" / args.case_set
    samples_dir = out / "samples" if args.samples_dir is None else Path(args.samples_dir)
    if args.samples_only:
        return _make_samples(cases, samples_dir, args, say)
    check_estimator(loop_args, args.without_estimator)  # refuses before any simulation
    if args.summary_only:
        result = user_confusion(cases, out, loop_args=loop_args, fallback=args.without_estimator,
                                out_jsonl=out / "cases.jsonl", run=False)
        return _finish(out, result, user_summary_lines(result), args.json, say, omit="cases")
    with progress(total=len(cases), desc=f"{args.case_set} cases", unit="cases") as bar:
        def done(row):
            say(f"{row['case']} ({row['class']}): {row['verdict']} [{row['scores']['loop']}] "
                f"({row['sample_s']:.0f} s magnum.np, {row['loop_s']:.0f} s loop)")
            bar.update()

        result = user_confusion(cases, out, loop_args=loop_args, fallback=args.without_estimator,
                                cache_dir=args.cache_dir, out_jsonl=out / "cases.jsonl", progress=done,
                                samples_dir=samples_dir)
    return _finish(out, result, user_summary_lines(result), args.json, say, omit="cases")


def _make_samples(cases, samples_dir, args, say) -> int:
    """``--samples-only``: the set's magnum.np samples into ``samples_dir``, no loop."""
    with progress(total=len(cases), desc=f"{args.case_set} samples", unit="cases") as bar:
        def done(line):
            say(f"{line['case']}: {line['status']} ({line['sample_s']:.0f} s magnum.np)"
                + (f": {line['error']}" if "error" in line else ""))
            bar.update()

        result = make_samples(cases, samples_dir, cache_dir=args.cache_dir, out_jsonl=samples_dir / "samples.jsonl",
                              progress=done)
    say(f"{result['n_cases']} cases: {result['made']} samples made ({result['sample_s_total']:.0f} s, median "
        f"{result['sample_s_median']} s), {result['stored']} already stored, failed: {result['failed'] or 'none'}")
    if args.json:
        print(json.dumps(result))
    return 0


def _shard(text: str, count: int) -> slice:
    """``--shard K/N`` as the slice of the case list it runs (every N-th case from the K-th); ConfigError
    for anything else."""
    try:
        k, n = (int(v) for v in str(text).split("/"))
    except ValueError:
        raise ConfigError(f"--shard {text!r}: give K/N, e.g. 1/2") from None
    if not 1 <= k <= n:
        raise ConfigError(f"--shard {text!r}: K must be in 1..N")
    return slice(k - 1, count, n)


def _finish(out, result: dict, lines, as_json: bool, say, omit: str) -> int:
    """Write ``out``/summary.json, print the table, end with the JSON line (without the ``omit`` list)."""

    write_json(out / "summary.json", result)
    for line in lines:
        say(line)
    if as_json:
        print(json.dumps({k: v for k, v in result.items() if k != omit}))
    return 0


def _bench_learn(args, say) -> int:
    # loads torch: imported only when this target runs
    from ..learn.ablation import HeadAblation, run_head_ablation, summary_lines

    ablation = HeadAblation(parameters=args.parameters, heads=args.heads, epochs=args.epochs, patience=args.patience,
                            seed=args.seed, threads=args.threads)
    result = run_head_ablation(args.dataset, ablation, learning_config=args.learning_config, out=args.out, log=say)
    say("")
    for line in summary_lines(result):
        say(line)
    if args.out:
        say(f"wrote {args.out}")
    if args.json:
        print(json.dumps(result))
    return 0


REALISATION_RUNS = ("results/realisations/R1", "results/realisations/R4")
"""The runs of config/experiments/realisations_R1.yaml and _R4.yaml (docs/results/2026-11-29-realisations.md)."""


def _bench_realisations(args, say) -> int:
    runs = _two_runs(args, REALISATION_RUNS)
    result = realisations.compare(*runs)
    if args.cross_reading:
        result["cross_reading"] = realisations.cross_reading(*runs)
    write_json(f"{args.realisations_out}/summary.json", result)
    realisations.figure(result, f"{args.realisations_out}/realisations.png")
    for line in realisations.summary_lines(result):
        say(line)
    if args.json:
        print(json.dumps({k: result[k] for k in ("points", "decision", "rule")}))
    return 0


PRIOR_CLASS_RUNS = ("results/realisations/R1", "results/prior/perpendicular")
"""The runs of config/experiments/realisations_R1.yaml (paper) and prior_perpendicular.yaml."""


def _two_runs(args, default: tuple) -> list:
    runs = list(args.runs)
    if any("=" in r for r in runs):  # film-learning's NAME=DIR default: not given for this target
        runs = list(default)
    if len(runs) != 2:
        raise ConfigError(f"{args.target} --runs: expected two results folders (got {len(runs)})")
    return runs


def _bench_prior_learning(args, say) -> int:
    result = prior_learning.compare_classes(*_two_runs(args, PRIOR_CLASS_RUNS))
    write_json(f"{args.prior_learning_out}/summary.json", result)
    for line in prior_learning.summary_lines(result):
        say(line)
    if args.json:
        print(json.dumps({k: result[k] for k in ("mean_mae_difference_c_minus_a", "mean_mae_difference_ci90",
                                                 "decision", "rule")}))
    return 0


def _bench_film_learning(args, say) -> int:
    runs = {}
    for item in args.runs:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ConfigError(f"--runs {item!r}: expected NAME=RESULTS_DIR")
        runs[name] = path
    result = film_learning.compare_films(runs)
    write_json(f"{args.learning_out}/summary.json", result)
    film_learning.figure(result, f"{args.learning_out}/film_learning.png")
    for line in film_learning.summary_lines(result):
        say(line)
    if args.json:
        print(json.dumps(result["at_common_budget"]))
    return 0


def _bench_films(args, say) -> int:
    if args.summarize_only:
        summary = films.summarize(args.out_dir)
        write_json(f"{args.out_dir}/summary.json", summary)
        films.figure(summary, f"{args.out_dir}/films.png")
        for line in films.summary_lines(summary):
            say(line)
        if args.json:
            print(json.dumps({k: v for k, v in summary.items() if k != "rows"}))
        return 0
    cfg = load_config(args.config or shipped_config("config"))
    plan = []
    for item in args.films:
        try:
            name, counts = item.split(":")
            n_ham, n_real = (int(v) for v in counts.split("x"))
        except ValueError:
            raise ConfigError(f"--films {item!r}: expected FILM:NxR, e.g. box128:20x2") from None
        if name not in films.FILMS:
            raise ConfigError(f"--films {item!r}: unknown film {name!r}; known: {', '.join(films.FILMS)}")
        plan.append((name, min(n_ham, args.hamiltonians), n_real))
    say(f"screening draws of seed {cfg['seed']} on the laptop film for {args.hamiltonians} Hamiltonians")
    hamiltonians = films.pick_hamiltonians(cfg, args.hamiltonians, progress=counter("screen", "Hamiltonians"))
    jobs = films.plan(hamiltonians, plan)
    say(f"{len(jobs)} families planned in {args.out_dir}")
    films.run_jobs(cfg, jobs, args.out_dir, workers=args.workers, say=say)
    summary = films.summarize(args.out_dir)
    write_json(f"{args.out_dir}/summary.json", summary)
    films.figure(summary, f"{args.out_dir}/films.png")
    for line in films.summary_lines(summary):
        say(line)
    if args.json:
        print(json.dumps({k: v for k, v in summary.items() if k != "rows"}))
    return 0


def _workflow_splits(stage: dict, data) -> dict:
    """Index arrays per split of the dataset, as the workflow's learning stage (``stage``) drew them."""
    learning = {**defaults("learning"), **stage.get("learning", {})}
    return assign_splits(data.sample_id, stage["seed"], learning["split"], learning["protocol"])


def _held_out_families(args):
    """(the workflow's learning.json, the dataset, the posterior, indices of the ``--split`` families)
    for the benches that run on held-out families of a trained posterior."""
    # loads torch: imported only when this target runs
    from ..learn.posterior import PosteriorEstimator

    stage = read_json(args.learning_config or f"{os.path.dirname(args.dataset)}/learning.json", what="learning config")
    data = load_dataset(args.dataset)
    est = PosteriorEstimator.load(args.posterior)
    return stage, data, est, _workflow_splits(stage, data)[args.split]


def _bench_fit(args, say) -> int:
    """Refined vs amortized posterior on held-out test families with known truth (nested budgets)."""
    import numpy as np

    budgets = sorted(set(args.budgets))
    if args.extend_prior and args.method != "pmc":
        raise ConfigError("--extend-prior needs --method pmc")
    if args.extension_reference and not args.extend_prior:
        raise ConfigError("--extension-reference judges refinements in an extended box: it needs --extend-prior")
    if args.first_family < 0 or args.families < 1:
        raise ConfigError(f"--first-family must be >= 0 and --families >= 1 (got {args.first_family}, {args.families})")
    if any(b % args.round_size for b in budgets):
        raise ConfigError(f"--budgets {budgets} must be multiples of --round-size {args.round_size} (nested rounds)")
    cfg = load_config(args.config or shipped_config("config"))
    stage, data, est, held_out = _held_out_families(args)
    if args.first_family + args.families > len(held_out):
        raise ConfigError(f"the {args.split} split has {len(held_out)} families: --first-family {args.first_family} "
                          f"+ --families {args.families} is beyond it")
    chosen = held_out[args.first_family: args.first_family + args.families]
    extend = parse_extension(args.extend_prior, tuple(est.names))
    reference = None
    if args.extension_reference:
        reference = read_reference(args.extension_reference, round_size=args.round_size, prior=args.prior,
                                   budget_run=budgets[-1], extend=extend, what="extension-check reference")
    observations = _case_observations(args, cfg, data, held_out, chosen) if args.case else None
    rows = []
    import h5py

    with h5py.File(args.dataset, "r") as h5:
        for n, k in enumerate(chosen, 1):
            sid = int(data.sample_id[k])
            path = f"{args.fit_dir}/sample_{sid}.json"
            result = read_json(path, what="fit result") if os.path.exists(path) else None
            if result is not None and result.get("prior", "uniform") != args.prior:
                raise ConfigError(f"{path} was refined with the {result.get('prior', 'uniform')} prior, not "
                                  f"--prior {args.prior}: use another --fit-dir")
            if result is not None and result.get("method", "pmc") != args.method:
                raise ConfigError(f"{path} was refined by the {result.get('method', 'pmc')} method, not "
                                  f"--method {args.method}: use another --fit-dir")
            if result is not None and (result.get("extend") or {}) != extend:
                raise ConfigError(f"{path} was refined with the prior's box extended as {result.get('extend') or {}}, "
                                  f"not {extend}: use another --fit-dir")
            state_path = f"{args.fit_dir}/state_{sid}.npz"
            if (result is not None and extend and os.path.exists(state_path)
                    and "log_likelihood_ratio_by_budget" not in (result.get("beyond_prior") or {})):
                # a result from before Λ: from its saved particles
                result["beyond_prior"] = beyond_prior(Refinement.load(state_path))
                write_json(path, result)
            if result is None or any(str(b) not in result["refined_by_budget"] for b in budgets):
                say(f"family {n}/{len(chosen)} (sample {sid}{', case ' + args.case if args.case else ''}): "
                    f"budget {budgets[-1]}")
                if observations is None:
                    image, family, truth = (data.images[k], h5["curves_mz"][k].astype(float),
                                            {p: data.values[p][k] for p in data.values})
                else:
                    image, family, truth = observations[n - 1]
                state = f"{args.fit_dir}/{'adjusted' if args.method == 'adjusted' else 'state'}_{sid}.npz"
                result = fit_function(args.method)(cfg, est, image, family, float(data.values["Ms"][k]),
                                                   budget=budgets[-1], round_size=args.round_size,
                                                   workers=args.fit_workers, seed=stage["seed"], key=sid,
                                                   checkpoints=tuple(budgets), state_path=state, prior=args.prior,
                                                   extend=extend)
                # in an extended box the truth may lie beyond the bound, and is scored there
                result["truth_normalized"] = {p: float(np.clip(normalize(p, truth[p], data.bounds), 0,
                                                               extend.get(p, 1.0))) for p in result["names"]}
                if args.case:
                    result["case"] = args.case
                write_json(path, result)
            rows.append(result)

    out = {"split": args.split, "method": args.method, "prior": args.prior, "case": args.case, "sample_ids": [int(data.sample_id[k]) for k in chosen],
           **fit_summary(rows, budgets, data.bounds, np.random.default_rng(stage["seed"]))}
    for line in fit_lines(out):
        say(line)
    if args.method == "adjusted":  # the rule that chooses the answer's reading (on validation families)
        out["reading_choice"] = reading_choice(rows, budgets[-1], np.random.default_rng(stage["seed"]))
        for line in choice_lines(out["reading_choice"]):
            say(line)
    if extend:
        out["extend"] = extend
        out["beyond_prior"] = {str(sid): r.get("beyond_prior") for sid, r in zip(out["sample_ids"], rows)}
        for sid, beyond in out["beyond_prior"].items():
            for line in beyond_prior_lines(beyond):
                say(f"sample {sid}: {line}")
        _extension_check(args, out, rows, budgets[-1], extend, reference, say)
    write_json(f"{args.fit_dir}/summary.json", out)
    print(json.dumps(out))
    return 0


def _extension_check(args, out, rows, budget, extend, reference, say) -> None:
    """The extension check (``infer.predictive_check``, Λ) of a bench over films refined in an extended box:
    a run on validation families writes its reference (FIT_DIR/extension_reference.json); with a
    reference, each family is judged and the flag rate goes into the summary (key ``extension_check``)."""
    import numpy as np

    values = [predictive_statistic(r, budget, extension=True) for r in rows]
    out["log_likelihood_ratio"] = {str(s): v for s, v in zip(out["sample_ids"], values)}
    if args.split == "validation" and not args.case:
        made = make_reference(values, budget=budget, round_size=args.round_size, prior=args.prior,
                              sample_ids=out["sample_ids"], extend=extend)
        write_json(f"{args.fit_dir}/extension_reference.json", made)
        say(f"extension check: reference of {len(values)} validation families written to "
            f"{args.fit_dir}/extension_reference.json (log-likelihood ratio median {np.median(values):.3g}, "
            f"max {np.max(values):.3g}; smallest p it can give {made['resolvable_p']:.3f})")
    if reference is not None:
        checks = [predictive_check(r, reference) for r in rows]
        flagged = sum(c["misspecified"] for c in checks)
        out["extension_check"] = {"reference": args.extension_reference, "flagged": int(flagged), "of": len(checks),
                                  "per_family": {str(s): {k: c[k] for k in ("statistic", "p_value", "misspecified")}
                                                 for s, c in zip(out["sample_ids"], checks)}}
        for sid, c in zip(out["sample_ids"], checks):
            say(f"sample {sid}: extension check: {c['verdict']}")
        say(f"extension check: {flagged} of {len(checks)} families flagged (α {checks[0]['alpha']:g}, "
            f"{checks[0]['n_reference']} reference families)")
        check_figure(f"{args.fit_dir}/extension_check.png", reference,
                     {f"sample {sid}": c for sid, c in zip(out["sample_ids"], checks)},
                     title=f"extension check, {args.case or args.split} films: {flagged} of {len(checks)} flagged")
        say(f"extension check: figure {args.fit_dir}/extension_check.png")


def _case_observations(args, cfg, data, held_out, chosen) -> list:
    """(image, grid family, truth SI) of the ``--case`` families stored by ``bench ood`` for ``chosen``
    (the first families of the split, as ``bench ood`` took them); the truth is the case's Hamiltonian
    (N_pin 0 for magnumnp and no_pinning, three times the prior's bound beyond it)."""
    import numpy as np

    if args.case not in CASES:
        raise ConfigError(f"unknown case {args.case!r} (one of {', '.join(CASES)})")
    path = os.path.join(args.ood_dir, f"{args.case}.npz")
    if not os.path.exists(path):
        raise ConfigError(f"{path} not found: make the case's families first (forcdecode bench ood --ood-cases "
                          f"{args.case} --predictive-budget ...)")
    stored = np.load(path)
    if "curves" not in stored.files:
        raise ConfigError(f"{path} holds images only: run bench ood with --predictive-budget on it to keep its families")
    if args.first_family + args.families > len(stored["images"]):
        raise ConfigError(f"{path} holds {len(stored['images'])} families: --first-family {args.first_family} + "
                          f"--families {args.families} is beyond it")
    out = []
    for k in chosen:
        n = int(np.flatnonzero(held_out == k)[0])
        truth = {p: (int(data.values[p][k]) if p == "N_pin" else float(data.values[p][k])) for p in NAMES}
        truth = {**truth, "N_pin": 0} if args.case == "magnumnp" else case_film(dict(cfg), truth, args.case)[1]
        out.append((stored["images"][n], stored["curves"][n].astype(float), truth))
    return out


def _predictive_reference(args, stage, data, est, cfg, say) -> dict:
    """Settings of the predictive check and its reference: the statistic of ``--calibration-families``
    validation families (our film made them; the posterior never trained on them), refined with the
    same budget, round size and prior. Written to ``OOD_DIR/predictive_reference.json``."""
    import h5py
    import numpy as np

    if args.predictive_budget < args.round_size or args.predictive_budget % args.round_size:
        raise ConfigError(f"--predictive-budget {args.predictive_budget} must be a positive multiple of --round-size "
                          f"{args.round_size}")
    validation = _workflow_splits(stage, data)["validation"]
    if args.calibration_families < 1 or args.calibration_families > len(validation):
        raise ConfigError(f"--calibration-families must be 1..{len(validation)} (the validation split)")
    chosen = validation[: args.calibration_families]
    settings = {"budget": args.predictive_budget, "round_size": args.round_size, "workers": args.fit_workers,
                "seed": stage["seed"], "prior": args.prior, "fit_dir": f"{args.ood_dir}/predictive"}
    with h5py.File(args.dataset, "r") as h5:
        curves = [h5["curves_mz"][k].astype(float) for k in chosen]
    sids = [int(data.sample_id[k]) for k in chosen]
    say(f"predictive check: calibrating on {len(chosen)} validation families ({args.predictive_budget} simulations each)")
    validation = CaseFamilies(data.images[chosen], curves, data.values["Ms"][chosen], sids)
    results = predictive_statistics(est, cfg, validation, settings, f"{args.ood_dir}/predictive/validation", say)
    values = [predictive_statistic(r, args.predictive_budget) for r in results]
    reference = make_reference(values, budget=args.predictive_budget, round_size=args.round_size, prior=args.prior,
                               sample_ids=sids)
    write_json(f"{args.ood_dir}/predictive_reference.json", reference)
    say(f"predictive check: validation T median {np.median(values):.2f}, max {np.max(values):.2f}")
    return {**settings, "reference": reference, "cases": tuple(args.predictive_cases or args.ood_cases or ())}


def _bench_prior_class(args, say) -> int:
    """Rates of the prior-class rule (``learn.prior_class``) on the families of --dataset (read only)."""
    result = prior_class_bench(args.dataset)
    for line in prior_class_lines(result):
        say(line)
    if args.out:
        write_json(args.out, result)
    if args.json:
        print(json.dumps(result))
    return 0


def _bench_ood(args, say) -> int:
    """Flag rate of the posterior's OOD check on held-out Hamiltonians made in and out of the prior."""
    if args.families < 1 or args.workers < 1:
        raise ConfigError(f"--families and --workers must be >= 1 (got {args.families}, {args.workers})")
    import h5py

    stage, data, est, held_out = _held_out_families(args)
    with h5py.File(args.dataset, "r") as h5:
        cfg = json.loads(h5.attrs["config_json"])
    chosen = held_out[: args.families]
    rows = [{n: (int(data.values[n][k]) if n == "N_pin" else float(data.values[n][k])) for n in NAMES} for k in chosen]
    predictive = None
    if args.predictive_budget:
        predictive = _predictive_reference(args, stage, data, est, cfg, say)
    families = HeldOutFamilies(rows, [int(data.sample_id[k]) for k in chosen], data.ms_norm[chosen],
                               dataset_images=data.images[chosen])
    result = bench_ood(est, cfg, families, cases=tuple(args.ood_cases or CASES), workers=args.workers,
                       out_dir=args.ood_dir, say=say, predictive=predictive)
    if predictive is not None:
        result["predictive_reference"] = predictive["reference"]
    result.update(split=args.split, sample_ids=[int(data.sample_id[k]) for k in chosen], posterior=str(args.posterior))
    summary = os.path.join(args.ood_dir, "summary.json")
    result = carry_over(read_json(summary, what="OOD summary") if os.path.exists(summary) else None, result)
    for line in ood_lines(result):
        say(line)
    write_json(summary, result)
    if args.json:
        line = {case: row["flagged_fraction"] for case, row in result["cases"].items()}
        line.update({f"{case}_predictive": row["predictive"]["flagged_fraction"]
                     for case, row in result["cases"].items() if "predictive" in row})
        print(json.dumps(line))
    return 0


TARGETS = {"engine": _bench_engine, "protocols": _bench_protocols, "effects": _bench_effects, "learn": _bench_learn,
           "films": _bench_films, "film-learning": _bench_film_learning, "realisations": _bench_realisations,
           "prior-learning": _bench_prior_learning, "fit": _bench_fit, "ood": _bench_ood,
           "information": _bench_information, "prior-class": _bench_prior_class, "thickness": _bench_thickness}
"""`forcdecode bench TARGET`: each target's runner (args, say) → exit status."""
