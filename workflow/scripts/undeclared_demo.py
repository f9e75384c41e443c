"""Demonstration of the closed loop on a simulated "measured" file with an undeclared effect.

Takes a test-split sample of the dataset, writes its FORC family as a PMC MicroMag 0015 file with a
substrate background (χ = 0.1 of the film moment per tesla) and 0.3 % noise, and runs
`forcdecode loop` on it with the trained models (the effect is not declared anywhere).

    python workflow/scripts/undeclared_demo.py results/dataset.h5 results/learn/K_u_predictions.parquet OUT_DIR
"""

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pandas as pd

from forcdecode.loop.instrument import simulated_instrument_curves
from forcdecode.measured.writers import write_micromag_0015

dataset, predictions, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
out.mkdir(parents=True, exist_ok=True)
frame = pd.read_parquet(predictions)
sample = int(frame.loc[frame["split"] == "test", "sample_id"].iloc[0])
with h5py.File(dataset, "r") as h5:
    ids = list(h5["sample_id"][:])
    k = ids.index(sample)
    family, fields = h5["curves_mz"][k].astype(float), h5["fields_T"][:]
    columns = list(h5["parameters"].attrs["columns"])
    Ms = float(h5["parameters"][k, columns.index("Ms")])
family = np.where(np.tril(np.ones_like(family), -1).astype(bool), np.nan, family)
reversal, curves = simulated_instrument_curves(family, fields, 1e-8, background_chi_per_T=0.1, noise=0.003,
                                               rng=np.random.default_rng(1))
path = write_micromag_0015(out / f"sample_{sample}_background.frc", reversal, curves)
print(f"sample {sample}, M_s {Ms / 1e3:.0f} kA/m -> {path}", flush=True)
sys.exit(subprocess.call([sys.executable, "-m", "forcdecode.cli", "loop", str(path), "--out", str(out / "loop"),
                          "--Ms-kA-m", f"{Ms / 1e3:.3f}", "--profiles", "4", *sys.argv[4:]]))
