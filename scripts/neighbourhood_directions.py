"""How far the Hamiltonian moved along each direction its decode leaves open explains a file's residual,
beside the physics candidates (issue 59, docs/loop.md "A physics candidate against every direction the
decode leaves open").

For each FILE:REPORT (an instrument file and the report.json of a ``forcdecode loop`` run on it): the
decoded Hamiltonian re-simulated (20 profiles, as the loop), the physics candidates' families and the
neighbourhood's (``physics_effects.decode_neighbourhood`` of the report's prediction, one family per
value on the re-simulation's first disorder profile), and the held-out RMS (every 4th curve held out in
turn, the loop's split) of: no change, each physics candidate, each direction alone, and the neighbourhood
(the best direction chosen on each fold's training curves, ``fit_neighbourhood``). About 3 minutes a file
on one core.

    .venv/bin/python scripts/neighbourhood_directions.py DIR/laptop-dev-020-bias_field.csv:LOOP/report.json ...
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


def directions_table(path: str, report_path: str) -> list[str]:
    """The lines printed for one file."""
    cfg = load_config()
    report = json.loads(open(report_path).read())
    params, prediction = report["parameters"], report.get("prediction") or {}
    measurement, _ = read_domain(path, cfg)
    measured = measurement.family
    base = resimulate(cfg, params, n_profiles=20, key="measured")
    values = decode_neighbourhood(prediction, params)
    families = physics_candidate_families(cfg, params, hamiltonian_values=values)
    reference = families["physics_reference_family"]
    on_base = {name: {v: base + (f - reference) for v, f in nodes.items()}
               for name, nodes in families["hamiltonian_families"].items()}
    physics = {name: {v: base + (f - reference) for v, f in nodes.items()}
               for name, nodes in families["physics_families"].items()}
    folds = heldout_folds(measured, EVERY_K, True)
    lines = [f"{path}", f"  no change: held-out RMS {_rms(measured, lambda rows: base, folds):.4f}"]
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
    args = parser.parse_args(argv)
    for item in args.files:
        path, _, report_path = item.rpartition(":")
        if not path:
            parser.error(f"{item!r}: give FILE:REPORT")
        print("\n".join(directions_table(path, report_path)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
