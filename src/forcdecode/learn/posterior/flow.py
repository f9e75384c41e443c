"""The flow of the joint posterior (``learn.posterior``): its settings, the bounded latent space (u
squeezed to [ε, 1 − ε], logit, standardized), the flow's coordinates (``box`` or ``prior``), the
embeddings of the observation and M_s, and ``PosteriorNet`` (embedding + regression head + zuko
neural spline flow)."""

from __future__ import annotations

import functools
from contextlib import contextmanager

import numpy as np
import torch
from torch import nn

from ...config import defaults, schema
from ...core.errors import ConfigError
from ...dataset.params import draw_prior_cdf, draw_prior_ppf
from ..models import MS_NODES, conv_features

SQUEEZE = 1e-3
"""u is squeezed to [ε, 1 − ε] before the logit."""
EMBEDDINGS = ("cnn", "mlp")

BOUNDED_SUPPORT = (f"flow in logit space: u squeezed to [{SQUEEZE:g}, {1 - SQUEEZE:g}], z = logit(u) standardized "
                   "by the training split; draws mapped back by the sigmoid (inside [0, 1], no clipping)")



@contextmanager
def _float32_default():
    """Run with torch's default dtype float32 (importing magnum.np switches it to float64 for the whole
    process; the flow's internal tensors must not follow), restoring whatever was set."""
    previous = torch.get_default_dtype()
    torch.set_default_dtype(torch.float32)
    try:
        yield
    finally:
        torch.set_default_dtype(previous)


def _float32(function):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with _float32_default():
            return function(*args, **kwargs)
    return wrapper


def posterior_settings(overrides: dict | None = None, source: str = "posterior settings") -> dict:
    """The schema's ``posterior`` defaults updated by ``overrides``, validated against the schema's
    ``posterior`` section (ConfigError naming the key)."""
    from jsonschema import Draft202012Validator
    from jsonschema.exceptions import best_match

    settings = {**defaults("posterior"), **(overrides or {})}
    error = best_match(Draft202012Validator(schema()["properties"]["posterior"]).iter_errors(settings))
    if error is not None:
        key = ".".join(str(p) for p in error.absolute_path) or "(section)"
        raise ConfigError(f"{source}: invalid value at posterior.{key}: {error.message}")
    return settings


# ---------------------------------------------------------------- the bounded latent space
def to_latent(u) -> np.ndarray:
    """u ∈ [0, 1] → logit of the squeezed value (unstandardized)."""
    s = SQUEEZE + (1.0 - 2.0 * SQUEEZE) * np.asarray(u, dtype=float)
    return np.log(s) - np.log1p(-s)


def from_latent(z) -> np.ndarray:
    """Inverse of :func:`to_latent`: logit space → u ∈ [0, 1]."""
    s = 1.0 / (1.0 + np.exp(-np.asarray(z, dtype=float)))
    return np.clip((s - SQUEEZE) / (1.0 - 2.0 * SQUEEZE), 0.0, 1.0)


def to_coordinates(u, Ms, names, bounds, coordinates: str, prior: str = "paper") -> np.ndarray:
    """u (…, d) → the coordinates the flow models: ``box``, u itself; ``prior``, v_j = F_j(u_j | M_s),
    the CDF of the draw prior given M_s (``dataset.params.draw_prior_cdf``): the prior becomes uniform,
    so the flow learns only what the image adds (A_ex's dependence on M_s through the exchange length
    and K_u's triangular draw no longer have to be learned from a few hundred families). ``Ms`` (A/m)
    broadcasts against u's leading axes; ``prior``: the prior class of that draw."""
    u = np.asarray(u, dtype=float)
    if coordinates == "box":
        return u

    Ms = np.broadcast_to(np.asarray(Ms, dtype=float), u.shape[:-1])
    return np.stack([draw_prior_cdf(n, u[..., j], Ms, bounds or None, prior=prior) for j, n in enumerate(names)],
                    axis=-1)


def from_coordinates(v, Ms, names, bounds, coordinates: str, prior: str = "paper") -> np.ndarray:
    """Inverse of :func:`to_coordinates`."""
    v = np.asarray(v, dtype=float)
    if coordinates == "box":
        return v

    Ms = np.broadcast_to(np.asarray(Ms, dtype=float), v.shape[:-1])
    return np.stack([draw_prior_ppf(n, v[..., j], Ms, bounds or None, prior=prior) for j, n in enumerate(names)],
                    axis=-1)


# ---------------------------------------------------------------- networks
class ConvEmbedding(nn.Module):
    """The small head's layout: convolutions 1→8→16 (3×3, ReLU), 4×4 average pool, the pooled features
    joined with ``MS_NODES`` copies of the normalized M_s (as Alice's), dense → ``width`` (ReLU,
    dropout). M_s enters before the dense layer so that features can combine image and M_s (e.g. the
    switching field scales as 2K_u/M_s). (image (n, side, side) in [0, 1], M_s (n,)) → (n, width)."""

    def __init__(self, image_size: int, width: int, dropout: float):
        super().__init__()
        self.conv1 = nn.Conv2d(1, 8, 3)
        self.conv2 = nn.Conv2d(8, 16, 3)
        self.pool = nn.AvgPool2d(4)
        self.dense = nn.Linear(conv_features(image_size, pooled=True) + MS_NODES, width)
        self.drop = nn.Dropout(dropout)

    def forward(self, image: torch.Tensor, ms_norm: torch.Tensor) -> torch.Tensor:
        x = image.unsqueeze(1) if image.dim() == 3 else image
        x = self.pool(torch.relu(self.conv2(torch.relu(self.conv1(x))))).flatten(1)
        x = torch.cat([x, ms_norm.reshape(-1, 1).expand(-1, MS_NODES)], dim=1)
        return self.drop(torch.relu(self.dense(x)))


class MLPEmbedding(nn.Module):
    """Two dense layers for vector observations: ((n, features), M_s (n,)) → (n, width) (low-dimensional tests)."""

    def __init__(self, features: int, width: int, dropout: float):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(features + 1, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU(),
                                 nn.Dropout(dropout))

    def forward(self, x: torch.Tensor, ms_norm: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([x, ms_norm.reshape(-1, 1)], dim=1))


SUMMARIES = ("crossfit", "features", "joint")


def _make_embedding(a: dict) -> nn.Module:
    if a["embedding"] == "cnn":
        return ConvEmbedding(a["image_size"], a["width"], a["dropout"])
    if a["embedding"] == "mlp":
        return MLPEmbedding(a["features"], a["width"], a["dropout"])
    raise ConfigError(f"unknown embedding {a['embedding']!r} (one of {', '.join(EMBEDDINGS)})")


class PosteriorNet(nn.Module):
    """Embedding (+ regression head) + M_s → context of a zuko neural spline flow over the
    standardized logits. ``summary``: ``crossfit`` (context = the head's regression of the logits,
    6 numbers, and M_s), ``features`` (context = the embedding's features and M_s) or ``joint``
    (the same context, embedding and flow trained together)."""

    def __init__(self, architecture: dict):
        import zuko

        super().__init__()
        a = architecture
        self.summary = a.get("summary", "features")
        if self.summary not in SUMMARIES:
            raise ConfigError(f"unknown posterior summary {self.summary!r} (one of {', '.join(SUMMARIES)})")
        self.embedding = _make_embedding(a)
        self.head = nn.Linear(a["width"] + 1, a["dim"])
        context = a["dim"] + 1 if self.summary == "crossfit" else a["width"] + 1
        self.flow = zuko.flows.NSF(a["dim"], context=context, bins=a["bins"], transforms=a["transforms"],
                                   hidden_features=(a["hidden"], a["hidden"]))
        self.register_buffer("z_mean", torch.zeros(a["dim"]))
        self.register_buffer("z_std", torch.ones(a["dim"]))
        self.float()

    def features(self, x: torch.Tensor, ms_norm: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.embedding(x, ms_norm), ms_norm.reshape(-1, 1)], dim=1)

    def context(self, x: torch.Tensor, ms_norm: torch.Tensor) -> torch.Tensor:
        features = self.features(x, ms_norm)
        if self.summary == "crossfit":
            return torch.cat([self.head(features), ms_norm.reshape(-1, 1)], dim=1)
        return features

    def log_prob(self, z_std: torch.Tensor, x: torch.Tensor, ms_norm: torch.Tensor) -> torch.Tensor:
        """log density of the standardized logits given the observation."""
        return self.flow(self.context(x, ms_norm)).log_prob(z_std)
