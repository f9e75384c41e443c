"""Is the laptop film the paper's film? The same Hamiltonians simulated on films of different size,
thickness and grain size, and two disorder realisations of each, compared on the FORC family.

Films (cells of 2 × 2 × 4 nm; periodic in the plane; grains columnar Voronoi cells):

=====================  =========  =======  ===========  =====================================
name                   cells      box nm   grain nm     role
=====================  =========  =======  ===========  =====================================
``laptop``             64²×1      128×4    ≈ 8 (255)    the laptop default until 2026-11-25
``laptop_paper_grains`` 64²×1     128×4    ≈ 32 (16)    the laptop default (2026-11-25 on)
``box128``             128²×1     256×4    ≈ 32 (64)    twice the box, the paper's grain size
``paper``              256²×2     512×8    ≈ 32 (255)   the seed paper's film
=====================  =========  =======  ===========  =====================================

(The names are those of the measurements in ``results/bench/films``: ``laptop`` is the 8 nm-grain film,
``config/films/laptop_8nm_grains.yaml``; ``laptop_paper_grains`` is ``config/config.yaml`` today.)

Hamiltonians are the dataset's draws (Table I priors, ``draw_parameters``) that pass the laptop
screening; N_pin keeps its density (``scale_to_reference``). Each (film, Hamiltonian, realisation)
is one job run in its own process (so its peak resident memory is its own, read with ``wait4``),
written atomically to ``OUT/<film>_<sample>_<realisation>.h5``: a killed run resumes where it
stopped. ``summarize`` compares the families: mean and max |Δm| over the FORC family on the common
64-field grid, the mean |Δ| of the 8-bit images in grey levels, and the shift of the FORC-diagram
peak (H_c, H_u); the realisation floor is the same comparison between two disorder draws of one
Hamiltonian on one film.
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ..core import physics
from ..core.io import append_jsonl, atomic_path
from ..core.progress import counter
from ..core.streams import stream_rng
from ..dataset.params import draw_parameters
from ..dataset.simulate import screen
from ..forc.diagram import forc_distribution
from ..forc.protocol import quasistatic_family
from ..forc.raster import rasterize_grid_family
from ..micromag.build import build_film, sweep_options

FILMS: dict[str, dict] = {
    "laptop": dict(nx=64, ny=64, nz=1, n_grains=255),
    "laptop_paper_grains": dict(nx=64, ny=64, nz=1, n_grains=16),
    "box128": dict(nx=128, ny=128, nz=1, n_grains=64),
    "paper": dict(nx=256, ny=256, nz=2, n_grains=255),
}
"""Film name -> cells and grain count (the grain size is box / sqrt(n_grains))."""


def film_config(base_cfg: dict, film: str, films: dict | None = None) -> dict:
    """The config ``base_cfg`` with the mesh and grain count of ``film`` (in ``films``, default ``FILMS``)."""
    spec = (FILMS if films is None else films)[film]
    cfg = copy.deepcopy(base_cfg)
    cfg["mesh"].update(nx=spec["nx"], ny=spec["ny"], nz=spec["nz"])
    cfg["n_grains"] = spec["n_grains"]
    return cfg


def pick_hamiltonians(cfg: dict, n: int, first_id: int = 0, progress=None, prior: str | None = None) -> list[dict]:
    """The first ``n`` dataset draws (ids from ``first_id``) that pass the laptop screening, under the
    prior class ``prior`` (None: ``dataset.params``' default class, as the films bench has always drawn;
    ``cfg["prior"]`` gives the draws of the config's own main job)."""
    picked, sample_id = [], first_id
    prior_class = {} if prior is None else {"prior": prior}
    while len(picked) < n:
        params = draw_parameters(cfg["seed"], sample_id, **prior_class)
        if screen(film_config(cfg, "laptop"), params, sample_id)["screen_status"] == "passed":
            picked.append({"sample_id": sample_id, **params})
            if progress is not None:
                progress(len(picked), n)
        sample_id += 1
    return picked


def job_path(out_dir, film: str, sample_id: int, realisation: int) -> Path:
    return Path(out_dir) / f"{film}_{sample_id:05d}_{realisation}.h5"


def run_job(cfg: dict, film: str, params: dict, realisation: int, out_dir) -> None:
    """Simulate one family in this process and write it (curves, cost) atomically."""
    import h5py

    fcfg = film_config(cfg, film)
    sample_id = int(params["sample_id"])
    rng = stream_rng(cfg["seed"], "bench_film", "films", sample_id, realisation)
    start = time.perf_counter()
    film_obj, m0, _ = build_film(fcfg, params, rng=rng)
    setup_s = time.perf_counter() - start
    family = quasistatic_family(film_obj, m0, n_fields=fcfg["field"]["n_fields"], B_max_T=fcfg["field"]["B_max_T"],
                                **sweep_options(fcfg),
                                progress=counter(f"{film} sample {sample_id} r{realisation}", "curves",
                                                 interval_s=60.0))
    path = job_path(out_dir, film, sample_id, realisation)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f["curves_mz"] = family.curves_mz
        f["fields_T"] = family.fields_T
        f.attrs.update(film=film, sample_id=sample_id, realisation=realisation, setup_s=setup_s,
                       family_s=family.stats["wall_s"], iterations=family.stats["iterations"],
                       relaxations=family.stats["relaxations"], unconverged=family.stats["unconverged"],
                       curves_shortened=family.stats["curves_shortened"], n_cells=film_obj.mesh.n_cells,
                       params=json.dumps(params))


def plan(hamiltonians: list[dict], films_realisations) -> list[tuple]:
    """Jobs (film, params, realisation), each once: ``films_realisations`` lists (film,
    n_hamiltonians, n_realisations): the first n Hamiltonians on that film, that many realisations each."""
    jobs, seen = [], set()
    for film, n_ham, n_real in films_realisations:
        for params in hamiltonians[:n_ham]:
            for r in range(n_real):
                if (film, params["sample_id"], r) not in seen:
                    seen.add((film, params["sample_id"], r))
                    jobs.append((film, params, r))
    return jobs


def run_jobs(cfg: dict, jobs, out_dir, workers: int = 1, say=print) -> list[dict]:
    """Run the jobs not yet on disk, each in a fresh process (``workers`` at a time); returns the
    peak resident memory (MiB) and exit status of each job run now (also in ``OUT/costs.jsonl``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    todo = [j for j in jobs if not job_path(out_dir, j[0], j[1]["sample_id"], j[2]).exists()]
    running: dict[int, tuple] = {}
    rows = []
    cfg_path = out_dir / "config.json"
    cfg_path.write_text(json.dumps(cfg))
    while todo or running:
        while todo and len(running) < workers:
            film, params, r = todo.pop(0)
            spec = json.dumps({"config": str(cfg_path), "film": film, "params": params, "realisation": r,
                               "out": str(out_dir)})
            proc = subprocess.Popen([sys.executable, "-m", "forcdecode.bench.films", spec],
                                    env={**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
            running[proc.pid] = (film, params["sample_id"], r, time.perf_counter())
        pid, status, usage = os.wait4(-1, 0)
        if pid not in running:
            continue
        film, sample_id, r, started = running.pop(pid)
        row = {"film": film, "sample_id": sample_id, "realisation": r, "exit_status": os.waitstatus_to_exitcode(status),
               "process_wall_s": time.perf_counter() - started, "peak_rss_MiB": usage.ru_maxrss / 1024,
               "process_cpu_s": usage.ru_utime + usage.ru_stime}
        rows.append(row)
        append_jsonl(out_dir / "costs.jsonl", row)
        say(f"{film} sample {sample_id} realisation {r}: exit {row['exit_status']}, "
            f"{row['process_wall_s']:.0f} s, peak {row['peak_rss_MiB']:.0f} MiB ({len(todo)} jobs left)")
    return rows


def load(out_dir) -> dict:
    """All finished jobs: (film, sample_id, realisation) -> dict(curves, attrs)."""
    import h5py

    found = {}
    for path in sorted(Path(out_dir).glob("*.h5")):
        with h5py.File(path, "r") as f:
            attrs = {k: (v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
            found[(attrs["film"], int(attrs["sample_id"]), int(attrs["realisation"]))] = {
                "curves": f["curves_mz"][...], "fields": f["fields_T"][...], **attrs}
    costs = {}
    cost_file = Path(out_dir) / "costs.jsonl"
    if cost_file.exists():
        for line in cost_file.read_text().splitlines():
            row = json.loads(line)
            costs[(row["film"], int(row["sample_id"]), int(row["realisation"]))] = row
    for key, job in found.items():
        job["peak_rss_MiB"] = costs.get(key, {}).get("peak_rss_MiB", float("nan"))
        job["process_cpu_s"] = costs.get(key, {}).get("process_cpu_s", float("nan"))
    return found


def _peak(fields, curves) -> tuple[float, float]:
    """(H_c, H_u) in T of the largest value of the FORC distribution (Pike kernel, SF 3)."""

    d = forc_distribution(fields, fields, curves, smoothing_factor=3, kernel="pike")
    rho = np.where(np.isfinite(d.rho), d.rho, -np.inf)
    if not np.isfinite(rho).any() or rho.max() <= 0:
        return float("nan"), float("nan")
    i, j = np.unravel_index(np.argmax(rho), rho.shape)
    return float(d.coercive_T[i, j]), float(d.interaction_T[i, j])


def compare(a: dict, b: dict) -> dict:
    """Distance between two families on the same field grid."""

    valid = np.isfinite(a["curves"]) & np.isfinite(b["curves"])
    diff = np.abs(a["curves"] - b["curves"])[valid]
    images = np.abs(rasterize_grid_family(a["curves"]).astype(int) - rasterize_grid_family(b["curves"]).astype(int))
    pa, pb = _peak(a["fields"], a["curves"]), _peak(b["fields"], b["curves"])
    return {"mean_abs_dm": float(diff.mean()), "max_abs_dm": float(diff.max()),
            "image_mean_abs_levels": float(images.mean()),
            "peak_shift_T": float(np.hypot(pa[0] - pb[0], pa[1] - pb[1]))}


def _nanmax(values) -> float:
    """Largest finite value, NaN when none (families run in-process have no per-process memory)."""
    finite = [v for v in values if np.isfinite(v)]
    return float(max(finite)) if finite else float("nan")


def summarize(out_dir) -> dict:
    """Per Hamiltonian: every pair of films (realisation 0; ``B_vs_A``, A the smaller film of
    ``FILMS``) and the realisation floor (r0 vs r1) of each film; medians per comparison and per
    parameter region; cost per family and per film."""
    jobs = load(out_dir)
    samples = sorted({k[1] for k in jobs})
    films = [f for f in FILMS if any(k[0] == f for k in jobs)]
    rows = []
    for s in samples:
        params = None
        row = {"sample_id": s}
        for film in films:
            j0 = jobs.get((film, s, 0))
            if j0 is None:
                continue
            params = params or json.loads(j0["params"])
            j1 = jobs.get((film, s, 1))
            if j1 is not None:
                row[f"floor_{film}"] = compare(j0, j1)
            for other in films[:films.index(film)]:  # every pair of films once, smaller film first
                if (other, s, 0) in jobs:
                    row[f"{film}_vs_{other}"] = compare(jobs[(other, s, 0)], j0)
        row["params"] = params
        rows.append(row)
    cost = {}
    for film in films:
        mine = [j for k, j in jobs.items() if k[0] == film]
        cost[film] = {"families": len(mine), "median_family_s": float(np.median([j["family_s"] for j in mine])),
                      "mean_family_s": float(np.mean([j["family_s"] for j in mine])),
                      "median_iterations": float(np.median([j["iterations"] for j in mine])),
                      "median_relaxations": float(np.median([j["relaxations"] for j in mine])),
                      "max_peak_rss_MiB": _nanmax([j["peak_rss_MiB"] for j in mine]),
                      "median_process_cpu_s": float(np.nanmedian([j["process_cpu_s"] for j in mine]))
                      if any(np.isfinite(j["process_cpu_s"]) for j in mine) else float("nan"),
                      "mean_process_cpu_s": float(np.nanmean([j["process_cpu_s"] for j in mine]))
                      if all(np.isfinite(j["process_cpu_s"]) for j in mine) else float("nan"),
                      "n_cells": int(mine[0]["n_cells"]), "unconverged": int(sum(j["unconverged"] for j in mine))}
    medians = {}
    keys = sorted({k for r in rows for k in r if k not in ("sample_id", "params")})
    for key in keys:
        values = [r[key]["mean_abs_dm"] for r in rows if key in r]
        medians[key] = {"n": len(values), "median_mean_abs_dm": float(np.median(values)),
                        "max_mean_abs_dm": float(np.max(values)),
                        "median_image_levels": float(np.median([r[key]["image_mean_abs_levels"] for r in rows if key in r])),
                        "median_peak_shift_T": float(np.nanmedian([r[key]["peak_shift_T"] for r in rows if key in r]))}
    result = {"rows": rows, "cost": cost, "medians": medians, "films": {f: FILMS[f] for f in films},
              "by_region": by_region(rows)}
    result["cost_16k"] = cost_table(result)
    return result


REGIONS = {
    "N_pin < 85": lambda p: p["N_pin"] < 85,
    "N_pin >= 85": lambda p: p["N_pin"] >= 85,
    "Q < 2": lambda p: quality_factor(p) < 2.0,
    "Q >= 2": lambda p: quality_factor(p) >= 2.0,
}
"""Parameter regions the realisation floor is reported in: pinning density (sites on the paper's
256×256×2 grid) and the quality factor Q = 2K_u/(μ0 M_s²) (Q near 1: soft, domain-forming films)."""


def quality_factor(params: dict) -> float:
    """Q = 2 K_u / (μ0 M_s²): anisotropy over shape anisotropy."""
    return physics.quality_factor(params["K_u"], params["Ms"])


def by_region(rows: list[dict]) -> dict:
    """Median mean |Δm| of every comparison within each parameter region (with the count)."""
    out = {}
    keys = sorted({k for r in rows for k in r if k not in ("sample_id", "params")})
    for region, inside in REGIONS.items():
        chosen = [r for r in rows if r.get("params") and inside(r["params"])]
        out[region] = {key: {"n": len([r for r in chosen if key in r]),
                             "median_mean_abs_dm": (float(np.median([r[key]["mean_abs_dm"] for r in chosen if key in r]))
                                                    if any(key in r for r in chosen) else None)} for key in keys}
    return out


def figure(summary: dict, path) -> None:
    """Per Hamiltonian (sorted by the laptop floor): the realisation floor of each film and each film's
    distance to the paper's film, mean |Δm| over the family."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    rows = sorted(summary["rows"], key=lambda r: r.get("floor_laptop", {}).get("mean_abs_dm", np.inf))
    keys = list(summary["medians"])
    fig, ax = plt.subplots(figsize=(8, 4))
    for n, key in enumerate(keys):
        x = [i for i, r in enumerate(rows) if key in r]
        y = [r[key]["mean_abs_dm"] for r in rows if key in r]
        ax.plot(x, y, "o" if key.startswith("floor_") else "s", ms=4, label=key.replace("_", " "),
                mfc="none" if key.startswith("floor_") else None)
    ax.axhline(2 / 255, color="k", lw=0.8, ls=":", label="one 8-bit step")
    ax.set_yscale("log")
    ax.set_xlabel("Hamiltonian (sorted by the laptop film's realisation floor)")
    ax.set_ylabel("mean |Δm| over the FORC family")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def cost_table(summary: dict, n_families: int = 16_000, pass_rate: float = 0.2, screen_fraction: float = 0.19,
               cores=(1, 64, 1024)) -> dict:
    """Core-hours for ``n_families`` passing families on each film, from the measured mean family time:
    families + screening of n_families/pass_rate draws, a screen costing ``screen_fraction`` of a
    family (the laptop dataset measured 0.46 CPU-s per screen against 2.40 per family on 2026-11-25,
    since curve merging made families cheaper and not the screening half loop; the paper reports a
    ~20 % pass rate, the laptop draws pass at 37 %). Wall time on each number of ``cores`` (perfect scaling: the
    families are independent jobs)."""
    out = {}
    for film, c in summary["cost"].items():
        # CPU time where the job's was recorded (the machine may have been shared: wall ≥ CPU)
        seconds = c.get("mean_process_cpu_s")
        seconds = seconds if seconds is not None and np.isfinite(seconds) else c["mean_family_s"]
        family_h = seconds / 3600.0
        core_h = n_families * family_h * (1.0 + screen_fraction / pass_rate)
        out[film] = {"mean_family_s": c["mean_family_s"], "mean_cpu_s_used": seconds * 1.0, "core_hours": core_h,
                     "wall_days": {str(n): core_h / n / 24.0 for n in cores}}
    return {"n_families": n_families, "pass_rate": pass_rate, "screen_fraction": screen_fraction, "films": out}


def summary_lines(summary: dict) -> list[str]:
    """A table a reader can scan: cost per film, then each comparison's median distances."""
    lines = ["film                 cells    families  median CPU s/family  iterations  peak MiB"]
    for film, c in summary["cost"].items():
        cpu = c.get("median_process_cpu_s")
        cpu = cpu if cpu is not None and np.isfinite(cpu) else c["median_family_s"]
        lines.append(f"{film:20s} {c['n_cells']:7d}  {c['families']:8d}  {cpu:19.1f}  "
                     f"{c['median_iterations']:10.0f}  {c['max_peak_rss_MiB']:8.0f}")
    costs = cost_table(summary)
    lines.append(f"{costs['n_families']} passing families (pass rate {costs['pass_rate']:.0%}), core-hours and wall days "
                 f"on 1 / 64 / 1024 cores:")
    for film, c in costs["films"].items():
        days = c["wall_days"]
        lines.append(f"  {film:20s} {c['core_hours']:10.0f} core-h   {days['1']:8.1f} / {days['64']:6.2f} / "
                     f"{days['1024']:6.3f} days")
    lines.append("comparison                      n   median mean|dm|  max mean|dm|  image levels  peak shift T")
    for key, m in summary["medians"].items():
        lines.append(f"{key:30s} {m['n']:3d}  {m['median_mean_abs_dm']:15.3f}  {m['max_mean_abs_dm']:12.3f}  "
                     f"{m['median_image_levels']:12.2f}  {m['median_peak_shift_T']:12.3f}")
    return lines


def _main(spec_json: str) -> int:
    spec = json.loads(spec_json)
    cfg = json.loads(Path(spec["config"]).read_text())
    run_job(cfg, spec["film"], spec["params"], int(spec["realisation"]), spec["out"])
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1]))
