"""The loop's pool sub-step, chosen on the laptop bench's dev set (issue 59 item 4): single realisations
of a dev case's Hamiltonian on its file's protocol (``reference.independent.measurement_protocol``: the
case's curves and shift, points every half reversal spacing), swept with field sub-steps of at most
2 mT (the pool's default until 2026-12-02; 1 mT to see whether 2 mT is converged), 5, 10 and 20 mT, and the file's own points (no sub-steps),
at the same disorder. Prints per case the RMS (m in units of M_s, over every measured point) between each coarse
sweep and the 2 mT one, beside the RMS between two disorder realisations swept at 2 mT (the realisation
spread the pool exists to measure), and the seconds each sweep took.

    .venv/bin/python scripts/choose_pool_step.py [--cases 12]      (about 1-2 min per case on one core)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from forcdecode.bench.laptop_cases import load_cases
from forcdecode.config import load_config, shipped_config
from forcdecode.core.streams import stream_rng
from forcdecode.infer.resimulate import DISORDER_STREAM, simulate_measured
from forcdecode.reference.independent import measurement_protocol

STEPS = {"2 mT": 0.002, "1 mT": 0.001, "5 mT": 0.005, "10 mT": 0.010, "20 mT": 0.020, "file's points": None}


def _points(family) -> np.ndarray:
    return np.concatenate([np.asarray(c, float) for c in family.curves])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=12, help="the first N dev cases (default 12)")
    args = parser.parse_args()
    cfg = load_config(shipped_config("config"))
    rows = []
    for case in load_cases("dev")[: args.cases]:
        params = {**case["hamiltonian"], **case.get("physics", {})}
        reversal, fields = measurement_protocol(case["protocol"]["curves"], 1.0, case["protocol"]["shift"])
        fields = [np.concatenate([[h], f[1:]]) for h, f in zip(reversal, fields)]
        sweeps, seconds = {}, {}
        for k in range(2):
            for label, step in STEPS.items():
                if k == 1 and label != "2 mT":
                    continue
                start = time.perf_counter()
                family = simulate_measured(cfg, params, stream_rng(cfg["seed"], DISORDER_STREAM, "pool_step", k),
                                           reversal, fields, max_step_T=step)
                seconds[(label, k)] = time.perf_counter() - start
                sweeps[(label, k)] = _points(family)
        base = sweeps[("2 mT", 0)]
        spread = float(np.sqrt(np.mean((sweeps[("2 mT", 1)] - base) ** 2)))
        row = {"case": case["name"], "N_pin": params["N_pin"], "realisation_rms": spread}
        for label in STEPS:
            row[f"rms[{label}]"] = float(np.sqrt(np.mean((sweeps[(label, 0)] - base) ** 2)))
            row[f"s[{label}]"] = seconds[(label, 0)]
        rows.append(row)
        print("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    for label in STEPS:
        rms = np.array([r[f"rms[{label}]"] for r in rows])
        ratio = rms / np.array([r["realisation_rms"] for r in rows])
        cost = np.array([r[f"s[{label}]"] for r in rows])
        print(f"{label}: RMS against 2 mT median {np.median(rms):.3g} (max {rms.max():.3g}); "
              f"/ realisation spread median {np.median(ratio):.3g} (max {ratio.max():.3g}); "
              f"seconds per single median {np.median(cost):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
