"""``forcdecode diagram FILE --out PNG``: the FORC diagram of a measured file (any format
``forcdecode read`` knows) or of one sample of a simulated ``dataset.h5`` (``--sample ID``)."""

from __future__ import annotations

import argparse
import sys

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="measured FORC file, or a dataset.h5 with --sample")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--sf", type=int, default=3, help="smoothing factor SF (patch of (2SF+1)² points)")
    parser.add_argument("--sample", type=int, help="sample id in a dataset.h5")
    parser.add_argument("--no-drift-correction", action="store_true")


def measured_grid(measurement):
    """Curves of a measurement on a common uniform field grid (step = median field step), moments
    normalized by the largest |moment|; rows sorted by reversal field. Returns (H_r, H, m)."""
    curves = sorted(measurement.curves, key=lambda c: c.reversal_field_T)
    steps = np.concatenate([np.diff(c.field_T) for c in curves if len(c) > 1])
    step = float(np.median(steps[steps > 0]))
    lo = min(c.field_T.min() for c in curves)
    hi = max(c.field_T.max() for c in curves)
    fields = np.arange(lo, hi + 0.5 * step, step)
    scale = max(np.abs(c.moment_Am2).max() for c in curves)
    grid = np.full((len(curves), fields.size), np.nan)
    for i, c in enumerate(curves):
        order = np.argsort(c.field_T)
        f, m = c.field_T[order], c.moment_Am2[order] / scale
        inside = (fields >= f[0]) & (fields <= f[-1])
        grid[i, inside] = np.interp(fields[inside], f, m)
    return np.array([c.reversal_field_T for c in curves]), fields, grid


def run(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..dataset.io import atomic_path
    from .diagram import forc_distribution, plot_diagram

    if args.sample is not None:
        import h5py

        with h5py.File(args.file, "r") as h5:
            ids = list(h5["sample_id"][:])
            if args.sample not in ids:
                print(f"error: sample {args.sample} is not in {args.file}", file=sys.stderr)
                return 2
            k = ids.index(args.sample)
            fields = h5["fields_T"][:]
            diagram = forc_distribution(fields, fields, h5["curves_mz"][k].astype(float), args.sf)
        title = f"sample {args.sample} (simulated)"
    else:
        from ..measured import ForcFormatError, read_forc

        try:
            measurement = read_forc(args.file, drift_correction=not args.no_drift_correction)
        except (ForcFormatError, OSError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        hr, h, m = measured_grid(measurement)
        diagram = forc_distribution(hr, h, m, args.sf)
        title = f"{measurement.source.name if hasattr(measurement.source, 'name') else args.file}"
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    plot_diagram(diagram, ax, title=f"{title}, SF={args.sf}")
    fig.tight_layout()
    with atomic_path(args.out) as tmp:
        fig.savefig(tmp, dpi=150, format="png")
    print(f"wrote {args.out}")
    return 0
