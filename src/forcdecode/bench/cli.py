"""``forcdecode bench engine|protocols|effects|learn [--json]``: prints figures; with --json the last
line is one JSON object."""

from __future__ import annotations

import argparse
import json
import os


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=["engine", "protocols", "effects", "learn", "films"], help="what to benchmark")
    parser.add_argument("--samples", type=int, default=3, help="protocols: samples compared")
    parser.add_argument("--seeds", type=int, default=3, help="effects: noise seeds per effect and size")
    parser.add_argument("--json", action="store_true", help="end with one JSON line (always printed last)")
    parser.add_argument("--skip-magnumnp", action="store_true", help="do not run the magnum.np peer")
    parser.add_argument("--skip-256", action="store_true", help="skip the 256×256×2 grid")
    parser.add_argument("--cache-dir", default=".cache/magnumnp", help="magnum.np demag-kernel cache")
    parser.add_argument("--seconds", type=float, default=2.0, help="minimum timing window per figure")
    parser.add_argument("--eager-magnumnp", action="store_true",
                        help="run magnum.np without torch.compile (default: compiled, its fastest)")
    films = parser.add_argument_group("films (the same Hamiltonians on the laptop film and larger ones)")
    films.add_argument("--config", default=None, help="films: base config (default: the shipped laptop config)")
    films.add_argument("--hamiltonians", type=int, default=20, help="films: screened dataset draws compared")
    films.add_argument("--films", nargs="+", default=["laptop:20x2", "laptop_paper_grains:20x2", "box128:20x1",
                                                       "box128:8x2", "paper:5x1"],
                       help="films: FILM:NxR = the first N Hamiltonians with R disorder realisations each")
    films.add_argument("--workers", type=int, default=1, help="films: families simulated at once (one core each)")
    films.add_argument("--out-dir", default="results/bench/films", help="films: one HDF5 per family (resumable)")
    films.add_argument("--summarize-only", action="store_true", help="films: only summarize the families on disk")
    learn = parser.add_argument_group("learn (paper network vs laptop head, same split and optimizer)")
    learn.add_argument("--dataset", default="results/dataset.h5", help="merged dataset (forcdecode dataset merge)")
    learn.add_argument("--learning-config", help="the workflow's learning.json (seed, split, lr, batch size; "
                       "default: learning.json beside the dataset)")
    learn.add_argument("--parameters", nargs="+", default=["K_u", "D"], help="targets to train")
    learn.add_argument("--heads", nargs="+", default=["small", "paper"], choices=["small", "paper"])
    learn.add_argument("--epochs", type=int, default=40, help="epoch budget (both heads)")
    learn.add_argument("--patience", type=int, default=10, help="early-stopping patience (both heads)")
    learn.add_argument("--seed", type=int, default=1, help="weight/shuffle seed (both heads; the split is the workflow's)")
    learn.add_argument("--threads", type=int, default=2, help="torch threads")
    learn.add_argument("--out", help="also write the rows and ratios to this JSON file (atomically)")


def run(args) -> int:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")

    from ..core.progress import counter, echo, progress

    say = echo  # result lines on stdout; progress on stderr (a bar on a terminal, lines in a log)

    if args.target == "learn":
        return _bench_learn(args, say)
    if args.target == "films":
        return _bench_films(args, say)
    from . import engine

    if args.target == "effects":
        from .effects import effects_confusion, n_cases, summary_lines

        with progress(total=n_cases(args.seeds), desc="effects", unit="cases") as bar:
            result = effects_confusion(seeds=range(args.seeds), progress=lambda row: bar.update())
        for line in summary_lines(result):
            say(line)
        if args.json:
            print(json.dumps({k: v for k, v in result.items() if k != "cases"}))
        return 0
    if args.target == "protocols":
        with progress(total=args.samples, desc="protocols", unit="samples") as bar:
            def row_done(row):
                say(engine.protocol_row_line(row))
                bar.update()

            result = engine.compare_protocols(args.samples, progress=row_done)
        say(engine.protocols_summary(result))
        if args.json:
            print(json.dumps(result))
        return 0

    report = engine.benchmark_engine(["64"] if args.skip_256 else ["64", "256"], args.seconds,
                                     magnumnp=not args.skip_magnumnp, cache_dir=args.cache_dir,
                                     compile=not args.eager_magnumnp, say=say,
                                     progress=counter("family", "curves"))
    if args.json:
        print(json.dumps(report))
    return 0


def _bench_learn(args, say) -> int:
    from ..learn.ablation import run_head_ablation, summary_lines

    result = run_head_ablation(args.dataset, learning_config=args.learning_config, parameters=args.parameters,
                               heads=args.heads, epochs=args.epochs, patience=args.patience, seed=args.seed,
                               threads=args.threads, out=args.out, log=say)
    say("")
    for line in summary_lines(result):
        say(line)
    if args.out:
        say(f"wrote {args.out}")
    if args.json:
        print(json.dumps(result))
    return 0


def _bench_films(args, say) -> int:
    from ..config import load_config, shipped_config
    from ..core.errors import ConfigError
    from ..core.io import write_json
    from ..core.progress import counter
    from . import films

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
