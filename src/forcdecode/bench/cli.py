"""``forcdecode bench engine|protocols|effects|learn [--json]``: prints figures; with --json the last
line is one JSON object."""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=["engine", "protocols", "effects", "learn"], help="what to benchmark")
    parser.add_argument("--samples", type=int, default=3, help="protocols: samples compared")
    parser.add_argument("--seeds", type=int, default=3, help="effects: noise seeds per effect and size")
    parser.add_argument("--json", action="store_true", help="end with one JSON line (always printed last)")
    parser.add_argument("--skip-magnumnp", action="store_true", help="do not run the magnum.np peer")
    parser.add_argument("--skip-256", action="store_true", help="skip the 256×256×2 grid")
    parser.add_argument("--cache-dir", default=".cache/magnumnp", help="magnum.np demag-kernel cache")
    parser.add_argument("--seconds", type=float, default=2.0, help="minimum timing window per figure")
    parser.add_argument("--eager-magnumnp", action="store_true",
                        help="run magnum.np without torch.compile (default: compiled, its fastest)")
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

    def say(text):
        print(text, flush=True)

    if args.target == "learn":
        return _bench_learn(args, say)
    from . import engine

    if args.target == "effects":
        from .effects import abbreviate, effects_confusion

        result = effects_confusion(seeds=range(args.seeds))
        say(f"residual analysis on undeclared effects (simulated film, MicroMag files): {result['accuracy']:.0%} "
            f"named correctly over {result['n_cases']} cases (setup {result['setup_s']:.0f} s, "
            f"analysis {result['analysis_s']:.0f} s)")
        truths = list(result["confusion"])
        chosen = truths + sorted({c for row in result["confusion"].values() for c in row} - set(truths))
        say("true \\ chosen".ljust(16) + "".join(abbreviate(n)[:9].rjust(10) for n in chosen))
        for true in truths:
            say(abbreviate(true)[:15].ljust(16)
                + "".join(str(result["confusion"][true].get(n, 0) or ".").rjust(10) for n in chosen))
        say("")
        say("effect".ljust(16) + "size".ljust(52) + "correct  median held-out cut  chosen")
        for row in result["by_size"]:
            size = ", ".join(f"{k.replace('background_', '')}={v:g}" for k, v in row["size"].items()) or "-"
            say(abbreviate(row["effect"])[:15].ljust(16) + size[:51].ljust(52) + f"{row['correct']}/{row['n']}".ljust(9)
                + f"{row['median_reduction']:.0%}".rjust(18) + "  " + ", ".join(map(abbreviate, row["chosen"])))
        if args.json:
            print(json.dumps({k: v for k, v in result.items() if k != "cases"}))
        return 0
    if args.target == "protocols":
        result = engine.compare_protocols(args.samples, progress=lambda row: say(
            f"sample {row['sample_id']}: quasi-static {row['quasistatic_s']:.2f} s, LLG {row['llg_s']:.1f} s, "
            f"mean |dm_z| {row['mean_abs_dmz']:.3f}, max {row['max_abs_dmz']:.3f}"))
        say(f"LLG/quasi-static time ratio {result['time_ratio_llg_over_quasistatic']:.0f}x, "
            f"mean |dm_z| between the protocols' families {result['mean_abs_dmz']:.3f}")
        if args.json:
            print(json.dumps(result))
        return 0
    grids = ["64"] if args.skip_256 else ["64", "256"]
    report = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "threads": 1}
    for grid in grids:
        ours = engine.time_ours(grid, args.seconds)
        report[f"ours_{grid}"] = ours
        say(f"[{grid}] forcdecode: {ours['cells_per_s']:.3e} cell-evaluations/s, "
            f"{ours['field_eval_s'] * 1e3:.3f} ms per field, {ours['llg_step_s'] * 1e3:.3f} ms per RK45 step")
        if not args.skip_magnumnp:
            try:
                import torch

                torch.set_num_threads(1)
                peer = engine.time_magnumnp(grid, args.cache_dir, compile=not args.eager_magnumnp)
            except ImportError as error:
                say(f"[{grid}] magnum.np not available ({error}); install with pip install -e .[reference]")
                peer = None
            if peer is not None:
                report[f"magnumnp_{grid}"] = peer
                report[f"speedup_vs_magnumnp_{grid}"] = peer["field_eval_s"] / ours["field_eval_s"]
                report[f"llg_step_speedup_vs_magnumnp_{grid}"] = peer["llg_step_s"] / ours["llg_step_s"]
                say(f"[{grid}] magnum.np:  {peer['cells_per_s']:.3e} cell-evaluations/s, "
                    f"{peer['field_eval_s'] * 1e3:.3f} ms per field, {peer['llg_step_s'] * 1e3:.3f} ms per step "
                    f"(setup {peer['setup_s']:.1f} s) -> field speedup "
                    f"{report[f'speedup_vs_magnumnp_{grid}']:.1f}x, step speedup "
                    f"{report[f'llg_step_speedup_vs_magnumnp_{grid}']:.1f}x")
        report.setdefault(f"speedup_vs_magnumnp_{grid}", None)

    def progress(done, total):
        if done % 16 == 0 or done == total:
            print(f"  family: {done}/{total} curves", file=sys.stderr, flush=True)

    family = engine.time_laptop_family(progress=progress)
    report["laptop_family"] = family
    report["laptop_family_s"] = family["family_s"]
    say(f"[family] 64 reversal fields on 64x64x1, one core: {family['family_s']:.1f} s "
        f"({family['relaxations']} relaxations, {family['iterations']} minimizer iterations)")
    if args.json:
        print(json.dumps(report))
    return 0


def _bench_learn(args, say) -> int:
    import torch

    from ..dataset.io import read_config, write_json
    from ..learn.ablation import compare_heads, head_ratios
    from ..learn.data import TARGETS, load_dataset
    from ..learn.pipeline import DEFAULT_SETTINGS, make_splits

    unknown = sorted(set(args.parameters) - set(TARGETS))
    if unknown:
        raise SystemExit(f"error: unknown parameter(s) {unknown}; choose from {list(TARGETS)}")
    config_path = Path(args.learning_config or Path(args.dataset).with_name("learning.json"))
    if not config_path.exists():
        raise SystemExit(f"error: {config_path} not found: the ablation rebuilds the workflow's split from its "
                         f"learning.json (pass --learning-config)")
    cfg = read_config(config_path)
    settings = {**DEFAULT_SETTINGS, **cfg.get("learning", {})}
    torch.set_num_threads(args.threads)
    data = load_dataset(args.dataset)
    splits = make_splits(len(data), cfg["seed"], settings)
    say(f"{args.dataset}: {len(data)} families; split train {len(splits['train'])} / validation "
        f"{len(splits['validation'])} / test {len(splits['test'])}; Adadelta lr {settings['lr']}, batch "
        f"{settings['batch_size']}, {args.epochs} epochs (patience {args.patience}); {args.threads} torch threads")
    rows = compare_heads(data.images, data.ms_norm, {name: data.target(name) for name in args.parameters}, splits,
                         heads=args.heads, epochs=args.epochs, patience=args.patience,
                         batch_size=settings["batch_size"], lr=settings["lr"], width=settings["width"], seed=args.seed,
                         log=say)
    ratios = head_ratios(rows)
    say("")
    say("parameter  network  weights     test MAE  r      skill  best/run epochs  samples/s  wall s")
    for row in rows:
        say(f"{row['parameter']:<10} {row['network']:<8} {row['weights'] / 1e6:7.2f} M  {row['mae']:8.3f}  "
            f"{row['pearson_r']:5.2f}  {row['skill']:5.2f}  {row['best_epoch'] + 1:>4}/{row['epochs_run']:<4}        "
            f"{row['samples_per_s']:9.1f}  {row['wall_s']:6.0f}")
    for name, ratio in ratios.items():
        say(f"{name}: paper/small wall time {ratio['wall_ratio']:.1f}x, throughput {ratio['throughput_ratio']:.3f}x, "
            f"weights {ratio['weights_ratio']:.0f}x, MAE difference {ratio['mae_difference']:+.3f}")
    result = {"dataset": str(args.dataset), "n_families": len(data), "threads": args.threads,
              "settings": {"epochs": args.epochs, "patience": args.patience, "lr": settings["lr"],
                           "batch_size": settings["batch_size"], "width": settings["width"],
                           "optimizer": "Adadelta rho 0.9", "split_seed": cfg["seed"], "seed": args.seed},
              "rows": rows, "ratios": ratios}
    if args.out:
        write_json(args.out, result)
        say(f"wrote {args.out}")
    if args.json:
        print(json.dumps(result))
    return 0
