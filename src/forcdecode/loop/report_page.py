"""The closed loop's report page: ``report.html`` beside report.md and report.json.

One self-contained page (figures embedded) a rock-magnetist can read: what was measured and what was
completed (domain), the Hamiltonian used, the measured and re-simulated FORC diagrams side by side on
one colour scale (Pike kernel, SF 3, m normalized), the residual map, the effect the analysis chose
with its fitted size and uncertainty, the held-out error before and after, and the verdict; for a
file out of the domain, why it stopped.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

import numpy as np

from ..core.io import atomic_path, write_text
from ..forc.diagram import ForcDiagram, forc_distribution, plot_diagram


def diagrams_figure(path, fields_T, measured, resimulated, smoothing_factor: int = 3) -> dict:
    """Measured and re-simulated FORC diagrams (grid families, m normalized) side by side on one colour
    scale, and their difference; returns the peak (H_c, H_u) in T and max ρ of each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    diagrams = {name: forc_distribution(fields_T, fields_T, fam, smoothing_factor=smoothing_factor, kernel="pike")
                for name, fam in (("measured", measured), ("re-simulated", resimulated))}
    finite = [np.abs(d.rho[np.isfinite(d.rho)]) for d in diagrams.values()]
    vmax = max((float(f.max()) for f in finite if f.size), default=1.0) or 1.0
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    peaks = {}
    for ax, (name, d) in zip(axes, diagrams.items()):
        try:
            plot_diagram(d, ax=ax, title=f"{name} (Pike, SF {smoothing_factor})", vmax=vmax)
        except ValueError:
            ax.set_title(f"{name}: no finite distribution")
        rho = np.where(np.isfinite(d.rho) & (d.coercive_T >= 0), d.rho, -np.inf)
        i, j = np.unravel_index(np.argmax(rho), rho.shape)
        peaks[name] = {"coercive_T": float(d.coercive_T[i, j]), "interaction_T": float(d.interaction_T[i, j]),
                       "rho_max": float(rho[i, j]) if np.isfinite(rho[i, j]) else float("nan")}

    diff = ForcDiagram(diagrams["measured"].reversal_fields_T, diagrams["measured"].fields_T,
                       diagrams["measured"].rho - diagrams["re-simulated"].rho, smoothing_factor, "pike")
    try:
        plot_diagram(diff, ax=axes[2], title="measured − re-simulated", vmax=vmax)
    except ValueError:
        axes[2].set_title("difference: no finite values")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return peaks


def _embed_images(body: str, directory: Path) -> str:
    """Replace <img src="x.png"> of files in ``directory`` by data URIs (one file to send or archive)."""
    def data_uri(match):
        src = match.group(1)
        path = directory / src
        if not path.exists():
            return match.group(0)
        encoded = base64.b64encode(path.read_bytes()).decode()
        return f'src="data:image/png;base64,{encoded}"'

    return re.sub(r'src="([^"/:]+\.png)"', data_uri, body)


def _summary_box(report: dict) -> str:
    rows = [("file", report.get("file")), ("status", report.get("status"))]
    if report.get("status") == "out of domain":
        rows.append(("why it stopped", report.get("out_of_domain_reason")))
    else:
        analysis = report.get("analysis", {})
        params, unc = analysis.get("parameters") or {}, analysis.get("uncertainties") or {}
        size = ", ".join(f"{k} = {v:.4g}" + (f" ± {unc[k]:.2g}" if isinstance(unc.get(k), (int, float)) else "")
                         for k, v in params.items() if isinstance(v, (int, float))) or "—"
        rows += [("verdict", report.get("verdict")), ("chosen effect", report.get("effect")), ("effect size", size),
                 ("held-out RMS before → after",
                  f"{report.get('heldout_rms_before', float('nan')):.4f} → {report.get('heldout_rms_after', float('nan')):.4f}"),
                 ("observation RMS (grid)", f"{report.get('observation_rms', float('nan')):.4f}")]
        ood = report.get("ood")
        if ood:
            rows.append(("looks like the training data", ood.get("verdict")
                         + (f" ({ood['Ms_note']})" if ood.get("Ms_note") else "")))
            if ood.get("warning"):
                rows.append(("training-data check: warning", ood["warning"]))
        peaks = report.get("diagram_peaks")
        if peaks:
            rows.append(("FORC peak (H_c, H_u) measured / re-simulated",
                         " / ".join(f"({1e3 * p['coercive_T']:.0f}, {1e3 * p['interaction_T']:.0f}) mT"
                                    for p in peaks.values())))
    cells = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in rows)
    return f'<table class="summary">{cells}</table>'


STYLE = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:0.8em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:left;font-size:90%}
table.summary th{background:#eef}img{max-width:100%}code{background:#f4f4f4}"""


def write_report_page(out, report: dict, markdown_text: str, figures=("diagrams.png",)) -> Path:
    """``out``/report.html: the summary box, the figures named in ``figures`` (when present), then the
    markdown report rendered (its images embedded). Returns the path."""
    from markdown_it import MarkdownIt

    out = Path(out)
    body = MarkdownIt("commonmark").enable("table").render(markdown_text)
    extra = "".join(f'<p><img src="{name}" alt="{name}"></p>' for name in figures if (out / name).exists())
    title = html.escape(Path(str(report.get("file", "closed loop"))).name)
    summary = f"{_summary_box(report)}{extra}"
    if "</h1>" in body:  # the summary and the diagrams right under the report's title
        head, rest = body.split("</h1>", 1)
        body = f"{head}</h1>{summary}{rest}"
    else:
        body = f"<h1>Closed loop: {title}</h1>{summary}{body}"
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>Closed loop: {title}</title>"
            f"<style>{STYLE}</style></head><body>{body}</body></html>")
    path = out / "report.html"
    write_text(path, _embed_images(page, out))
    return path


__all__ = ["diagrams_figure", "write_report_page"]
