"""The saturated film's background evidence of instrument files, without running the loop (issue 59,
docs/loop.md "The background where the decoded film is not saturated").

For each FILE: the file's own saturated branches past its closure, read with the law of approach
(``signatures.file_saturated_points``, ``background_evidence``'s fallback); with FILE:REPORT (a loop's
report.json of that file) also the evidence the loop reads, against the decoded Hamiltonian's saturated
film (``refit.measured_saturation``: 8 major loops of that Hamiltonian, a few seconds each). The truth is
printed where a bench case's JSON lies beside the file (``scripts/dev_case_file.py`` writes it).

    .venv/bin/python scripts/background_evidence_files.py DIR/laptop-dev-007-background.csv[:LOOP/report.json] ...
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from forcdecode.loop.command import load_config
from forcdecode.loop.measured_loop import read_domain
from forcdecode.loop.refit import measured_saturation
from forcdecode.loop.signatures import background_evidence, file_saturated_points, measured_point_arrays


def _line(label: str, evidence: dict) -> str:
    if evidence.get("chi_per_T") is None:
        return f"  {label}: no evidence ({evidence.get('reason', '')})"
    return (f"  {label}: χ {evidence['chi_per_T']:+.4f} ± {evidence['se_per_T']:.4f} per T "
            f"({evidence['chi_per_T'] / evidence['se_per_T']:+.1f} se), significant {evidence['significant']}, "
            f"sides agree {evidence.get('sides_agree')}, form p {evidence.get('linear_p')}; "
            f"against {evidence.get('reference')}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", help="FILE or FILE:REPORT.json")
    args = parser.parse_args()
    cfg = load_config(None)
    for item in args.files:
        path, _, report = item.partition(":")
        measurement, _ = read_domain(path, cfg)
        points = measured_point_arrays(measurement.data, measurement.moment_saturation,
                                       measurement.domain.moment_offset_Am2)
        case = Path(path).with_suffix(".json")
        truth = json.loads(case.read_text())["case"]["instrument"] if case.exists() else "unknown"
        own = file_saturated_points(points)
        print(f"{Path(path).name}: truth {truth}; the file's own closure "
              f"{np.round(own.closure_T, 3).tolist() if own is not None else 'none'}", flush=True)
        if own is not None:
            print(_line("file only", background_evidence(own)), flush=True)
        if report:
            params = json.loads(Path(report).read_text())["parameters"]
            print(_line("the loop's", background_evidence(measured_saturation(cfg, params, points))), flush=True)


if __name__ == "__main__":
    main()
