"""Engine benchmark: field-evaluation throughput and LLG step time, ours against magnum.np, and the
wall time of one FORC family on the laptop grid.

All figures of one run are measured in the same process, one after the other, on the same machine,
so their ratios are meaningful even where the absolute times are noisy. numba runs single-threaded
(NUMBA_NUM_THREADS=1 is set by the CLI before numba is imported), magnum.np with one torch thread.
"""

from __future__ import annotations

import time

import numpy as np

from ..config import defaults, load_config, shipped_config
from ..core.streams import stream_rng
from ..dataset.params import draw_parameters
from ..forc.adaptive import adaptive_family
from ..forc.protocol import quasistatic_family
from ..forc.raster import rasterize_grid_family
from ..micromag import FilmMaterial, Mesh, disordered_film
from ..micromag.build import sweep_options
from ..micromag.effective_field import compute_effective_field
from ..reference.magnumnp_film import MagnumFilm, MagnumMaterial

# A representative sample of the seed paper's parameter space
SAMPLE = FilmMaterial(Ms=8e5, A_ex=1.2e-11, K_u=8e5, D=1.0e-3, sigma_K=0.1, sigma_theta_rad=np.radians(5.0), n_pin=100)
GRIDS = {"64": (64, 64, 1), "256": (256, 256, 2)}
CELL = (2e-9, 2e-9, 4e-9)


def _film(grid, pinning="full", seed=0, n_grains=255):
    nx, ny, nz = GRIDS[grid]
    mesh = Mesh(nx, ny, nz, *CELL)
    return disordered_film(mesh, SAMPLE, stream_rng(seed, "bench_film", "engine", grid), pinning=pinning,
                           n_grains=n_grains)


def _tilted_state(mesh, seed=1):
    rng = stream_rng(seed, "bench_film", "tilted_state")
    m = np.zeros(mesh.vector_shape)
    m[2] = 1.0
    m[:2] = 0.3 * rng.normal(size=(2,) + mesh.shape)
    return np.ascontiguousarray(m / np.linalg.norm(m, axis=0))


def time_ours(grid: str, min_seconds: float = 1.0) -> dict:
    """Seconds per full effective-field evaluation and per accepted+rejected RK45 LLG step."""

    film, _, _ = _film(grid)
    m = _tilted_state(film.mesh)
    out = np.empty_like(m)
    B = np.array([0.0, 0.0, 0.1])
    compute_effective_field(m, film.model, B, out)  # compile / warm up
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < min_seconds or n < 5:
        compute_effective_field(m, film.model, B, out)
        n += 1
    field_s = (time.perf_counter() - start) / n
    film.run_llg(m.copy(), 1e-13, 0.1, alpha=0.1)  # warm up
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < min_seconds or steps < 5:
        run = film.run_llg(m, 2e-13 if grid == "64" else 5e-14, 0.1, alpha=0.1, dt_s=2e-14)
        steps += run.accepted_steps + run.rejected_steps
    step_s = (time.perf_counter() - start) / steps
    return {"field_eval_s": field_s, "cells_per_s": film.mesh.n_cells / field_s, "llg_step_s": step_s,
            "field_evals_per_llg_step": 6}


def time_magnumnp(grid: str, cache_dir: str | None, repeats: int = 10, compile: bool = True) -> dict:
    """The same film in magnum.np (CPU): seconds per field evaluation and per LLG step."""

    film, _, _ = _film(grid)
    mesh = film.mesh
    m = _tilted_state(mesh)
    start = time.perf_counter()
    material = MagnumMaterial(film.Ms, film.A_ex, film.K_u, film.easy_axis, film.D, alpha=0.1)
    reference = MagnumFilm(mesh, material, cache_dir=cache_dir, compile=compile)
    reference.effective_field_T(m, 0.1)  # first call compiles (torch.compile); not timed
    setup_s = time.perf_counter() - start
    field_s = reference.time_field_evaluation(m, repeats=repeats, B_ext_T=0.1)
    step_s = reference.time_llg_step(m, n_steps=max(3, repeats // 2), B_ext_T=0.1)
    return {"field_eval_s": field_s, "cells_per_s": mesh.n_cells / field_s, "llg_step_s": step_s,
            "setup_s": setup_s, "compiled": compile}


LAPTOP_VARIANTS = {
    "reference": dict(same_state_tol=0.0, merge_curves=False),
    "descending_copy": dict(merge_curves=False),
    "shipped": dict(),
    "continuation": dict(warm_step=True, extrapolate=True),
    "fourier": dict(preconditioner="fourier"),
}
"""Laptop-family variants timed in one run: ``reference`` = no shortcut at all (every point of every
curve relaxed, plain minimizer); ``descending_copy`` = a curve's remainder copied only where it meets
the descending branch (what was shipped before 2026-11-25); ``shipped`` = what the default config runs
(``sweep_options`` of the schema's defaults: remainder copy from any curve already computed);
``continuation`` = that plus the warm BB step and the linear-response start (options); ``fourier`` =
that with the Fourier preconditioner (an option)."""


def _shipped_options() -> dict:
    """The protocol options of the default configuration, less the torque criterion and iteration cap."""
    options = sweep_options(defaults())
    options.pop("torque_tol_T")
    options.pop("max_iterations")
    return options


def family_agreement(family, reference) -> dict:
    """Image-level (8-bit grey levels) and ⟨m_z⟩ agreement of a family with a reference family."""

    valid = np.isfinite(family.curves_mz) & np.isfinite(reference.curves_mz)
    d = np.abs(family.curves_mz - reference.curves_mz)[valid]
    img = np.abs(rasterize_grid_family(family.curves_mz).astype(int)
                 - rasterize_grid_family(reference.curves_mz).astype(int))
    return {"image_mean_abs_levels": float(img.mean()), "image_max_abs_levels": int(img.max()),
            "image_mean_abs_m": float(img.mean() * 2.0 / 255.0), "mean_abs_dmz": float(d.mean()),
            "max_abs_dmz": float(d.max()),
            "descending_max_abs_dmz": float(np.abs(family.descending_mz - reference.descending_mz).max())}


def _shipped_grains() -> int:
    """The grain count of the shipped laptop film (``config/config.yaml``)."""

    return int(load_config(shipped_config("config"))["n_grains"])


def time_laptop_family(n_fields: int = 64, torque_tol_T: float = 1e-3, variants=None, progress=None, say=None,
                       n_grains: int | None = None) -> dict:
    """Wall time, relaxations and iterations of one FORC family (``n_fields`` reversal fields) on the
    64×64×1 laptop grid (``n_grains``: default the shipped laptop film's) for each variant of
    ``LAPTOP_VARIANTS``, and each one's agreement with the no-shortcut reference on the same film (one
    run, one process: the ratios are meaningful)."""
    variants = variants or LAPTOP_VARIANTS
    n_grains = _shipped_grains() if n_grains is None else int(n_grains)
    film, m0, _ = _film("64", n_grains=n_grains)
    for preconditioner in ("diagonal", "fourier"):  # compile both minimizers outside the timing
        film.preconditioner = preconditioner
        quasistatic_family(film, m0, n_fields=3, torque_tol_T=torque_tol_T)
    rows, families = {}, {}
    for name, options in variants.items():
        options = {**_shipped_options(), **options}
        film.preconditioner = options.pop("preconditioner", "diagonal")
        start = time.perf_counter()
        family = quasistatic_family(film, m0, n_fields=n_fields, torque_tol_T=torque_tol_T, progress=progress, **options)
        wall = time.perf_counter() - start
        families[name] = family
        rows[name] = {"family_s": wall, "relaxations": family.stats["relaxations"],
                      "iterations": family.stats["iterations"], "unconverged": family.stats["unconverged"],
                      "curves_shortened": family.stats["curves_shortened"], "options": variants[name]}
        if "reference" in families and name != "reference":
            rows[name]["agreement_with_reference"] = family_agreement(family, families["reference"])
        if say is not None:
            agree = rows[name].get("agreement_with_reference")
            say(f"[family] {name:9s} {wall:6.1f} s, {family.stats['relaxations']} relaxations, "
                f"{family.stats['iterations']} iterations"
                + (f"; vs reference: image mean {agree['image_mean_abs_levels']:.3f} levels "
                   f"(max {agree['image_max_abs_levels']}), mean |dm_z| {agree['mean_abs_dmz']:.4f}" if agree else ""))
    film.preconditioner = "diagonal"
    return rows


def compare_protocols(n_samples: int = 3, grid: int = 32, n_fields: int = 16, seed: int = 1, progress=None) -> dict:
    """Quasi-static and adaptive-LLG families of the same samples (drawn as in the dataset, on a small
    grid so the LLG protocol stays affordable): wall time of each and their image difference."""
    mesh = Mesh(grid, grid, 1, *CELL)
    rows = []
    sample_id = 0
    while len(rows) < n_samples and sample_id < 200:
        p = draw_parameters(seed, sample_id)
        sample_id += 1
        if p["K_u"] < 2e5 or p["Ms"] > 1.0e6:  # keep perpendicular, switchable samples (cheap screen)
            continue
        material = FilmMaterial(Ms=p["Ms"], A_ex=p["A_ex"], K_u=p["K_u"], D=p["D"], sigma_K=p["sigma_K"],
                                sigma_theta_rad=np.radians(p["sigma_theta_deg"]),
                                n_pin=int(round(p["N_pin"] * mesh.n_cells / 131072)))
        n_grains = max(4, 255 * mesh.n_cells // 131072)
        film, m0, _ = disordered_film(mesh, material, stream_rng(seed, "disorder", sample_id - 1), pinning="full",
                                      n_grains=n_grains)
        start = time.perf_counter()
        quasi = quasistatic_family(film, m0, n_fields=n_fields)
        t_quasi = time.perf_counter() - start
        film, m0, _ = disordered_film(mesh, material, stream_rng(seed, "disorder", sample_id - 1), pinning="slaved",
                                      n_grains=n_grains)
        start = time.perf_counter()
        llg = adaptive_family(film, m0, n_fields=n_fields)
        t_llg = time.perf_counter() - start
        difference = np.abs(quasi.curves_mz - llg.curves_mz)
        images = np.abs(rasterize_grid_family(quasi.curves_mz).astype(int) - rasterize_grid_family(llg.curves_mz).astype(int))
        rows.append({"sample_id": sample_id - 1, "quasistatic_s": t_quasi, "llg_s": t_llg,
                     "mean_abs_dmz": float(np.nanmean(difference)), "max_abs_dmz": float(np.nanmax(difference)),
                     "image_mean_abs_diff_levels": float(images.mean()), "llg_steps": llg.stats["llg_steps"],
                     "tau_z_max_per_s": llg.stats["tau_z_max_per_s"], "alpha_prime": llg.stats["alpha_prime"]})
        if progress is not None:
            progress(rows[-1])
    return {"grid": f"{grid}x{grid}x1", "n_fields": n_fields, "samples": rows,
            "time_ratio_llg_over_quasistatic": float(np.mean([r["llg_s"] / r["quasistatic_s"] for r in rows])),
            "mean_abs_dmz": float(np.mean([r["mean_abs_dmz"] for r in rows]))}


def protocol_row_line(row: dict) -> str:
    return (f"sample {row['sample_id']}: quasi-static {row['quasistatic_s']:.2f} s, LLG {row['llg_s']:.1f} s, "
            f"mean |dm_z| {row['mean_abs_dmz']:.3f}, max {row['max_abs_dmz']:.3f}")


def protocols_summary(result: dict) -> str:
    return (f"LLG/quasi-static time ratio {result['time_ratio_llg_over_quasistatic']:.0f}x, "
            f"mean |dm_z| between the protocols' families {result['mean_abs_dmz']:.3f}")


def benchmark_engine(grids=("64", "256"), seconds: float = 2.0, magnumnp: bool = True, cache_dir=None,
                     compile: bool = True, say=print, progress=None) -> dict:
    """Field-evaluation and LLG-step throughput on each grid (ours, and magnum.np's where installed),
    then the wall time of one laptop FORC family; figures printed through ``say`` as they come."""
    import os
    import platform

    report = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "threads": 1}
    for grid in grids:
        ours = time_ours(grid, seconds)
        report[f"ours_{grid}"] = ours
        say(f"[{grid}] forcdecode: {ours['cells_per_s']:.3e} cell-evaluations/s, "
            f"{ours['field_eval_s'] * 1e3:.3f} ms per field, {ours['llg_step_s'] * 1e3:.3f} ms per RK45 step")
        if magnumnp:
            try:
                import torch

                torch.set_num_threads(1)
                peer = time_magnumnp(grid, cache_dir, compile=compile)
            except ImportError as error:
                say(f"[{grid}] magnum.np not available ({error}); install with pip install -e .[reference]")
                peer = None
            if peer is not None:
                report[f"magnumnp_{grid}"] = peer
                report[f"speedup_vs_magnumnp_{grid}"] = peer["field_eval_s"] / ours["field_eval_s"]
                report[f"llg_step_speedup_vs_magnumnp_{grid}"] = peer["llg_step_s"] / ours["llg_step_s"]
                say(f"[{grid}] magnum.np:  {peer['cells_per_s']:.3e} cell-evaluations/s, "
                    f"{peer['field_eval_s'] * 1e3:.3f} ms per field, {peer['llg_step_s'] * 1e3:.3f} ms per step "
                    f"(setup {peer['setup_s']:.1f} s) -> field speedup "
                    f"{report[f'speedup_vs_magnumnp_{grid}']:.1f}x, step speedup "
                    f"{report[f'llg_step_speedup_vs_magnumnp_{grid}']:.1f}x")
        report.setdefault(f"speedup_vs_magnumnp_{grid}", None)
    n_grains = _shipped_grains()
    say(f"[family] 64 reversal fields on 64x64x1 ({n_grains} grains, the shipped laptop film), one core, the same "
        "film for every variant:")
    family = time_laptop_family(progress=progress, say=say, n_grains=n_grains)
    report["laptop_family"] = family
    report["laptop_n_grains"] = n_grains
    if n_grains != 255:  # the 8 nm-grain film shipped until 2026-11-25, for continuity (shipped protocol only)
        say("[family] the same sample on the 8 nm-grain film (255 grains; the laptop default until 2026-11-25):")
        previous = time_laptop_family(variants={"shipped": {}}, say=say, n_grains=255)
        report["laptop_8nm_grains_family_s"] = previous["shipped"]["family_s"]
    report["laptop_family_s"] = family["shipped"]["family_s"]
    report["reference_family_s"] = family["reference"]["family_s"]
    report["reference_agreement"] = family["shipped"]["agreement_with_reference"]
    report["speedup_vs_reference"] = family["reference"]["family_s"] / family["shipped"]["family_s"]
    for name in ("descending_copy", "continuation", "fourier"):
        report[f"{name}_family_s"] = family[name]["family_s"]
        report[f"{name}_speedup"] = family["shipped"]["family_s"] / family[name]["family_s"]
        report[f"{name}_reference_agreement"] = family[name]["agreement_with_reference"]
    say(f"[family] shipped protocol {report['laptop_family_s']:.1f} s ({report['speedup_vs_reference']:.1f}x faster "
        f"than the no-shortcut reference, {1 / report['descending_copy_speedup']:.1f}x faster than the descending-branch "
        f"copy alone); image agreement with the reference "
        f"{report['reference_agreement']['image_mean_abs_levels']:.3f} grey levels on average (one level = 0.0078); "
        f"relative to it: continuation {report['continuation_speedup']:.2f}x, fourier {report['fourier_speedup']:.2f}x "
        f"({report['fourier_reference_agreement']['image_mean_abs_levels']:.2f} levels from the reference)")
    return report
