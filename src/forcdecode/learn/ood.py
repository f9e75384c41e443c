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
held-out families nothing below p = 2/(n + 1) can be resolved: n ≥ 40 for α = 0.05).

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

import numpy as np
import torch

from ..core.errors import ModelFileError

K_NEIGHBOURS = 5
ALPHA = 0.05


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


def _pooled(images) -> np.ndarray:
    """Images (n, side, side) uint8 → (n, features) in [0, 1], average-pooled to at most 16×16."""
    x = np.asarray(images, dtype=float) / 255.0
    side = x.shape[-1]
    factor = max(1, side // 16)
    if factor > 1 and side % factor == 0:
        x = x.reshape(x.shape[0], side // factor, factor, side // factor, factor).mean(axis=(2, 4))
    return x.reshape(x.shape[0], -1)


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
    if "image_basis" in ref and images.ndim == 3:
        image_scores = _image_scores(images, np.asarray(ref["image_mean"], float), np.asarray(ref["image_basis"], float))
        p_img = _p_values(image_scores, ref["image_validation_scores"])
    else:
        image_scores, p_img = np.full(len(scores), np.nan), np.ones(len(scores))
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
                                 if flagged else f"in distribution (combined p = {p:.2f})")})
    return rows[0] if single else rows


__all__ = ["K_NEIGHBOURS", "ALPHA", "embedding_features", "fit_ood_reference", "ood_check"]
