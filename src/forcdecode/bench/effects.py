"""Confusion table of the residual analysis on undeclared effects (``forcdecode bench effects``).

One small simulated film (16×16×1 cells, 32 grains, 32 fields over ±1 T; K_u = 4e5 J/m³,
M_s = 6e5 A/m) and its physics-side candidate families are simulated once. For every effect, size
and seed, a "measurement" is made from the film with that effect switched on (physics-side effects
by re-simulation, measured-side ones by a simulated instrument, noise 0.2 % of the film moment),
written as a MicroMag 0015 file, read back, put on the grid and analysed by
``loop.physics_effects.analyse_residual`` with every candidate, not told the effect.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from ..core.streams import stream_rng
from ..forc.raster import measured_image
from ..infer.resimulate import resimulate
from ..loop.instrument import simulated_instrument_curves
from ..loop.physics_effects import analyse_residual, physics_candidate_families
from ..measured import read_forc
from ..measured.writers import write_micromag_0015
from ..micromag.build import mesh_from_config

CONFIG = {"seed": 7, "n_grains": 32, "mesh": {"nx": 16, "ny": 16, "nz": 1, "dx_nm": 2.0, "dy_nm": 2.0, "dz_nm": 4.0},
          "field": {"B_max_T": 1.0, "n_fields": 32}, "minimizer": {"torque_tol_T": 0.003, "max_iterations": 5000},
          "pinning": {"treatment": "full", "scale_to_reference": False}}
PARAMS = {"Ms": 6e5, "A_ex": 2e-12, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 15.0, "sigma_K": 0.3}
GRIDS = {"K_2_ratios": (-0.2, -0.1, 0.1, 0.2, 0.3), "bias_fields_T": (-0.03, -0.02, -0.01, 0.01, 0.02, 0.03),
         "soft_K_u_ratios": (0.05, 0.1, 0.2, 0.3)}

# effect -> sizes; a size is the instrument settings (measured side) or the physics to switch on
SIZES = {
    "none": [{}],
    "background": [{"background_chi_per_T": c} for c in (0.001, 0.005, 0.02, 0.05, 0.1)],
    "field_offset": [{"field_offset_T": d} for d in (0.0003, 0.001, 0.002, 0.004, 0.008)],
    "additive_drift": [{"additive_drift": d} for d in (0.001, 0.003, 0.01, 0.03, 0.05)],
    "multiplicative_drift": [{"multiplicative_drift": d} for d in (0.001, 0.003, 0.01, 0.03, 0.05)],
    "scale": [{"scale": a} for a in (0.999, 0.995, 0.98, 0.95, 0.9)],
    "background+additive_drift": [{"background_chi_per_T": c, "additive_drift": d}
                                  for c, d in ((0.02, 0.01), (0.05, 0.03), (0.1, 0.05))],
    "background+multiplicative_drift": [{"background_chi_per_T": c, "multiplicative_drift": d}
                                        for c, d in ((0.02, 0.01), (0.05, 0.03), (0.1, 0.05))],
    "background+field_offset": [{"background_chi_per_T": c, "field_offset_T": d}
                                for c, d in ((0.02, 0.002), (0.05, 0.004), (0.1, 0.008))],
    "field_offset+scale": [{"field_offset_T": d, "scale": a} for d, a in ((0.002, 0.98), (0.004, 0.95), (0.008, 0.9))],
    "K_2": [{"K_2_over_K_u": r} for r in (0.1, 0.2, 0.25)],            # 0.25: between grid values
    "bias_field": [{"B_bias_T": b} for b in (0.01, 0.02, 0.025)],       # 0.025: between grid values
    "second_phase": [{"K_u_soft_over_K_u": r, "fraction": f}            # 0.15: between grid values
                     for r, f in ((0.1, 0.05), (0.1, 0.2), (0.15, 0.2))],
}

ABBREVIATIONS = {"background": "bg", "field_offset": "offset", "additive_drift": "add", "multiplicative_drift": "mul",
                 "second_phase": "phase2", "bias_field": "bias"}


def abbreviate(name: str) -> str:
    return "+".join(ABBREVIATIONS.get(part, part) for part in name.split("+"))


def _truth(base, size, cfg, resimulate):
    """The true family and the instrument settings of one case."""
    size = dict(size)
    if "K_2_over_K_u" in size:
        return resimulate(cfg, {**PARAMS, "K_2": size.pop("K_2_over_K_u") * PARAMS["K_u"]}), size
    if "B_bias_T" in size:
        return resimulate(cfg, {**PARAMS, "B_bias_T": size.pop("B_bias_T")}), size
    if "K_u_soft_over_K_u" in size:
        soft = resimulate(cfg, {**PARAMS, "K_u": size.pop("K_u_soft_over_K_u") * PARAMS["K_u"]})
        f = size.pop("fraction")
        return (1 - f) * base + f * soft, size
    return base, size


def n_cases(n_seeds: int, sizes=None) -> int:
    """The number of cases ``effects_confusion`` runs with ``n_seeds`` seeds (the control 4 × as many)."""
    return sum(len(values) * n_seeds * (4 if effect == "none" else 1) for effect, values in (sizes or SIZES).items())


def effects_confusion(seeds=range(3), sizes=None, noise: float = 0.002, progress=None) -> dict:
    """Run every (effect, size, seed) case (the control ``none`` with 4 × as many seeds); returns {"confusion": {true: {chosen: count}},
    "accuracy", "n_cases", "by_size": [...], "cases": [...], "setup_s", "analysis_s"}."""
    sizes = sizes or SIZES
    start = time.perf_counter()
    cfg = CONFIG
    n = cfg["field"]["n_fields"]
    fields = np.linspace(-1, 1, n)
    base = resimulate(cfg, PARAMS)
    candidates = physics_candidate_families(cfg, PARAMS, **GRIDS)
    mesh = mesh_from_config(cfg)
    moment = PARAMS["Ms"] * mesh.n_cells * mesh.cell_volume
    setup_s = time.perf_counter() - start
    table, rows = {}, []
    with tempfile.TemporaryDirectory() as tmp:
        for effect, values in sizes.items():
            for size in values:
                truth, instrument = _truth(base, size, cfg, resimulate)
                # the control gets four times the seeds: a false-alarm rate needs more cases
                for seed in (range(4 * len(seeds)) if effect == "none" else seeds):
                    reversal, curves = simulated_instrument_curves(truth, fields, moment, noise=noise,
                                                                   rng=stream_rng(seed, "instrument_noise", "bench"),
                                                                   **instrument)
                    data = read_forc(write_micromag_0015(Path(tmp) / "case.frc", reversal, curves))
                    _, measured, _ = measured_image(data.reversal_fields_T,
                                                    [(c.field_T, c.moment_Am2) for c in data.curves], moment, 1.0, n)
                    result = analyse_residual(measured, base, fields, seed=seed, **candidates)
                    chosen = result["chosen"]
                    table.setdefault(effect, {}).setdefault(chosen, 0)
                    table[effect][chosen] += 1
                    rows.append({"effect": effect, "size": size, "seed": seed, "chosen": chosen,
                                 "rms_before": result["heldout_rms_before"], "rms_after": result["heldout_rms_after"],
                                 "reduction": result["heldout_reduction"],
                                 "same_observable": chosen == effect or effect in result["same_observable_as"]})
                    if progress is not None:
                        progress(rows[-1])
    by_size = []
    for effect, values in sizes.items():
        for size in values:
            cases = [r for r in rows if r["effect"] == effect and r["size"] == size]
            by_size.append({"effect": effect, "size": size, "correct": sum(r["chosen"] == effect for r in cases),
                            "n": len(cases), "median_reduction": float(np.median([r["reduction"] for r in cases])),
                            "chosen": sorted({r["chosen"] for r in cases})})
    correct = sum(r["effect"] == r["chosen"] for r in rows)
    return {"confusion": table, "accuracy": correct / len(rows), "n_cases": len(rows), "by_size": by_size,
            "cases": rows, "setup_s": setup_s, "analysis_s": time.perf_counter() - start - setup_s}


def summary_lines(result: dict) -> list[str]:
    """The confusion table (true effect × chosen effect) and the per-size table, as printed lines."""
    lines = [f"residual analysis on undeclared effects (simulated film, MicroMag files): {result['accuracy']:.0%} "
             f"named correctly over {result['n_cases']} cases (setup {result['setup_s']:.0f} s, "
             f"analysis {result['analysis_s']:.0f} s)"]
    truths = list(result["confusion"])
    chosen = truths + sorted({c for row in result["confusion"].values() for c in row} - set(truths))
    lines.append("true \\ chosen".ljust(16) + "".join(abbreviate(n)[:9].rjust(10) for n in chosen))
    for true in truths:
        lines.append(abbreviate(true)[:15].ljust(16)
                     + "".join(str(result["confusion"][true].get(n, 0) or ".").rjust(10) for n in chosen))
    lines += ["", "effect".ljust(16) + "size".ljust(52) + "correct  median held-out cut  chosen"]
    for row in result["by_size"]:
        size = ", ".join(f"{k.replace('background_', '')}={v:g}" for k, v in row["size"].items()) or "-"
        lines.append(abbreviate(row["effect"])[:15].ljust(16) + size[:51].ljust(52)
                     + f"{row['correct']}/{row['n']}".ljust(9) + f"{row['median_reduction']:.0%}".rjust(18) + "  "
                     + ", ".join(map(abbreviate, row["chosen"])))
    return lines
