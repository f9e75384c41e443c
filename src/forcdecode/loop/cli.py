"""``forcdecode loop FILE --out DIR``: close the loop on a measured (or simulated-as-measured) file.

Reads the file, puts the family on the training grid (normalized by its saturation moment, flagged
out of domain if it does not span ±B_max or does not saturate), takes the Hamiltonian (``--params``
JSON with M_s, A_ex, K_u, D, N_pin, σ_θ, σ_K) or predicts it with the trained Alice networks,
sweeping M_s when it is not given and keeping the M_s whose re-simulation is closest to the
measurement; re-simulates it averaged over pinning profiles, and traces the residual on the raw
curves to an effect the model lacks (measured-side and physics-side candidates, chosen on held-out
curves: ``physics_effects.analyse_residual``). Writes DIR/report.json, DIR/report.md and figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="measured FORC file (any format `forcdecode read` knows)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--models", default="results/models", help="trained Alice/Bob model files (<parameter>.pt)")
    parser.add_argument("--params", help="JSON file with a Hamiltonian to re-simulate (SI) instead of predicting one")
    parser.add_argument("--Ms-kA-m", dest="ms_kA_m", type=float, help="known M_s (kA/m): no sweep")
    parser.add_argument("--Ms-sweep-kA-m", dest="ms_sweep", type=float, nargs=3, default=[470.0, 1400.0, 6],
                        metavar=("LOW", "HIGH", "N"), help="M_s values swept when M_s is not known (default 470 1400 6)")
    parser.add_argument("--config", default=str(Path(__file__).resolve().parents[3] / "config" / "config.yaml"),
                        help="simulation config (grid, field window, minimizer)")
    parser.add_argument("--profiles", type=int, default=20, help="pinning profiles averaged in the final re-simulation")
    parser.add_argument("--sweep-profiles", type=int, default=2, help="pinning profiles per M_s during the sweep")
    parser.add_argument("--every-k", type=int, default=4, help="hold out every k-th curve")
    parser.add_argument("--no-physics", action="store_true", help="skip the physics-side candidates (K_2, bias, second phase)")
    parser.add_argument("--force", action="store_true", help="analyse even when the file is out of domain")


def load_config(path) -> dict:
    import yaml
    from snakemake.utils import validate

    cfg = yaml.safe_load(Path(path).read_text())
    schema = Path(__file__).resolve().parents[3] / "workflow" / "schemas" / "config.schema.yaml"
    validate(cfg, str(schema), set_default=True)
    return cfg


def _progress(text):
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def _json_ready(obj):
    if isinstance(obj, dict):
        return {str(k): _json_ready(v) for k, v in obj.items() if k != "arrays"}
    if isinstance(obj, (list, tuple)):
        return [_json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_ready(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def predict_and_sweep(cfg, models, image, family, ms_values, n_profiles, log=_progress):
    """Predict the Hamiltonian at each M_s, re-simulate it, keep the M_s whose family is closest to
    the measured one (observation-space RMS). Returns (best, sweep rows); each row keeps its
    re-simulated ``family`` and ``n_profiles``."""
    from ..learn.predictor import hamiltonian, predict_parameters
    from .resimulate import observation_error, resimulate

    rows = []
    for k, ms in enumerate(ms_values):
        prediction = predict_parameters(models, image, ms)
        params = hamiltonian(prediction)
        resim = resimulate(cfg, params, n_profiles=n_profiles)
        rms = observation_error(family, resim)["rms"]
        rows.append({"Ms": float(ms), "prediction": prediction, "params": params, "observation_rms": rms,
                     "family": resim, "n_profiles": n_profiles})
        log(f"M_s {ms / 1e3:.0f} kA/m ({k + 1}/{len(ms_values)}): observation RMS {rms:.4f}")
    best = min(rows, key=lambda r: r["observation_rms"])
    return best, rows


def run(args) -> int:
    from ..dataset.io import write_json
    from ..forc.raster import measurement_on_grid
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
    image, family, domain_note, moment_saturation = measurement_on_grid(data, B_max, n)
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
    from .physics_effects import analyse_residual, physics_candidate_families
    from .resimulate import observation_error, resimulate

    fields = np.linspace(-B_max, B_max, n)
    resim = None  # the final re-simulation, unless the prediction step already made it
    if args.params:
        params = json.loads(Path(args.params).read_text())
        report.update(parameters=params, Ms_source="given (--params)")
    else:
        from ..learn.predictor import load_models

        models = load_models(args.models)
        if args.ms_kA_m is not None:
            ms_values = [args.ms_kA_m * 1e3]
        else:
            low, high, count = args.ms_sweep
            ms_values = list(np.linspace(low * 1e3, high * 1e3, max(1, int(count))))
        best, sweep = predict_and_sweep(cfg, models, image, family, ms_values,
                                        args.sweep_profiles if len(ms_values) > 1 else args.profiles)
        params = best["params"]
        report.update(parameters=params, prediction=best["prediction"], Ms_chosen_A_per_m=best["Ms"],
                      Ms_source="given" if len(ms_values) == 1 else "swept",
                      Ms_sweep=[{"Ms": r["Ms"], "observation_rms": r["observation_rms"]} for r in sweep])
        if best["n_profiles"] == args.profiles:
            resim = best["family"]
    if resim is None:
        resim = resimulate(cfg, params, n_profiles=args.profiles,
                           progress=lambda p, total: _progress(f"re-simulation {p}/{total}"))
    error = observation_error(family, resim)
    candidates = {} if args.no_physics else physics_candidate_families(cfg, params)
    analysis = analyse_residual(family, resim, fields, every_k=args.every_k, **candidates)
    residual = family - resim
    report.update(status="analysed", observation_rms=error["rms"],
                  per_curve_rms=[None if not np.isfinite(v) else float(v) for v in error["per_curve"]],
                  effect=analysis["chosen"], analysis=_json_ready(analysis),
                  heldout_rms_before=analysis["heldout_rms_before"], heldout_rms_after=analysis["heldout_rms_after"])
    write_json(out / "report.json", _json_ready(report))
    _figures(out, fields, family, resim, residual, analysis.get("arrays", {}).get("residual_after"))
    (out / "report.md").write_text(_markdown(args.file, report, analysis))
    print(f"effect: {analysis['chosen']}; held-out RMS {analysis['heldout_rms_before']:.4f} -> "
          f"{analysis['heldout_rms_after']:.4f}; report in {out}")
    return 0


def _markdown(path, report, analysis) -> str:
    lines = [f"# Closed loop: {Path(path).name}", "",
             f"Format {report['format']}, {report['n_curves']} curves, drift {report['drift_percent']:.2f} %.", ""]
    prediction = report.get("prediction")
    if prediction:
        lines += [f"M_s {report['Ms_chosen_A_per_m'] / 1e3:.0f} kA/m ({report['Ms_source']}).", "",
                  "| parameter | value | 68 % interval | 90 % interval | Bob's error (normalized) |", "|---|---|---|---|---|"]
        for name, e in prediction.items():
            if isinstance(e, dict):
                lines.append(f"| {name} | {e['value']:.4g} | {e['interval_68'][0]:.3g}–{e['interval_68'][1]:.3g} | "
                             f"{e['interval_90'][0]:.3g}–{e['interval_90'][1]:.3g} | {e['bob_error_normalized']:.3f} |")
        if len(report.get("Ms_sweep", [])) > 1:
            lines += ["", "M_s sweep: " + ", ".join(f"{r['Ms'] / 1e3:.0f} kA/m → {r['observation_rms']:.4f}" for r in report["Ms_sweep"])]
    lines += ["", f"Observation-space RMS error (all FORC points): {report['observation_rms']:.4f}.", "",
              f"**Effect chosen on held-out curves: {analysis['chosen']}** ({analysis.get('kind', '')}) "
              f"{_json_ready(analysis.get('parameters', {}))} ± {_json_ready(analysis.get('uncertainties', {}))}", "",
              f"Held-out RMS {analysis['heldout_rms_before']:.4f} → {analysis['heldout_rms_after']:.4f}"
              f" (reduction {_json_ready(analysis.get('heldout_reduction'))}, 90 % CI {_json_ready(analysis.get('heldout_reduction_ci90'))}).", "",
              "| candidate | held-out RMS | accepted |", "|---|---|---|"]
    for name, c in sorted(analysis["candidates"].items(), key=lambda kv: kv[1]["heldout_rms"]):
        lines.append(f"| {name} | {c['heldout_rms']:.4f} | {c.get('accepted', '')} |")
    lines += ["", "![families](families.png)", "", "![residual](residual.png)", ""]
    return "\n".join(lines)


def _figures(out, fields, measured, resim, residual, residual_after=None):
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
    if residual_after is not None:
        b.plot(fields, np.sqrt(np.nanmean(np.asarray(residual_after) ** 2, axis=1)), "s-", label="after the chosen effect")
        b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "residual.png", dpi=130)
    plt.close(fig)
