"""HTML tables for the Snakemake report (its viewer renders images and HTML, not Markdown or Parquet).

Snakemake script (rule ``report_tables``): the metrics table of ``metrics.md``, the screening and
family outcomes of ``samples.parquet`` and the closed loop's ``closed_loop.json`` summary, each as
one self-contained HTML page. Pandas only (no forcdecode import), so it runs in any environment
that has the workflow's dependencies.
"""

import html
import json
import os
import tempfile
from pathlib import Path

import pandas as pd

STYLE = ("<style>body{font-family:sans-serif;font-size:13px}table{border-collapse:collapse;margin:1em 0}"
         "th,td{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#eee}</style>")


def page(title: str, body: str) -> str:
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>{STYLE}"
            f"</head><body><h2>{html.escape(title)}</h2>{body}</body></html>\n")


def markdown_tables(text: str) -> str:
    """HTML of the Markdown text's headings and pipe tables (the only constructs metrics.md uses)."""
    parts, table = [], []

    def flush():
        if table:
            head, rows = table[0], [r for r in table[1:] if not set("".join(r)) <= set("-: ")]
            parts.append(pd.DataFrame(rows, columns=head).to_html(index=False, escape=True))
            table.clear()

    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("|"):
            table.append([cell.strip() for cell in stripped.strip("|").split("|")])
            continue
        flush()
        if stripped.startswith("#"):
            parts.append(f"<h3>{html.escape(stripped.lstrip('#').strip())}</h3>")
        elif stripped:
            parts.append(f"<p>{html.escape(stripped)}</p>")
    flush()
    return "\n".join(parts)


def outcome_tables(samples: pd.DataFrame) -> str:
    """Counts of the screening outcomes (status, reason) and of the family status of every drawn sample."""
    # the reason without its per-sample numbers ("... at -B_max (m_z=-0.31)" -> "... at -B_max")
    reason = samples["screen_reason"].fillna("").astype(str).str.replace(r"\s*\([^)]*\)", "", regex=True)
    screen = (samples.assign(screen_reason=reason).groupby(["screen_status", "screen_reason"]).size()
              .rename("samples").reset_index())
    parts = [f"<p>{len(samples)} samples drawn</p>", screen.to_html(index=False)]
    if "family_status" in samples:
        family = samples["family_status"].fillna("not simulated").value_counts().rename("samples")
        parts.append(family.rename_axis("family_status").reset_index().to_html(index=False))
    return "\n".join(parts)


def summary_table(summary: dict) -> str:
    """Key/value table of a JSON summary's scalar entries (lists and objects are left to the JSON)."""
    rows = [(k, v) for k, v in summary.items() if isinstance(v, (int, float, str, bool)) or v is None]
    return pd.DataFrame(rows, columns=["quantity", "value"]).to_html(index=False, float_format=lambda x: f"{x:.4g}")


def write_atomic(path, text: str) -> None:
    """Write text through a temporary file in the same folder, renamed into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main(inputs, outputs, log) -> None:
    write_atomic(outputs.metrics, page("Metrics (metrics.md)",
                                       markdown_tables(Path(inputs.metrics).read_text(encoding="utf-8"))))
    write_atomic(outputs.samples, page("Drawn samples: screening and FORC families",
                                       outcome_tables(pd.read_parquet(inputs.samples))))
    write_atomic(outputs.closed_loop, page("Closed loop on the simulated test set",
                                           summary_table(json.loads(Path(inputs.closed_loop).read_text()))))
    Path(log).write_text("".join(f"wrote {path}\n" for path in outputs))


if "snakemake" in globals():
    main(snakemake.input, snakemake.output, snakemake.log[0])  # noqa: F821 (injected by Snakemake)
