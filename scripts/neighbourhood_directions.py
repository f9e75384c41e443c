"""How far the Hamiltonian moved along each direction its decode leaves open explains a file's residual,
beside the physics candidates (issue 59, docs/loop.md "A physics candidate against every direction the
decode leaves open").

For each FILE:REPORT (an instrument file and the report.json of a ``forcdecode loop`` run on it): the
decoded Hamiltonian re-simulated (20 profiles, as the loop), the physics candidates' families and the
neighbourhood's (``physics_effects.decode_neighbourhood`` of the report's prediction, one family per
value on the re-simulation's first disorder profile), and the held-out RMS (every 4th curve held out in
turn, the loop's split) of: no change, each physics candidate, each direction alone, and the neighbourhood
(the best direction chosen on each fold's training curves, ``fit_neighbourhood``). About 3 minutes a file
on one core. ``--all-parameters``: every decoded parameter moved (N_pin and those not read for the file
too) to the edges of its 90 % interval, and of its 68 % interval where read: the rule of 30178cd, before
the directions the file does not carry were dropped (docs/loop.md).

    .venv/bin/python scripts/neighbourhood_directions.py [--all-parameters] DIR/laptop-dev-020-bias_field.csv:LOOP/report.json ...
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from forcdecode.infer.resimulate import resimulate
from forcdecode.loop.command import load_config
from forcdecode.loop.effects import heldout_folds, heldout_mse
from forcdecode.loop.measured_loop import read_domain
from forcdecode.loop.physics_effects import (decode_neighbourhood, fit_interpolated_effect, fit_neighbourhood,
                                             physics_candidate_families)

EVERY_K = 4


def _rms(measured, model_of_rows, folds) -> float:
    return float(np.sqrt(np.nanmean(heldout_mse(measured, model_of_rows, folds))))


def every_parameter(prediction: dict, params: dict) -> tuple:
    """30178cd's neighbourhood: every decoded parameter (N_pin and those not read for this file too) to the
    edges of its 90 % interval, and of its 68 % interval where read for this file."""
    values = []
    for name in ("K_u", "D", "A_ex", "N_pin", "sigma_K", "sigma_theta_deg"):
        entry = prediction.get(name)
        if not isinstance(entry, dict) or name not in params or entry.get("interval_90") is None:
            continue
        edges = list(entry["interval_90"]) + (list(entry["interval_68"]) if entry.get("read_for_this_file") else [])
        for v in sorted(float(e) for e in edges):
            v = float(round(v)) if name == "N_pin" else v
            if v != float(params[name]) and (name, v) not in values:
                values.append((name, v))
    return tuple(values)


def floor_lines(report: dict) -> list[str]:
    """From the loop's report: the neighbourhood it used, its relative held-out gain on the file and on each
    effect-free film of the realisation floor (``patches.null_gain_per_film``, key "K_u change")."""
    analysis = report.get("analysis") or {}
    h = analysis.get("hamiltonian_neighbourhood") or {}
    none = (analysis.get("candidates") or {}).get("none", {}).get("heldout_rms")
    if not h or not none:
        return ["  (the report holds no neighbourhood)"]
    films = [g.get("K_u change", {}).get("relative") for g in (report.get("patches") or {}).get("null_gain_per_film") or []]
    films = [f for f in films if f is not None]
    gain = 1 - h["heldout_rms"] ** 2 / none**2
    return [f"  the report's neighbourhood ({h.get('parameter', 'K_u')}): relative gain {gain:.3f} on the file, "
            f"{max(films):.3f} at most on {len(films)} effect-free films" if films else
            f"  the report's neighbourhood: relative gain {gain:.3f} on the file (no floor recorded)"]


def directions_table(path: str, report_path: str, all_parameters: bool = False) -> list[str]:
    """The lines printed for one file."""
    cfg = load_config()
    report = json.loads(open(report_path).read())
    params, prediction = report["parameters"], report.get("prediction") or {}
    measurement, _ = read_domain(path, cfg)
    measured = measurement.family
    base = resimulate(cfg, params, n_profiles=20, key="measured")
    values = (every_parameter if all_parameters else decode_neighbourhood)(prediction, params)
    families = physics_candidate_families(cfg, params, hamiltonian_values=values)
    reference = families["physics_reference_family"]
    on_base = {name: {v: base + (f - reference) for v, f in nodes.items()}
               for name, nodes in families["hamiltonian_families"].items()}
    physics = {name: {v: base + (f - reference) for v, f in nodes.items()}
               for name, nodes in families["physics_families"].items()}
    folds = heldout_folds(measured, EVERY_K, True)
    lines = [f"{path}"] + floor_lines(report)
    lines.append(f"  no change: held-out RMS {_rms(measured, lambda rows: base, folds):.4f}")
    for name, nodes in physics.items():
        rms = _rms(measured, lambda rows, nodes=nodes: fit_interpolated_effect(measured, nodes, base, rows)["model"],
                   folds)
        lines.append(f"  physics {name}: {rms:.4f}")
    everything = list(range(len(measured)))
    for name, nodes in on_base.items():
        rms = _rms(measured, lambda rows, nodes=nodes: fit_interpolated_effect(measured, nodes, base, rows)["model"],
                   folds)
        change = fit_interpolated_effect(measured, nodes, base, everything)["value"]
        lines.append(f"  direction {name} (nodes {sorted(v + float(params[name]) for v in nodes)}): {rms:.4f}, "
                     f"change {change:+.4g} from {params[name]:.4g} on all curves")
    rms = _rms(measured, lambda rows: fit_neighbourhood(measured, on_base, base, rows)["model"], folds)
    best = fit_neighbourhood(measured, on_base, base, everything)
    lines.append(f"  neighbourhood (best direction per fold): {rms:.4f}; on all curves {best['direction']} "
                 f"{best['value']:+.4g}")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", metavar="FILE:REPORT")
    parser.add_argument("--all-parameters", action="store_true",
                        help="move every decoded parameter (30178cd's neighbourhood), not only those read for the file")
    args = parser.parse_args(argv)
    for item in args.files:
        path, _, report_path = item.rpartition(":")
        if not path:
            parser.error(f"{item!r}: give FILE:REPORT")
        print("\n".join(directions_table(path, report_path, args.all_parameters)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
