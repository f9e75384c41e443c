"""The closed loop on one measured (or simulated-as-measured) FORC file.

Reads the file, puts the family on the training grid (normalized by its saturation moment, flagged
out of domain if it does not span ±B_max or does not saturate), takes the given Hamiltonian (SI) or
predicts it with the trained Alice networks, sweeping M_s when it is not given and keeping the M_s
whose re-simulation is closest to the measurement; re-simulates it averaged over pinning profiles,
and traces the residual on the raw curves to an effect the model lacks (measured-side and
physics-side candidates, chosen on held-out curves: ``physics_effects.analyse_residual``). Writes
OUT/report.json, OUT/report.md and figures (fields μ0H in T, m normalized).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.io import atomic_path, write_json, write_text
from ..core.progress import counter, progress, say


def _progress(text):
    say(text)  # timestamped on stderr; on a terminal, above the progress bar


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
    for k, ms in enumerate(progress(ms_values, desc="M_s sweep", unit="values")):
        prediction = predict_parameters(models, image, ms)
        params = hamiltonian(prediction)
        resim = resimulate(cfg, params, n_profiles=n_profiles)
        rms = observation_error(family, resim)["rms"]
        rows.append({"Ms": float(ms), "prediction": prediction, "params": params, "observation_rms": rms,
                     "family": resim, "n_profiles": n_profiles})
        log(f"M_s {ms / 1e3:.0f} kA/m ({k + 1}/{len(ms_values)}): observation RMS {rms:.4f}")
    best = min(rows, key=lambda r: r["observation_rms"])
    return best, rows


def close_loop_on_file(path, out, cfg: dict, *, params: dict | None = None, models_dir="results/models",
                       ms_values_A_per_m=None, profiles: int = 20, sweep_profiles: int = 2, every_k: int = 4,
                       physics: bool = True, force: bool = False, log=_progress) -> dict:
    """Run the closed loop on the measured file ``path`` with the validated config ``cfg``; writes
    ``out``/report.json, report.md and figures and returns the report.

    ``params``: a Hamiltonian (SI) to re-simulate instead of predicting one with the models of
    ``models_dir``; ``ms_values_A_per_m``: M_s values tried (one: known M_s; several: swept, each
    re-simulated with ``sweep_profiles`` profiles). ``profiles``: profiles of the final
    re-simulation. A file out of the training domain is reported and not analysed unless ``force``.
    Raises InputFileError for an unreadable file, ModelFileError for missing models."""
    from ..forc.raster import measurement_on_grid
    from ..measured import read_forc

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    data = read_forc(path)
    B_max, n = cfg["field"]["B_max_T"], cfg["field"]["n_fields"]
    image, family, domain_note, moment_saturation = measurement_on_grid(data, B_max, n)
    report = {"file": str(path), "format": data.format, "n_curves": len(data.curves),
              "drift_percent": data.drift_percent, "moment_saturation_Am2": moment_saturation,
              "in_domain": domain_note is None, "out_of_domain_reason": domain_note}
    if domain_note is not None and not force:
        report["status"] = "out of domain"
        write_json(out / "report.json", report)
        write_text(out / "report.md", f"# {Path(path).name}\n\n**Out of the training domain**: {domain_note}.\n\n"
                                       "The networks were trained on ±1 T perpendicular-film FORCs; no prediction is made.\n")
        return report
    from .physics_effects import analyse_residual, physics_candidate_families
    from .resimulate import observation_error, resimulate

    fields = np.linspace(-B_max, B_max, n)
    resim = None  # the final re-simulation, unless the prediction step already made it
    if params is not None:
        report.update(parameters=params, Ms_source="given (--params)")
    else:
        from ..learn.predictor import load_models

        models = load_models(models_dir)
        ms_values = list(ms_values_A_per_m if ms_values_A_per_m is not None else np.linspace(470e3, 1400e3, 6))
        best, sweep = predict_and_sweep(cfg, models, image, family, ms_values,
                                        sweep_profiles if len(ms_values) > 1 else profiles, log=log)
        params = best["params"]
        report.update(parameters=params, prediction=best["prediction"], Ms_chosen_A_per_m=best["Ms"],
                      Ms_source="given" if len(ms_values) == 1 else "swept",
                      Ms_sweep=[{"Ms": r["Ms"], "observation_rms": r["observation_rms"]} for r in sweep])
        if best["n_profiles"] == profiles:
            resim = best["family"]
    if resim is None:
        resim = resimulate(cfg, params, n_profiles=profiles,
                           progress=counter("re-simulation", "profiles"))
    error = observation_error(family, resim)
    candidates = (physics_candidate_families(cfg, params, progress=counter("physics-side candidates", "families"))
                  if physics else {})
    analysis = analyse_residual(family, resim, fields, every_k=every_k, seed=cfg["seed"], **candidates)
    residual = family - resim
    report.update(status="analysed", observation_rms=error["rms"],
                  per_curve_rms=[None if not np.isfinite(v) else float(v) for v in error["per_curve"]],
                  effect=analysis["chosen"], analysis=_json_ready(analysis),
                  heldout_rms_before=analysis["heldout_rms_before"], heldout_rms_after=analysis["heldout_rms_after"])
    write_json(out / "report.json", _json_ready(report))
    _figures(out, fields, family, resim, residual, analysis.get("arrays", {}).get("residual_after"))
    write_text(out / "report.md", _markdown(path, report, analysis))
    return report


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
    with atomic_path(out / "families.png") as tmp:
        fig.savefig(tmp, dpi=130, format="png")
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
    with atomic_path(out / "residual.png") as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    plt.close(fig)
