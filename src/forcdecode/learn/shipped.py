"""The laptop default's trained models, shipped with the package (issue 60 item 1): a physicist with a
file decodes it minutes after install, with the answer the project has validated, instead of re-training
for 105 minutes first.

What ships (``SHIPPED``, package data ``forcdecode/shipped/laptop``), as the main job (`make run`) writes
it under ``results/``:

- ``models/<parameter>.pt``: Alice and Bob per parameter with their conformal calibration and their
  identification block (the "read from the image" flags), weights stored in half precision
  (``HALF_PRECISION``; loading casts them back to float32: ``load_state_dict`` copies into the network's
  own dtype);
- ``models/ood_image_reference.json``: the image-only training-data check's reference, fitted on the
  train split of the networks' dataset (``learn.ood.training_image_reference``), so that the check runs
  without the 600-family dataset;
- ``posterior/model.pt``: the posterior ensemble and its recalibration (half precision as well);
- ``manifest.json``: the config hash, the code commit, the dataset's SHA-256, the prior class, the film,
  the files with their SHA-256, and the sealed-set figures the models scored (``results/metrics.json``
  → ``sealed``).

``predict`` and ``loop`` use them when ``--models`` is not given and say so on their first line
(``resolve_models``). `make run` re-makes the models into ``results/models``; ``compare`` (the CLI's
`forcdecode models check`) says whether a fresh run's sealed figures agree with the manifest's within
their 90 % intervals; ``ship`` (`forcdecode models ship`) writes a new shipped set from a finished run.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
from pathlib import Path

import numpy as np

from ..config import film_thickness_nm, load_config, shipped_config
from ..core.errors import ConfigError, ModelFileError
from ..core.io import atomic_path, read_json, write_json
from ..core.parameters import normalize
from ..dataset.merge import config_hash, physics_config
from .data import load_dataset

SHIPPED = Path(__file__).resolve().parents[1] / "shipped" / "laptop"
MANIFEST = "manifest.json"
FORMAT = "forcdecode-shipped-models/1"
HALF_PRECISION = True
"""Weights stored as float16 (sizes halve); ``check_half_precision`` measures what it changes."""


def sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_manifest(directory=SHIPPED) -> dict:
    """The manifest of a shipped set; ModelFileError when it is missing or not one."""
    path = Path(directory) / MANIFEST
    if not path.exists():
        raise ModelFileError(f"no shipped models at {directory} (no {MANIFEST}): train them with `make run` and give "
                             "--models results/models")
    manifest = read_json(path, what="shipped models manifest")
    if manifest.get("format") != FORMAT:
        raise ModelFileError(f"{path} is not a shipped-models manifest (format {manifest.get('format')!r})")
    return manifest


WORKFLOW_MODELS = Path("results/models")
"""Where the main job writes the models (`make run`), used when no set is shipped."""


def resolve_models(models, directory=SHIPPED) -> tuple[Path, str]:
    """(the Alice models directory, the line that says which models answer). ``models``: the user's
    ``--models`` (used as given), or None: the shipped set, or where none is installed the main job's
    ``results/models``."""
    if models is not None:
        return Path(models), f"models: {models} (--models)"
    if not (Path(directory) / MANIFEST).exists():
        return WORKFLOW_MODELS, (f"models: {WORKFLOW_MODELS} (no shipped models in this installation; `make run` "
                                 "trains them there)")
    manifest = read_manifest(directory)
    return Path(directory) / "models", shipped_line(manifest)


def shipped_line(manifest: dict) -> str:
    """The first line of an answer made with the shipped models."""
    return (f"models: the shipped {manifest['film']['name']} models ({manifest['prior_class']} prior, trained "
            f"{manifest['trained']}, code {manifest['code_commit'][:10]}, config {manifest['config_hash'][:12]}); "
            "--models DIR for your own")


def _half(obj):
    """``obj`` (a state dict or a nested payload) with floating tensors as float16."""
    import torch  # heavy: only when a set is written

    if isinstance(obj, torch.Tensor):
        return obj.half() if obj.is_floating_point() else obj
    if isinstance(obj, dict):
        return type(obj)((k, _half(v)) for k, v in obj.items())
    if isinstance(obj, list):
        return [_half(v) for v in obj]
    return obj


def _copy_model(source: Path, target: Path, half: bool) -> None:
    import torch  # heavy: only when a set is written

    if not half:
        shutil.copyfile(source, target)
        return
    payload = torch.load(source, map_location="cpu", weights_only=True)
    with atomic_path(target) as tmp:
        torch.save(_half(payload), tmp)


def _code_commit(root) -> str:
    try:
        return subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _sealed_figures(metrics: dict) -> dict:
    """{name: {"skill", "ci90", "mae", "against"}} of the sealed set (Alice): a parameter's skill over the best
    trivial predictor (chosen on validation); a combination's the smaller of its skills over the prior and
    over M_s only (the README's rule)."""
    sealed = metrics.get("sealed") or {}
    out = {}
    for name, row in (sealed.get("parameters") or {}).items():
        if "skill_vs_best_trivial" in row:
            out[name] = {"skill": row["skill_vs_best_trivial"], "ci90": row.get("skill_vs_best_trivial_ci90"),
                         "mae": row.get("mae"), "against": "best trivial predictor"}
    for name, row in (sealed.get("combinations") or {}).items():
        skills = [(row[f"skill_vs_{k}"], row.get(f"skill_vs_{k}_ci90"), k) for k in ("prior", "ms_only")
                  if row.get(f"skill_vs_{k}") is not None]
        if skills:
            skill, ci90, against = min(skills, key=lambda s: s[0])
            out[name] = {"skill": skill, "ci90": ci90, "mae": row.get("mae"), "against": against}
    return out


PRECISION_CHECK_IMAGES = 300
"""Dataset families on which ``precision_effect`` compares the shipped weights with the trained ones."""


def precision_effect(trained_dir, shipped_dir, dataset_path, count: int = PRECISION_CHECK_IMAGES) -> dict:
    """What storing the weights in half precision changes: per parameter, the largest and the mean |Δu| of
    the prediction (normalized units, prior width = 1) and the change of its MAE against the truth, over the
    first ``count`` families of the networks' dataset (float32 models in ``trained_dir``, shipped ones in
    ``shipped_dir``)."""
    # loads torch: imported only when this runs
    from .predictor import load_models

    data = load_dataset(dataset_path)
    k = min(count, len(data.images))
    images, ms = data.images[:k], data.values["Ms"][:k]
    trained, shipped = load_models(trained_dir), load_models(shipped_dir)
    out = {"n": int(k)}
    for name, model in trained.items():
        a = model.predict(images, ms)["normalized"]
        b = shipped[name].predict(images, ms)["normalized"]
        truth = normalize(name, data.values[name][:k], model.bounds)
        row = {"max_abs_du": float(np.max(np.abs(a - b))), "mean_abs_du": float(np.mean(np.abs(a - b)))}
        row["mae_change"] = float(np.mean(np.abs(b - truth)) - np.mean(np.abs(a - truth)))
        out[name] = row
    return out


def ship(results="results", out=SHIPPED, half: bool = HALF_PRECISION, root=None) -> dict:
    """Write the shipped set from a finished main job in ``results`` (models, the training-data check's
    reference, the posterior, the manifest). Returns the manifest."""
    # loads torch: imported only when this runs
    from .ood import IMAGE_REFERENCE_FILE, training_image_reference
    from .predictor import load_models, models_prior_class

    results, out = Path(results), Path(out)
    models_dir = results / "models"
    models = load_models(models_dir)  # ModelFileError without a trained run
    hashes = sorted({str(m.payload.get("config_hash")) for m in models.values()})
    reference, note = training_image_reference(models_dir, None, hashes)
    if reference is None:
        raise ModelFileError(f"cannot ship: the training-data check's reference: {note}")
    cfg = read_json(results / "config.json", what="the main job's resolved config")  # the dataset's physics only
    metrics = read_json(results / "metrics.json", what="metrics")
    if not metrics.get("sealed"):
        raise ModelFileError(f"cannot ship: {results / 'metrics.json'} has no sealed-set figures (run the main job to "
                             "its end)")
    (out / "models").mkdir(parents=True, exist_ok=True)
    (out / "posterior").mkdir(parents=True, exist_ok=True)
    for path in sorted(models_dir.glob("*.pt")):
        _copy_model(path, out / "models" / path.name, half)
    write_json(out / "models" / IMAGE_REFERENCE_FILE, {"key": {"shipped": True, "config_hash": hashes[0]},
                                                       "reference": reference})
    posterior = results / "posterior" / "model.pt"
    if posterior.exists():
        _copy_model(posterior, out / "posterior" / "model.pt", half)
    files = {str(p.relative_to(out)): {"sha256": sha256(p), "bytes": p.stat().st_size}
             for p in sorted(out.rglob("*")) if p.is_file() and p.name != MANIFEST}
    manifest = {"format": FORMAT, "config_hash": config_hash(physics_config(cfg)), "model_config_hashes": hashes,
                "physics_config": physics_config(cfg),
                "code_commit": _code_commit(root or Path(__file__).resolve().parents[3]),
                "dataset_sha256": sha256(results / "dataset.h5"), "prior_class": models_prior_class(models),
                "film": {"name": "laptop default", "mesh": cfg["mesh"], "n_grains": cfg["n_grains"],
                         "field": cfg["field"], "thickness_nm": cfg["mesh"]["dz_nm"] * cfg["mesh"]["nz"]},
                "trained": str(np.datetime64(int((results / "metrics.json").stat().st_mtime), "s"))[:10],
                "half_precision": bool(half), "parameters": sorted(models), "files": files,
                "sealed": _sealed_figures(metrics), "sealed_n": (metrics.get("sealed") or {}).get("n_sealed"),
                "made_by": "forcdecode models ship --results " + str(results)}
    posterior_metrics = results / "posterior" / "metrics.json"
    if posterior_metrics.exists():  # the posterior's sealed calibration, which the README quotes
        sealed = read_json(posterior_metrics, what="posterior metrics").get("sealed") or {}
        manifest["posterior_sealed"] = {
            "coverage_90": {n: row.get("coverage_90") for n, row in (sealed.get("per_parameter") or {}).items()},
            "tarp_coverage_90": ((sealed.get("joint") or {}).get("tarp") or {}).get("coverage_90")}
    if half:  # measured, not assumed: the predictions of the stored weights against the trained ones
        manifest["half_precision_effect"] = precision_effect(models_dir, out / "models", results / "dataset.h5")
    write_json(out / MANIFEST, manifest)
    return manifest


THICKNESS_FILE = "thickness.json"
"""The thickness study of a models set (``forcdecode bench thickness``: the table and the safe range), beside
the manifest of a shipped set or in the models directory."""


def thickness_study(models_dir) -> dict | None:
    """The thickness study made for the models in ``models_dir`` (that directory or its parent), or None."""
    for place in (Path(models_dir), Path(models_dir).parent):
        if (place / THICKNESS_FILE).exists():
            return read_json(place / THICKNESS_FILE, what="thickness study")
    return None


def models_thickness_nm(models_dir) -> float:
    """The film thickness (nm) the models in ``models_dir`` were trained on: their thickness study's reference,
    else their shipped manifest's film, else the shipped laptop config's film."""
    study = thickness_study(models_dir)
    if study is not None:
        return float(study["reference_nm"])
    for place in (Path(models_dir), Path(models_dir).parent):
        if (place / MANIFEST).exists():
            return float(read_json(place / MANIFEST, what="shipped manifest")["film"]["thickness_nm"])
    return film_thickness_nm(load_config(shipped_config("config")))


def check_thickness(models_dir, thickness_nm: float | None, models_nm: float, force: bool = False) -> str:
    """What the user's film thickness means for these models, in one line; ConfigError where the thickness
    lies outside the range the thickness study shows safe (or no study exists for a thickness other than the
    models' own) and ``force`` is not given. ``None``: the models' own thickness is assumed, and said."""
    if thickness_nm is None:
        return (f"film thickness: {models_nm:g} nm assumed (the models' film); give --thickness-nm for yours "
                "(the re-simulation uses it)")
    study = thickness_study(models_dir)
    if abs(thickness_nm - models_nm) < 1e-9:
        return f"film thickness: {thickness_nm:g} nm, the models' own"
    if study is None:
        verdict = (f"no thickness study exists for the models in {models_dir} (forcdecode bench thickness), so "
                   f"a {thickness_nm:g} nm film decoded by {models_nm:g} nm models has no measured error")
        safe = None
    else:
        lo, hi = study["safe_nm"]
        safe = lo <= thickness_nm <= hi
        verdict = (f"the thickness study of these models accepts {lo:g}-{hi:g} nm (at most "
                   f"{study['safe_mae_increase']} prior widths of MAE lost by any parameter read from the image)")
    if safe:
        return f"film thickness: {thickness_nm:g} nm, inside the models' safe range ({verdict})"
    if not force:
        raise ConfigError(f"film thickness {thickness_nm:g} nm: the models were trained on a {models_nm:g} nm film and "
                          f"{verdict}. Train models on your thickness (config mesh.dz_nm, make run) or pass --force "
                          "to decode anyway (the re-simulation then uses your thickness)")
    return f"film thickness: {thickness_nm:g} nm, OUTSIDE what the models were shown safe for (--force): {verdict}"


def compare(results="results", directory=SHIPPED) -> dict:
    """A fresh run's sealed figures against the manifest's: per quantity both skills and intervals, and
    whether they agree (each point estimate inside the other's 90 % interval). ``agree``: all do."""
    manifest = read_manifest(directory)
    fresh = _sealed_figures(read_json(Path(results) / "metrics.json", what="metrics"))
    rows = {}
    for name, shipped in manifest["sealed"].items():
        new = fresh.get(name)
        if new is None or shipped.get("ci90") is None or new.get("ci90") is None:
            rows[name] = {"shipped": shipped, "fresh": new, "agree": None}
            continue
        agree = bool(new["ci90"][0] <= shipped["skill"] <= new["ci90"][1]
                     and shipped["ci90"][0] <= new["skill"] <= shipped["ci90"][1])
        rows[name] = {"shipped": shipped, "fresh": new, "agree": agree}
    judged = [r["agree"] for r in rows.values() if r["agree"] is not None]
    if not judged:
        raise ConfigError(f"no sealed figure of {results} to compare with the shipped manifest")
    return {"agree": all(judged), "rows": rows, "shipped_commit": manifest["code_commit"],
            "shipped_config_hash": manifest["config_hash"]}


def compare_lines(result: dict) -> list[str]:
    lines = [f"{'quantity':<12}{'shipped skill [90 % CI]':>30}{'fresh skill [90 % CI]':>30}  agree"]
    for name, row in result["rows"].items():
        def cell(r):
            if r is None:
                return "—"
            lo, hi = r["ci90"] if r.get("ci90") else (float("nan"),) * 2
            return f"{r['skill']:+.2f} [{lo:+.2f}, {hi:+.2f}]"
        lines.append(f"{name:<12}{cell(row['shipped']):>30}{cell(row['fresh']):>30}  "
                     f"{'—' if row['agree'] is None else ('yes' if row['agree'] else 'NO')}")
    lines.append("the fresh run agrees with the shipped models' sealed figures" if result["agree"] else
                 "the fresh run DISAGREES with the shipped models' sealed figures (a point outside the other's interval)")
    return lines


__all__ = ["FORMAT", "HALF_PRECISION", "MANIFEST", "SHIPPED", "compare", "compare_lines", "read_manifest",
           "resolve_models", "sha256", "ship", "shipped_line"]
