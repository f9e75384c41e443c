"""``forcdecode bench information`` (issue 43): the Fisher map of the FORC family over films, at
fiducial Hamiltonians of the prior, with the micromagnetic engine as the simulator.

Fiducials. A pool of dataset draws (``draw_parameters``, ids 0..pool−1) is screened on the laptop
film (``dataset.simulate.screen`` with the shipped config); the passing draws give the prior's
screened mass in three regimes (K_eff = K_u − μ0M_s²/2, σ_w = 4√(A_ex K_eff) − π|D|):

* ``K_eff<0``  (in-plane shape anisotropy wins: K_eff < 0),
* ``spirals``  (K_eff > 0, σ_w ≤ 0: chiral spirals),
* ``domains``  (σ_w > 0: perpendicular domains).

The fiducials are allotted to the regimes by that mass (largest remainders, at least one for a
regime with any mass), spread over N_pin within each (evenly spaced N_pin quantiles), and ordered
round-robin over the regimes so a stopped run leaves a stratified subset. The list is written to
``OUT/fiducials.json`` before any family is simulated, and reused from there on a rerun.

Per fiducial and film: the families at u and at u ± δ e_i (normalized units, six parameters, M_s
fixed) for the realisations r = 0..R−1, each realisation's disorder from the ``bench_film`` stream
("information", film, sample id, r): the same at every stencil point (common random numbers; N_pin
changes the number of pinning cells, which re-draws their positions: its differences carry that
noise). One file per family, ``OUT/<film>/s<id>/<point>_r<r>.npz`` (resumable); a fiducial's
families are simulated by processes of their own (peak RSS and CPU time read with ``wait4``), one per
fiducial and, where the workers outnumber the fiducials left, more on one fiducial, each claiming a
family before simulating it (``<point>_r<r>.claim``). The first
``stability`` fiducials are simulated at every δ asked for (the stability check in R and δ);
the others at the first δ only.

Analysis per fiducial (``analyse_fiducial``): two channels, the float ⟨m_z⟩ (a solver floor of 1e-8, ``FLOAT_FLOOR``) and
the 8-bit image (grey levels back in m_z units, the quantization variance Δ²/12 added to Σ), both
on the 2080 points the family visits; for every R' ∈ {R/2, R} (the first R' realisations) and δ:
F, CRBs, eigen-decomposition, the angle between the best-identified (A_ex, D) direction (top
eigenvector of F's A_ex–D block) and ∇σ_w in normalized coordinates.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import physics
from ..core.io import append_jsonl, atomic_path, write_json
from ..core.parameters import denormalize, normalize
from ..core.streams import stream_rng
from ..dataset.params import draw_parameters
from ..dataset.simulate import screen
from ..forc.adaptive import SlewRate, adaptive_family
from ..forc.protocol import quasistatic_family
from ..forc.raster import rasterize_grid_family
from ..micromag.build import build_film, slew_rate_options, sweep_options
from .films import film_config
from .information import (QUANT_STEP, _finite_list, best_direction, best_matched_direction, compressed_fisher, crb,
                          fisher_from_families, matched_direction_crb, matched_filter_crb_pooled, principal_angle_deg,
                          stencil, upper_triangle)

NAMES = ("K_u", "A_ex", "D", "N_pin", "sigma_theta_deg", "sigma_K")
"""The parameters differentiated (normalized units; M_s is given)."""

FILMS: dict[str, dict] = {
    "laptop": dict(nx=64, ny=64, nz=1, n_grains=16, protocol="quasistatic", names=NAMES),
    "laptop_8nm": dict(nx=64, ny=64, nz=2, n_grains=16, protocol="quasistatic", names=NAMES),
    "box128_8nm": dict(nx=128, ny=128, nz=2, n_grains=64, protocol="quasistatic",
                       names=("K_u", "A_ex", "D", "N_pin")),
    "paper": dict(nx=256, ny=256, nz=2, n_grains=255, protocol="quasistatic", names=("K_u", "A_ex", "D", "N_pin")),
    "laptop_llg": dict(nx=64, ny=64, nz=1, n_grains=16, protocol="llg", names=("A_ex", "D"), disorder_of="laptop"),
    "period_box": dict(nx=136, ny=136, nz=1, n_grains=72, protocol="quasistatic",
                       names=("K_u", "A_ex", "D", "N_pin"), regimes=("spirals",)),
}
"""Films of the issue (cells 2 × 2 × 4 nm, grains ≈ 32 nm). ``paper`` (256²×2)
is listed so the summary can say it was not measured. ``laptop_llg`` is the laptop film under the
seed paper's adaptive slew-rate LLG protocol (``forc.adaptive``, pinning cells slaved as in the dataset's
``llg`` protocol), differentiated in A_ex and D only (the issue's question: does a finite sweep rate
carry information on them that a magnetometer-like quasi-static sweep does not); ``disorder_of`` makes
its realisation r the laptop film's realisation r (the same grains and pinning sites: common random
numbers across the two protocols, so the paired comparison sees only the protocol). ``period_box`` is the laptop film's 4 nm
sized from its fiducials' period: it runs only the fiducials of ``regimes`` (the chiral spirals, whose
period 4πA_ex/|D| is 103–133 nm at the laptop map's two spiral fiducials), in a 272 nm box that holds
≥ 2 of the longer period (2.05 and 2.6 periods) where the 128 nm laptop box holds about one; grains
≈ 32 nm as in the laptop film (72 in 272² nm²)."""

NOT_MEASURED = {
    "paper": "256x256x2: a family costs ~340x the laptop's (729 CPU-s, docs/films.md); >= 2 fiducials x 9 points x "
             "R >= 4 is days of 2 shared cores, and no GPU machine was lent",
}
NOT_YET = {
    "laptop_llg": "the LLG sweep-rate protocol is ~360x dearer than quasi-static (docs/engine.md, 2026-11-28): 4-6 CPU-h "
                  "a fiducial at R = 4 (A_ex and D; 189 CPU-s a 12-field family measured); not run yet",
    "period_box": "a box of >= 2 spiral periods (136^2x1, 272 nm, for the spiral fiducials): ~40 CPU-s a family, "
                  "72 families at R = 4 for the two spiral fiducials; not run yet",
}
"""Films that can run but have no fiducial measured: why, for the summary."""


def film_fiducials(film: str, fiducials: list[dict]) -> list[dict]:
    """The fiducials a film runs: all of them, or those in the film's ``regimes``."""
    regimes = FILMS[film].get("regimes")
    return [f for f in fiducials if regimes is None or f["regime"] in regimes]

REGIMES = ("K_eff<0", "spirals", "domains")

FLOAT_FLOOR = 1e-8
"""Variance (m_z²) added to Σ of the float channel: the minimizer's own scatter (torque tolerance
1 mT against fields of ~1 T: |Δm| ~ 1e-4), so that Σ stays invertible where every realisation agrees."""


def k_eff(p: dict) -> float:
    """K_eff = K_u − μ0 M_s²/2 (J/m³), ``core.physics``."""
    return physics.k_eff(p["K_u"], p["Ms"])


def sigma_w(p: dict) -> float:
    """Wall energy 4√(A_ex K_eff) − π|D| (J/m²); NaN where K_eff ≤ 0."""
    return physics.wall_energy(p["A_ex"], k_eff(p), p["D"])


def wall_width(p: dict) -> float:
    """The wall parameter Δ = √(A_ex/K_eff) (m; δ_w/π); NaN where K_eff ≤ 0."""
    return physics.wall_parameter(p["A_ex"], k_eff(p))


def regime(p: dict) -> str:
    if k_eff(p) < 0:
        return "K_eff<0"
    return "spirals" if sigma_w(p) <= 0 else "domains"


def to_unit(p: dict, names=NAMES) -> np.ndarray:
    return np.array([float(normalize(n, p[n])) for n in names])


def from_unit(u: np.ndarray, base: dict, names=NAMES) -> dict:
    """SI parameters with ``names`` set from u (N_pin stays a real number: ``pinning_cells`` rounds)."""
    out = dict(base)
    for n, v in zip(names, u):
        out[n] = float(denormalize(n, v))
    return out


def gradient(fn, p: dict, names, h: float = 1e-5) -> np.ndarray:
    """∂fn/∂u for ``names`` (central differences in normalized units)."""
    u = to_unit(p, names)
    g = np.zeros(len(names))
    for i in range(len(names)):
        up, um = u.copy(), u.copy()
        up[i] += h
        um[i] -= h
        g[i] = (fn(from_unit(up, p, names)) - fn(from_unit(um, p, names))) / (2 * h)
    return g


# --- fiducials -------------------------------------------------------------------------------------------

def screened_pool(cfg: dict, pool: int, say=print) -> list[dict]:
    """The draws 0..pool−1 that pass the screening of ``cfg`` (the laptop film), with their regime."""
    out = []
    for sid in range(pool):
        p = draw_parameters(cfg["seed"], sid)
        if screen(cfg, p, sid)["screen_status"] == "passed":
            out.append({"sample_id": sid, **p, "regime": regime(p), "K_eff": k_eff(p), "sigma_w": sigma_w(p)})
        if (sid + 1) % 25 == 0:
            say(f"screened {sid + 1}/{pool} draws, {len(out)} pass")
    return out


def allot(masses: dict[str, int], n: int) -> dict[str, int]:
    """Fiducials per regime proportional to ``masses`` (largest remainders; ≥ 1 where mass > 0)."""
    total = sum(masses.values())
    present = [r for r in REGIMES if masses.get(r, 0) > 0]
    counts = {r: 1 for r in present}
    left = n - len(present)
    share = {r: max(n * masses[r] / total - 1, 0.0) for r in present}
    scale = left / sum(share.values()) if sum(share.values()) > 0 else 0.0
    for r in present:
        counts[r] += int(np.floor(share[r] * scale))
    rest = sorted(present, key=lambda r: -(share[r] * scale - np.floor(share[r] * scale)))
    for r in rest[: n - sum(counts.values())]:
        counts[r] += 1
    return counts


def choose_fiducials(pool_rows: list[dict], n: int) -> dict:
    """Stratified fiducials (module docstring) from the screened pool."""
    masses = {r: sum(1 for p in pool_rows if p["regime"] == r) for r in REGIMES}
    counts = allot(masses, n)
    picked = {}
    for r, k in counts.items():
        members = sorted((p for p in pool_rows if p["regime"] == r), key=lambda p: (p["N_pin"], p["sample_id"]))
        k = min(k, len(members))
        idx = sorted({int(round((j + 0.5) * len(members) / k - 0.5)) for j in range(k)})
        picked[r] = [members[i] for i in idx]
    order = []
    for j in range(max((len(v) for v in picked.values()), default=0)):
        for r in sorted(picked, key=lambda r: -masses[r]):
            if j < len(picked[r]):
                order.append(picked[r][j])
    return {"pool": len(pool_rows), "screened_mass": masses,
            "mass_fraction": {r: masses[r] / max(len(pool_rows), 1) for r in REGIMES}, "allotted": counts,
            "fiducials": order}


# --- simulation -------------------------------------------------------------------------------------------

def points(u: np.ndarray, names, deltas) -> list[tuple[str, np.ndarray, float]]:
    """(label, u at the point, δ) of the stencil: the centre, then u ∓ δ e_i per parameter and δ."""
    out = [("c", u.copy(), 0.0)]
    for d in deltas:
        for i, n in enumerate(names):
            lo, hi = stencil(u[i], d)
            um, up = u.copy(), u.copy()
            um[i], up[i] = lo, hi
            out += [(f"{n}-{d:g}", um, d), (f"{n}+{d:g}", up, d)]
    return out


def family_path(out_dir, film: str, sid: int, label: str, r: int) -> Path:
    return Path(out_dir) / film / f"s{sid:05d}" / f"{label}_r{r}.npz"


def film_rng(cfg: dict, film: str, sid: int, r: int):
    """The disorder generator of realisation ``r`` at fiducial ``sid``: the ``bench_film`` stream of
    (film, sid, r), where film is the spec's ``disorder_of`` if it names one (the same grains and sites
    as that film's realisation r)."""

    return stream_rng(cfg["seed"], "bench_film", "information", FILMS[film].get("disorder_of", film), int(sid), int(r))


def simulate_family(cfg: dict, film: str, params: dict, sid: int, r: int) -> dict:
    """One family of realisation r: float curves (64×64, NaN below the diagonal), the uint8 image,
    CPU seconds of this process."""
    spec = FILMS[film]
    fcfg = film_config(cfg, film, FILMS)
    if spec["protocol"] not in ("quasistatic", "llg"):
        raise NotImplementedError(f"film {film}: protocol {spec['protocol']} not implemented here")
    cpu = time.process_time()
    rng = film_rng(cfg, film, sid, r)
    n_fields, B_max_T = fcfg["field"]["n_fields"], fcfg["field"]["B_max_T"]
    if spec["protocol"] == "llg":
        f, m0, _ = build_film(fcfg, params, pinning="slaved", rng=rng)
        fam = adaptive_family(f, m0, n_fields=n_fields, B_max_T=B_max_T, settings=SlewRate(**slew_rate_options(fcfg)))
    else:
        f, m0, _ = build_film(fcfg, params, rng=rng)
        fam = quasistatic_family(f, m0, n_fields=n_fields, B_max_T=B_max_T, **sweep_options(fcfg))
    return {"curves": fam.curves_mz.astype(np.float32), "image": rasterize_grid_family(fam.curves_mz),
            "cpu_s": time.process_time() - cpu, "unconverged": int(fam.stats.get("unconverged", 0))}


def claim_path(family: Path) -> Path:
    """The claim a process holds on a family while it simulates it (``<point>_r<r>.claim``)."""
    return Path(family).with_suffix(".claim")


def _claim(family: Path) -> bool:
    """Claim ``family`` for this process: True if no other process holds it and it is not on disk
    (the claim file is created exclusively, so two processes cannot both get it)."""
    if family.exists():
        return False
    family.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.close(os.open(claim_path(family), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    if family.exists():  # written, and its claim released, between the first look and the claim
        claim_path(family).unlink()
        return False
    return True


def fiducial_families(film: str, fid: dict, R: int, deltas, out_dir) -> list[tuple[Path, np.ndarray, dict, int]]:
    """(file, u, SI parameters, realisation) of every family of one fiducial: the stencil's points
    (``points``) × the realisations 0..R−1."""
    names = FILMS[film]["names"]
    sid = int(fid["sample_id"])
    base = {k: fid[k] for k in ("Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K")}
    return [(family_path(out_dir, film, sid, label, r), up, from_unit(up, base, names), r)
            for label, up, _ in points(to_unit(base, names), names, deltas) for r in range(R)]


def run_fiducial(cfg: dict, film: str, fid: dict, R: int, deltas, out_dir) -> None:
    """Every family of one fiducial that is neither on disk nor claimed by another process (this
    process; several may work on one fiducial, each family is simulated once)."""

    sid = int(fid["sample_id"])
    for path, up, params, r in fiducial_families(film, fid, R, deltas, out_dir):
        if not _claim(path):
            continue
        try:
            fam = simulate_family(cfg, film, params, sid, r)
        except Exception as error:  # recorded, the analysis drops the point
            fam = {"curves": np.full((64, 64), np.nan, np.float32), "image": np.zeros((64, 64), np.uint8),
                   "cpu_s": float("nan"), "unconverged": -1, "error": f"{type(error).__name__}: {error}"}
        fam["rss_MiB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, u=up, **fam)
        claim_path(path).unlink()


@dataclass(frozen=True)
class FiducialDesign:
    """What is simulated around each fiducial: ``R`` disorder realisations per family, ``deltas`` the
    relative steps δ of the central differences (fractions of the normalized parameter), and
    ``stability`` the number of fiducials (the first ones) simulated at every δ; the others at the
    first δ only."""

    R: int
    deltas: tuple
    stability: int


def run_fiducials(cfg: dict, film: str, fids: list[dict], design: FiducialDesign, out_dir, say=print,
                  stop_at: float | None = None, workers: int = 1) -> None:
    """The fiducials' families (``design``: realisations, steps δ) in processes of their own, ``workers``
    at a time (``stop_at``: a time.time() after which no process starts). Each worker starts a
    process on the open fiducial with the fewest processes (the first in the list on a tie): one per
    fiducial while there are more fiducials than workers, then the workers a finished fiducial frees
    join the fiducials still running that have a family left unclaimed (a process ends when its fiducial
    has none, which closes the fiducial to new processes). The last process of a fiducial to end
    analyses it.
    ``costs.jsonl``: each process's CPU time and peak RSS, from ``wait4``, so the cost per family does not
    depend on how many ran beside it. Claims left by a killed run are removed first: one run per
    results directory at a time."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    R, deltas, stability = design.R, design.deltas, design.stability
    out_dir = Path(out_dir)
    cfg_path = out_dir / "config.json"
    cfg_path.parent.mkdir(parents=True, exist_ok=True)
    cfg_path.write_text(json.dumps(cfg))
    lock = threading.Lock()

    def result_path(fid: dict) -> Path:
        return out_dir / film / f"s{int(fid['sample_id']):05d}.json"

    def deltas_of(k: int) -> list:  # the first ``stability`` fiducials at every δ, the others at the first
        return list(deltas) if k < stability else list(deltas)[:1]

    todo = [(k, fid) for k, fid in enumerate(fids) if not result_path(fid).exists()]
    for k, fid in todo:  # stale claims of a run that was killed
        for path, *_ in fiducial_families(film, fid, R, deltas_of(k), out_dir):
            claim_path(path).unlink(missing_ok=True)
    running = {k: 0 for k, _ in todo}
    closed: set[int] = set()
    failed: set[int] = set()

    def process(k: int, fid: dict) -> dict:
        ds = deltas_of(k)
        spec = json.dumps({"config": str(cfg_path), "film": film, "film_spec": FILMS[film], "fiducial": fid,
                           "R": R, "deltas": ds, "out": str(out_dir)})
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "forcdecode.bench.information_films", spec],
                                env={**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
        _, status, usage = os.wait4(proc.pid, 0)
        row = {"film": film, "sample_id": int(fid["sample_id"]), "exit": os.waitstatus_to_exitcode(status),
               "wall_s": time.perf_counter() - start, "cpu_s": usage.ru_utime + usage.ru_stime,
               "peak_rss_MiB": usage.ru_maxrss / 1024, "deltas": ds, "R": R, "workers": workers}
        with lock:
            append_jsonl(out_dir / "costs.jsonl", row)
        return row

    def finish(k: int, fid: dict, row: dict) -> None:
        """The fiducial's analysis, by its last process (the families of all of them on disk)."""
        if k in failed:
            say(f"{film} fiducial {fid['sample_id']}: a process exited non-zero (exit {row['exit']} last); not analysed")
            return
        analysis = analyse_fiducial(out_dir, film, fid, R, deltas_of(k))
        analysis["process"] = row
        write_json(result_path(fid), analysis)
        say(fiducial_line(analysis))

    def unclaimed_left(k: int, fid: dict) -> bool:
        return any(not (path.exists() or claim_path(path).exists())
                   for path, *_ in fiducial_families(film, fid, R, deltas_of(k), out_dir))

    def worker() -> None:
        while True:
            with lock:  # a fiducial is open to its first process, and to more while a family is unclaimed
                open_ = [(running[k], n, k, fid) for n, (k, fid) in enumerate(todo)
                         if k not in closed and (running[k] == 0 or unclaimed_left(k, fid))]
                if not open_:
                    return
                if stop_at is not None and time.time() > stop_at:
                    say(f"{film}: stop time reached before a process on fiducial {open_[0][3]['sample_id']}")
                    return
                _, _, k, fid = min(open_, key=lambda x: x[:2])
                running[k] += 1
            row = process(k, fid)
            with lock:
                running[k] -= 1
                closed.add(k)  # this process found no family left to claim (or failed): no new ones
                if row["exit"] != 0:
                    failed.add(k)
                last = running[k] == 0
            if last:
                finish(k, fid, row)

    if workers <= 1:
        worker()
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:  # threads only wait on the processes
        for future in [pool.submit(worker) for _ in range(workers)]:
            future.result()


# --- analysis ---------------------------------------------------------------------------------------------

def _load(out_dir, film, sid, label, R):
    rows = [np.load(family_path(out_dir, film, sid, label, r)) for r in range(R)]
    curves = np.stack([upper_triangle(x["curves"]) for x in rows])
    images = np.stack([upper_triangle(x["image"].astype(float) / 127.5 - 1.0) for x in rows])
    cpu = [float(x["cpu_s"]) for x in rows]
    rss = [float(x["rss_MiB"]) for x in rows]
    return curves, images, cpu, rss


def analyse_fiducial(out_dir, film: str, fid: dict, R: int, deltas) -> dict:
    """Fisher analysis of one fiducial from the families on disk (module docstring)."""
    names = FILMS[film]["names"]
    sid = int(fid["sample_id"])
    base = {k: fid[k] for k in ("Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K")}
    u = to_unit(base, names)
    pts = {label: (up, d) for label, up, d in points(u, names, deltas)}
    loaded = {label: _load(out_dir, film, sid, label, R) for label in pts}
    cpu = [c for v in loaded.values() for c in v[2]]
    out = {"film": film, "sample_id": sid, "params": base, "regime": regime(base), "K_eff": k_eff(base),
           "sigma_w": sigma_w(base), "wall_width_nm": wall_width(base) * 1e9,
           "spiral_period_nm": (4 * np.pi * base["A_ex"] / abs(base["D"]) * 1e9) if base["D"] else None, "u": u.tolist(), "names": list(names),
           "R": R, "deltas": list(deltas), "families": len(cpu),
           "cpu_s_per_family_median": float(np.nanmedian(cpu)), "cpu_s_per_family_mean": float(np.nanmean(cpu)),
           "failed_families": int(sum(not np.all(np.isfinite(v[0])) for v in loaded.values())),
           "channels": {}}
    has_aD = "A_ex" in names and "D" in names and np.isfinite(out["sigma_w"])
    g_sw = gradient(sigma_w, base, names) if has_aD else None
    g_ww = gradient(wall_width, base, names) if has_aD else None
    for channel, col, floor in (("float", 0, FLOAT_FLOOR), ("image", 1, QUANT_STEP**2 / 12)):
        res_ch = {}
        for d in deltas:
            for Rs in sorted({max(R // 2, 2), R}):
                center = loaded["c"][col][:Rs]
                plus = np.stack([loaded[f"{n}+{d:g}"][col][:Rs] for n in names])
                minus = np.stack([loaded[f"{n}-{d:g}"][col][:Rs] for n in names])
                steps = np.array([pts[f"{n}+{d:g}"][0][i] - pts[f"{n}-{d:g}"][0][i] for i, n in enumerate(names)])
                ok = np.all(np.isfinite(center), axis=0) & np.all(np.isfinite(plus), axis=(0, 1)) & \
                    np.all(np.isfinite(minus), axis=(0, 1))
                res = fisher_from_families(center[:, ok], plus[:, :, ok], minus[:, :, ok], steps, names, u, floor)
                row = res.to_json()
                row["points_used"] = int(ok.sum())
                dd = (plus[:, :, ok] - minus[:, :, ok]) / steps[:, None, None]  # k × R × p per realisation
                groups = [center[:, ok]] + [plus[k][:, ok] for k in range(len(names))] + \
                    [minus[k][:, ok] for k in range(len(names))]
                row["crb_conditional_matched_pooled"] = _finite_list(matched_filter_crb_pooled(groups, dd, floor))
                if "A_ex" in names and "D" in names and "K_u" in names:
                    sub2 = [names.index("A_ex"), names.index("D")]
                    sub3 = [names.index("K_u")] + sub2
                    row["crb_AD_compressed"] = _finite_list(crb(compressed_fisher(center[:, ok], dd, sub2, floor)))
                    row["crb_KAD_compressed"] = _finite_list(crb(compressed_fisher(center[:, ok], dd, sub3, floor)))
                if has_aD:
                    i, j = names.index("A_ex"), names.index("D")
                    lam, V = best_direction(res.F, names, ("A_ex", "D"))
                    row["AD_block_eigenvalues"] = lam.tolist()
                    row["AD_best_direction"] = V[:, 0].tolist()
                    row["sigma_w_alignment_deg"] = principal_angle_deg(V[:, 0], g_sw[[i, j]])
                    row["wall_width_alignment_deg"] = principal_angle_deg(V[:, 0], g_ww[[i, j]])
                    row["sigma_w_alignment_matched_deg"] = _matched_plane_angle(center[:, ok], plus[:, :, ok],
                                                                                minus[:, :, ok], steps, (i, j),
                                                                                g_sw[[i, j]], floor)
                    row["crb_matched_sigma_w_direction"] = _finite_or_none(
                        matched_direction_crb(center[:, ok], dd, (i, j), g_sw[[i, j]], floor))
                    best, v_best = best_matched_direction(center[:, ok], dd, (i, j), floor)
                    row["crb_matched_best_AD_direction"] = _finite_or_none(best)
                    row["best_AD_direction_matched"] = v_best.tolist()
                    row["sigma_w_alignment_best_matched_deg"] = principal_angle_deg(v_best, g_sw[[i, j]])
                    if "K_u" in names:
                        k3 = [names.index(n) for n in ("K_u", "A_ex", "D")]
                        lam3, V3 = best_direction(res.F, names, ("K_u", "A_ex", "D"))
                        row["KAD_best_direction"] = V3[:, 0].tolist()
                        row["sigma_w_alignment_KAD_deg"] = principal_angle_deg(V3[:, 0], g_sw[k3])
                res_ch[f"R{Rs}_d{d:g}"] = row
        out["channels"][channel] = res_ch
    if has_aD:
        out["grad_sigma_w_u"] = g_sw.tolist()
        out["grad_wall_width_u"] = g_ww.tolist()
    return out


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _matched_plane_angle(center, plus, minus, steps, idx, grad, floor) -> float:
    """Angle between ∇σ_w and the best-identified direction in the (A_ex, D) plane from the two
    projections t = [J_A, J_D]ᵀx alone (their 2 × 2 sample covariance, R − 1 dof; no Σ⁻¹ in p
    dimensions): F₂ = (J₂ᵀJ₂)(J₂ᵀSJ₂)⁻¹(J₂ᵀJ₂)."""
    d = (plus - minus) / np.asarray(steps, float)[:, None, None]
    J2 = d[list(idx)].mean(axis=1).T  # p × 2
    X = center - center.mean(axis=0)
    T = X @ J2
    St = T.T @ T / max(len(center) - 1, 1) + floor * (J2.T @ J2)
    G = J2.T @ J2
    try:
        F2 = G @ np.linalg.solve(St, G)
    except np.linalg.LinAlgError:
        return float("nan")
    lam, V = np.linalg.eigh(0.5 * (F2 + F2.T))
    return principal_angle_deg(V[:, np.argmax(lam)], grad)


def fiducial_line(a: dict) -> str:
    key = f"R{a['R']}_d{a['deltas'][0]:g}"
    row = a["channels"]["float"][key]
    crbs = " ".join(f"{n}={'inf' if c is None else f'{c:.3g}'}" for n, c in zip(a["names"], row["crb_single"]))
    return (f"{a['film']} s{a['sample_id']} [{a['regime']}] {key}: CRB(single) {crbs}; rho {row['rho']:.2f}; "
            f"sigma_w angle {row.get('sigma_w_alignment_deg', float('nan')):.0f} deg; "
            f"{a['cpu_s_per_family_median']:.1f} CPU-s/family")


def reanalyse(out_dir, say=print) -> int:
    """Re-make every fiducial's JSON from its families on disk (the analysis changed, the simulations
    did not); keeps the process row. Returns the number re-made."""

    out_dir = Path(out_dir)
    done = 0
    for path in sorted(out_dir.glob("*/s*.json")):
        old = json.loads(path.read_text())
        fid = {"sample_id": old["sample_id"], **old["params"]}
        if old["film"] not in FILMS:
            continue
        if not family_path(out_dir, old["film"], old["sample_id"], "c", 0).exists():
            continue  # a result kept without its families (e.g. committed under docs/results): kept as it is
        new = analyse_fiducial(out_dir, old["film"], fid, old["R"], old["deltas"])
        if "process" in old:
            new["process"] = old["process"]
        write_json(path, new)
        done += 1
    say(f"re-analysed {done} fiducials from their families")
    return done


# --- summary ----------------------------------------------------------------------------------------------

def _nan(v):
    return float("inf") if v is None else float(v)


def _stats(values) -> dict:
    v = np.array([_nan(x) for x in values], float)
    if len(v) == 0:
        return {"median": None, "iqr": None, "n": 0}
    q1, med, q3 = np.percentile(v, [25, 50, 75]) if np.all(np.isfinite(v)) else (
        np.nanpercentile(np.where(np.isfinite(v), v, 1e300), [25, 50, 75]))
    fix = lambda x: None if not np.isfinite(x) or x >= 1e299 else float(x)  # noqa: E731
    return {"median": fix(med), "iqr": [fix(q1), fix(q3)], "n": int(len(v)), "n_unidentified": int(np.sum(~np.isfinite(v)))}


def _block(analyses: list[dict], names, channel: str, key_of) -> dict:
    rows = [(a, a["channels"][channel].get(key_of(a))) for a in analyses]
    rows = [(a, r) for a, r in rows if r is not None]
    per = {}
    for i, n in enumerate(names):
        single = _stats([r["crb_single"][i] for _, r in rows])
        meanR = _stats([r["crb_mean_R"][i] for _, r in rows])
        noise = [r["noise_fraction"][i] for _, r in rows
                 if r["noise_fraction"][i] is not None and np.isfinite(r["noise_fraction"][i])]
        cond = {key: _stats([r.get(key, [None] * len(names))[i] for _, r in rows])
                for key in ("crb_conditional", "crb_conditional_noise_corrected", "crb_conditional_matched",
                            "crb_conditional_matched_pooled")}
        per[n] = {"crb_single_median": single["median"], "crb_single_iqr": single["iqr"],
                  **{f"{key}_median": c["median"] for key, c in cond.items()},
                  "crb_conditional_matched_iqr": cond["crb_conditional_matched"]["iqr"],
                  "crb_mean_R_median": meanR["median"], "n_unidentified": single.get("n_unidentified", 0),
                  "derivative_noise_fraction_median": float(np.nanmedian(noise)) if noise else None}
    angles = [r["sigma_w_alignment_deg"] for _, r in rows if r.get("sigma_w_alignment_deg") is not None
              and np.isfinite(r["sigma_w_alignment_deg"])]
    matched = [r["sigma_w_alignment_matched_deg"] for _, r in rows
               if r.get("sigma_w_alignment_matched_deg") is not None and np.isfinite(r["sigma_w_alignment_matched_deg"])]
    compressed = {}
    for key, sub in (("crb_AD_compressed", ("A_ex", "D")), ("crb_KAD_compressed", ("K_u", "A_ex", "D"))):
        vals = [r[key] for _, r in rows if key in r]
        if vals:
            compressed[key] = {n: _stats([v[m] for v in vals])["median"] for m, n in enumerate(sub)}
    combination = {}
    for key in ("crb_matched_sigma_w_direction", "crb_matched_best_AD_direction", "sigma_w_alignment_best_matched_deg"):
        vals = [r[key] for _, r in rows if key in r]
        if vals:
            stats = _stats(vals)
            combination[key] = {"median": stats["median"], "iqr": stats["iqr"], "n": stats["n"]}
    return {"n_fiducials": len(rows), "per_parameter": per, "compressed_median": compressed,
            "AD_combination": combination,
            "sigma_w_alignment_deg_median": float(np.median(angles)) if angles else None,
            "sigma_w_alignment_n": len(angles),
            "sigma_w_alignment_matched_deg_median": float(np.median(matched)) if matched else None,
            "rho_median": float(np.median([r["rho"] for _, r in rows])) if rows else None}


def paired_to(analyses: list[dict], reference: list[dict], names) -> dict:
    """A film against a reference film on the fiducials both measured (same Hamiltonian, float channel,
    each film's primary R and δ): per parameter, the ratio film/reference of the conditional matched-filter
    bound (conservative) and of the Ledoit–Wolf marginal bound, per fiducial and as a median, and how many
    fiducials the film bounds tighter. ∞ (unidentified) compares as larger than any finite bound.

    The reference stays at its own R even where it also has the film's smaller R (the laptop film at
    R = 8 has R = 4 rows): over the laptop's 16 fiducials its own R = 4 / R = 8 ratio of the matched
    bound spans 0.5–1.7 for A_ex and 0.04–20 for D (10–90 %), median 1.1, so a second R = 4 estimate
    in the denominator would add far more noise than the ~10 % bias it removes."""
    ref = {a["sample_id"]: a for a in reference}
    shared = [a for a in analyses if a["sample_id"] in ref]
    ref_names = ref[shared[0]["sample_id"]]["names"] if shared else []
    out = {"n_fiducials": len(shared), "sample_ids": [a["sample_id"] for a in shared], "per_parameter": {}}

    def bound(a, key, n):
        row = a["channels"]["float"][f"R{a['R']}_d{a['deltas'][0]:g}"]
        v = row.get(key, [None] * len(a["names"]))[a["names"].index(n)]
        return float("inf") if v is None else float(v)

    for n in names:
        if n not in ref_names:
            continue
        block = {}
        for key in ("crb_conditional_matched", "crb_single"):
            pairs = [(bound(a, key, n), bound(ref[a["sample_id"]], key, n)) for a in shared]
            ratios = [f / r if np.isfinite(f) and np.isfinite(r) and r > 0 else
                      (0.0 if np.isfinite(f) and not np.isfinite(r) else (float("inf") if np.isfinite(r) else None))
                      for f, r in pairs]
            finite = [x for x in ratios if x is not None]
            block[key] = {"ratios": [None if x is None or not np.isfinite(x) else x for x in ratios],
                          "median_ratio": (None if not finite or not np.isfinite(np.median(finite))
                                           else float(np.median(finite))),
                          "film_tighter": int(sum(f < r for f, r in pairs)), "n": len(pairs)}
        out["per_parameter"][n] = block
    return out


def stability(analyses: list[dict], names) -> dict:
    """Per fiducial simulated at several δ (float channel): every (R, δ)'s single-family marginal CRB
    (Ledoit–Wolf) and conditional matched-filter bound, as ratios to those at (R, δ₀); and their
    medians over those fiducials (1: stable)."""
    rows = []
    for a in analyses:
        if len(a["deltas"]) < 2:
            continue
        ref = a["channels"]["float"][f"R{a['R']}_d{a['deltas'][0]:g}"]
        row = {"sample_id": a["sample_id"], "regime": a["regime"], "crb_single": {}, "crb_conditional_matched": {},
               "ratio_single": {}, "ratio_matched": {}}
        for key, r in a["channels"]["float"].items():
            for what, ratio in (("crb_single", "ratio_single"), ("crb_conditional_matched", "ratio_matched")):
                row[what][key] = dict(zip(names, r[what]))
                row[ratio][key] = {n: (None if c is None or c0 is None else c / c0)
                                   for n, c, c0 in zip(names, r[what], ref[what])}
        rows.append(row)
    medians = {}
    for ratio in ("ratio_single", "ratio_matched"):
        keys = sorted({k for r in rows for k in r[ratio]})
        medians[ratio] = {k: {n: _median_or_none([r[ratio][k][n] for r in rows if k in r[ratio]]) for n in names}
                          for k in keys}
    return {"fiducials": rows, "median_ratio_to_reference": medians,
            "reference": f"R{analyses[0]['R']}_d{analyses[0]['deltas'][0]:g}" if analyses else None}


def _median_or_none(values):
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else None


MAIN_JOB = {
    "draws": 1000,
    "film_core_s": 703 + 1528 + 1100 + 497,
    "other_core_s": 2950 + 600,
    "wall_over_ideal": 1.4,
    "laptop_family_core_s": 2.1,
}
"""The laptop main job (config/config.yaml, 1,000 draws, 404 families), measured from fresh clones on
2026-11-28 (docs/workflow.md, docs/results/2026-11-28-sealed.md): CPU-s that scale with a film's cost
(screening 703, families 1,528, the sealed set's draws and families ≈ 1,100, the closed loop's
re-simulations 497) and that do not (the learning stage 2,950, the posterior's training and checks
≈ 600); the wall on 2 cores is ≈ 1.4 × the ideal core-s / 2 (85–92 min measured against 61 ideal). A
film's family cost is compared with the laptop film's from the same summary when it is there (a ratio
measured in one run), else with the 2.1 CPU-s of the laptop map of 2026-11-28."""
MIN_DRAWS = 500
"""Fewest draws a main job may shrink to and still be a main job (~200 families: a test split of ~60 and a
learning curve past its flat point at ~30 families, docs/learning.md)."""
WALL_LIMIT_HOURS = 2.0


def _laptop_cost(out_dir) -> float:
    """CPU-s of a laptop family: the median over the laptop fiducials on disk, else the 2026-11-28 figure."""
    rows = [json.loads(p.read_text())["cpu_s_per_family_median"] for p in sorted((Path(out_dir) / "laptop").glob("s*.json"))]
    return float(np.median(rows)) if rows else MAIN_JOB["laptop_family_core_s"]


def main_job_estimate(cost_ratio: float, draws: int = MAIN_JOB["draws"]) -> dict:
    """Core-hours and wall hours on 2 cores of the main job at ``draws`` draws on a film whose family
    costs ``cost_ratio`` × the laptop film's, and the most draws that keep it within 2 hours."""
    film = MAIN_JOB["film_core_s"] * cost_ratio * draws / MAIN_JOB["draws"]
    core_s = film + MAIN_JOB["other_core_s"]
    budget = WALL_LIMIT_HOURS * 3600 * 2 / MAIN_JOB["wall_over_ideal"] - MAIN_JOB["other_core_s"]
    fit = int(MAIN_JOB["draws"] * budget / (MAIN_JOB["film_core_s"] * cost_ratio)) if budget > 0 else 0
    return {"cost_ratio_to_laptop": float(cost_ratio), "draws": int(draws), "core_hours": core_s / 3600,
            "wall_hours_2_cores": MAIN_JOB["wall_over_ideal"] * core_s / 2 / 3600,
            "draws_within_2h": fit, "eligible": fit >= MIN_DRAWS}


def summarize(out_dir, films=None) -> dict:
    """summary.json from whatever is on disk (films or fiducials not yet measured are marked)."""
    out_dir = Path(out_dir)
    fid_file = out_dir / "fiducials.json"
    fiducials = json.loads(fid_file.read_text()) if fid_file.exists() else None
    costs = {}
    if (out_dir / "costs.jsonl").exists():
        for line in (out_dir / "costs.jsonl").read_text().splitlines():
            row = json.loads(line)
            costs.setdefault(row["film"], []).append(row)
    summary = {"fiducials": fiducials, "films": {}, "not_measured": {}}
    for film, spec in FILMS.items():
        analyses = [json.loads(p.read_text()) for p in sorted((out_dir / film).glob("s*.json"))] \
            if (out_dir / film).exists() else []
        if not analyses:
            summary["not_measured"][film] = NOT_MEASURED.get(film, NOT_YET.get(film, "no fiducial measured yet"))
            continue
        names = spec["names"]
        R = max(a["R"] for a in analyses)
        d0 = analyses[0]["deltas"][0]
        primary = lambda a: f"R{a['R']}_d{d0:g}"  # noqa: E731
        cpu = float(np.median([a["cpu_s_per_family_median"] for a in analyses]))
        film_row = {"mesh": [spec["nx"], spec["ny"], spec["nz"]], "thickness_nm": 4 * spec["nz"],
                    "box_nm": [2 * spec["nx"], 2 * spec["ny"], 4 * spec["nz"]], "protocol": spec["protocol"],
                    "n_grains": spec["n_grains"], "cost_core_s_per_family": cpu,
                    "peak_rss_MiB": float(max(r["peak_rss_MiB"] for r in costs.get(film, [{"peak_rss_MiB": np.nan}]))),
                    "R": R, "delta": d0, "parameters": list(names),
                    "fiducials_measured": [a["sample_id"] for a in analyses],
                    "fiducials_not_yet": [f["sample_id"] for f in film_fiducials(film, (fiducials or {}).get("fiducials", []))
                                          if f["sample_id"] not in {a["sample_id"] for a in analyses}]}
        if spec.get("regimes"):
            periods = [a["spiral_period_nm"] for a in analyses if a.get("spiral_period_nm")]
            film_row.update(regimes=list(spec["regimes"]), spiral_period_nm=periods,
                            box_periods=[2 * spec["nx"] / p for p in periods])
        main = _block(analyses, names, "float", primary)
        film_row.update(n_fiducials=main["n_fiducials"], per_parameter=main["per_parameter"],
                        sigma_w_alignment_deg_median=main["sigma_w_alignment_deg_median"],
                        sigma_w_alignment_matched_deg_median=main["sigma_w_alignment_matched_deg_median"],
                        compressed_median=main["compressed_median"], AD_combination=main["AD_combination"],
                        rho_median=main["rho_median"])
        film_row["image"] = _block(analyses, names, "image", primary)
        film_row["per_regime"] = {r: {"float": _block([a for a in analyses if a["regime"] == r], names, "float", primary),
                                      "image": _block([a for a in analyses if a["regime"] == r], names, "image", primary)}
                                  for r in REGIMES}
        film_row["stability"] = stability(analyses, names)
        laptop = [json.loads(p.read_text()) for p in sorted((out_dir / "laptop").glob("s*.json"))]
        if film != "laptop" and laptop:
            film_row["paired_to_laptop"] = paired_to(analyses, laptop, names)
        film_row["main_job"] = main_job_estimate(cpu / _laptop_cost(out_dir))
        film_row["main_job_core_hours"] = film_row["main_job"]["core_hours"]
        film_row["main_job_wall_hours_2_cores"] = film_row["main_job"]["wall_hours_2_cores"]
        film_row["bound_at_one_core_hour"] = {
            n: (None if film_row["per_parameter"][n]["crb_single_median"] is None else
                film_row["per_parameter"][n]["crb_single_median"] * np.sqrt(cpu / 3600.0)) for n in names}
        film_row["matched_bound_at_one_core_hour"] = {
            n: (None if film_row["per_parameter"][n]["crb_conditional_matched_median"] is None else
                film_row["per_parameter"][n]["crb_conditional_matched_median"] * np.sqrt(cpu / 3600.0)) for n in names}
        summary["films"][film] = film_row
    for film, why in NOT_MEASURED.items():
        if film not in summary["films"]:
            summary["not_measured"][film] = why
    summary["chosen_film"] = choose_film(summary["films"])
    summary["estimators"] = ESTIMATORS
    return summary


ESTIMATORS = {
    "crb_single": "marginal CRB sqrt((F^-1)_ii) of one family, F = J^T Sigma^-1 J, J by CRN central differences "
                  "(mean over the R realisations), Sigma the Ledoit-Wolf shrinkage (to mu*I) of the R families at "
                  "the fiducial plus a floor (float 1e-8, image (2/255)^2/12); normalized units (prior width 1)",
    "crb_mean_R": "the same for the mean of R families (Sigma/R)",
    "crb_conditional": "1/sqrt(F_ii): the other parameters known",
    "crb_conditional_noise_corrected": "1/sqrt(F_ii - N_ii), N_ii the share of F_ii from the noise of J-hat",
    "crb_conditional_matched": "conservative conditional bound from the projection J_i^T x alone: sqrt(J_i^T S J_i) / "
                               "|J_i|^2 (S the unbiased sample covariance; |J_i|^2 noise-corrected); >= the true "
                               "conditional CRB, needs no inverse covariance in p = 2080 dimensions, stable at R = 8",
    "crb_conditional_matched_pooled": "crb_conditional_matched with the projection's scatter pooled over the 2k+1 "
                                      "stencil points (each about its own mean): steadier at R = 4, the bound of the "
                                      "delta-neighbourhood; reported, not used by the choice",
    "crb_AD_compressed": "marginal bounds of A_ex and D (the other four known) from the 2 projections [J_A, J_D]^T x "
                         "with their 2x2 sample covariance, Hartlap-debiased ((R-4)/(R-1)); crb_KAD_compressed: the "
                         "same for (K_u, A_ex, D) ((R-5)/(R-1)); conservative",
    "crb_matched_sigma_w_direction": "the matched-filter conditional bound on the combination v^T u, v = grad sigma_w "
                                     "in the normalized (A_ex, D) plane (a direction fixed by physics, not by the data; "
                                     "K_u, N_pin, ... known), in prior widths along v",
    "crb_matched_best_AD_direction": "the same along the direction of the (A_ex, D) plane that minimizes it (a 1-degree "
                                     "grid; chosen on the same families, slightly optimistic); "
                                     "sigma_w_alignment_best_matched_deg: its angle to grad sigma_w",
    "sigma_w_alignment_deg": "angle between the top eigenvector of F's (A_ex, D) block and grad sigma_w (normalized u)",
    "sigma_w_alignment_matched_deg": "the same from the 2x2 Fisher of the projections [J_A, J_D]^T x",
}


def _score(row: dict, key: str) -> float | None:
    """Geometric mean over A_ex, D, N_pin of a film's bound at one core-hour (``key``); ∞ where one of
    them is unidentified at the median, None where the film has no such bound."""
    b = [row[key].get(n, "missing") for n in CHOICE_PARAMETERS]
    if any(v == "missing" for v in b):
        return None
    return float("inf") if any(v is None for v in b) else float(np.exp(np.mean(np.log(b))))


CHOICE_PARAMETERS = ("A_ex", "D", "N_pin")


def choose_film(films: dict) -> dict:
    """Lowest bound per core-hour for A_ex, D, N_pin among films whose main job stays within 2 h on 2
    cores at ≥ ``MIN_DRAWS`` draws (``main_job_estimate``). Bound per core-hour: a single-family bound
    × √(CPU-h per family), i.e. the bound of the mean of the families one core-hour buys; the score is
    its geometric mean over A_ex, D, N_pin (∞ if one is unidentified).

    The choice rests on the conservative matched-filter conditional bound: on the closed-form check
    (``information_check``) the Ledoit–Wolf marginal bound is 0.23–0.29 of the analytic one at R = 8
    (too optimistic, by a factor that depends on the film's dimension and scatter), the matched filter
    0.86–1.08. The Ledoit–Wolf score is reported beside it (``scores_ledoit_wolf``), never used. A film
    without a matched-filter bound for all three does not compete, nor one measured on a single regime's
    fiducials (``regimes`` in ``FILMS``: its median is that regime's, not the prior's)."""
    rule = ("lowest geometric mean over A_ex, D, N_pin of crb_conditional_matched_median * "
            "sqrt(cost_core_s_per_family / 3600) (the conservative bound of the mean of the families one core-hour "
            "buys) among films whose main job fits 2 h on 2 cores with >= "
            f"{MIN_DRAWS} draws (main_job.eligible; n_samples = main_job.draws_within_2h where below 1000)")
    # a film measured on one regime's fiducials only (period_box) has a median of that regime: not comparable
    eligible = {film: row for film, row in films.items() if row["main_job"]["eligible"] and not row.get("regimes")}
    matched = {film: _score(row, "matched_bound_at_one_core_hour") for film, row in eligible.items()}
    ledoit_wolf = {film: _score(row, "bound_at_one_core_hour") for film, row in eligible.items()}
    competing = {film: v for film, v in matched.items() if v is not None}
    finite = lambda d: {k: (None if v is None or not np.isfinite(v) else v) for k, v in d.items()}  # noqa: E731
    if not competing:
        return {"film": None, "rule": rule, "scores": {}, "scores_ledoit_wolf": finite(ledoit_wolf)}
    best = min(competing, key=competing.get)
    if not np.isfinite(competing[best]):
        best = None  # no eligible film identifies all three at its median
    return {"film": best, "rule": rule, "scores": finite(competing), "scores_ledoit_wolf": finite(ledoit_wolf),
            "not_eligible": sorted(set(films) - set(eligible)),
            "note": "only the films measured compete" + ("" if len(competing) > 1 else ": one film measured, chosen by default")}


def _combination_line(c: dict) -> str:
    """The matched bounds of the A_ex-D combinations (medians over the fiducials)."""
    fmt = lambda k: "n/a" if k not in c else ("inf" if c[k]["median"] is None else f"{c[k]['median']:.3g}")  # noqa: E731
    return (f"A_ex-D combinations, matched-filter conditional: along grad sigma_w {fmt('crb_matched_sigma_w_direction')}, "
            f"best direction {fmt('crb_matched_best_AD_direction')} at {fmt('sigma_w_alignment_best_matched_deg')} deg "
            "from grad sigma_w")


def summary_lines(summary: dict) -> list[str]:
    lines = []
    fids = summary.get("fiducials") or {}
    if fids:
        lines.append(f"fiducials: pool of {fids['pool']} screened draws, mass {fids['screened_mass']}, "
                     f"allotted {fids['allotted']}")
    for film, row in summary["films"].items():
        lines.append(f"{film} ({'x'.join(map(str, row['mesh']))}, {row['protocol']}): {row['n_fiducials']} fiducials, "
                     f"R={row['R']}, delta={row['delta']}, {row['cost_core_s_per_family']:.1f} CPU-s/family, "
                     f"peak {row['peak_rss_MiB']:.0f} MiB, LW rho {row['rho_median']:.2f}")
        lines.append("  parameter        CRB single median [IQR]        CRB mean-of-R   unidentified  J-noise  "
                     "conditional: LW  matched-filter")
        for n, p in row["per_parameter"].items():
            fmt = lambda v: "inf" if v is None else f"{v:.3g}"  # noqa: E731
            iqr = p["crb_single_iqr"] or [None, None]
            lines.append(f"  {n:16s} {fmt(p['crb_single_median']):>8s} [{fmt(iqr[0])}, {fmt(iqr[1])}]"
                         f"{fmt(p['crb_mean_R_median']):>18s} {p['n_unidentified']:10d}  "
                         f"{fmt(p['derivative_noise_fraction_median']):>7s}  {fmt(p['crb_conditional_median']):>15s}  "
                         f"{fmt(p['crb_conditional_matched_median'])}")
        lines.append(f"  sigma_w alignment (A_ex-D best direction vs grad sigma_w), median: "
                     f"{row['sigma_w_alignment_deg_median']}")
        if row.get("AD_combination"):
            lines.append("  " + _combination_line(row["AD_combination"]))
        job = row["main_job"]
        lines.append(f"  main job: {job['cost_ratio_to_laptop']:.2f}x the laptop family, {job['wall_hours_2_cores']:.2f} h "
                     f"on 2 cores at 1000 draws; {job['draws_within_2h']} draws fit 2 h")
        paired = row.get("paired_to_laptop")
        if paired and paired["n_fiducials"]:
            parts = []
            for n, blk in paired["per_parameter"].items():
                m = blk["crb_conditional_matched"]
                ratio = "n/a" if m["median_ratio"] is None else f"{m['median_ratio']:.2f}"
                parts.append(f"{n} {ratio} ({m['film_tighter']}/{m['n']} tighter)")
            lines.append(f"  vs laptop on {paired['n_fiducials']} shared fiducials, matched bound ratio median: "
                         + ", ".join(parts))
        for r, blk in row["per_regime"].items():
            b = blk["float"]
            if b["n_fiducials"]:
                crbs = ", ".join(f"{n} {('inf' if p['crb_single_median'] is None else format(p['crb_single_median'], '.3g'))}"
                                 for n, p in b["per_parameter"].items())
                lines.append(f"  [{r}] n={b['n_fiducials']}: LW marginal {crbs}; sigma_w angle "
                             f"{b['sigma_w_alignment_deg_median']} (matched {b['sigma_w_alignment_matched_deg_median']})")
                matched = ", ".join(f"{n} {('inf' if p['crb_conditional_matched_median'] is None else format(p['crb_conditional_matched_median'], '.3g'))}"
                                    for n, p in b["per_parameter"].items())
                comp = "; ".join(f"{k.replace('crb_', '')}: " + ", ".join(
                    f"{n} {'inf' if v is None else format(v, '.3g')}" for n, v in c.items())
                    for k, c in b["compressed_median"].items())
                lines.append(f"      matched-filter conditional {matched}")
                if b.get("AD_combination"):
                    lines.append("      " + _combination_line(b["AD_combination"]))
                lines.append(f"      {comp}")
    for film, why in summary["not_measured"].items():
        lines.append(f"not measured: {film}: {why}")
    ch = summary["chosen_film"]
    lines.append(f"chosen film: {ch['film']} ({ch['rule']})")
    return lines


def figure(summary: dict, path) -> None:
    """Write ``draw_figure``'s figure to ``path`` (PNG, atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = draw_figure(summary)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


def draw_figure(summary: dict):
    """CRB (single family, median with IQR over the fiducials) per parameter against the CPU cost of
    a family. One colour per film, fixed by its place in ``FILMS``. Circles: float ⟨m_z⟩ (Ledoit–Wolf,
    marginal); open squares: the 8-bit image; triangles: the conservative conditional matched-filter
    bound (float); a marker at the top edge: unidentified (∞) at the median. Dotted: the prior's
    width (1). One legend beside the panels lists every film, whichever panels it has. Returns the
    matplotlib Figure."""
    import matplotlib
    import matplotlib.lines
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = 30.0
    fig, axes = plt.subplots(2, 3, figsize=(12, 6), sharex=True, sharey=True)
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colour = {film: cycle[k % len(cycle)] for k, film in enumerate(FILMS)}
    lowest = 1.0
    for ax, n in zip(axes.flat, ("K_u", "A_ex", "D", "N_pin", "sigma_theta_deg", "sigma_K")):
        for film, row in summary["films"].items():
            for blk, fmt, shift, what in ((row, "o", 1.0, "crb_single"), (row["image"], "s", 1.08, "crb_single"),
                                          (row, "^", 0.93, "crb_conditional_matched")):
                p = blk["per_parameter"].get(n)
                if p is None:
                    continue
                med = p[f"{what}_median"]
                iqr = p[f"{what}_iqr"] or [None, None]
                y = med if med is not None else top
                lo = iqr[0] if iqr[0] is not None else top
                hi = iqr[1] if iqr[1] is not None else top
                lowest = min(lowest, lo)
                ax.errorbar([row["cost_core_s_per_family"] * shift], [y], yerr=[[max(y - lo, 0)], [max(hi - y, 0)]],
                            fmt=fmt, capsize=3, color=colour[film],
                            mfc="none" if fmt == "s" or med is None else None)
        ax.axhline(1.0, color="k", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(n, fontsize=9)
    axes.flat[0].set_ylim(max(lowest / 3, 1e-6), top * 1.5)
    costs = [row["cost_core_s_per_family"] for row in summary["films"].values()]
    if costs and min(costs) > 0:
        axes.flat[0].set_xlim(min(costs) / 3, max(costs) * 3)
    for ax in axes[1]:
        ax.set_xlabel("CPU-s per family")
    for ax in axes[:, 0]:
        ax.set_ylabel("CRB, one family (normalized u)")
    line = matplotlib.lines.Line2D
    handles = [line([], [], color=colour[film], lw=6, label=film) for film in FILMS if film in summary["films"]]
    handles += [line([], [], color="grey", ls="none", marker=m, mfc=mfc, label=what) for m, mfc, what in (
        ("o", None, "float, Ledoit–Wolf"), ("s", "none", "8-bit image, Ledoit–Wolf"),
        ("^", None, "float, matched filter\n(conservative, conditional)"),
        ("^", "none", "open at the top edge:\nunidentified at the median"))]
    fig.legend(handles=handles, loc="center right", fontsize=8, frameon=False)
    fig.suptitle("Cramér–Rao bound per parameter vs cost of a family (median, IQR over fiducials; dotted: prior width)",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.8, 1))
    return fig


def _main(spec_json: str) -> int:
    spec = json.loads(spec_json)
    cfg = json.loads(Path(spec["config"]).read_text())
    # the parent's film spec is authoritative (a film of a test, or one the parent changed, runs as specified)
    FILMS[spec["film"]] = {**spec["film_spec"], "names": tuple(spec["film_spec"]["names"])}
    run_fiducial(cfg, spec["film"], spec["fiducial"], int(spec["R"]), spec["deltas"], spec["out"])
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1]))
