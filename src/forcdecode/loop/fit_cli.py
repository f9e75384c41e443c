"""``forcdecode fit INPUT --budget N``: refine the amortized posterior of one FORC family by simulating
that film (``loop.fit``), and ``forcdecode bench fit``'s per-family runs.

    fit results/dataset.h5 --sample-id 33 --posterior results/posterior/model.pt --budget 200 --out DIR
    fit FILE.frc --Ms-kA-m 800 --budget 200 --out DIR            (a measured file, on the training grid)

Writes DIR/fit.json (amortized and refined medians, 68/90 % intervals, effective sample size, wall
time per checkpoint budget; SI values beside the normalized ones) atomically.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np


PRIORS = ("draw", "uniform")
"""The refinement's priors: the dataset's draw prior given M_s, or the uniform box."""


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
    parser.add_argument("--prior", choices=PRIORS, default="draw",
                        help="the refinement's prior: the dataset's draw prior given M_s (default) or uniform")
    parser.add_argument("--predictive-reference", help="the posterior-predictive check's reference "
                        "(predictive_reference.json of `forcdecode bench ood --predictive-budget B`): fit.json then "
                        "says whether a film inside the prior reproduces this family")
    parser.add_argument("--out", required=True, help="output directory (fit.json)")


def observation(path, sample_id, cfg, ms_kA_m):
    """(image uint8, grid family, M_s in A/m, truth dict or None) of the input."""
    from ..core.errors import InputFileError

    n, B_max = cfg["field"]["n_fields"], cfg["field"]["B_max_T"]
    p = Path(path)
    if p.suffix in (".h5", ".hdf5"):
        from ..learn.data import load_dataset

        if sample_id is None:
            raise InputFileError(f"{path}: a dataset input needs --sample-id")
        data = load_dataset(p)
        where = np.flatnonzero(data.sample_id == sample_id)
        if where.size == 0:
            raise InputFileError(f"sample {sample_id} is not in {path}")
        k = int(where[0])
        import h5py

        with h5py.File(p, "r") as h5:
            family = h5["curves_mz"][k].astype(float)
        truth = {name: float(v[k]) for name, v in data.values.items()}
        return data.images[k], family, truth["Ms"], truth
    from ..forc.raster import measurement_on_grid
    from ..measured import read_forc

    if ms_kA_m is None:
        raise InputFileError("a measured file needs --Ms-kA-m")
    image, family, _note, _moment = measurement_on_grid(read_forc(p), B_max, n)
    return image, family, ms_kA_m * 1e3, None


def family_key(label: str) -> int:
    """The disorder key of a refinement (common random numbers) from a label naming its family."""
    return int(hashlib.sha1(label.encode()).hexdigest()[:8], 16)


def start_fit(cfg, est, image, family, Ms, *, budget, round_size, workers, seed, key, checkpoints=(), prior="draw"):
    """The refinement's initial state (``loop.fit.Refinement``) for one family: amortized draws, and
    σ² (of candidate − observation: two realisations) and ν from the amortized median on 4 disorder
    realisations. The state carries what later rounds
    need (``context``: M_s, key, names, the amortized summary, the prior) so that each round can run as a
    job. ``prior``: "draw", the dataset's draw prior given M_s (``dataset.params.draw_log_density``),
    or "uniform" on the normalized box (the former target, kept for comparison)."""
    from ..core.errors import ConfigError

    if prior not in PRIORS:
        raise ConfigError(f"prior {prior!r} is not one of {PRIORS}")
    from ..core.parameters import normalize
    from ..core.streams import stream_rng, stream_seed
    from ..learn.calibration import recalibrate_draws
    from .fit import Refinement, difference_variance, summarize_particles
    from .posterior_predictive import draws_as_hamiltonians
    from .simulated import run_tasks

    names = tuple(est.names)
    ms_norm = float(normalize("Ms", Ms, est.bounds))
    # the proposal q₀ is the flow itself: its draws and its density (log_prob) must be the same law
    draws = est.sample(np.asarray(image)[None], [ms_norm], 4000, seed=stream_seed(seed, "posterior", "fit", key),
                       recalibrated=False)[0]
    # the amortized answer reported beside the refinement: the posterior as `predict` gives it (the same
    # flow draws, recalibrated)
    reported = draws if est.recalibration is None else recalibrate_draws(draws[None], est.recalibration, names)[0]
    median = np.median(draws, axis=0)
    # the disorder floor: the amortized median on four realisations (0 is the one every candidate uses)
    params = draws_as_hamiltonians(median[None], names, Ms, est.bounds)[0]
    n_real = 4
    floor = [c for c, _ in run_tasks(cfg, [(params, key, r) for r in range(n_real)], workers) if c is not None]
    sigma2, nu = difference_variance(floor, quantization_step=2 / 255)
    state = Refinement(family, draws, sigma2, budget, round_size, stream_rng(seed, "posterior", "fit_rounds", key),
                       names, checkpoints=checkpoints, n_effective=nu)
    state.context = {"names": list(names), "Ms": float(Ms), "ms_norm": ms_norm, "key": int(key), "sigma2": sigma2,
                     "prior": prior,
                     "n_effective": nu, "simulations_for_sigma2": n_real,
                     "amortized": summarize_particles(reported, np.ones(len(reported)), names),
                     "image_uint8": np.asarray(image, dtype=np.uint8).tolist()}
    return state


def fit_round(state, cfg, est, workers: int = 1) -> None:
    """One round of the refinement: propose, simulate this film (common random numbers), update."""
    from .fit import simulate_on_film

    ctx = state.context
    simulate = simulate_on_film(cfg, state.names, ctx["Ms"], est.bounds, ctx["key"], workers)
    started = time.perf_counter()
    take = state.propose()
    families = simulate(take)
    state.update(take, families, _proposal_logpdf(est, state)(take), wall_s=time.perf_counter() - started,
                 log_prior=prior_logpdf(state, est.bounds)(take))


def prior_logpdf(state, bounds):
    """log p(u) of the refinement's prior (the state's ``context["prior"]``; older states: uniform)."""
    from ..dataset.params import draw_log_density

    ctx = state.context
    if ctx.get("prior", "uniform") == "uniform":
        return lambda u: np.zeros(len(np.atleast_2d(u)))
    return lambda u: draw_log_density(u, state.names, ctx["Ms"], bounds)


def finish_fit(state) -> dict:
    """fit.json's content (plain values) from a finished refinement state."""
    from .fit import observation_rms

    ctx = state.context
    result = state.result()
    return {"names": ctx["names"], "Ms": ctx["Ms"], "prior": ctx.get("prior", "uniform"), "sigma2": ctx["sigma2"], "n_effective": ctx["n_effective"],
            "simulations_for_sigma2": ctx["simulations_for_sigma2"], "amortized": ctx["amortized"],
            "refined_by_budget": {str(b): v for b, v in result["by_budget"].items()},
            "betas": result["betas"], "ess_per_round": result["ess"],
            "reached_full_likelihood": result["reached_full_likelihood"], "wall_s": state.wall_s,
            "observation_rms": observation_rms(state)}


def _proposal_logpdf(est, state):
    """log q₀(u) of the amortized posterior at this observation (the image is kept in the state)."""
    image = np.asarray(state.context["image_uint8"], dtype=np.uint8)
    ms_norm = state.context["ms_norm"]

    def logpdf(u):
        u = np.atleast_2d(u)
        out = np.empty(len(u))
        images = np.repeat(image[None], min(256, len(u)), axis=0)
        for s in range(0, len(u), 256):
            part = u[s:s + 256]
            out[s:s + len(part)] = est.log_prob(part, images[:len(part)], np.full(len(part), ms_norm))
        return out

    return logpdf


def fit_one(cfg, est, image, family, Ms, *, budget, round_size, workers, seed, key, checkpoints=(), log=None,
            state_path=None, prior="draw") -> dict:
    """Amortized posterior → refined posterior of one family (see ``loop.fit``); plain-value dict.
    The same rounds as ``forcdecode fit-step`` runs one job at a time (identical results).
    ``state_path``: the state (every particle) is saved there after each round; a run that stops
    resumes from it."""
    from ..core.errors import ConfigError
    from .fit import Refinement

    if state_path is not None and Path(state_path).exists():
        state = Refinement.load(state_path)
        if state.round_size != round_size:
            raise ConfigError(f"{state_path}: saved with rounds of {state.round_size}, asked for {round_size}")
        if state.context.get("prior", "uniform") != prior:
            raise ConfigError(f"{state_path}: refined with the {state.context.get('prior', 'uniform')} prior, "
                              f"asked for {prior}")
        state.extend(budget, checkpoints)  # nested rounds: a longer budget continues the saved run
    else:
        state = start_fit(cfg, est, image, family, Ms, budget=budget, round_size=round_size, workers=workers,
                          seed=seed, key=key, checkpoints=checkpoints, prior=prior)
    while not state.done:
        fit_round(state, cfg, est, workers)
        if state_path is not None:
            state.save(state_path)
        if log:
            log(f"simulated {len(state.rounds) * state.round_size}/{state.n_rounds * state.round_size}")
    return finish_fit(state)


def run(args) -> int:
    from ..config import load_config, shipped_config
    from ..core.errors import ConfigError
    from ..core.io import write_json
    from ..learn.posterior import PosteriorEstimator

    if args.budget < args.round_size or args.round_size < 2 or args.workers < 1:
        raise ConfigError("--budget must be at least one round (--round-size >= 2) and --workers >= 1")
    cfg = load_config(args.config or shipped_config("config"))
    reference = None
    if args.predictive_reference:
        from ..core.io import read_json
        from .predictive_check import check_reference

        reference = read_json(args.predictive_reference, what="predictive-check reference")
        check_reference(reference, round_size=args.round_size, prior=args.prior, budget_run=args.budget)
    est = PosteriorEstimator.load(args.posterior)
    image, family, Ms, truth = observation(args.input, args.sample_id, cfg, args.ms_kA_m)
    key = family_key(f"{Path(args.input).name}:{args.sample_id}")
    result = fit_one(cfg, est, image, family, Ms, budget=args.budget, round_size=args.round_size,
                     workers=args.workers, seed=args.seed, key=key, prior=args.prior,
                     checkpoints=tuple(range(args.round_size, args.budget + 1, args.round_size)),
                     log=lambda m: print(f"[{time.strftime('%H:%M:%S')}] {m}", file=sys.stderr, flush=True))
    result["truth"] = truth
    if reference is not None:
        from .predictive_check import predictive_check

        result["predictive_check"] = predictive_check(result, reference)
    write_json(Path(args.out) / "fit.json", result)
    final = result["refined_by_budget"][str(max(int(b) for b in result["refined_by_budget"]))]
    print(f"{'parameter':16s} {'amortized median':>17s} {'refined median':>15s}  refined 90 % interval (normalized)")
    for name in result["names"]:
        a, r = result["amortized"]["parameters"][name], final["parameters"][name]
        print(f"{name:16s} {a['median']:17.3f} {r['median']:15.3f}  [{r['interval_90'][0]:.3f}, {r['interval_90'][1]:.3f}]")
    print(f"effective sample size {final['ess']:.1f} of {args.budget} simulations; {result['wall_s']:.0f} s")
    if final.get("tempered"):
        print(f"warning: {final['note']}")
    if reference is not None:
        print(("warning: " if result["predictive_check"]["misspecified"] else "") + result["predictive_check"]["verdict"])
    return 0
