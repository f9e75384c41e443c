"""Does the posterior's out-of-distribution check (``learn/ood.py``) flag the films it should?

The issue asks that a film whose pinning density or grain size lies outside the training prior, or
another code's discretization of the same physics, be flagged, while families like the training ones
are flagged at most at the check's level α. This bench measures it on FORC families made for the
purpose, from the Hamiltonians of held-out families (test split by default: in the prior, screened),
each on a new disorder realisation:

- ``control``: the training film itself (our engine, the dataset's grid and grains);
- ``no_pinning``: the same with N_pin = 0 (the prior's lower edge: the control of ``magnumnp``);
- ``pinning_beyond_prior``: N_pin three times the prior's upper bound (a denser pinning than any
  training film had);
- ``grains_8nm``: 255 grains in the box instead of the dataset's (8 nm grains where the prior's film
  has ~32 nm ones);
- ``magnumnp``: the Hamiltonian without pinning computed by magnum.np (``reference.independent``:
  another grid, 2.2 nm cells over nearly the same box, its own grain tessellation and minimizer) on
  the training field grid — the same physics, another discretization (the ``reference`` extra).

Per case: the fraction flagged at the model's α with its 90 % Clopper–Pearson interval, and the
median combined p-value. Images and p-values per case are kept in ``out_dir`` (resumable).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError
from ..core.parameters import DEFAULT_BOUNDS

CASES = ("control", "no_pinning", "pinning_beyond_prior", "grains_8nm", "magnumnp")
DISORDER_KEY_OFFSET = 1_000_000
"""New disorder realisations: the dataset's disorder stream keyed by sample id + this offset."""
PINNING_FACTOR = 3.0
GRAINS_8NM = 255


def clopper_pearson(k: int, n: int, level: float = 0.9) -> tuple[float, float]:
    """Exact binomial interval of a fraction k / n at ``level``."""
    from scipy import stats

    tail = (1.0 - level) / 2.0
    low = 0.0 if k == 0 else float(stats.beta.ppf(tail, k, n - k + 1))
    high = 1.0 if k == n else float(stats.beta.ppf(1.0 - tail, k + 1, n - k))
    return low, high


def case_film(cfg: dict, params: dict, case: str) -> tuple[dict, dict]:
    """(config, SI parameters) of one family of ``case`` on our engine (not ``magnumnp``)."""
    params = dict(params)
    cfg = dict(cfg)
    if case == "no_pinning":
        params["N_pin"] = 0
    elif case == "pinning_beyond_prior":
        high = float(cfg.get("bounds", {}).get("N_pin", DEFAULT_BOUNDS["N_pin"])[1])
        params["N_pin"] = int(round(PINNING_FACTOR * high))
    elif case == "grains_8nm":
        cfg["n_grains"] = GRAINS_8NM
    elif case != "control":
        raise ConfigError(f"unknown OOD case {case!r} for our engine (one of {', '.join(CASES[:-1])})")
    return cfg, params


def our_family(job) -> np.ndarray:
    """uint8 image of one family on our engine: job = (cfg, params, disorder key)."""
    from ..dataset.simulate import simulate

    cfg, params, key = job
    out = simulate(cfg, params, key)
    if out["status"] != "ok":
        raise RuntimeError(f"family (key {key}) failed: {out['reason']}")
    return out["image"]


def magnumnp_image(job) -> np.ndarray:
    """uint8 image of one magnum.np family on the training field grid: job = (cfg, params, seed)."""
    from ..forc.raster import rasterize_grid_family
    from ..reference.independent import IndependentFilm, magnumnp_family

    cfg, params, seed = job
    mesh = cfg["mesh"]
    box_nm = mesh["nx"] * mesh["dx_nm"]
    cell_nm = 2.2
    n = int(round(box_nm / cell_nm))
    film = IndependentFilm(nx=n, ny=n, cell_nm=box_nm / n, thickness_nm=mesh["nz"] * mesh["dz_nm"],
                           n_grains=int(cfg["n_grains"]), torque_tol_T=cfg["minimizer"]["torque_tol_T"],
                           max_iterations=cfg["minimizer"]["max_iterations"])
    grid = np.linspace(-cfg["field"]["B_max_T"], cfg["field"]["B_max_T"], cfg["field"]["n_fields"])
    family = magnumnp_family(params, grid, [grid[k:] for k in range(len(grid))], film=film, seed=seed)
    curves = np.full((len(grid), len(grid)), np.nan)
    for k, values in enumerate(family.curves):
        curves[k, k:] = values
    return rasterize_grid_family(curves)


def make_case(case: str, cfg: dict, rows: list[dict], keys: list[int], workers: int = 1) -> np.ndarray:
    """Images (n, side, side) of ``case`` for the Hamiltonians ``rows`` (SI dicts), new disorder per key."""
    if case == "magnumnp":
        from ..reference.magnumnp_film import magnumnp_available

        if not magnumnp_available():
            raise ConfigError("the magnumnp case needs magnum.np (pip install -e .[reference])")
        jobs = [(cfg, {**r, "N_pin": 0}, int(k)) for r, k in zip(rows, keys)]
        worker = magnumnp_image
    else:
        jobs = []
        for r, k in zip(rows, keys):
            c, p = case_film(cfg, r, case)
            jobs.append((c, p, int(k) + DISORDER_KEY_OFFSET))
        worker = our_family
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            return np.stack(list(pool.map(worker, jobs)))
    return np.stack([worker(j) for j in jobs])


def bench_ood(est, cfg: dict, rows: list[dict], sample_ids, ms_norm, cases=CASES, workers: int = 1,
              out_dir=None, say=print, dataset_images=None) -> dict:
    """Flag rate of the OOD check per case (module docstring); ``rows`` the held-out Hamiltonians (SI,
    with Ms), ``ms_norm`` their normalized M_s. With ``dataset_images`` (the dataset's own images of
    the same Hamiltonians, another disorder realisation) each case also reports how far its images
    lie from them (mean |Δ| in grey levels): for ``control`` that is the realisation floor, and a case
    whose images differ by no more than the floor cannot be told from an in-prior film by any check
    of the image."""
    from ..learn.ood import ood_check

    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise ConfigError(f"unknown OOD case(s) {', '.join(unknown)} (one of {', '.join(CASES)})")
    if not est.metadata.get("ood"):
        raise ConfigError("the posterior model has no OOD reference (train it with forcdecode learn posterior)")
    out = {"n_families": len(rows), "alpha": float(est.metadata["ood"]["alpha"]), "cases": {}}
    for case in cases:
        path = Path(out_dir) / f"{case}.npz" if out_dir else None
        started = time.perf_counter()
        if path is not None and path.exists():
            images = np.load(path)["images"]
            if len(images) != len(rows):
                raise ConfigError(f"{path} holds {len(images)} families, not the {len(rows)} asked for: "
                                  "use another --ood-dir or the same --families")
        else:
            say(f"ood: simulating {len(rows)} families of case {case}")
            images = make_case(case, cfg, rows, list(sample_ids), workers)
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(".tmp.npz")
                np.savez_compressed(tmp, images=images)
                tmp.replace(path)
        checks = ood_check(est, images, ms_norm)
        flagged = sum(r["out_of_distribution"] for r in checks)
        low, high = clopper_pearson(flagged, len(checks))
        p = np.array([r["p_value"] for r in checks])
        row = {"flagged": int(flagged), "n": len(checks), "flagged_fraction": flagged / len(checks),
               "interval_90": [low, high], "median_p": float(np.median(p)), "p_values": p.tolist(),
               "wall_s": time.perf_counter() - started}
        if dataset_images is not None:
            diff = np.abs(images.astype(float) - np.asarray(dataset_images, dtype=float)).mean(axis=(1, 2))
            row["grey_levels_from_dataset_family"] = diff.tolist()
            row["median_grey_levels_from_dataset_family"] = float(np.median(diff))
        out["cases"][case] = row
        say(f"ood {case}: {flagged}/{len(checks)} flagged [{low:.2f}, {high:.2f}], median p {np.median(p):.3f}")
    return out


def ood_lines(result: dict) -> list[str]:
    """The table: one line per case."""
    lines = [f"{'case':24s} {'flagged':>9s} {'90 % interval':>15s} {'median p':>9s} {'|Δ| to dataset family':>22s}",
             f"(α = {result['alpha']}; {result['n_families']} held-out Hamiltonians, new disorder; |Δ| in grey "
             "levels, median over families; control's is the realisation floor)"]
    for case, row in result["cases"].items():
        lo, hi = row["interval_90"]
        delta = row.get("median_grey_levels_from_dataset_family", float("nan"))
        lines.append(f"{case:24s} {row['flagged']:>4d}/{row['n']:<4d} {f'[{lo:.2f}, {hi:.2f}]':>15s} "
                     f"{row['median_p']:9.3f} {delta:22.1f}")
    return lines


__all__ = ["CASES", "bench_ood", "case_film", "clopper_pearson", "make_case", "ood_lines"]

