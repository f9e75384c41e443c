"""``forcdecode read FILE [--json] [--no-drift-correction] [--allow-incomplete]``."""

from __future__ import annotations

import argparse
import json

from .reader import read_forc


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="measured FORC file (format found by content)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (fields in T, moments in A m^2; "
                             "moment_max_Am2 is the largest |moment| on the curves)")
    parser.add_argument("--no-drift-correction", action="store_true",
                        help="leave the moments as measured (no calibration-point correction)")
    parser.add_argument("--allow-incomplete", action="store_true",
                        help="read a truncated file (fewer curves than declared, no end marker) "
                             "instead of failing; the summary says complete: false")


def run(args: argparse.Namespace) -> int:
    # an unreadable or malformed file raises InputFileError: forcdecode.cli prints it, exit code 2
    measurement = read_forc(args.file, drift_correction=not args.no_drift_correction,
                            allow_incomplete=args.allow_incomplete)
    summary = measurement.summary()
    if args.json:
        print(json.dumps(summary))
        return 0

    def fmt(value, unit: str = "") -> str:
        return "n/a" if value is None else f"{value:.6g}{unit}"

    declared = f" (declared: {summary['units_declared']})" if summary["units_declared"] else ""
    count = f"{summary['n_curves']} curves"
    if summary["n_curves_header"] is not None:
        count += f" (header: {summary['n_curves_header']})"
    drift = fmt(summary["drift_percent"], " %")
    drift += ", corrected" if summary["drift_corrected"] else ", not corrected"
    lines = [
        f"{summary['source']}",
        f"  format        {summary['format']}",
        f"  units         {summary['units']}{declared}",
        f"  curves        {count}, {summary['n_points']} points"
        f" + {summary['n_calibration_points']} calibration points",
        f"  field         {fmt(summary['field_min_T'], ' T')} .. "
        f"{fmt(summary['field_max_T'], ' T')}",
        f"  reversal      {fmt(summary['reversal_field_min_T'], ' T')} .. "
        f"{fmt(summary['reversal_field_max_T'], ' T')}",
        f"  max |moment|  {fmt(summary['moment_max_Am2'], ' A m^2')}",
        f"  drift         {drift}",
    ]
    if not summary["complete"]:
        lines.append("  WARNING       file is incomplete (read with --allow-incomplete)")
    print("\n".join(lines))
    return 0
