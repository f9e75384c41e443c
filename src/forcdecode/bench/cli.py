"""``forcdecode bench engine [--json]``: prints engine figures; the last line is one JSON object."""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", choices=["engine", "protocols", "effects"], help="what to benchmark")
    parser.add_argument("--samples", type=int, default=3, help="protocols: samples compared")
    parser.add_argument("--seeds", type=int, default=3, help="effects: noise seeds per effect and size")
    parser.add_argument("--json", action="store_true", help="end with one JSON line (always printed last)")
    parser.add_argument("--skip-magnumnp", action="store_true", help="do not run the magnum.np peer")
    parser.add_argument("--skip-256", action="store_true", help="skip the 256×256×2 grid")
    parser.add_argument("--cache-dir", default=".cache/magnumnp", help="magnum.np demag-kernel cache")
    parser.add_argument("--seconds", type=float, default=2.0, help="minimum timing window per figure")
    parser.add_argument("--eager-magnumnp", action="store_true",
                        help="run magnum.np without torch.compile (default: compiled, its fastest)")


def run(args) -> int:
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from . import engine

    def say(text):
        print(text, flush=True)

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
