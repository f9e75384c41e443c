"""Where the loop's residual on an off-grid file comes from (docs/loop.md, 2026-12-02), on the example
control (examples/control.frc, its truth in examples/control.truth.json):

1. the grid protocol (one relaxation per 32 mT grid step) against a 2 mT sweep of the same realisation,
   compared on the grid: RMS per realisation (the protocol shortcut);
2. the example's 8-patch film simulated on the grid against the file put on the grid
   (``forc.raster.measurement_on_grid``), same disorder: the rasterization of an off-grid file.

    .venv/bin/python scripts/check_rasterization.py          (about 1-2 min on one core)
"""

import json
from pathlib import Path

import numpy as np

from forcdecode.config import load_config, shipped_config
from forcdecode.core.streams import stream_rng
from forcdecode.forc.measured_protocol import grid_protocol, protocol_to_grid
from forcdecode.forc.raster import measurement_on_grid
from forcdecode.infer.resimulate import DISORDER_STREAM, resimulate, simulate_family, simulate_measured
from forcdecode.measured import read_forc

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    cfg = load_config(shipped_config("config"))
    truth = json.loads((ROOT / "examples" / "control.truth.json").read_text())
    params, n = truth["hamiltonian_SI"], cfg["field"]["n_fields"]
    reversal, fields = grid_protocol(n, cfg["field"]["B_max_T"])
    for k in range(3):
        rng = lambda: stream_rng(cfg["seed"], DISORDER_STREAM, "check", k)  # noqa: E731
        grid = simulate_family(cfg, params, rng())
        swept = protocol_to_grid(simulate_measured(cfg, params, rng(), reversal, fields, max_step_T=0.002), n)
        print(f"realisation {k}: grid protocol against a 2 mT sweep, RMS {np.sqrt(np.nanmean((grid - swept) ** 2)):.2g}")
    film = resimulate(cfg, params, n_profiles=truth["patches_averaged"], key="example")
    data = read_forc(ROOT / "examples" / "control.frc")
    _, family, _, _, _ = measurement_on_grid(data, cfg["field"]["B_max_T"], n, with_domain=True)
    print(f"the example's film on the grid against the file put on the grid: RMS "
          f"{np.sqrt(np.nanmean((family - film) ** 2)):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
