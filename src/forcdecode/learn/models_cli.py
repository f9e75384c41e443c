"""``forcdecode models show|ship|check``: the trained models shipped with the package (``learn.shipped``).

- ``show``: the shipped set's manifest (film, prior class, code commit, config hash, sealed figures).
- ``ship --results DIR [--out DIR]``: write a shipped set from a finished main job (half-precision weights,
  the training-data check's reference, the posterior, the manifest).
- ``check --results DIR``: whether a fresh main job's sealed-set figures agree with the shipped models'
  within their 90 % intervals (exit 1 when they do not).
"""

from __future__ import annotations

import argparse
import json

from .shipped import SHIPPED, compare, compare_lines, read_manifest, ship


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("show", "ship", "check"))
    parser.add_argument("--results", default="results", help="the main job's results directory (ship, check)")
    parser.add_argument("--shipped", default=str(SHIPPED), help="the shipped set's directory (default: the package's)")
    parser.add_argument("--full-precision", action="store_true", help="ship: keep float32 weights")
    parser.add_argument("--json", action="store_true")


def _show(args) -> int:
    manifest = read_manifest(args.shipped)
    if args.json:
        print(json.dumps(manifest, indent=2))
        return 0
    size = sum(f["bytes"] for f in manifest["files"].values())
    print(f"shipped models: {manifest['film']['name']} film, {manifest['prior_class']} prior, code "
          f"{manifest['code_commit'][:10]}, config {manifest['config_hash'][:12]}, {len(manifest['files'])} files, "
          f"{size / 1e6:.1f} MB ({'half' if manifest['half_precision'] else 'full'} precision)")
    for name, row in manifest["sealed"].items():
        lo, hi = row["ci90"] if row.get("ci90") else (float("nan"),) * 2
        print(f"  sealed skill over the best trivial predictor: {name:<10} {row['skill']:+.2f} [{lo:+.2f}, {hi:+.2f}]")
    return 0


def _ship(args) -> int:
    manifest = ship(args.results, args.shipped, half=not args.full_precision)
    size = sum(f["bytes"] for f in manifest["files"].values())
    print(json.dumps({k: manifest[k] for k in ("config_hash", "code_commit", "dataset_sha256", "prior_class")})
          if args.json else f"shipped {len(manifest['files'])} files ({size / 1e6:.1f} MB) to {args.shipped}")
    return 0


def _check(args) -> int:
    result = compare(args.results, args.shipped)
    print(json.dumps(result) if args.json else "\n".join(compare_lines(result)))
    return 0 if result["agree"] else 1


ACTIONS = {"show": _show, "ship": _ship, "check": _check}


def run(args) -> int:
    return ACTIONS[args.action](args)
