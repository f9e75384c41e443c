"""Write the instrument file of laptop bench cases (magnum.np sample, cached) and print the user's loop
command for each, so that one dev case can be re-run with the loop as it is now without the bench's
resume skipping it (a row already in cases.jsonl is not run again).

    .venv/bin/python scripts/dev_case_file.py laptop-dev-006-background [...] --out DIR [--cache-dir C]

Prints, per case: the file, the sample's seconds and `forcdecode loop FILE --out DIR/loop/NAME --Ms-kA-m M`
(M: the truth × the case's M_s error factor, as the bench gives it). Only the dev split is accepted: the
eval cases are run by the bench alone.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from forcdecode.bench.effects_user import case_file, user_loop_argv
from forcdecode.bench.laptop_cases import load_cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="+", help="laptop dev case names (bench/effects_cases_laptop.yaml)")
    parser.add_argument("--out", required=True, type=Path, help="folder for the files (and the loop's reports)")
    parser.add_argument("--cache-dir", type=Path, default=None, help="magnum.np sample cache (as the bench's)")
    args = parser.parse_args()
    cases = {c["name"]: c for c in load_cases("dev")}
    unknown = [name for name in args.cases if name not in cases]
    if unknown:
        parser.error(f"not laptop dev cases: {', '.join(unknown)}")
    for name in args.cases:
        case = cases[name]
        path, sample_s = case_file(case, args.out, cache_dir=args.cache_dir, samples_dir=args.out / "samples")
        command = ["forcdecode", "loop", *user_loop_argv(case, path, args.out / "loop" / name)]
        print(f"{name}: {path} ({sample_s:.0f} s of sample)\n  {shlex.join(command)}", flush=True)


if __name__ == "__main__":
    main()
