"""What the film thickness does to an answer of models trained on one thickness (issue 60 item 2).

The laptop models are trained on a 4 nm film (64²×1 cells of 2×2×4 nm). A user's film is 0.6–20 nm thick,
and thickness changes the demagnetising field (the shape anisotropy is μ0M_s²/2 only in the thin limit;
the stray field of a domain pattern grows with t), the wall energy per area of film and the domain period.
This bench measures it before deciding anything: the same Hamiltonians (drawn from the models' prior,
screened on the models' film) and the same disorder realisation are simulated as films of each thickness
(one layer of cells ``dz_nm = t``), decoded by the models, and scored per parameter:

- MAE in prior widths (normalized u) against the truth, with a percentile bootstrap 90 % interval;
- the paired change of MAE against the models' own thickness (same Hamiltonians), with its interval;
- the skill over the trivial predictor that reads M_s alone (the prior's median given M_s).

``safe_range`` turns the table into the range of thicknesses the tool accepts without ``--force``: a
thickness is safe when, for every parameter the models read from the image (skill above 0 at the models'
thickness), the paired MAE change's 90 % upper bound stays below ``SAFE_MAE_INCREASE`` prior widths; the
range is the contiguous run of safe tested thicknesses around the models' own. Rows are appended to
``rows.jsonl`` as they are made (a stopped run resumes).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..config import film_thickness_nm, with_thickness
from ..core.io import append_jsonl, write_json
from ..core.prior import Prior
from ..core.streams import stream_rng
from ..dataset.simulate import screen, simulate
from ..learn.predictor import load_models, predict_parameters
from ..learn.scoring import bootstrap_interval

THICKNESSES_NM = (2.0, 3.0, 4.0, 5.0, 6.0, 8.0)
"""The film thicknesses simulated (nm); 4 is the laptop models' own."""

FIRST_ID = 90000
"""Sample ids of the study's Hamiltonians (ids 90000..): no dataset (0..), sealed (60000..) or bench (900000..)
sample's."""

SAFE_MAE_INCREASE = 0.02
"""The largest MAE increase (prior widths) a thickness may cost a parameter read from the image and still be
accepted: a fifth of the typical gap between a read parameter's MAE and its trivial predictor's (~0.1)."""

FILE = "thickness.json"
"""The study's summary (the table and the safe range); shipped beside the models' manifest."""


def draw_cases(cfg: dict, count: int, first_id: int = FIRST_ID, max_draws: int | None = None) -> list[tuple[int, dict]]:
    """``count`` Hamiltonians of the config's prior class that pass the dataset's screening on the config's
    own film (what the models were trained on), with their sample ids (the disorder of each is its id's)."""
    prior = Prior(cfg.get("prior", "paper"), cfg.get("bounds"))
    cases, sample_id = [], first_id
    limit = first_id + (max_draws or 4 * count)
    while len(cases) < count and sample_id < limit:
        params = prior.sample(cfg["seed"], sample_id)
        if screen(cfg, params, sample_id)["screen_status"] == "passed":
            cases.append((sample_id, params))
        sample_id += 1
    return cases


def decode_row(cfg: dict, models: dict, sample_id: int, params: dict, thickness_nm: float) -> dict:
    """One Hamiltonian as a film of ``thickness_nm``, decoded: truth and prediction in prior widths."""
    prior = Prior(cfg.get("prior", "paper"), cfg.get("bounds"))
    start = time.perf_counter()
    family = simulate(with_thickness(cfg, thickness_nm), params, sample_id)
    row = {"sample_id": int(sample_id), "thickness_nm": float(thickness_nm), "status": family["status"],
           "family_s": time.perf_counter() - start}
    if family["status"] != "ok":
        return {**row, "reason": family["reason"]}
    prediction = predict_parameters(models, family["image"], params["Ms"])
    row["truth_u"] = {n: float(prior.normalize(n, params[n])) for n in models}
    row["predicted_u"] = {n: float(prediction[n]["normalized"]) for n in models}
    row["ms_only_u"] = {n: float(prior.quantiles(n, params["Ms"], [0.5])[0]) for n in models}
    return row


def read_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def run_study(cfg: dict, models_dir, out_dir, count: int = 60, thicknesses_nm=THICKNESSES_NM, progress=None) -> dict:
    """Simulate and decode every (Hamiltonian, thickness) pair not yet in ``out_dir/rows.jsonl``, then
    summarize (``summarize``) into ``out_dir/thickness.json``."""
    models = load_models(models_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    done = {(r["sample_id"], r["thickness_nm"]) for r in read_rows(rows_path)}
    cases = draw_cases(cfg, count)
    for sample_id, params in cases:
        for t in thicknesses_nm:
            if (sample_id, float(t)) in done:
                continue
            row = decode_row(cfg, models, sample_id, params, float(t))
            append_jsonl(rows_path, row)
            if progress:
                progress(row)
    ids = {sample_id for sample_id, _ in cases}
    rows = [r for r in read_rows(rows_path) if r["sample_id"] in ids and r["thickness_nm"] in set(map(float, thicknesses_nm))]
    summary = summarize(rows, reference_nm=film_thickness_nm(cfg), seed=cfg["seed"])
    write_json(out / FILE, summary)
    return summary


def summarize(rows: list[dict], reference_nm: float = 4.0, seed: int = 0, n_boot: int = 2000) -> dict:
    """Per thickness and parameter: MAE (prior widths) with its 90 % interval, the paired MAE change against
    ``reference_nm`` with its interval, and the skill over the M_s-only trivial predictor; the safe range."""
    ok = [r for r in rows if r.get("status") == "ok"]
    thicknesses = sorted({r["thickness_nm"] for r in ok})
    names = sorted({n for r in ok for n in r["truth_u"]})
    by = {(r["sample_id"], r["thickness_nm"]): r for r in ok}
    table = {}
    for t in thicknesses:
        ids = sorted(i for i, tt in by if tt == t and (i, reference_nm) in by)
        table[str(t)] = {"n": len(ids), "failed": sum(1 for r in rows if r["thickness_nm"] == t and r.get("status") != "ok")}
        for name in names:
            err = np.array([abs(by[i, t]["predicted_u"][name] - by[i, t]["truth_u"][name]) for i in ids])
            ref = np.array([abs(by[i, reference_nm]["predicted_u"][name] - by[i, reference_nm]["truth_u"][name]) for i in ids])
            triv = np.array([abs(by[i, t]["ms_only_u"][name] - by[i, t]["truth_u"][name]) for i in ids])
            rng = stream_rng(seed, "thickness_bootstrap", len(ids), int(round(t * 10)))
            table[str(t)][name] = {
                "mae": float(err.mean()) if len(ids) else float("nan"),
                "mae_ci90": bootstrap_interval(np.mean, [err], rng, n_boot),
                "mae_change": float((err - ref).mean()) if len(ids) else float("nan"),
                "mae_change_ci90": bootstrap_interval(lambda a, b: float(np.mean(a - b)), [err, ref], rng, n_boot),
                "skill": float(1 - err.mean() / triv.mean()) if len(ids) and triv.mean() > 0 else float("nan"),
                "skill_ci90": bootstrap_interval(lambda a, b: float(1 - a.mean() / b.mean()), [err, triv], rng, n_boot),
            }
    return {"reference_nm": reference_nm, "thicknesses_nm": thicknesses, "names": names, "table": table,
            "safe_nm": safe_range(table, reference_nm, names), "safe_mae_increase": SAFE_MAE_INCREASE,
            "rule": "a thickness is safe when every parameter read at the models' thickness (skill > 0) loses at "
                    f"most {SAFE_MAE_INCREASE} prior widths of MAE (90 % upper bound of the paired change); the "
                    "safe range is the contiguous safe run around the models' own thickness"}


def safe_range(table: dict, reference_nm: float, names) -> list[float]:
    """[lowest, highest] tested thickness (nm) of the contiguous safe run containing ``reference_nm``."""
    read = [n for n in names if table.get(str(reference_nm), {}).get(n, {}).get("skill", 0.0) > 0]

    def safe(t: float) -> bool:
        row = table[str(t)]
        return all(np.isfinite(row[n]["mae_change_ci90"][1]) and row[n]["mae_change_ci90"][1] <= SAFE_MAE_INCREASE
                   for n in read)

    tested = sorted(float(t) for t in table)
    if reference_nm not in tested:
        return [reference_nm, reference_nm]
    k = tested.index(reference_nm)
    lo = hi = k
    while lo > 0 and safe(tested[lo - 1]):
        lo -= 1
    while hi < len(tested) - 1 and safe(tested[hi + 1]):
        hi += 1
    return [tested[lo], tested[hi]]


def summary_lines(summary: dict) -> list[str]:
    """The table as a user reads it: per thickness, each parameter's MAE change [90 %] and skill."""
    names = summary["names"]
    lines = [f"thickness study: models of a {summary['reference_nm']:g} nm film decoding films of other thicknesses "
             "(MAE change in prior widths [90 % interval]; skill over the M_s-only predictor)"]
    lines.append(f"{'t (nm)':>7} {'n':>4}  " + "  ".join(f"{n:>26}" for n in names))
    for t in summary["thicknesses_nm"]:
        row = summary["table"][str(t)]
        cells = []
        for n in names:
            c = row[n]
            cells.append(f"{c['mae_change']:+.3f} [{c['mae_change_ci90'][0]:+.3f},{c['mae_change_ci90'][1]:+.3f}] "
                         f"s{c['skill']:+.2f}")
        lines.append(f"{t:7g} {row['n']:4d}  " + "  ".join(f"{c:>26}" for c in cells))
    lo, hi = summary["safe_nm"]
    lines.append(f"safe range: {lo:g}-{hi:g} nm ({summary['rule']})")
    return lines


__all__ = ["FILE", "FIRST_ID", "SAFE_MAE_INCREASE", "THICKNESSES_NM", "decode_row", "draw_cases", "run_study",
           "safe_range", "summarize", "summary_lines"]
