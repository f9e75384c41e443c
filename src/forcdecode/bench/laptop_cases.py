"""The effects bench's laptop case set (issue 59 item 3): cases a 2-core machine can run to their end,
fixed before any run, beside the 207-case cluster set (``effects_independent.CASES_FILE``, kept for the
SLURM profile).

Each case is a magnum.np film (``reference.independent``: another code, grid and disorder than the
fitting film) recorded by the independent instrument model into a MicroMag or Lake Shore file, then run
through `forcdecode loop` as a user runs it (``effects_user.run_user_case``). What differs from
the cluster set:

- **Pinned films.** The Hamiltonian's N_pin is kept as drawn (the cluster set sets it to 0); a film gets
  ``reference.independent.pins_for_density`` pinning cells, so most cases are pinned.
- **Patches.** A file averages 1, 2, 4 or 8 independent films (the case's ``patches``, ``PATCH_PLAN``), in
  turn: a small element reverses in jumps, a larger area is smoother.
- **Disorder statistics the engine does not draw**, on at least a quarter of the cases (``VARIANTS``):
  log-normal grain sizes, other grain counts, a uniform grain-anisotropy distribution, pins along ±z only.
- **Smaller films, fewer curves**, sized so that a case (the magnum.np sample and the loop) costs a few
  CPU-minutes: ``GRIDS`` of 30–36 cells of 3.5–4.2 nm (boxes of 126–128 nm), ``CURVES`` curves.

Counts (``COUNTS``): eval 24 controls, 12 each of background, drift (additive and multiplicative
together), field offset and second phase, 6 each of scale, K_2, bias field and field tilt, 12 outside the
library (3 per outside class); dev the same classes, fewer. Dev and eval share no seed and no
Hamiltonian (ids 200000.. and 300000.. of the dataset's parameter stream under ``SEED``; tested).
Thermal activation is not made (the generator has no temperature). M_s reaches the loop with a ±5 %
error (``effects_independent.MS_ERROR``); nothing else of the truth does.

Regenerate (the file is committed; a test checks it against this generator):
    python -c 'from forcdecode.bench.laptop_cases import write_cases_file; write_cases_file()'
"""

from __future__ import annotations

from pathlib import Path


from ..core.streams import stream_rng
from . import effects_independent
from .effects_independent import (LIBRARY_CLASSES, MS_ERROR, NOISE, _sig, _sizes, case_stem, draw_hamiltonians,
                                  fresh_seed, library_case, outside_cases)

CASES_FILE = Path(__file__).with_name("effects_cases_laptop.yaml")
SEED = 59
"""Seed of every draw of the laptop set (Hamiltonians: ``dataset.params.draw_parameters(SEED, id)``)."""

FIRST_ID = {"dev": 200000, "eval": 300000}

COUNTS = {
    "dev": {"controls": 6, "background": 3, "drift": 4, "field_offset": 3, "second_phase": 3, "scale": 2, "K_2": 2,
            "bias_field": 2, "field_tilt": 2, "per_outside_class": 1},
    "eval": {"controls": 24, "background": 12, "drift": 12, "field_offset": 12, "second_phase": 12, "scale": 6,
             "K_2": 6, "bias_field": 6, "field_tilt": 6, "per_outside_class": 3},
}
"""Cases per split and class ("drift": additive and multiplicative drifts, half each)."""

PATCH_PLAN = (1, 2, 4, 8)
"""Independent films a case's file averages, in turn over the cases of a split (shuffled): one patch (a
small element, one jump per avalanche), two, four and eight, the most a laptop pays for. Each patch is one
more magnum.np family: measured before the set was fixed (2026-12-02, a 32 × 32 film of 4 nm cells with 2
pins, 28 curves, 5 mT sweep nodes) a family took 264 s on a loaded core (1,279 relaxations), so the
issue's 16 or "many" patches (millimetre films) would cost an hour a case; eight patches of a 128 nm box
stand for the smooth end here, and the cluster set keeps the rest."""

GRIDS = ({"nx": 32, "cell_nm": 4.0}, {"nx": 30, "cell_nm": 4.2}, {"nx": 34, "cell_nm": 3.75}, {"nx": 36, "cell_nm": 3.5})
"""magnum.np grids (square, periodic, 4 nm thick): boxes of 126–128 nm, none our 64 × 64 × 2 nm."""

WALL_NM_MIN = 4.2
"""Walls √(A_ex/K_u) at least the largest cell: the coarse grids resolve them."""

CURVES = 24
SWEEP_STEP_T = 0.005
SHIFT = (0.2, 0.8)

VARIANTS = ("standard", "standard", "lognormal_grains", "more_grains", "uniform_anisotropy", "pins_along_z")
"""The disorder statistics of a case, in turn over a split's cases (shuffled): two of six standard (equal
grains of 12–32 per box, Gaussian grain anisotropy, pins of isotropic initial orientation), four of six
what our engine does not draw: log-normal grain sizes, 48–80 grains per box (grains of ≈ 15 nm), a
uniform anisotropy distribution, pins along ±z only."""


def _plan(split: str, rng) -> list[tuple]:
    """(kind, class, physics, instrument, size) per case of ``split``."""
    counts = COUNTS[split]
    plan = [("control", "none", {}, {}, None)] * counts["controls"]
    for name in ("background", "field_offset", "second_phase", "scale", "K_2", "bias_field", "field_tilt"):
        _, _, bounds, signed, grid = LIBRARY_CLASSES[name]
        sizes = _sizes(rng, counts[name], bounds, signed, grid)
        if name == "K_2":
            sizes = [max(v, -0.2) if v < 0 else v for v in sizes]
        plan += [library_case(name, v, rng) for v in sizes]
    half = counts["drift"] // 2
    for name, n in (("additive_drift", half), ("multiplicative_drift", counts["drift"] - half)):
        _, _, bounds, signed, _ = LIBRARY_CLASSES[name]
        plan += [library_case(name, v, rng) for v in _sizes(rng, n, bounds, signed)]
    return plan + outside_cases(rng, counts["per_outside_class"])


def _in_turn(rng, values, n: int) -> list:
    """``n`` values cycling through ``values``, shuffled: each value in equal share (±1)."""
    cycle = [values[i % len(values)] for i in range(n)]
    return [cycle[i] for i in rng.permutation(n)]


def _sample(rng, variant: str) -> dict:
    grid = GRIDS[int(rng.integers(len(GRIDS)))]
    n_grains = int(rng.integers(48, 81)) if variant == "more_grains" else int(rng.integers(12, 33))
    return {"nx": grid["nx"], "ny": grid["nx"], "cell_nm": grid["cell_nm"], "n_grains": n_grains,
            "anisotropy_distribution": "uniform" if variant == "uniform_anisotropy" else "gaussian",
            "grain_sizes": "lognormal" if variant == "lognormal_grains" else "equal",
            "pin_orientation": "z" if variant == "pins_along_z" else "isotropic", "variant": variant}


def generate_cases() -> dict:
    """The dev and eval cases of the laptop set (deterministic: everything from ``SEED``)."""
    sets, seeds_used = {}, set()
    for split in ("dev", "eval"):
        rng = stream_rng(SEED, "bench_film", "laptop_cases", split)
        plan = _plan(split, rng)
        hamiltonians = draw_hamiltonians(FIRST_ID[split], len(plan), seed=SEED, keep_pinning=True,
                                         wall_nm_min=WALL_NM_MIN)
        patches = _in_turn(rng, PATCH_PLAN, len(plan))
        variants = _in_turn(rng, VARIANTS, len(plan))
        cases = []
        for i, ((kind, name, physics, instrument, size), (h_id, h)) in enumerate(zip(plan, hamiltonians)):
            seed = fresh_seed(rng, seeds_used)
            stem = case_stem(name)
            cases.append({
                "name": f"laptop-{split}-{i:03d}-{stem}", "split": f"laptop-{split}", "kind": kind, "class": name,
                "hamiltonian_id": h_id, "hamiltonian": h, "in_prior": True, "sample": _sample(rng, variants[i]),
                "patches": int(patches[i]),
                "protocol": {"curves": CURVES, "shift": _sig(rng.uniform(*SHIFT), 3), "sweep_step_T": SWEEP_STEP_T},
                "realisation_seed": seed, "noise": _sig(NOISE[0] * (NOISE[1] / NOISE[0]) ** rng.uniform(), 3),
                "format": ["micromag0015", "lakeshore_csv"][int(rng.integers(2))],
                "physics": dict(physics), "instrument": dict(instrument),
                "size": None if size is None else _sig(size, 3),
                "Ms_error_factor": _sig(1 + rng.uniform(-MS_ERROR, MS_ERROR), 4)})
        sets[split] = cases
    return {"seed": SEED, "generator": "forcdecode.bench.laptop_cases.generate_cases",
            "patch_plan": list(PATCH_PLAN), "variants": list(VARIANTS), "dev": sets["dev"], "eval": sets["eval"]}


HEADER = ("# The effects bench's laptop case set (issue 59), fixed before any run: written by\n"
          "#   python -c 'from forcdecode.bench.laptop_cases import write_cases_file; write_cases_file()'\n"
          "# and checked against the generator by tests/bench/test_laptop_cases.py. Choices are made on `dev`;\n"
          "# `eval` is only reported. Do not edit by hand.\n")


def write_cases_file(path=CASES_FILE) -> Path:
    """Write ``generate_cases()`` as YAML (atomically)."""
    return effects_independent.write_cases_file(path, generate_cases(), HEADER)


def load_cases(split: str, path=CASES_FILE) -> list[dict]:
    """The cases of ``split`` ("dev" or "eval") of the laptop set; ConfigError otherwise."""
    return effects_independent.load_cases(split, path)


__all__ = ["CASES_FILE", "COUNTS", "GRIDS", "PATCH_PLAN", "SEED", "VARIANTS", "generate_cases", "load_cases",
           "write_cases_file"]
