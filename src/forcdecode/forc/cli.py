"""``forcdecode diagram FILE --out PNG``: the FORC diagram of a measured file (any format
``forcdecode read`` knows) or of one sample of a simulated ``dataset.h5`` (``--sample ID``)."""

from __future__ import annotations

import argparse

from .render import measured_grid  # noqa: F401  (re-export for old callers)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="measured FORC file, or a dataset.h5 with --sample")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--sf", type=int, default=3, help="smoothing factor SF (patch of (2SF+1)² points)")
    parser.add_argument("--sample", type=int, help="sample id in a dataset.h5")
    parser.add_argument("--no-drift-correction", action="store_true")


def run(args) -> int:
    from .render import measured_diagram, save_diagram_png, simulated_diagram

    if args.sample is not None:
        diagram = simulated_diagram(args.file, args.sample, args.sf)
        title = f"sample {args.sample} (simulated)"
    else:
        diagram, title = measured_diagram(args.file, args.sf, drift_correction=not args.no_drift_correction)
    save_diagram_png(diagram, args.out, title=f"{title}, SF={args.sf}")
    print(f"wrote {args.out}")
    return 0
