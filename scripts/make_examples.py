"""Write the example files in examples/ (issue 60 item 3): simulated FORC measurements a newcomer can run
`forcdecode loop` on minutes after install, each with its truth beside it.

    .venv/bin/python scripts/make_examples.py [--out examples]

Each example is the laptop film of config/config.yaml (64 x 64 x 1 cells of 2 x 2 x 4 nm, 16 grains) at a
Hamiltonian of the perpendicular class, simulated by our own engine on a MicroMag-style protocol off the
training grid (40 curves over +-1 T, reversal fields shifted by 0.37 of a step, points every half step,
the field swept on 2 mT nodes), averaged over 8 disorder realisations (stream closed_loop_disorder, key
"example"), with 0.3 % white noise of the saturation moment, written in an instrument format:

- control.frc (MicroMag 0015): no effect.
- background.csv (Lake Shore 8600 CSV): the same film with a declared linear background of
  0.05 M_sat per tesla (a substrate's diamagnet or paramagnet), the commonest instrument effect.

These are made by the model the loop uses, so they show what the tool prints, not how well it does:
the loop's accuracy is judged on an independent code's films (`forcdecode bench effects --independent`).
Cost: 8 realisations of one family, about 1-2 min on one core.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from forcdecode.config import load_config, shipped_config
from forcdecode.core.streams import stream_rng
from forcdecode.infer.resimulate import resimulate_measured
from forcdecode.measured.writers import write_lakeshore_csv, write_micromag_0015
from forcdecode.micromag.build import mesh_from_config

HAMILTONIAN = {"Ms": 8.0e5, "A_ex": 1.3e-11, "K_u": 7.0e5, "D": 1.0e-3, "N_pin": 40, "sigma_theta_deg": 5.0,
               "sigma_K": 0.1}
"""The example film (SI): K_eff = K_u - mu0 Ms^2/2 = 2.98e5 J/m^3 > 0 (perpendicular), Q = 1.74."""

CURVES, SHIFT, PATCHES, NOISE, CHI_PER_T = 40, 0.37, 8, 0.003, 0.05


def protocol(n_curves: int = CURVES, B_max_T: float = 1.0, shift: float = SHIFT):
    """Reversal fields on a lattice of spacing 2 B_max/n shifted by ``shift`` of a step, points every half
    step from each reversal field up to the top lattice point (as a MicroMag FORC script)."""
    spacing = 2 * B_max_T / n_curves
    reversal = -B_max_T + (np.arange(n_curves) + shift) * spacing
    top = reversal[-1] + np.floor((B_max_T - reversal[-1]) / (spacing / 2) + 1e-9) * spacing / 2
    return reversal, [h + np.arange(int(np.rint((top - h) / (spacing / 2))) + 1) * spacing / 2 for h in reversal]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="examples")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_config(shipped_config("config"))
    reversal, fields = protocol()
    m = resimulate_measured(cfg, HAMILTONIAN, reversal, fields, n_profiles=PATCHES, key="example", max_step_T=0.002)
    mesh = mesh_from_config(cfg)
    moment = HAMILTONIAN["Ms"] * mesh.n_cells * mesh.cell_volume  # A m^2 of the simulated box
    rng = stream_rng(cfg["seed"], "instrument_noise", "examples", 0)
    truth = {"hamiltonian_SI": HAMILTONIAN, "Ms_kA_m": HAMILTONIAN["Ms"] / 1e3, "thickness_nm": cfg["mesh"]["dz_nm"],
             "film": "config/config.yaml (laptop default: 64 x 64 x 1 cells of 2 x 2 x 4 nm, 16 grains)",
             "engine": "forcdecode's own (the model the loop uses: an example, not a test)",
             "patches_averaged": PATCHES, "noise_of_saturation_moment": NOISE, "curves": CURVES,
             "made_by": "scripts/make_examples.py"}
    files = {"control.frc": ({}, write_micromag_0015), "background.csv": ({"background": {"chi_per_T": CHI_PER_T}},
                                                                          write_lakeshore_csv)}
    for name, (effect, writer) in files.items():
        chi = effect.get("background", {}).get("chi_per_T", 0.0)
        curves = [(f, moment * (c + chi * f + NOISE * rng.normal(size=f.size))) for f, c in zip(fields, m)]
        writer(out / name, reversal, curves, sample_name=f"forcdecode example: {name}")
        (out / f"{Path(name).stem}.truth.json").write_text(
            json.dumps({**truth, "file": name, "effect": effect or "none"}, indent=2) + "\n")
        print(f"wrote {out / name} (effect: {effect or 'none'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
