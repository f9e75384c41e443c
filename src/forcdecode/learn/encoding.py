"""Distribution-matching encoding of a normalized parameter (the seed paper's authors' 2023 code).

A parameter u ∈ [0, 1] (normalized by the configured bounds) is scaled to y = 10u ∈ [0, 10] and
encoded on 11 nodes as a log-Gaussian of width one bin: t_k = 20 − (k − y)²/2, k = 0..10. The
network is trained with MSE on its raw outputs. Readouts:

- ``parabola`` (the authors'): vertex of the least-squares parabola through the 5 nodes around the
  highest node (that node clamped to 2..8). Exact for a perfect output. Guard: where the fitted
  parabola is flat or convex (curvature ≥ −1e-6) the vertex is meaningless; the 5-node
  softmax-weighted mean is used instead, and the vertex is clipped to the 5-node window.
- ``softmax``: expectation of k under softmax(outputs) (a smooth alternative).
"""

from __future__ import annotations

import numpy as np

N_NODES = 11
NODES = np.arange(N_NODES, dtype=float)


def encode(u) -> np.ndarray:
    """u ∈ [0, 1] (any shape) → targets of shape (..., 11)."""
    y = 10.0 * np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    return 20.0 - 0.5 * (NODES - y[..., None]) ** 2


def _softmax_mean(outputs):
    """Expectation of the node index under softmax(outputs)."""
    w = np.exp(outputs - outputs.max(axis=-1, keepdims=True))
    return (w * NODES).sum(axis=-1) / w.sum(axis=-1)


def readout(outputs, method: str = "parabola") -> np.ndarray:
    """Network outputs (..., 11) → u ∈ [0, 1]."""
    return readout_with_variance(outputs, method)[0]


def readout_with_variance(outputs, method: str = "parabola") -> tuple[np.ndarray, np.ndarray]:
    """Network outputs (..., 11) → (u ∈ [0, 1], v̂ the variance of u the outputs carry).

    The targets are quadratic in y = 10u, so the MSE-optimal output is 20 − (k − μ)²/2 − v/2 with
    μ = E[y|x], v = Var(y|x): the height of the fitted parabola's vertex gives v̂ = 2(20 − peak)
    (clipped at 0), returned in units of u² (v/100). NaN where the fit is flat or convex (no vertex);
    the softmax readout returns the softmax variance of k/10 instead."""
    outputs = np.asarray(outputs, dtype=float)
    if outputs.shape[-1] != N_NODES:
        raise ValueError(f"expected {N_NODES} output nodes, got {outputs.shape[-1]}")
    flat = outputs.reshape(-1, N_NODES)
    shape = outputs.shape[:-1]
    if method == "softmax":
        w = np.exp(flat - flat.max(axis=-1, keepdims=True))
        w /= w.sum(axis=-1, keepdims=True)
        mean = (w * NODES).sum(axis=-1)
        var = (w * (NODES - mean[:, None]) ** 2).sum(axis=-1)
        return np.clip(mean / 10.0, 0.0, 1.0).reshape(shape), (var / 100.0).reshape(shape)
    if method != "parabola":
        raise ValueError(f"unknown readout {method!r}")
    centre = np.clip(np.argmax(flat, axis=1), 2, 8)
    offsets = np.arange(-2, 3)
    window_k = centre[:, None] + offsets[None, :]  # (n, 5)
    window_t = np.take_along_axis(flat, window_k, axis=1)
    # least squares t = a x² + b x + c on x = offsets (symmetric: closed form)
    x = offsets.astype(float)
    a = ((window_t * (x**2 - 2.0)).sum(axis=1)) / ((x**2 - 2.0) ** 2).sum()
    b = (window_t * x).sum(axis=1) / (x**2).sum()
    concave = a < -1e-6
    vertex = np.where(concave, -b / (2 * np.where(concave, a, -1.0)), 0.0)
    vertex = np.clip(vertex, -2.0, 2.0)
    z = window_t - window_t.max(axis=1, keepdims=True)
    weights = np.exp(z)
    fallback = (weights * x).sum(axis=1) / weights.sum(axis=1)
    y = centre + np.where(concave, vertex, fallback)
    c = (window_t.sum(axis=1) - a * (x**2).sum()) / x.size  # intercept of the fitted parabola
    peak = a * vertex**2 + b * vertex + c
    variance = np.where(concave, np.maximum(2.0 * (20.0 - peak), 0.0) / 100.0, np.nan)
    return np.clip(y / 10.0, 0.0, 1.0).reshape(shape), variance.reshape(shape)
