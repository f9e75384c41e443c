"""``forcdecode fit INPUT --budget N``: refine the amortized posterior of one FORC family by simulating
that film (``infer.fit``), and ``forcdecode bench fit``'s per-family runs.

    fit results/dataset.h5 --sample-id 33 --posterior results/posterior/model.pt --budget 200 --out DIR
    fit FILE.frc --Ms-kA-m 800 --budget 200 --out DIR            (a measured file, on the training grid)

Writes DIR/fit.json (amortized and refined medians, 68/90 % intervals, effective sample size, wall
time per checkpoint budget; SI values beside the normalized ones) atomically.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..config import load_config, shipped_config
from ..core.errors import ConfigError
from ..core.io import write_json
from .predictive_check import check_figure, predictive_check, read_reference
from .refine import (RefineRun, add_refinement_arguments, beyond_prior_lines, family_key, fit_function, observation,
                     parse_extension)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="dataset.h5 (with --sample-id) or a measured FORC file")
    parser.add_argument("--sample-id", type=int, help="sample of dataset.h5 (its M_s and, for scoring, its truth)")
    parser.add_argument("--Ms-kA-m", dest="ms_kA_m", type=float, help="M_s (kA/m); required for a measured file")
    parser.add_argument("--posterior", default="results/posterior/model.pt", help="the amortized posterior (.pt)")
    parser.add_argument("--config", help="simulation config (default: the shipped config.yaml)")
    parser.add_argument("--budget", type=int, default=200, help="simulations (default 200)")
    parser.add_argument("--round-size", type=int, default=25, help="simulations per round (default 25)")
    parser.add_argument("--workers", type=int, default=1, help="processes simulating in parallel")
    parser.add_argument("--seed", type=int, default=0, help="seed of the draws and of the proposal rounds")
    add_refinement_arguments(parser)
    parser.add_argument("--predictive-reference", help="the misspecification check's reference: without "
                        "--extend-prior predictive_reference.json of `forcdecode bench ood --predictive-budget B` "
                        "(fit.json then says whether a film inside the prior reproduces this family); with it "
                        "extension_reference.json of `forcdecode bench fit --extend-prior --split validation` "
                        "(whether a film beyond the bound fits better than any inside)")
    parser.add_argument("--out", required=True, help="output directory (fit.json)")

def print_summary(result: dict, budget: int) -> None:
    """Print a fit's answer at its largest budget: amortized and refined medians, the refined 90 % interval,
    the effective sample size, the summaries' resolution, which reading answers and, where the image
    reading was refused, why."""
    final = result["refined_by_budget"][str(max(int(b) for b in result["refined_by_budget"]))]
    print(f"{'parameter':16s} {'amortized median':>17s} {'refined median':>15s}  refined 90 % interval (normalized)")
    for name in result["names"]:
        a, r = result["amortized"]["parameters"][name], final["parameters"][name]
        print(f"{name:16s} {a['median']:17.3f} {r['median']:15.3f}  [{r['interval_90'][0]:.3f}, {r['interval_90'][1]:.3f}]")
    print(f"effective sample size {final['ess']:.1f} of {budget} simulations; {result['wall_s']:.0f} s")
    if "summary_resolution" in final:
        print("summary resolution (width at which one simulated family locates the parameter / spread of the "
              "draws; above 1 the simulations cannot narrow it): " + ", ".join(
                  f"{n} {v:.2g}" for n, v in final["summary_resolution"].items()))
    if "image_summaries" in final:
        reading = final["image_summaries"]
        print(f"summaries from the simulated images ({reading['components']} components, ridge {reading['ridge']:g}), "
              "resolution: " + ", ".join(f"{n} {v:.2g}" for n, v in reading["resolution"].items()))
        if reading["outside_simulations"]:
            print(f"the observed image summary lies outside the simulated ones (distance² "
                  f"{reading['distance2_observed']:.3g} > {reading['distance2_simulated_max']:.3g}): not read from the images")
    if "reading" in result:
        print(f"answer: reading {result['reading']!r} (others under 'variants' in fit.json)")
    if final.get("tempered"):
        print(f"warning: {final['note']}")
    for line in beyond_prior_lines(result.get("beyond_prior")):
        print(line)

def run(args) -> int:
    from ..learn.posterior import PosteriorEstimator  # local: the posterior imports torch

    if args.budget < args.round_size or args.round_size < 2 or args.workers < 1:
        raise ConfigError("--budget must be at least one round (--round-size >= 2) and --workers >= 1")
    cfg = load_config(args.config or shipped_config("config"))
    reference = None
    if args.predictive_reference and args.method != "pmc":
        raise ConfigError("--predictive-reference needs --method pmc (its statistic is the particles' observation RMS)")
    if args.extend_prior and args.method != "pmc":
        raise ConfigError("--extend-prior needs --method pmc (the adjusted fit only reweights the amortized draws, "
                          "which never leave the prior's box)")
    est = PosteriorEstimator.load(args.posterior)
    extend = parse_extension(args.extend_prior, tuple(est.names))
    if args.predictive_reference:
        reference = read_reference(args.predictive_reference, round_size=args.round_size, prior=args.prior,
                                   budget_run=args.budget, extend=extend)
    image, family, Ms, truth = observation(args.input, args.sample_id, cfg, args.ms_kA_m)
    key = family_key(f"{Path(args.input).name}:{args.sample_id}")
    log = lambda m: print(f"[{time.strftime('%H:%M:%S')}] {m}", file=sys.stderr, flush=True)  # noqa: E731
    run = RefineRun(budget=args.budget, round_size=args.round_size, workers=args.workers, seed=args.seed, key=key,
                    prior=args.prior, checkpoints=tuple(range(args.round_size, args.budget + 1, args.round_size)),
                    extend=extend)
    result = fit_function(args.method)(cfg, est, image, family, Ms, run, log=log)
    result["truth"] = truth
    if reference is not None:
        result["predictive_check"] = check = predictive_check(result, reference)
        label = Path(args.input).name + ("" if args.sample_id is None else f":{args.sample_id}")
        check_figure(Path(args.out) / "predictive_check.png", reference, {label: check},
                     title=f"{check['check']} check")
    write_json(Path(args.out) / "fit.json", result)
    print_summary(result, args.budget)
    if reference is not None:
        print(("warning: " if result["predictive_check"]["misspecified"] else "") + result["predictive_check"]["verdict"])
    return 0
