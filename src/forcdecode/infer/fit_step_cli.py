"""``forcdecode fit-step init|round|report``: the refinement of ``forcdecode fit`` one round per process,
so that each round is its own workflow job (``workflow/rules/fit.smk``: on a cluster, one SLURM job
per round, its simulations spread over the job's cores). The state between rounds is one .npz
(``infer.fit.Refinement``: particles, proposals, β, the generator's state), written atomically; the
rounds give exactly what ``forcdecode fit`` gives in one process.

    fit-step init INPUT [--sample-id N | --Ms-kA-m M] --posterior P --budget N --round-size R --state S0.npz
                  [--extend-prior NAME[=F] ...]
    fit-step round --state-in S0.npz --state-out S1.npz --posterior P [--workers W]
    fit-step report --state SK.npz --out fit.json
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..config import load_config, shipped_config
from ..core.errors import ConfigError
from ..core.io import read_config, write_json
from .fit import Refinement
from .predictive_check import check_figure, predictive_check, read_reference
from .refine import (DEFAULT_PRIOR, RefineRun, add_refinement_arguments, family_key, finish_fit, fit_round,
                     observation, parse_extension, start_fit)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("step", choices=("init", "round", "report"), help="init: amortized draws and the disorder floor; "
                        "round: one round of simulations; report: fit.json from the last state")
    parser.add_argument("input", nargs="?", help="init: dataset.h5 (with --sample-id) or a measured FORC file")
    parser.add_argument("--sample-id", type=int, help="init: sample of dataset.h5")
    parser.add_argument("--Ms-kA-m", dest="ms_kA_m", type=float, help="init: M_s (kA/m) of a measured file")
    parser.add_argument("--posterior", default="results/posterior/model.pt", help="init, round: the amortized posterior")
    parser.add_argument("--config", help="init, round: simulation config, a YAML config or the workflow's resolved "
                                         "config.json (default: the shipped config.yaml)")
    parser.add_argument("--budget", type=int, default=200, help="init: simulations in all (default 200)")
    parser.add_argument("--round-size", type=int, default=25, help="init: simulations per round (default 25)")
    parser.add_argument("--seed", type=int, default=0, help="init: seed of the draws and of the proposal rounds")
    parser.add_argument("--workers", type=int, default=1, help="init, round: processes simulating in parallel")
    add_refinement_arguments(parser, scope="init: ", method=False, prior=False)
    parser.add_argument("--state", help="init: the state written; report: the state read")
    parser.add_argument("--state-in", help="round: the state before the round")
    parser.add_argument("--state-out", help="round: the state after the round")
    parser.add_argument("--out", help="report: fit.json")
    parser.add_argument("--predictive-reference", metavar="JSON",
                        help="init: refuse now a reference that cannot judge this refinement; report: the calibrated "
                             "check of forcdecode fit --predictive-reference (T in the prior's box, Λ in an extended "
                             "one) in fit.json, and its figure (predictive_check.png beside it)")


def run(args) -> int:
    def need(*names):
        missing = [f"--{n.replace('_', '-')}" for n in names if getattr(args, n) in (None, "")]
        if missing:
            raise ConfigError(f"fit-step {args.step} needs {', '.join(missing)}")

    if args.workers < 1:
        raise ConfigError("--workers must be >= 1")
    if args.step == "report":
        need("state", "out")
        state = Refinement.load(args.state)
        if not state.done:
            raise ConfigError(f"{args.state}: {len(state.rounds)} of {state.n_rounds} rounds run; run the rest first")
        result = finish_fit(state)
        result["truth"] = state.context.get("truth")
        if args.predictive_reference:
            reference = read_reference(args.predictive_reference, round_size=state.round_size,
                                       prior=result["prior"], budget_run=state.budget, extend=result.get("extend"))
            result["predictive_check"] = check = predictive_check(result, reference)
            check_figure(Path(args.out).with_name("predictive_check.png"), reference,
                         {Path(args.out).parent.name or "film": check}, title=f"{check['check']} check")
            print(("warning: " if check["misspecified"] else "") + check["verdict"])
        write_json(args.out, result)
        return 0
    from ..learn.posterior import PosteriorEstimator  # local: the posterior imports torch

    if args.config and str(args.config).endswith(".json"):
        cfg = read_config(args.config)  # the workflow's resolved config (validated when it was written)
    else:
        cfg = load_config(args.config or shipped_config("config"))
    est = PosteriorEstimator.load(args.posterior)
    if args.step == "init":
        need("input", "state")
        if args.budget < args.round_size or args.round_size < 2:
            raise ConfigError("--budget must be at least one round (--round-size >= 2)")
        extend = parse_extension(args.extend_prior, tuple(est.names))
        if args.predictive_reference:
            read_reference(args.predictive_reference, round_size=args.round_size, prior=DEFAULT_PRIOR,
                           budget_run=args.budget, extend=extend)
        image, family, Ms, truth = observation(args.input, args.sample_id, cfg, args.ms_kA_m)
        key = family_key(f"{Path(args.input).name}:{args.sample_id}")
        state = start_fit(cfg, est, image, family, Ms, RefineRun(
            budget=args.budget, round_size=args.round_size, workers=args.workers, seed=args.seed, key=key,
            prior=DEFAULT_PRIOR, checkpoints=tuple(range(args.round_size, args.budget + 1, args.round_size)),
            extend=extend))
        state.context["truth"] = truth
        state.save(args.state)
        print(f"{state.n_rounds} rounds of {state.round_size} simulations to run")
        return 0
    need("state_in", "state_out")
    state = Refinement.load(args.state_in)
    if list(state.names) != list(est.names):
        raise ConfigError(f"{args.state_in} was started with parameters {list(state.names)}, the posterior "
                          f"{args.posterior} has {list(est.names)}")
    started = time.perf_counter()
    fit_round(state, cfg, est, args.workers)
    state.save(args.state_out)
    print(f"round {len(state.rounds)}/{state.n_rounds}: beta {state.beta:.3g}, ESS {state.ess[-1]:.1f}, "
          f"{time.perf_counter() - started:.0f} s")
    return 0
