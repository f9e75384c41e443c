"""``forcdecode loop FILE --out DIR``: close the loop on a measured (or simulated-as-measured) file.

Reads the file, puts the family on the training grid (normalized by its saturation moment, flagged
out of domain if it does not span ±B_max or does not saturate), takes the Hamiltonian (``--params``
JSON with M_s, A_ex, K_u, D, N_pin, σ_θ, σ_K; predicted by the trained networks once they exist),
re-simulates it averaged over pinning profiles, and analyses the residual on the raw curves:
measured-side effects fitted and selected on held-out curves. Writes DIR/report.json, DIR/report.md
and figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="measured FORC file (any format `forcdecode read` knows)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--params", help="JSON file with the Hamiltonian to re-simulate (SI)")
    parser.add_argument("--config", default=str(Path(__file__).resolve().parents[3] / "config" / "config.yaml"),
                        help="simulation config (grid, field window, minimizer)")
    parser.add_argument("--profiles", type=int, default=20, help="pinning profiles averaged in the re-simulation")
    parser.add_argument("--every-k", type=int, default=4, help="hold out every k-th curve")
    parser.add_argument("--force", action="store_true", help="analyse even when the file is out of domain")


def load_config(path) -> dict:
    import yaml
    from snakemake.utils import validate

    cfg = yaml.safe_load(Path(path).read_text())
    schema = Path(__file__).resolve().parents[3] / "workflow" / "schemas" / "config.schema.yaml"
    validate(cfg, str(schema), set_default=True)
    return cfg


def run(args) -> int:
    from ..dataset.io import write_json
    from ..forc.raster import measured_image
    from ..measured import ForcFormatError, read_forc

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        data = read_forc(args.file)
    except (ForcFormatError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    cfg = load_config(args.config)
    B_max, n = cfg["field"]["B_max_T"], cfg["field"]["n_fields"]
    tops = [c.moment_Am2[np.argmax(c.field_T)] for c in data.curves]
    moment_saturation = float(np.median(tops))
    image, family, domain_note = measured_image([c.reversal_field_T for c in data.curves],
                                                [(c.field_T, c.moment_Am2) for c in data.curves],
                                                moment_saturation, B_max, n)
    report = {"file": str(args.file), "format": data.format, "n_curves": len(data.curves),
              "drift_percent": data.drift_percent, "moment_saturation_Am2": moment_saturation,
              "in_domain": domain_note is None, "out_of_domain_reason": domain_note}
    if domain_note is not None and not args.force:
        report["status"] = "out of domain"
        write_json(out / "report.json", report)
        (out / "report.md").write_text(f"# {Path(args.file).name}\n\n**Out of the training domain**: {domain_note}.\n\n"
                                       "The networks were trained on ±1 T perpendicular-film FORCs; no prediction is made.\n")
        print(f"{args.file}: out of domain ({domain_note}); report in {out}")
        return 0
    if not args.params:
        print("error: no Hamiltonian: give --params FILE.json (prediction by trained networks is not "
              "available in this version)", file=sys.stderr)
        return 2
    params = json.loads(Path(args.params).read_text())
    from . import resimulate
    from .effects import select_effect

    fields = np.linspace(-B_max, B_max, n)
    resim = resimulate(cfg, params, n_profiles=args.profiles,
                       progress=lambda p, total: print(f"re-simulation {p}/{total}", file=sys.stderr, flush=True))
    # curves were measured from high to low reversal field: that order is the drift clock
    order = np.linspace(1.0, 0.0, n)
    selection = select_effect(family, resim, fields, order, every_k=args.every_k)
    residual = family - resim
    report.update(status="analysed", parameters=params, effect=selection["chosen"],
                  effects={k: {kk: vv for kk, vv in v.items()} for k, v in selection["candidates"].items()},
                  heldout_rms_before=selection["heldout_rms_before"], heldout_rms_after=selection["heldout_rms_after"],
                  observation_rms=float(np.sqrt(np.nanmean(residual**2))),
                  per_curve_rms=[None if not np.isfinite(v) else float(v) for v in np.sqrt(np.nanmean(residual**2, axis=1))])
    write_json(out / "report.json", report)
    _figures(out, fields, family, resim, residual)
    chosen = selection["chosen"]
    (out / "report.md").write_text(
        f"# {Path(args.file).name}\n\nObservation-space RMS error {report['observation_rms']:.4f}. "
        f"Effect chosen on held-out curves: **{chosen}** "
        f"{selection['candidates'][chosen].get('parameters', '')}; held-out RMS {selection['heldout_rms_before']:.4f} → "
        f"{selection['heldout_rms_after']:.4f}.\n\n![families](families.png)\n\n![residual](residual.png)\n")
    print(f"effect: {chosen}; held-out RMS {selection['heldout_rms_before']:.4f} -> {selection['heldout_rms_after']:.4f}")
    return 0


def _figures(out, fields, measured, resim, residual):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for i in range(0, fields.size, 4):
        ax.plot(fields[i:], measured[i, i:], color="tab:red", lw=0.8)
        ax.plot(fields[i:], resim[i, i:], color="0.2", lw=0.8, ls="--")
    ax.set_xlabel(r"$\mu_0H$ (T)")
    ax.set_ylabel(r"$m$")
    ax.set_title("measured (red) vs re-simulated (dashed)")
    fig.tight_layout()
    fig.savefig(out / "families.png", dpi=130)
    plt.close(fig)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    vmax = np.nanmax(np.abs(residual)) or 1.0
    im = a.imshow(residual, origin="lower", cmap="RdBu_r", vmin=-vmax, vmax=vmax,
                  extent=[fields[0], fields[-1], fields[0], fields[-1]])
    a.set_xlabel(r"$\mu_0H$ (T)")
    a.set_ylabel(r"$\mu_0H_r$ (T)")
    a.set_title("residual m_measured − m_resimulated")
    fig.colorbar(im, ax=a)
    b.plot(fields, np.sqrt(np.nanmean(residual**2, axis=1)), "o-")
    b.set_xlabel(r"$\mu_0H_r$ (T)")
    b.set_ylabel("per-curve RMS")
    fig.tight_layout()
    fig.savefig(out / "residual.png", dpi=130)
    plt.close(fig)
