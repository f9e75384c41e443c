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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError
from ..core.io import read_json, write_json
from ..core.parameters import DEFAULT_BOUNDS
from ..dataset.simulate import simulate
from ..forc.raster import rasterize_grid_family
from ..infer.predictive_check import check_figure, predictive_check
from ..infer.refine import fit_one
from ..reference.independent import IndependentFilm, magnumnp_family
from ..reference.magnumnp_film import magnumnp_available

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


def our_family(job) -> tuple[np.ndarray, np.ndarray]:
    """(uint8 image, grid family m_z (n, n)) of one family on our engine: job = (cfg, params, disorder key)."""

    cfg, params, key = job
    out = simulate(cfg, params, key)
    if out["status"] != "ok":
        raise RuntimeError(f"family (key {key}) failed: {out['reason']}")
    return out["image"], np.asarray(out["curves_mz"], dtype=float)


def magnumnp_image(job) -> tuple[np.ndarray, np.ndarray]:
    """(uint8 image, grid family) of one magnum.np family on the training field grid: job = (cfg, params, seed)."""
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
    return rasterize_grid_family(curves), curves


def make_case(case: str, cfg: dict, rows: list[dict], keys: list[int], workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Images (n, side, side) and grid families (n, n_fields, n_fields) of ``case`` for the Hamiltonians
    ``rows`` (SI dicts), new disorder per key."""
    if case == "magnumnp":
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
            done = list(pool.map(worker, jobs))
    else:
        done = [worker(j) for j in jobs]
    return np.stack([d[0] for d in done]), np.stack([d[1] for d in done])


@dataclass(frozen=True)
class HeldOutFamilies:
    """The held-out families a bench case re-makes: ``rows`` their Hamiltonians (SI dicts, with Ms in
    A/m), ``sample_ids`` their ids (the disorder keys of the new realisations), ``ms_norm`` their
    normalized M_s, and ``dataset_images`` the dataset's own images of them (another disorder
    realisation, uint8 (n, side, side)) or None."""

    rows: list
    sample_ids: object
    ms_norm: object
    dataset_images: object = None


@dataclass(frozen=True)
class CaseFamilies:
    """One case's families for the predictive check: ``images`` (n, side, side) uint8, ``curves`` their
    grid families (n, n_fields, n_fields; moment / M_s), ``Ms`` their saturation magnetisations (A/m)
    and ``keys`` their disorder keys (the sample ids)."""

    images: object
    curves: object
    Ms: object
    keys: object


def bench_ood(est, cfg: dict, families: HeldOutFamilies, cases=CASES, workers: int = 1, out_dir=None, say=print,
              predictive: dict | None = None) -> dict:
    """Flag rate of the OOD check per case (module docstring) on the held-out ``families``. With their
    ``dataset_images`` each case also reports how far its images lie from them (mean |Δ| in grey
    levels): for ``control`` that is the realisation floor, and a case whose images differ by no more
    than the floor cannot be told from an in-prior film by any check of the image. With ``predictive``
    (budget, round_size, workers, seed, prior, fit_dir and the validation ``reference`` of
    ``infer.predictive_check``; ``cases``: those it runs on, empty for all) every family is also refined
    and judged by the posterior-predictive check."""
    rows, sample_ids, ms_norm = families.rows, families.sample_ids, families.ms_norm
    dataset_images = families.dataset_images
    # loads torch: imported only when this runs
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
        use_predictive = predictive is not None and (not predictive.get("cases") or case in predictive["cases"])
        images = curves = None
        if path is not None and path.exists():
            stored = np.load(path)
            images = stored["images"]
            curves = stored["curves"] if "curves" in stored.files else None
            if len(images) != len(rows):
                raise ConfigError(f"{path} holds {len(images)} families, not the {len(rows)} asked for: "
                                  "use another --ood-dir or the same --families")
        if images is None or (use_predictive and curves is None):
            say(f"ood: simulating {len(rows)} families of case {case}")
            fresh, curves = make_case(case, cfg, rows, list(sample_ids), workers)
            if images is not None and not np.array_equal(fresh, images):
                say(f"ood: {path} held other images for case {case} (median |Δ| "
                    f"{np.median(np.abs(fresh.astype(float) - images).mean(axis=(1, 2))):.2f} grey levels): replaced")
            images = fresh
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(".tmp.npz")
                np.savez_compressed(tmp, images=images, curves=curves.astype(np.float32))
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
        say(f"ood {case}: {flagged}/{len(checks)} flagged [{low:.2f}, {high:.2f}], median p {np.median(p):.3f}")
        if use_predictive:
            case_families = CaseFamilies(images, curves, [r["Ms"] for r in rows], list(sample_ids))
            row["predictive"] = predictive_case(est, cfg, case_families, predictive, Path(predictive["fit_dir"]) / case,
                                                say, ood_flags=[r["out_of_distribution"] for r in checks])
        out["cases"][case] = row
    return out


def carry_over(previous: dict | None, result: dict) -> dict:
    """``result`` with the rows of an earlier run over the same families (same split, sample ids and
    posterior) that this run did not compute: a run over some cases (``--ood-cases``,
    ``--predictive-cases``) then adds to summary.json instead of erasing the others. Earlier
    predictive rows are kept only where they were judged against the same validation reference."""
    if not previous or any(previous.get(k) != result.get(k) for k in ("split", "sample_ids", "posterior")):
        return result
    reference = result.get("predictive_reference", previous.get("predictive_reference"))
    same_reference = previous.get("predictive_reference") == reference
    for case, row in previous.get("cases", {}).items():
        now = result["cases"].setdefault(case, {k: v for k, v in row.items() if k != "predictive" or same_reference})
        if same_reference and "predictive" in row and "predictive" not in now:
            now["predictive"] = row["predictive"]
    if reference is not None and any("predictive" in row for row in result["cases"].values()):
        result["predictive_reference"] = reference
    return result


def predictive_statistics(est, cfg: dict, families: CaseFamilies, settings: dict, fit_dir, say=print) -> list[dict]:
    """Refine each of ``families`` for ``settings["budget"]`` simulations (``infer.refine.fit_one``; one
    fit.json and state per family in ``fit_dir``, resumable) and return the fit results."""
    images, curves, Ms, keys = families.images, families.curves, families.Ms, families.keys
    fit_dir = Path(fit_dir)
    fit_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for n, (image, family, ms, key) in enumerate(zip(images, curves, Ms, keys), 1):
        path = fit_dir / f"sample_{int(key)}.json"
        result = read_json(path, what="fit result") if path.exists() else None
        budget = int(settings["budget"])
        if result is None or str(budget) not in result["observation_rms"].get("best_over_floor_by_budget", {}):
            say(f"predictive check: refining family {n}/{len(keys)} (key {key}), {budget} simulations")
            result = fit_one(cfg, est, image, np.asarray(family, float), float(ms), budget=budget,
                             round_size=int(settings["round_size"]), workers=int(settings["workers"]),
                             seed=int(settings["seed"]), key=int(key), checkpoints=(budget,),
                             state_path=str(fit_dir / f"state_{int(key)}.npz"), prior=settings["prior"])
            write_json(path, result)
        results.append(result)
    return results


def predictive_case(est, cfg, families: CaseFamilies, settings: dict, fit_dir, say=print, ood_flags=None) -> dict:
    """The predictive check on one case's ``families`` against ``settings["reference"]`` (validation),
    with its figure (``fit_dir``/predictive_check.png)."""
    keys = families.keys
    results = predictive_statistics(est, cfg, families, settings, fit_dir, say)
    checks = [predictive_check(r, settings["reference"]) for r in results]
    flagged = [c["misspecified"] for c in checks]
    either = flagged if ood_flags is None else [a or b for a, b in zip(flagged, ood_flags)]
    low, high = clopper_pearson(sum(flagged), len(flagged))
    lo2, hi2 = clopper_pearson(sum(either), len(either))
    row = {"flagged": int(sum(flagged)), "n": len(flagged), "flagged_fraction": sum(flagged) / len(flagged),
           "interval_90": [low, high], "statistics": [c["statistic"] for c in checks],
           "p_values": [c["p_value"] for c in checks], "median_statistic": float(np.median([c["statistic"] for c in checks])),
           "flagged_by_either": int(sum(either)), "either_interval_90": [lo2, hi2]}
    say(f"  predictive check: {row['flagged']}/{row['n']} flagged [{low:.2f}, {high:.2f}], median T "
        f"{row['median_statistic']:.2f}; with the training-data check: {row['flagged_by_either']}/{row['n']}")
    check_figure(Path(fit_dir) / "predictive_check.png", settings["reference"],
                 {f"key {int(k)}": c for k, c in zip(keys, checks)},
                 title=f"predictive check, {Path(fit_dir).name}: {row['flagged']} of {row['n']} flagged")
    return row


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
    if any("predictive" in row for row in result["cases"].values()):
        ref = result.get("predictive_reference", {})
        lines += ["", f"posterior-predictive check (best of {ref.get('budget', '?')} simulations / realisation floor; "
                      f"calibrated on {len(ref.get('values', []))} validation families, median "
                      f"{np.median(ref.get('values', [np.nan])):.2f}, max {np.max(ref.get('values', [np.nan])):.2f})",
                  f"{'case':24s} {'flagged':>9s} {'90 % interval':>15s} {'median T':>9s} {'either check':>13s}"]
        for case, row in result["cases"].items():
            pr = row.get("predictive")
            if pr is None:
                continue
            lo, hi = pr["interval_90"]
            lines.append(f"{case:24s} {pr['flagged']:>4d}/{pr['n']:<4d} {f'[{lo:.2f}, {hi:.2f}]':>15s} "
                         f"{pr['median_statistic']:9.2f} {pr['flagged_by_either']:>8d}/{pr['n']:<4d}")
    return lines


__all__ = ["CASES", "CaseFamilies", "HeldOutFamilies", "bench_ood", "case_film", "clopper_pearson", "make_case", "ood_lines", "predictive_case",
           "predictive_statistics"]

