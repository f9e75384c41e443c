"""Figure 1 of the seed paper: a FORC family with one minor loop highlighted, and its 64×64 image."""

from __future__ import annotations

import h5py
import numpy as np

from ..core import io
from ..core.errors import DatasetError


def figure1(dataset_path: str, out_path: str, index: int | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with h5py.File(dataset_path, "r") as h5:
        if h5["images"].shape[0] == 0:
            raise DatasetError(f"{dataset_path} holds no FORC family to plot")
        if index is None:  # the richest minor loops: FORCs farthest from both major-loop branches
            curves_all = h5["curves_mz"][:].astype(float)
            ascending = curves_all[:, :1, :]
            descending = np.diagonal(curves_all, axis1=1, axis2=2)[:, None, :]
            away = np.minimum(np.abs(curves_all - ascending), np.abs(curves_all - descending))
            index = int(np.argmax(np.nanmean(away, axis=(1, 2))))
        curves = h5["curves_mz"][index].astype(float)
        image = h5["images"][index]
        fields = h5["fields_T"][:]
        sample_id = int(h5["sample_id"][index])
    n = len(fields)
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4.2))
    for i in range(0, n, 2):
        left.plot(fields[i:], curves[i, i:], "--", color="0.25", lw=0.6)
    descending = np.diag(curves)
    left.plot(fields, descending, "-", color="tab:blue", lw=1.6, label="major loop")
    left.plot(fields, curves[0], "-", color="tab:blue", lw=1.6)  # ascending: the FORC from -B_max
    # highlight the minor loop whose reversal field is nearest the coercive field
    k = int(np.argmin(np.abs(descending)))
    left.plot(fields[k:], curves[k, k:], "-", color="tab:red", lw=2.0, label=f"FORC at $\\mu_0H_r$={fields[k]:+.2f} T")
    left.set_xlabel(r"$\mu_0 H$ (T)")
    left.set_ylabel(r"$\langle m_z \rangle$")
    left.set_title(f"(a) FORC family, sample {sample_id}")
    left.legend(loc="lower right", fontsize=8)
    right.imshow(image, origin="lower", cmap="gray", extent=[fields[0], fields[-1], fields[0], fields[-1]])
    right.set_xlabel(r"$\mu_0 H$ (T)")
    right.set_ylabel(r"$\mu_0 H_r$ (T)")
    right.set_title(f"(b) {n}×{n} image (uint8)")
    fig.tight_layout()
    with io.atomic_path(out_path) as tmp:
        fig.savefig(tmp, dpi=150, format="png")
    plt.close(fig)
