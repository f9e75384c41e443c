"""Bit-for-bit identity check of a refactor: runs a few cheap deterministic commands that exercise the
loop, the per-file inference (fit, fit-step, loop --refine) and the residual analysis on the tiny
config, and writes their outputs to one JSON (floats at full precision: JSON reports as they are,
arrays as the sha256 of their bytes, other files as the sha256 of their bytes).

    PYTHONPATH=src python scripts/check_refactor_identity.py OUT.json [--cases loop,fit,...]

The case ``bench_effects`` is one real bench, ``forcdecode bench effects --seeds 1 --json`` (about 2 min on one
core); it is not in the default ``--cases`` (run it with ``--cases bench_effects``).

Run it before and after a refactor and compare the two files (``cmp`` or ``diff``)."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K"]
N_FIELDS = 24


def _resimulate():
    try:
        from forcdecode.infer.resimulate import resimulate
    except ImportError:
        from forcdecode.loop.resimulate import resimulate
    return resimulate


def _make_reference():
    try:
        from forcdecode.infer.predictive_check import make_reference
    except ImportError:
        from forcdecode.loop.predictive_check import make_reference
    return make_reference


def sha(array) -> str:
    array = np.ascontiguousarray(array)
    return f"{array.dtype.str}{list(array.shape)}:" + hashlib.sha256(array.tobytes()).hexdigest()


TIMING_KEYS = {"wall_s"}
"""Keys whose values are measured times (they differ between any two runs): replaced by "<time>"."""


def without_timings(value):
    if isinstance(value, dict):
        return {k: "<time>" if k in TIMING_KEYS else without_timings(v) for k, v in value.items()}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def npz_entry(array):
    """A JSON string stored in an array (a state file's metadata) as its contents, other arrays hashed."""
    if array.dtype.kind == "U" and array.size == 1:
        try:
            return without_timings(json.loads(str(array.reshape(-1)[0])))
        except ValueError:
            pass
    return sha(array)


def describe_dir(directory: Path) -> dict:
    """Every file under ``directory``: JSON contents, arrays hashed, other files hashed."""
    out = {}
    for path in sorted(p for p in directory.rglob("*") if p.is_file()):
        key = str(path.relative_to(directory))
        if path.suffix == ".json":
            out[key] = without_timings(json.loads(path.read_text()))
        elif path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                out[key] = {name: npz_entry(data[name]) for name in sorted(data.files)}
        elif path.suffix == ".npy":
            out[key] = sha(np.load(path, allow_pickle=False))
        else:
            out[key] = "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def tiny_config(tmp: Path, n_fields: int = N_FIELDS) -> Path:
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = n_fields
    path = tmp / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def film_file(tmp: Path, params: dict, background: float, noise: float) -> tuple[Path, Path]:
    """A simulated film written as a MicroMag file (as tests/loop/test_loop_cli.py makes it)."""
    from forcdecode.config import load_config
    from forcdecode.measured.writers import write_micromag_0015
    from forcdecode.micromag.build import mesh_from_config

    config_path = tiny_config(tmp)
    cfg = yaml.safe_load(config_path.read_text())
    truth = _resimulate()(load_config(config_path), params, n_profiles=1)
    mesh = mesh_from_config(cfg)
    scale = params["Ms"] * mesh.n_cells * mesh.cell_volume
    fields = np.linspace(-1, 1, N_FIELDS)
    rng = np.random.default_rng(0)
    curves = [(fields[i:], (truth[i, i:] + background * fields[i:] + noise * rng.normal(size=N_FIELDS - i)) * scale)
              for i in range(N_FIELDS)]
    return write_micromag_0015(tmp / "film.frc", fields, curves), config_path


def case_loop(tmp: Path) -> dict:
    """`forcdecode loop` with a given Hamiltonian on a film with an undeclared background (physics on)."""
    from forcdecode.cli import main

    params = {"Ms": 6e5, "A_ex": 1.0e-11, "K_u": 6e5, "D": 1e-3, "N_pin": 2, "sigma_theta_deg": 5.0, "sigma_K": 0.1}
    (tmp / "params.json").write_text(json.dumps(params))
    path, config_path = film_file(tmp, params, background=0.1, noise=0.002)
    out = tmp / "loop"
    code = main(["loop", str(path), "--out", str(out), "--params", str(tmp / "params.json"),
                 "--config", str(config_path), "--profiles", "1", "--every-k", "3", "--force"])
    return {"exit": code, "outputs": describe_dir(out)}


def case_refit(tmp: Path) -> dict:
    """``refit.analyse_with_refit`` (as ``forcdecode loop --refit K_u`` runs it): a film of its own disorder
    realisation with K_u 10 % above the prediction, the effects judged against the Hamiltonian refitted
    without them, with a realisation floor of two other disorder realisations."""
    from forcdecode.loop.refit import analyse_with_refit

    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = N_FIELDS
    prediction = {"Ms": 6e5, "A_ex": 5e-12, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 5.0, "sigma_K": 0.05}
    fields = np.linspace(-1, 1, N_FIELDS)
    film = _resimulate()(cfg, {**prediction, "K_u": 1.1 * prediction["K_u"]}, key="sample")
    film = film + 0.002 * np.random.default_rng(0).normal(size=film.shape)
    result = analyse_with_refit(cfg, prediction, film, fields, names=("K_u",), n_profiles=1, budget=6,
                                physics_grids=dict(K_2_ratios=(-0.1, 0.3), bias_fields_T=(0.02,), soft_K_u_ratios=(0.2,),
                                                   tilts_deg=(6.0,)),
                                noise_sigma=0.002, seed=1, null_realisations=2)
    return {"film": sha(film), "result": _clean(result)}


def train_bar_posterior(tmp: Path) -> Path:
    """The posterior of tests/loop/test_loop_posterior.py: trained on bar images, all six parameters."""
    import torch

    from forcdecode.core.parameters import DEFAULT_BOUNDS, denormalize, normalize
    from forcdecode.learn.data import LearningData
    from forcdecode.learn.posterior import train_posterior

    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    n = 200
    u = rng.random((n, 6))
    images = np.zeros((n, N_FIELDS, N_FIELDS))
    for k, row in enumerate(np.rint(u[:, 2] * (N_FIELDS - 1)).astype(int)):
        images[k, :row + 1] = 235
    images = (images + rng.integers(0, 20, images.shape)).astype(np.uint8)
    ms = rng.uniform(*DEFAULT_BOUNDS["Ms"], n)
    values = {"Ms": ms, **{name: denormalize(name, u[:, j]) for j, name in enumerate(NAMES)}}
    data = LearningData(images=images, ms_norm=normalize("Ms", ms), values=values, sample_id=np.arange(n),
                        bounds=dict(DEFAULT_BOUNDS), config_hash="bars", fields_T=np.linspace(-1, 1, N_FIELDS))
    settings = {"parameters": NAMES, "width": 8, "dropout": 0.0, "epochs": 5, "patience": 3, "batch_size": 32,
                "transforms": 1, "hidden": 8, "draws": 50}
    out = tmp / "post"
    out.mkdir()
    train_posterior(data, settings, {"split": [0.5, 0.2, 0.2, 0.1], "protocol": "holdout"}, 3, out / "model.pt",
                    out / "metrics.json", out / "fig.png", log=lambda *_: None)
    return out / "model.pt"


def describe_model(path: Path) -> dict:
    import torch

    blob = torch.load(path, map_location="cpu", weights_only=False)

    def walk(value):
        if isinstance(value, torch.Tensor):
            return sha(value.detach().cpu().numpy())
        if isinstance(value, np.ndarray):
            return sha(value)
        if isinstance(value, dict):
            return {str(k): walk(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [walk(v) for v in value]
        if isinstance(value, (str, int, float, bool)) or value is None:
            return value
        return f"<{type(value).__module__}.{type(value).__qualname__}>"

    return walk(blob)


def case_inference(tmp: Path) -> dict:
    """The posterior trained, `forcdecode fit`, `fit-step` init/round/report and `loop --refine` on a square film."""
    from forcdecode.cli import main

    result = {}
    posterior = train_bar_posterior(tmp)
    result["posterior_model"] = describe_model(posterior)
    result["posterior_metrics"] = without_timings(json.loads((posterior.parent / "metrics.json").read_text()))
    film = tmp / "film"
    film.mkdir()
    params = {"Ms": 6e5, "A_ex": 1.0e-11, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 5.0, "sigma_K": 0.1}
    path, cfg = film_file(film, params, background=0.0, noise=0.0)
    reference = tmp / "reference.json"
    reference.write_text(json.dumps(_make_reference()([1e6] * 20, budget=3, round_size=3, prior="draw",
                                                      sample_ids=range(20))))
    common = ["--posterior", str(posterior), "--config", str(cfg)]
    fit_out = tmp / "fit"
    result["fit_exit"] = main(["fit", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                               "--out", str(fit_out), "--predictive-reference", str(reference)])
    result["fit"] = describe_dir(fit_out)
    steps = tmp / "steps"
    steps.mkdir()
    states = [steps / f"round_{r}.npz" for r in range(3)]
    codes = [main(["fit-step", "init", str(path), "--Ms-kA-m", "600", *common, "--budget", "6", "--round-size", "3",
                   "--extend-prior", "N_pin=3", "--state", str(states[0])])]
    for r in (1, 2):
        codes.append(main(["fit-step", "round", *common, "--state-in", str(states[r - 1]), "--state-out", str(states[r])]))
    codes.append(main(["fit-step", "report", "--state", str(states[2]), "--out", str(steps / "fit.json")]))
    result["fit_step_exits"] = codes
    result["fit_step"] = describe_dir(steps)
    loop_out = tmp / "loop"
    result["loop_refine_exit"] = main(["loop", str(path), "--out", str(loop_out), "--config", str(cfg), "--estimator",
                                       "posterior", "--posterior", str(posterior), "--Ms-kA-m", "600", "--profiles",
                                       "1", "--no-physics", "--no-measured-protocol", "--force", "--refine", "6",
                                       "--refine-round-size", "3"])
    result["loop_refine"] = describe_dir(loop_out)
    return result


def _clean(value):
    """Arrays hashed, numpy scalars as Python numbers, keys as strings."""
    if isinstance(value, np.ndarray):
        return sha(value)
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def case_analyse(tmp: Path) -> dict:
    """``analyse_residual`` on a fixed residual: a re-simulated film plus a background and noise, with a
    small physics-side candidate grid."""
    from forcdecode.loop.physics_effects import analyse_residual, physics_candidate_families

    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = N_FIELDS
    params = {"Ms": 6e5, "A_ex": 2e-12, "K_u": 4e5, "D": 1e-3, "N_pin": 0, "sigma_theta_deg": 15.0, "sigma_K": 0.3}
    fields = np.linspace(-1, 1, N_FIELDS)
    base = _resimulate()(cfg, params)
    candidates = physics_candidate_families(cfg, params, K_2_ratios=(-0.1, 0.2), bias_fields_T=(-0.02, 0.02),
                                            soft_K_u_ratios=(0.1,))
    rng = np.random.default_rng(3)
    measured = base + 0.08 * fields[None, :] + 0.002 * rng.normal(size=base.shape)
    measured = np.where(np.isnan(base), np.nan, measured)
    result = analyse_residual(measured, base, fields, seed=3, **candidates)
    return {"base": sha(base), "candidates": _clean(candidates), "result": _clean(result)}


def case_bench_effects(tmp: Path) -> dict:
    """`forcdecode bench effects --seeds 1 --json` (the own-simulator bench of the residual analysis: 50 cases,
    each a MicroMag file read back and judged by ``analyse_residual``): its stdout (the two timings in the first
    line masked) and the full result of ``bench.effects.effects_confusion`` with every case's row (captured by
    wrapping the function the command calls; its ``setup_s`` and ``analysis_s`` masked)."""
    import contextlib
    import io
    import re

    from forcdecode.bench import effects
    from forcdecode.cli import main

    captured = []
    original = effects.effects_confusion

    def recording(*args, **kwargs):
        captured.append(original(*args, **kwargs))
        return captured[-1]

    stdout = io.StringIO()
    effects.effects_confusion = recording
    try:
        with contextlib.redirect_stdout(stdout):
            code = main(["bench", "effects", "--seeds", "1", "--json"])
    finally:
        effects.effects_confusion = original
    lines = stdout.getvalue().splitlines()
    summary = json.loads(lines[-1])
    masked = [re.sub(r"\(setup \d+ s, analysis \d+ s\)", "(setup <time> s, analysis <time> s)", line)
              for line in lines[:-1]]
    timings = ("setup_s", "analysis_s")
    return {"exit": code, "stdout": masked, "json": {k: "<time>" if k in timings else v for k, v in summary.items()},
            "result": {k: "<time>" if k in timings else _clean(v) for k, v in captured[0].items()}}


CASES = {"loop": case_loop, "analyse": case_analyse, "inference": case_inference, "refit": case_refit,
         "bench_effects": case_bench_effects}
DEFAULT_CASES = ["loop", "analyse", "inference", "refit"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="JSON file written")
    parser.add_argument("--cases", default=",".join(DEFAULT_CASES), help="comma-separated, of " + ", ".join(CASES)
                        + " (default: all but bench_effects)")
    parser.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "refactor_identity_work"),
                        help="working directory, emptied first (fixed, so that paths in the reports match)")
    args = parser.parse_args()
    results = {}
    for name in args.cases.split(","):
        start = time.perf_counter()
        work = Path(args.work) / name
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        results[name] = CASES[name](work)
        print(f"{name}: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    Path(args.out).write_text(json.dumps(results, indent=1, sort_keys=True, default=repr))
    return 0


if __name__ == "__main__":
    sys.exit(main())
