"""Does a FORC family look like the training data? A conformal out-of-distribution check in the
posterior's embedding space, made before any posterior is trusted.

Two scores, each calibrated on the held-out validation and calibration families (never test; the
flow never trained on them):

- features: the mean Euclidean distance from the observation's embedding features (the CNN features
  and M_s that condition the flow, dropout off) to its k nearest training families, each feature
  standardized by its training mean and spread;
- image: the distance of the image (grey levels / 255, average-pooled to at most 16×16) from the
  principal subspace of the training images (components holding 95 % of their variance): a summary
  network trained to read parameters can map an unfamiliar image onto familiar features, the
  reconstruction error of the image itself cannot hide it.

Each is a conformal test: with n held-out scores, the p-value of an observation is
(1 + #{held-out scores ≥ its score}) / (n + 1), super-uniform under exchangeability with the
held-out families; the two are combined by Bonferroni, p = min(1, 2 min(p_f, p_i)), so flagging
p < α keeps the false-alarm rate on in-distribution families at most α (0.05 by default; with n
held-out families nothing below p = 2/(n + 1) can be resolved: n ≥ 40 for α = 0.05; ``ood_power``
says so, and every verdict carries ``can_flag`` and, where it cannot flag, a ``warning``).

Alice's networks have no posterior embedding: for them the image score alone is the check
(``image_ood_check``, p = p_image, nothing below 1/(n + 1)), its reference fitted on the train split of
the dataset the networks were trained on and held out on its validation and calibration families
(``training_image_reference``, cached beside the models).

What it catches is measured, not assumed (``forcdecode bench ood``, README): images unlike any
training image are flagged; a film outside the prior whose family still looks like one inside it is
not. On the laptop film, pinning three times denser than the prior allows changes the image by 4×
the realisation floor and is flagged in 0 of 12 families (the image moves along the training
manifold, as a harder film's would); 8 nm grains and magnum.np's discretization change it by no more
than the floor, so no check of the image can tell them. The posterior-predictive check of
``infer.predictive_check`` asks the question in observation space instead: does any simulated in-prior
Hamiltonian reproduce the family to within the realisation floor, judged against validation families.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from ..config import defaults
from ..core.errors import ModelFileError
from ..core.io import write_json
from .splits import assign_splits

K_NEIGHBOURS = 5
ALPHA = 0.05
IMAGE_REFERENCE_FILE = "ood_image_reference.json"
"""The image-only reference of Alice's networks, cached in their directory (``training_image_reference``)."""


@torch.no_grad()
def embedding_features(est, x, ms_norm, chunk: int = 256) -> np.ndarray:
    """(n, width + 1) features of the posterior's embedding (eval mode: no dropout)."""
    tensor, ms = est._inputs(x, ms_norm)
    est.net.eval()
    out = [est.net.features(tensor[s:s + chunk], ms[s:s + chunk]).double().numpy()
           for s in range(0, tensor.shape[0], chunk)]
    return np.concatenate(out) if out else np.zeros((0, 1))


def _scores(features, reference, mean, scale, k) -> np.ndarray:
    a = (np.asarray(features) - mean) / scale
    b = (np.asarray(reference) - mean) / scale
    d = np.sort(np.sqrt(np.maximum(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2), 0.0)), axis=1)
    k = max(1, min(k, d.shape[1]))
    return d[:, :k].mean(axis=1)


def _pooled(images, chunk: int = 512) -> np.ndarray:
    """Images (n, side, side) uint8 → (n, features) in [0, 1], average-pooled to at most 16×16 (in
    chunks: a whole dataset never held as floats at full size)."""
    images = np.asarray(images)
    side = images.shape[-1]
    factor = max(1, side // 16)
    out = []
    for s in range(0, max(images.shape[0], 1), chunk):
        x = images[s:s + chunk].astype(float) / 255.0
        if factor > 1 and side % factor == 0:
            x = x.reshape(x.shape[0], side // factor, factor, side // factor, factor).mean(axis=(2, 4))
        out.append(x.reshape(x.shape[0], int(np.prod(x.shape[1:]))))
    return np.concatenate(out)


def _image_scores(images, mean, basis) -> np.ndarray:
    centred = _pooled(images) - mean
    residual = centred - (centred @ basis.T) @ basis
    return np.sqrt((residual ** 2).sum(axis=1))


def _image_reference(images_train, variance: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    x = _pooled(images_train)
    mean = x.mean(axis=0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    share = np.cumsum(s ** 2) / max(float((s ** 2).sum()), 1e-30)
    n = int(np.searchsorted(share, variance) + 1)
    return mean, vt[:n]


def fit_ood_reference(est, x, ms_norm, train, val, k: int = K_NEIGHBOURS) -> dict:
    """The reference the check needs, as plain values for the model file: training features, their
    standardization, k and the validation scores."""
    train, val = np.asarray(train), np.asarray(val)
    if len(train) < 2 or len(val) < 1:
        raise ValueError("the OOD reference needs >= 2 training and >= 1 validation families")
    f_train = embedding_features(est, np.asarray(x)[train], np.asarray(ms_norm)[train])
    mean = f_train.mean(axis=0)
    scale = f_train.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)  # dead (always-zero) features carry no distance
    f_val = embedding_features(est, np.asarray(x)[val], np.asarray(ms_norm)[val])
    val_scores = _scores(f_val, f_train, mean, scale, k)
    ref = {"k": int(k), "alpha": ALPHA, "train_features": f_train.astype(np.float32).tolist(),
           "mean": mean.tolist(), "scale": scale.tolist(), "validation_scores": sorted(float(s) for s in val_scores),
           "score": f"mean distance to the {k} nearest training families in standardized embedding features"}
    if np.asarray(x).ndim == 3:
        image_mean, basis = _image_reference(np.asarray(x)[train])
        ref.update(image_mean=image_mean.tolist(), image_basis=basis.astype(np.float32).tolist(),
                   image_validation_scores=sorted(float(v) for v in _image_scores(np.asarray(x)[val], image_mean, basis)))
    return ref


def _p_values(scores, reference_scores) -> np.ndarray:
    ref = np.asarray(reference_scores, dtype=float)
    return np.array([(1.0 + float((ref >= s).sum())) / (ref.size + 1.0) for s in scores])


def ood_power(n_reference: int, n_scores: int = 2, alpha: float = ALPHA) -> dict:
    """Can a check with ``n_reference`` held-out scores flag anything at ``alpha``? Its smallest p-value
    is n_scores/(n + 1) (one score: 1/(n + 1); two, Bonferroni: 2/(n + 1)), and a flag needs p < alpha.
    ``can_flag``, ``smallest_p``, ``n_reference_needed`` and, where it cannot, a ``warning``."""
    n = int(n_reference)
    smallest = n_scores / (n + 1.0)
    needed = int(math.floor(n_scores / alpha - 1.0 + 1e-9)) + 1  # smallest n with n_scores/(n + 1) < alpha
    out = {"can_flag": bool(smallest < alpha), "smallest_p": smallest, "n_reference": n,
           "n_reference_needed": needed}
    if not out["can_flag"]:
        rule = "1/(n + 1)" if n_scores == 1 else f"{n_scores}/(n + 1) (Bonferroni of {n_scores} scores)"
        out["warning"] = (f"the check's reference holds {n} held-out families: the smallest p-value it can give is "
                          f"{rule} = {smallest:.3f} >= alpha = {alpha:g}, so it cannot flag anything "
                          f"(it needs at least {needed})")
    return out


def ood_check(est, x, ms_norm, alpha: float | None = None) -> dict:
    """Score, conformal p-value and verdict per observation (a list), or ``{"available": False}`` for a
    model saved without the reference (older files)."""
    ref = est.metadata.get("ood")
    if not ref:
        return {"available": False, "verdict": "not available (the posterior model has no OOD reference)"}
    try:
        train = np.asarray(ref["train_features"], dtype=float)
        mean, scale = np.asarray(ref["mean"], float), np.asarray(ref["scale"], float)
        val = np.asarray(ref["validation_scores"], float)
    except (KeyError, TypeError, ValueError) as error:
        raise ModelFileError(f"the posterior model's OOD reference is damaged: {error}") from None
    alpha = float(ref.get("alpha", ALPHA) if alpha is None else alpha)
    x = np.asarray(x)
    single = x.ndim == 2
    features = embedding_features(est, x[None] if single else x, np.atleast_1d(ms_norm))
    scores = _scores(features, train, mean, scale, int(ref["k"]))
    p_feat = _p_values(scores, val)
    images = x[None] if single else x
    has_image = "image_basis" in ref and images.ndim == 3
    if has_image:
        image_scores = _image_scores(images, np.asarray(ref["image_mean"], float), np.asarray(ref["image_basis"], float))
        p_img = _p_values(image_scores, ref["image_validation_scores"])
    else:
        image_scores, p_img = np.full(len(scores), np.nan), np.ones(len(scores))
    power = ood_power(val.size, 2 if has_image else 1, alpha)
    rows = []
    for s, si, pf, pi in zip(scores, image_scores, p_feat, p_img):
        p = min(1.0, 2.0 * min(pf, pi))
        flagged = p < alpha
        where = "embedding features" if pf <= pi else "image"
        rows.append({"available": True, "score": float(s), "image_score": float(si), "p_value": p,
                     "p_features": float(pf), "p_image": float(pi), "alpha": alpha, "n_validation": int(val.size),
                     "out_of_distribution": bool(flagged),
                     "verdict": (f"out of distribution: its {where} lie farther from the training families than "
                                 f"those of the validation families (combined p = {p:.3f} < {alpha})"
                                 if flagged else f"in distribution (combined p = {p:.2f})"),
                     "check": "posterior: embedding features and image", **power})
    return rows[0] if single else rows


def fit_image_reference(images, train, held_out, variance: float = 0.95) -> dict:
    """The image-only reference (plain values): the principal subspace of the ``train`` images and the
    scores of the ``held_out`` ones (never trained on), for ``image_ood_check``."""
    images, train, held_out = np.asarray(images), np.asarray(train, dtype=int), np.asarray(held_out, dtype=int)
    if len(train) < 2 or len(held_out) < 1:
        raise ValueError("the image reference needs >= 2 training and >= 1 held-out families")
    mean, basis = _image_reference(images[train], variance)
    scores = _image_scores(images[held_out], mean, basis)
    return {"alpha": ALPHA, "image_side": int(images.shape[-1]), "n_train": int(len(train)),
            "image_mean": mean.tolist(), "image_basis": basis.astype(np.float32).tolist(),
            "image_validation_scores": sorted(float(v) for v in scores),
            "score": (f"distance of the image (grey levels / 255, pooled to at most 16x16) from the principal subspace "
                      f"({basis.shape[0]} components, {100 * variance:.0f} % of the variance) of {len(train)} "
                      "training images")}


def image_ood_check(ref: dict, x, alpha: float | None = None):
    """The image-only check of one image (a dict) or several (a list): score, conformal p-value (one
    score, nothing below 1/(n + 1)), verdict, ``can_flag`` (``ood_power``)."""
    try:
        mean, basis = np.asarray(ref["image_mean"], float), np.asarray(ref["image_basis"], float)
        val = np.asarray(ref["image_validation_scores"], float)
    except (KeyError, TypeError, ValueError) as error:
        raise ModelFileError(f"the image OOD reference is damaged: {error}") from None
    alpha = float(ref.get("alpha", ALPHA) if alpha is None else alpha)
    x = np.asarray(x)
    single = x.ndim == 2
    images = x[None] if single else x
    side = ref.get("image_side")
    if side is not None and images.shape[-1] != int(side):
        raise ValueError(f"the image OOD reference is of {side}x{side} images, not {images.shape[-1]}x{images.shape[-1]}")
    scores = _image_scores(images, mean, basis)
    p_img = _p_values(scores, val)
    power = ood_power(val.size, 1, alpha)
    rows = []
    for si, p in zip(scores, p_img):
        flagged = bool(p < alpha)
        rows.append({"available": True, "check": "image only (no posterior)", "image_score": float(si),
                     "p_value": float(p), "p_image": float(p), "alpha": alpha, "n_validation": int(val.size),
                     "out_of_distribution": flagged,
                     "verdict": (f"out of distribution: the image lies farther from the principal subspace of the "
                                 f"training images than those of the held-out families (p = {p:.3f} < {alpha})"
                                 if flagged else f"in distribution (image p = {p:.2f})"),
                     **power})
    return rows[0] if single else rows


def _splits_of(dataset_path: Path, h5, models_dir: Path) -> tuple[dict, str]:
    """(seed and learning section, where they came from) of the run that trained the models: the
    workflow's ``learning.json`` beside the models' directory, else the dataset's own configuration."""

    learning_json = models_dir.parent / "learning.json"
    if learning_json.exists():
        cfg, source = json.loads(learning_json.read_text()), str(learning_json)
    else:
        cfg, source = json.loads(h5.attrs["config_json"]), f"the configuration stored in {dataset_path}"
    return {"seed": int(cfg["seed"]), "learning": {**defaults("learning"), **(cfg.get("learning") or {})}}, source


def _shipped_reference(models_dir: Path, config_hashes=None) -> tuple[dict, str] | None:
    """The reference shipped beside the models (``learn.shipped``: made from the train split of their
    dataset when the set was shipped, key ``shipped``), when its config hash is the models'."""
    cache = models_dir / IMAGE_REFERENCE_FILE
    if not cache.exists():
        return None
    try:
        cached = json.loads(cache.read_text())
        key = cached["key"]
        if not key.get("shipped"):
            return None
        hashes = sorted(set(config_hashes or ()))
        if hashes and hashes != [key.get("config_hash")]:
            return None
        return cached["reference"], f"shipped with the models ({cache})"
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return None


def training_image_reference(models_dir, dataset=None, config_hashes=None, log=None) -> tuple[dict | None, str]:
    """(reference, note) of the image-only check of Alice's networks in ``models_dir``: fitted on the
    train split of their dataset (``dataset``, default ``models_dir``/../dataset.h5; splits of
    ``learn.splits`` by the seed and learning section of ``learning.json`` beside the models' directory,
    else of the dataset's configuration), held out on its validation and calibration families. Cached in
    ``models_dir``/ood_image_reference.json, keyed by the dataset's path, size, time and the splits.
    (None, why) when it cannot be made: no dataset, a dataset of another configuration (``config_hashes``:
    the models' config hashes), too few families."""
    import h5py

    models_dir = Path(models_dir)
    path = Path(dataset) if dataset is not None else models_dir.parent / "dataset.h5"
    if not path.exists():
        shipped = _shipped_reference(models_dir, config_hashes)
        if shipped is not None and dataset is None:
            return shipped
        return None, f"no training dataset at {path} (the networks' training data; --dataset names it)"
    try:
        h5 = h5py.File(path, "r")
    except OSError as error:
        return None, f"cannot open the training dataset {path}: {error}"
    with h5:
        try:
            data_hash = str(h5.attrs["config_hash"])
            settings, source = _splits_of(path, h5, models_dir)
        except (KeyError, ValueError, TypeError) as error:
            return None, f"the training dataset {path} lacks its configuration ({error})"
        hashes = sorted(set(config_hashes or ()))
        if hashes and hashes != [data_hash]:
            return None, (f"the dataset {path} (config hash {data_hash}) is not the one the networks were trained on "
                          f"(config hash {', '.join(hashes)})")
        stat = path.stat()
        key = {"dataset": str(path.resolve()), "size": int(stat.st_size), "mtime_ns": int(stat.st_mtime_ns),
               "config_hash": data_hash, "seed": settings["seed"], "split": list(settings["learning"]["split"]),
               "protocol": settings["learning"]["protocol"]}
        cache = models_dir / IMAGE_REFERENCE_FILE
        if cache.exists():
            try:
                cached = json.loads(cache.read_text())
                if cached.get("key") == key:
                    return cached["reference"], f"cached in {cache}"
            except (OSError, ValueError, KeyError, AttributeError):
                pass  # rebuilt below
        ids = h5["sample_id"][:]
        splits = assign_splits(ids, settings["seed"], settings["learning"]["split"], settings["learning"]["protocol"])
        train, held_out = splits["train"], np.union1d(splits["validation"], splits["calibration"])
        if len(train) < 2 or len(held_out) < 1:
            return None, (f"the training dataset {path} has {len(train)} training and {len(held_out)} held-out "
                          "families: too few for a reference")
        images = h5["images"][:]
    reference = fit_image_reference(images, train, held_out)
    reference["splits_from"], reference["dataset"] = source, str(path)
    note = f"fitted on {len(train)} training images of {path}, held out on {len(held_out)} (splits: {source})"
    try:
        write_json(cache, {"key": key, "reference": reference})
        note += f"; cached in {cache}"
    except OSError as error:  # a read-only model directory: computed again next time
        note += f"; not cached ({error})"
    if log is not None:
        log(f"training-data check: image reference {note}")
    return reference, note


__all__ = ["K_NEIGHBOURS", "ALPHA", "IMAGE_REFERENCE_FILE", "embedding_features", "fit_ood_reference", "ood_check",
           "ood_power", "fit_image_reference", "image_ood_check", "training_image_reference"]
