"""``forcdecode diagram FILE --out PNG``: the FORC diagram of a measured file (any format
``forcdecode read`` knows) or of one sample of a simulated ``dataset.h5`` (``--sample ID``)."""

from __future__ import annotations

import argparse

from ..core.errors import ConfigError
from .diagram import Variforc
from .render import measured_diagram, measured_grid, save_diagram_png, simulated_diagram


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="measured FORC file, or a dataset.h5 with --sample")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--sf", type=int, default=3, help="smoothing factor SF (patch of (2SF+1)² points)")
    parser.add_argument("--sample", type=int, help="sample id in a dataset.h5")
    parser.add_argument("--no-drift-correction", action="store_true")
    parser.add_argument("--kernel", choices=("pike", "loess"), default="pike",
                        help="constant smoothing: Pike et al. 1999 least-squares patch (default) or FORCinel/PmagPy LOESS")
    parser.add_argument("--variforc", nargs=6, type=float, metavar=("SC0", "SC1", "SU0", "SU1", "LAMBDA_C", "LAMBDA_U"),
                        help="VARIFORC variable smoothing (Egli 2013), e.g. 3 7 3 7 0.07 0.07; replaces --sf/--kernel")


def run(args) -> int:
    try:
        variforc = Variforc(*args.variforc) if args.variforc else None
    except ValueError as error:
        raise ConfigError(f"--variforc: {error}") from None
    if args.sample is not None:
        diagram = simulated_diagram(args.file, args.sample, args.sf, args.kernel, variforc)
        title = f"sample {args.sample} (simulated)"
    else:
        diagram, title = measured_diagram(args.file, args.sf, drift_correction=not args.no_drift_correction,
                                          kernel=args.kernel, variforc=variforc)
    smoothing = "VARIFORC " + " ".join(f"{v:g}" for v in args.variforc) if variforc else f"SF={args.sf}, {args.kernel}"
    save_diagram_png(diagram, args.out, title=f"{title}, {smoothing}")
    print(f"wrote {args.out}")
    return 0
