"""FORC diagrams of files: a measured file (any format ``forcdecode read`` knows) or one sample of a
simulated ``dataset.h5``, and the diagram written as a PNG (atomically)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputFileError
from ..core.io import atomic_path
from ..measured import read_forc
from .diagram import ForcDiagram, Variforc, forc_distribution, plot_diagram, variforc_distribution


def diagram_of_grid(reversal_fields_T, fields_T, curves_m, smoothing_factor: int = 3, kernel: str = "pike",
                    variforc: Variforc | None = None) -> ForcDiagram:
    """ρ of gridded curves: constant smoothing with the ``pike`` or ``loess`` kernel, or VARIFORC
    variable smoothing where ``variforc`` settings are given (``smoothing_factor`` is then unused)."""
    if variforc is not None:
        return variforc_distribution(reversal_fields_T, fields_T, curves_m, variforc)
    return forc_distribution(reversal_fields_T, fields_T, curves_m, smoothing_factor, kernel=kernel)


def measured_grid(measurement):
    """Curves of a measurement on a common uniform field grid (step = median field step, T), moments
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


def simulated_diagram(dataset_path, sample_id: int, smoothing_factor: int = 3, kernel: str = "pike",
                      variforc: Variforc | None = None) -> ForcDiagram:
    """The diagram of sample ``sample_id`` of a ``dataset.h5``; InputFileError if it is not there."""
    import h5py

    try:
        h5 = h5py.File(dataset_path, "r")
    except OSError as error:
        raise InputFileError(f"cannot open dataset {dataset_path}: {error}") from None
    with h5:
        ids = [int(i) for i in h5["sample_id"][:]]
        if sample_id not in ids:
            raise InputFileError(f"sample {sample_id} is not in {dataset_path}")
        k = ids.index(sample_id)
        fields = h5["fields_T"][:]
        return diagram_of_grid(fields, fields, h5["curves_mz"][k].astype(float), smoothing_factor, kernel, variforc)


def measured_diagram(path, smoothing_factor: int = 3, drift_correction: bool = True, kernel: str = "pike",
                     variforc: Variforc | None = None) -> tuple[ForcDiagram, str]:
    """The diagram of a measured file and its title; InputFileError (ForcFormatError) if unreadable."""

    measurement = read_forc(path, drift_correction=drift_correction)
    hr, h, m = measured_grid(measurement)
    source = measurement.source
    return (diagram_of_grid(hr, h, m, smoothing_factor, kernel, variforc),
            str(getattr(source, "name", Path(path).name)))


def save_diagram_png(diagram: ForcDiagram, out, title: str, dpi: int = 150) -> None:
    """Plot the diagram (``plot_diagram``) into a PNG at ``out``, written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    plot_diagram(diagram, ax, title=title)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
