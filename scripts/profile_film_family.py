"""Where one FORC family's time goes on a film of the information map (issue 62 item 1: profile first).

For the film (default ``box128_8nm``: 128 × 128 × 2 cells of 2 × 2 × 4 nm, 64 grains, the 256 nm × 8 nm
film that bounds N_pin 0.13× the laptop's) and one perpendicular Hamiltonian (the example control's:
M_s 800 kA/m, A_ex 13 pJ/m, K_u 700 kJ/m³, D 1 mJ/m², N_pin 40, σ_θ 5°, σ_K 0.1), prints:

1. the cost of one effective-field evaluation, all terms, and of each term alone (demag = the FFT
   convolution), averaged over repeated calls;
2. one quasi-static family (64 reversal fields, the config's shortcuts) of that Hamiltonian and of
   ``--draws`` draws of the config's prior (sample ids 1…): wall and CPU seconds, relaxations,
   minimizer iterations (each one field evaluation plus the Barzilai–Borwein step), and from them the
   iterations per relaxation and the seconds per iteration, against the field evaluation's own cost
   (the rest is the minimizer's vector work and the protocol's bookkeeping).

    .venv/bin/python scripts/profile_film_family.py [--film box128_8nm] [--repeats 20] [--draws 3]
    (minutes per prior draw on one core for the 128 x 128 x 2 film)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from forcdecode.bench.films import film_config
from forcdecode.bench.information_films import FILMS
from forcdecode.config import load_config, shipped_config
from forcdecode.core.prior import Prior
from forcdecode.core.streams import stream_rng
from forcdecode.forc.protocol import quasistatic_family
from forcdecode.micromag.build import build_film, sweep_options

PARAMS = {"Ms": 8e5, "A_ex": 1.3e-11, "K_u": 7e5, "D": 1e-3, "N_pin": 40, "sigma_theta_deg": 5.0, "sigma_K": 0.1}


def _seconds_per_call(fn, repeats: int) -> float:
    fn()  # compiled and warmed
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--film", default="box128_8nm", choices=sorted(FILMS))
    parser.add_argument("--repeats", type=int, default=20, help="field evaluations timed per term")
    parser.add_argument("--draws", type=int, default=0, help="also this many prior draws (sample ids 1..N)")
    args = parser.parse_args()
    cfg = film_config(load_config(shipped_config("config")), args.film, FILMS)
    film, m0, _ = build_film(cfg, PARAMS, rng=stream_rng(cfg["seed"], "bench_film", "profile", args.film))
    mesh = cfg["mesh"]
    print(f"film {args.film}: {mesh['nx']}x{mesh['ny']}x{mesh['nz']} cells, {cfg['n_grains']} grains")
    m = np.array(m0, copy=True)
    total = _seconds_per_call(lambda: film.effective_field(m, 0.3), args.repeats)
    print(f"one effective-field evaluation, all terms: {1e3 * total:.2f} ms")
    for term in film.terms:
        alone = film.with_terms((term,))
        t = _seconds_per_call(lambda: alone.effective_field(m, 0.3), args.repeats)
        print(f"  {term:10s} alone: {1e3 * t:.2f} ms ({100 * t / total:.0f} % of all terms)")
    prior = Prior(cfg.get("prior", "perpendicular"), cfg.get("bounds"))
    hamiltonians = [("the example's Hamiltonian", PARAMS)]
    hamiltonians += [(f"prior draw {k}", prior.sample(cfg["seed"], k)) for k in range(1, args.draws + 1)]
    for label, params in hamiltonians:
        film, m0, _ = build_film(cfg, params, rng=stream_rng(cfg["seed"], "bench_film", "profile", args.film))
        wall, cpu = time.perf_counter(), time.process_time()
        family = quasistatic_family(film, m0, n_fields=cfg["field"]["n_fields"], B_max_T=cfg["field"]["B_max_T"],
                                    **sweep_options(cfg))
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        stats = family.stats
        per_relaxation = stats["iterations"] / max(stats["relaxations"], 1)
        per_iteration = cpu / max(stats["iterations"], 1)
        shown = ", ".join(f"{k} {v:.3g}" for k, v in params.items())
        print(f"{label} ({shown}): {wall:.1f} s wall, {cpu:.1f} CPU-s; {stats['relaxations']} relaxations, "
              f"{stats['iterations']} iterations ({per_relaxation:.1f} per relaxation), "
              f"{1e3 * per_iteration:.2f} ms per iteration = {per_iteration / total:.2f} field evaluations; "
              f"unconverged {stats.get('unconverged', 0)}, curves shortened {stats.get('curves_shortened', 0)}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
