"""The informative film's family cost over prior draws, and a faster minimizer checked against the
reference on the same draws (issue 62 item 1; ``forcdecode.bench.film_family``).

    .venv/bin/python scripts/check_film_family.py [--film box128_8nm] [--draws 8] [--floor auto|always|never]
        [--json OUT.json]

One core: run it with NUMBA_NUM_THREADS=1 (set below before numba loads). Minutes per tail draw
(labyrinth films) on the 128 x 128 x 2 film.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from forcdecode._runtime import limit_blas_threads  # noqa: E402
from forcdecode.bench.film_family import film_family_check, summary_line  # noqa: E402
from forcdecode.bench.information_films import FILMS  # noqa: E402
from forcdecode.core.io import write_json  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--film", default="box128_8nm", choices=sorted(FILMS))
    parser.add_argument("--draws", type=int, default=8)
    parser.add_argument("--floor", default="auto", choices=("auto", "always", "never"))
    parser.add_argument("--json", default=None, help="write the report here")
    args = parser.parse_args()
    limit_blas_threads()
    report = film_family_check(args.draws, args.film, with_floor=args.floor, say=lambda s: print(s, flush=True))
    print(summary_line(report), flush=True)
    if args.json:
        write_json(args.json, report)
    return 0 if report["passed"] == report["n"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
