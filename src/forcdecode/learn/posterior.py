"""Neural posterior estimation (NPE): the joint posterior p(θ | FORC image, M_s) of the learned
parameters θ = (N_pin, A_ex, K_u, D, σ_θ, σ_K), normalized to u ∈ [0, 1] by the configured bounds
(K_u on a log scale, as in the parameter table).

Model: a CNN embedding of the image and M_s (the small head's two 3×3 convolutions and 4×4 average
pool, M_s joined as in Alice, then a dense layer of ``width`` features) conditions a neural spline
flow (``zuko.flows.NSF``: autoregressive rational-quadratic splines; zuko, not a hand-written flow).
Everything is fitted on the workflow's train split with early stopping on its validation split (the
same hash split as Alice: ``splits.py``); the test split serves only the calibration
(``calibration.py``). Default summary (``features``), for the few hundred families of a laptop run:

1. the CNN and a linear head are fitted as a regression of the six standardized logits (MSE, early
   stopping on validation): the CNN learns features that carry the posterior means;
2. the CNN is then fixed, and the flow learns p(θ | CNN features, M_s) by maximum likelihood (early
   stopping on the validation likelihood).

``joint`` trains CNN and flow together by the likelihood alone (its early stopping also answers to
the parameters the image does not tell). ``crossfit`` conditions the flow on the regression's six
outputs, the training samples' taken out of fold (K regressions, each blind to its fold, as Bob's
errors are), so that the flow sees summaries as noisy as a new image's. Chosen on validation
likelihood, 5-fold cross-validation over the 148 laptop families: features 6.99 and 7.12 nats (two
weight seeds), crossfit 7.25 (calibration alike, 5 more regressions); on a 104-family snapshot joint
and features were alike (7.52, 7.58).

Bounded support: the flow lives in logit space. u is squeezed to [ε, 1 − ε] (ε = 1e-3, so a value
on a bound, e.g. N_pin = 0, stays finite), z = logit(u), standardized by the training split's mean
and spread (the spline acts on [−5, 5]); draws map back by the sigmoid and lie inside [0, 1] by
construction (no clipping of the density). N_pin is a count: its 256 levels on the laptop grid are
0.004 apart in u, far below any posterior width, and it is treated as continuous.

Every random number derives from the config seed through the stream ``posterior`` (weights, batch
order, dropout, draws); the same model and seed give the same draws after a save and a reload.
"""

from __future__ import annotations

import functools
import pickle
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..config import defaults, schema
from ..core import io
from ..core.errors import ConfigError, DatasetError, ModelFileError, OutOfDomainError
from ..core.parameters import LOG_SCALE, TARGETS, denormalize
from ..core.streams import stream_rng, stream_seed
from .models import MS_NODES, conv_features, image_tensor
from .scoring import binomial_band
from .splits import SPLITS, assign_splits

FORMAT = "forcdecode-posterior/1"
SQUEEZE = 1e-3
"""u is squeezed to [ε, 1 − ε] before the logit."""
RECALIBRATION_REFERENCE_DRAWS = 1000
"""Draws behind each observation's marginal CDFs when a recalibrated sample of fewer is asked."""
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


def to_coordinates(u, Ms, names, bounds, coordinates: str) -> np.ndarray:
    """u (…, d) → the coordinates the flow models: ``box``, u itself; ``prior``, v_j = F_j(u_j | M_s),
    the CDF of the draw prior given M_s (``dataset.params.draw_prior_cdf``): the prior becomes uniform,
    so the flow learns only what the image adds (A_ex's dependence on M_s through the exchange length
    and K_u's triangular draw no longer have to be learned from a few hundred families). ``Ms`` (A/m)
    broadcasts against u's leading axes."""
    u = np.asarray(u, dtype=float)
    if coordinates == "box":
        return u
    from ..dataset.params import draw_prior_cdf

    Ms = np.broadcast_to(np.asarray(Ms, dtype=float), u.shape[:-1])
    return np.stack([draw_prior_cdf(n, u[..., j], Ms, bounds or None) for j, n in enumerate(names)], axis=-1)


def from_coordinates(v, Ms, names, bounds, coordinates: str) -> np.ndarray:
    """Inverse of :func:`to_coordinates`."""
    v = np.asarray(v, dtype=float)
    if coordinates == "box":
        return v
    from ..dataset.params import draw_prior_ppf

    Ms = np.broadcast_to(np.asarray(Ms, dtype=float), v.shape[:-1])
    return np.stack([draw_prior_ppf(n, v[..., j], Ms, bounds or None) for j, n in enumerate(names)], axis=-1)


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


# ---------------------------------------------------------------- the estimator
@dataclass
class PosteriorEstimator:
    """A trained posterior: ``sample`` gives draws of u ∈ [0, 1] per observation."""

    net: PosteriorNet
    architecture: dict
    names: tuple
    bounds: dict = field(default_factory=dict)
    history: dict = field(default_factory=dict)
    best_epoch: int = -1
    metadata: dict = field(default_factory=dict)
    members: list = field(default_factory=list)
    """Further networks of a deep ensemble (``net`` is the first): the posterior is the equal mixture of
    the members' flows, each fitted from its own weight seed on the same data."""

    @property
    def nets(self) -> list:
        """Every member of the ensemble, ``net`` first (one network: ``[net]``)."""
        return [self.net, *self.members]

    @property
    def image_size(self) -> int:
        """Side of the FORC images the CNN embedding was trained on."""
        if self.architecture["embedding"] != "cnn":
            raise OutOfDomainError("this posterior reads vectors, not FORC images")
        return int(self.architecture["image_size"])

    def _inputs(self, x, ms_norm) -> tuple[torch.Tensor, torch.Tensor]:
        a = self.architecture
        x = np.asarray(x)
        if a["embedding"] == "cnn":
            if x.ndim == 2:
                x = x[None]
            side = a["image_size"]
            if x.ndim != 3 or x.shape[-2:] != (side, side):
                raise OutOfDomainError(f"the posterior was trained on {side}×{side} FORC images, got shape {x.shape}")
            tensor = image_tensor(x)
        else:
            if x.ndim == 1:
                x = x[None]
            if x.ndim != 2 or x.shape[1] != a["features"]:
                raise OutOfDomainError(f"the posterior expects observations of {a['features']} features, got shape {x.shape}")
            tensor = torch.as_tensor(x, dtype=torch.float32)
        ms = np.broadcast_to(np.asarray(ms_norm, dtype=float), (x.shape[0],))
        if not (np.isfinite(ms).all() and torch.isfinite(tensor).all()):
            raise OutOfDomainError("the observation or M_s is not finite")
        return tensor, torch.tensor(ms, dtype=torch.float32)

    @property
    def recalibration(self) -> dict | None:
        """Beta quantile recalibration per parameter (``learn.calibration``), fitted on held-out
        splits by ``train_posterior``; None for a model saved without it."""
        return (self.metadata.get("recalibration") or {}).get("beta")

    def sample(self, x, ms_norm, n_draws: int, seed: int, chunk: int = 64, recalibrated: bool = True) -> np.ndarray:
        """Draws of u ∈ [0, 1], shape (n_obs, n_draws, n_params); the same for the same ``seed``.

        ``recalibrated`` (default): the flow's draws mapped by the model's quantile recalibration when
        it has one (each marginal's PIT made uniform on held-out families; the dependence between
        parameters kept). The marginal CDFs come from the draws themselves, or from
        ``RECALIBRATION_REFERENCE_DRAWS`` extra draws when fewer are asked. ``recalibrated=False``:
        the flow itself, whose density ``log_prob`` gives (what an importance-sampling proposal needs)."""
        draws = self._sample_flow(x, ms_norm, n_draws, seed, chunk)
        beta = self.recalibration if recalibrated else None
        if not beta:
            return draws
        from .calibration import recalibrate_draws

        reference = None
        if n_draws < RECALIBRATION_REFERENCE_DRAWS:
            reference = self._sample_flow(x, ms_norm, RECALIBRATION_REFERENCE_DRAWS,
                                          stream_seed(int(seed), "posterior", "recalibration_reference"), chunk)
        return recalibrate_draws(draws, beta, self.names, reference)

    @_float32
    def _sample_flow(self, x, ms_norm, n_draws: int, seed: int, chunk: int = 64) -> np.ndarray:
        """The flow's draws (see ``sample``). An ensemble of K members is sampled stratified: draw d
        comes from member d mod K (every prefix of the draws is a balanced mixture); member 0 uses
        ``seed`` itself, so K = 1 is the single flow."""
        x, ms = self._inputs(x, ms_norm)
        if n_draws < 1:
            raise ConfigError(f"n_draws must be positive, got {n_draws}")
        nets = self.nets
        per_member = -(-n_draws // len(nets))
        draws = np.zeros((x.shape[0], n_draws, len(self.names)))
        for k, net in enumerate(nets):
            taken = len(range(k, n_draws, len(nets)))
            if taken == 0:
                continue
            member_seed = int(seed) if k == 0 else stream_seed(int(seed), "posterior", "ensemble_member", k)
            draws[:, k::len(nets)] = self._sample_net(net, x, ms, per_member, member_seed, chunk)[:, :taken]
        return self.from_coordinates(draws, ms.double().numpy()[:, None])

    @staticmethod
    def _sample_net(net, x, ms, n_draws: int, seed: int, chunk: int) -> np.ndarray:
        """One member's draws in the flow's coordinates (before ``from_coordinates``), (n_obs, n_draws, d)."""
        net.eval()
        out = []
        with torch.no_grad(), torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed))
            for start in range(0, x.shape[0], chunk):
                ctx = net.context(x[start:start + chunk], ms[start:start + chunk])
                z = net.flow(ctx).sample((n_draws,))          # (n_draws, chunk, dim)
                z = z * net.z_std + net.z_mean
                out.append(from_latent(z.transpose(0, 1).double().numpy()))
        if not out:
            return np.zeros((0, n_draws, net.z_mean.numel()))
        return np.concatenate(out)

    @_float32
    def log_prob(self, u, x, ms_norm) -> np.ndarray:
        """log density of the flow (not recalibrated: ``sample(recalibrated=False)`` draws from it) at
        u ∈ [0, 1], one u per observation, change of variables included."""
        x, ms = self._inputs(x, ms_norm)
        u = np.atleast_2d(np.asarray(u, dtype=float))
        ms_np = ms.double().numpy()
        log_prior = self.coordinates_log_jacobian(u, ms_np)
        u = self.to_coordinates(u, ms_np)
        z = to_latent(u)
        s = SQUEEZE + (1.0 - 2.0 * SQUEEZE) * u
        # du → dz: dz/du = (1 − 2ε)/(s(1 − s)); standardization: 1/σ_z (per member)
        log_jac = (np.log1p(-2.0 * SQUEEZE) - np.log(s) - np.log1p(-s)).sum(axis=1)
        members = []
        for net in self.nets:
            zs = torch.as_tensor((z - net.z_mean.numpy()) / net.z_std.numpy(), dtype=torch.float32)
            net.eval()
            with torch.no_grad():
                members.append(net.log_prob(zs, x, ms).double().numpy() - float(torch.log(net.z_std).sum()))
        # the ensemble's density: the mean of the members' densities
        from scipy.special import logsumexp

        mixture = logsumexp(np.stack(members), axis=0) - np.log(len(members))
        return mixture + log_jac + log_prior

    # the flow's coordinates: "box" (u itself) or "prior" (v = F(u | M_s), the draw prior's CDF)
    @property
    def coordinates(self) -> str:
        return self.architecture.get("coordinates", "box")

    def _Ms(self, ms_norm) -> np.ndarray:
        return denormalize("Ms", np.asarray(ms_norm, dtype=float), self.bounds or None)

    def to_coordinates(self, u, ms_norm) -> np.ndarray:
        """u (…, d) → the flow's coordinates (``ms_norm`` broadcast against u's leading axes)."""
        return to_coordinates(u, self._Ms(ms_norm), self.names, self.bounds, self.coordinates)

    def from_coordinates(self, v, ms_norm) -> np.ndarray:
        return from_coordinates(v, self._Ms(ms_norm), self.names, self.bounds, self.coordinates)

    def coordinates_log_jacobian(self, u, ms_norm) -> np.ndarray:
        """log |dv/du| per row (the draw prior's log density for "prior" coordinates, 0 for "box")."""
        u = np.atleast_2d(u)
        if self.coordinates == "box":
            return np.zeros(len(u))
        from ..dataset.params import draw_log_density

        return draw_log_density(u, self.names, self._Ms(ms_norm), self.bounds or None)

    def save(self, path, **metadata) -> None:
        """Atomic write of the weights, architecture, names, bounds and ``metadata`` (plain values)."""
        payload = {"format": FORMAT, "architecture": dict(self.architecture), "names": list(self.names),
                   "bounds": {k: [float(v[0]), float(v[1])] for k, v in self.bounds.items()},
                   "best_epoch": int(self.best_epoch), "state": self.net.state_dict(),
                   "member_states": [m.state_dict() for m in self.members], "metadata": metadata}
        with io.atomic_path(path) as tmp:
            torch.save(payload, tmp)

    @classmethod
    @_float32
    def load(cls, path) -> "PosteriorEstimator":
        """ModelFileError when the file is missing, unreadable or not a posterior model."""
        path = Path(path)
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except (OSError, RuntimeError, EOFError, ValueError, pickle.UnpicklingError) as error:
            raise ModelFileError(f"cannot load posterior model {path}: {error}") from None
        if not isinstance(payload, dict) or payload.get("format") != FORMAT:
            found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
            raise ModelFileError(f"{path} is not a forcdecode posterior model (format {found!r})")
        nets = []
        for state in [payload["state"], *payload.get("member_states", [])]:
            net = PosteriorNet(payload["architecture"])
            try:
                net.load_state_dict(state)
            except RuntimeError as error:
                raise ModelFileError(f"posterior model {path} does not match its architecture: {error}") from None
            nets.append(net.eval())
        return cls(nets[0], payload["architecture"], tuple(payload["names"]), payload["bounds"],
                   best_epoch=payload["best_epoch"], metadata=payload.get("metadata", {}), members=nets[1:])


@_float32
def fit_posterior(x, ms_norm, u, train, val, *, names, settings: dict | None = None, seed: int = 0,
                  embedding: str = "cnn", bounds: dict | None = None, log=None) -> PosteriorEstimator:
    """Maximum-likelihood fit of the flow and the embedding on ``train`` (AdamW), keeping the weights
    of the epoch with the lowest validation negative log-likelihood; ``x`` are uint8 images (cnn) or
    float vectors (mlp), ``u`` the targets in [0, 1], shape (n, len(names)).

    ``settings["ensemble"]`` = K > 1 fits K members from independent weight seeds (member 0 from
    ``seed`` itself, the others from the ``posterior`` stream's ``ensemble_fit`` keys) on the same
    split; the posterior is their equal mixture (a deep ensemble: members that agree where the data
    speak and disagree where they do not, so the mixture is wider exactly where one flow's
    maximum-likelihood fit on a few hundred families is over-sure)."""
    settings = posterior_settings(settings)
    members = []
    for k in range(int(settings["ensemble"])):
        member_seed = seed if k == 0 else stream_seed(seed, "posterior", "ensemble_fit", k)
        if log is not None and settings["ensemble"] > 1:
            log(f"posterior ensemble member {k + 1}/{settings['ensemble']}")
        members.append(_fit_member(x, ms_norm, u, train, val, names=names, settings=settings, seed=member_seed,
                                   embedding=embedding, bounds=bounds, log=log))
    est = members[0]
    est.members = [m.net for m in members[1:]]
    if len(members) > 1:
        est.history["ensemble_best_epochs"] = [int(m.best_epoch) for m in members]
        est.history["ensemble_val_nll"] = [float(m.history["val_nll"][m.best_epoch]) for m in members]
        est.history["train_seconds"] = float(sum(m.history["train_seconds"] for m in members))
    return est


def _fit_member(x, ms_norm, u, train, val, *, names, settings: dict, seed: int, embedding: str,
                bounds: dict | None, log) -> PosteriorEstimator:
    """One flow (and its embedding) fitted from the weight seed ``seed``: see :func:`fit_posterior`."""
    u = np.asarray(u, dtype=float)
    train, val = np.asarray(train), np.asarray(val)
    if u.ndim != 2 or u.shape[1] != len(names) or u.shape[0] != len(np.asarray(x)):
        raise DatasetError(f"targets of shape {u.shape} do not match {len(np.asarray(x))} observations of {len(names)} parameters")
    if not np.isfinite(u).all() or u.min() < 0.0 or u.max() > 1.0:
        raise DatasetError("normalized targets must be finite and inside [0, 1]")
    if len(train) < 2 or len(val) < 1:
        raise DatasetError(f"the posterior needs at least 2 training and 1 validation samples (got {len(train)}, {len(val)})")
    if embedding not in EMBEDDINGS:
        raise ConfigError(f"unknown embedding {embedding!r} (one of {', '.join(EMBEDDINGS)})")
    x = np.asarray(x)
    architecture = {"embedding": embedding, "summary": settings["summary"], "coordinates": settings["coordinates"],
                    "dim": len(names), "width": int(settings["width"]),
                    "dropout": float(settings["dropout"]), "transforms": int(settings["transforms"]),
                    "hidden": int(settings["hidden"]), "bins": int(settings["bins"])}
    if embedding == "cnn":
        if x.ndim != 3 or x.shape[1] != x.shape[2]:
            raise DatasetError(f"the CNN embedding needs square images (n, side, side), got {x.shape}")
        architecture["image_size"] = int(x.shape[-1])
    else:
        if x.ndim != 2:
            raise DatasetError(f"the MLP embedding needs vectors (n, features), got {x.shape}")
        architecture["features"] = int(x.shape[1])
    torch.manual_seed(stream_seed(seed, "posterior", "weights"))
    net = PosteriorNet(architecture)
    est = PosteriorEstimator(net, architecture, tuple(names), dict(bounds or {}))
    if architecture["coordinates"] == "prior" and not set(names) <= set(TARGETS):
        raise ConfigError(f"coordinates: prior needs the dataset's parameters (a draw prior), got {list(names)}; "
                          "use coordinates: box")
    x_all, ms_all = est._inputs(x, ms_norm)
    z = to_latent(est.to_coordinates(u, ms_all.double().numpy()))
    mean, std = z[train].mean(axis=0), z[train].std(axis=0) + 1e-6
    net.z_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
    net.z_std.copy_(torch.as_tensor(std, dtype=torch.float32))
    z_all = torch.as_tensor((z - mean) / std, dtype=torch.float32)
    generator = torch.Generator().manual_seed(stream_seed(seed, "posterior", "batches"))
    train_t, val_t = torch.as_tensor(train), torch.as_tensor(val)
    started = time.perf_counter()
    history = {}
    mode = settings["summary"]
    if mode == "joint":
        # embedding and flow together, by the flow's likelihood alone
        def nll(index):
            return -net.log_prob(z_all[index], x_all[index], ms_all[index]).mean()

        history["train_nll"], history["val_nll"], best_epoch = _train(net, nll, train_t, val_t, settings, generator,
                                                                      log, "posterior NLL")
    else:
        # 1. the embedding and a linear head as a regression of the standardized logits (early stopping
        #    on validation): learned summaries, estimates of the posterior means
        history["regression_train_mse"], history["regression_val_mse"], history["regression_best_epoch"] = _fit_regression(
            net.embedding, net.head, x_all, ms_all, z_all, train_t, val_t, settings, generator, log, "summary regression")
        net.embedding.requires_grad_(False)
        net.head.requires_grad_(False)
        with torch.no_grad():
            ctx_all = net.context(x_all, ms_all)
        if mode == "crossfit":
            # 2. the training samples' summaries out of fold (K regressions, each blind to its fold):
            #    the flow then learns how far summaries of unseen images are from the truth, as at test
            folds = max(2, min(int(settings["folds"]), len(train)))
            fold_of = stream_rng(seed, "posterior", "folds").permutation(len(train)) % folds
            for k in range(folds):
                held, kept = train[fold_of == k], train[fold_of != k]
                torch.manual_seed(stream_seed(seed, "posterior", "fold_weights", k))
                embedding, head = _make_embedding(architecture).float(), nn.Linear(architecture["width"] + 1, len(names)).float()
                _fit_regression(embedding, head, x_all, ms_all, z_all, torch.as_tensor(kept), val_t, settings,
                                generator, log, f"summary regression, fold {k + 1}/{folds}")
                with torch.no_grad():
                    held_t = torch.as_tensor(held)
                    features = torch.cat([embedding(x_all[held_t], ms_all[held_t]), ms_all[held_t].reshape(-1, 1)], 1)
                    ctx_all[held_t] = torch.cat([head(features), ms_all[held_t].reshape(-1, 1)], dim=1)
        # 3. the flow on the fixed summaries

        def nll(index):
            return -net.flow(ctx_all[index]).log_prob(z_all[index]).mean()

        history["train_nll"], history["val_nll"], best_epoch = _train(net.flow, nll, train_t, val_t, settings,
                                                                      generator, log, "posterior NLL")
        net.embedding.requires_grad_(True)
        net.head.requires_grad_(True)
    history["train_seconds"] = time.perf_counter() - started
    net.eval()
    est.history, est.best_epoch = history, best_epoch
    return est


def _fit_regression(embedding, head, x_all, ms_all, z_all, train_t, val_t, settings, generator, log, what):
    """Fit ``embedding`` + linear ``head`` by the MSE of the standardized logits (early stopping on
    validation); returns (train MSEs, validation MSEs, best epoch)."""
    module = nn.ModuleDict({"embedding": embedding, "head": head})

    def mse(index):
        features = torch.cat([embedding(x_all[index], ms_all[index]), ms_all[index].reshape(-1, 1)], dim=1)
        return torch.nn.functional.mse_loss(head(features), z_all[index])

    return _train(module, mse, train_t, val_t, settings, generator, log, what)


def _train(module: nn.Module, loss_of, train_t, val_t, settings, generator, log, what: str):
    """AdamW on ``loss_of(batch indices)`` over the training indices; early stopping on the validation
    loss; the module is left with the weights of its best epoch. Returns (train losses, validation
    losses, best epoch)."""
    optimizer = torch.optim.AdamW([p for p in module.parameters() if p.requires_grad], lr=settings["lr"],
                                  weight_decay=settings["weight_decay"])
    train_loss, val_loss = [], []
    best, best_state, best_epoch, waited = np.inf, None, -1, 0
    batch_size, epochs = int(settings["batch_size"]), int(settings["epochs"])
    for epoch in range(epochs):
        module.train()
        order = train_t[torch.randperm(len(train_t), generator=generator)]
        total = 0.0
        for start in range(0, len(order), batch_size):
            batch = order[start:start + batch_size]
            optimizer.zero_grad()
            loss = loss_of(batch)
            loss.backward()
            optimizer.step()
            total += loss.item() * len(batch)
        module.eval()
        with torch.no_grad():
            val = float(loss_of(val_t))
        train_loss.append(total / len(order))
        val_loss.append(val)
        if log is not None and (epoch % 10 == 0 or epoch == epochs - 1):
            log(f"{what}, epoch {epoch + 1}: train {train_loss[-1]:.3f}, validation {val:.3f}")
        if np.isfinite(val) and val < best:
            best, best_epoch, waited = val, epoch, 0
            best_state = {k: v.detach().clone() for k, v in module.state_dict().items()}
        else:
            waited += 1
            if waited >= int(settings["patience"]):
                break
    if best_state is None:
        raise DatasetError(f"the {what} on the validation split was never finite")
    module.load_state_dict(best_state)
    module.eval()
    return train_loss, val_loss, best_epoch


# ---------------------------------------------------------------- summaries (SI)
def summarize(samples, names, bounds, levels=(0.68, 0.9)) -> dict:
    """Per parameter: median, mean, central intervals (normalized and SI, through the bounds) of one
    observation's draws (n_draws, n_params); pairwise Pearson correlations of the draws in u."""
    samples = np.asarray(samples, dtype=float)
    out = {"parameters": {}, "correlation": {"names": list(names),
                                             "matrix": np.corrcoef(samples, rowvar=False).tolist()}}
    for j, name in enumerate(names):
        col = samples[:, j]
        row = {"median": float(np.median(col)), "mean": float(col.mean()),
               "median_value": float(denormalize(name, np.median(col), bounds))}
        for level in levels:
            tag = int(round(level * 100))
            lo, hi = np.quantile(col, [(1 - level) / 2, (1 + level) / 2])
            row[f"interval_{tag}"] = [float(lo), float(hi)]
            row[f"value_{tag}"] = [float(denormalize(name, lo, bounds)), float(denormalize(name, hi, bounds))]
        out["parameters"][name] = row
    return out


def posterior_prediction(est: PosteriorEstimator, image_uint8, Ms_A_per_m: float, n_draws: int = 4000,
                         seed: int = 0) -> dict:
    """One FORC image and M_s (A/m) → per parameter the posterior median (``value``, SI), mean, the
    68 % and 90 % central credible intervals (SI and normalized), the same conformalized on the
    calibration split (``interval_90_conformal``; models trained with a calibration split), and the
    pairwise correlations of the draws (``posterior_correlation``): the format of
    ``predict_parameters``, Bob's fields absent."""
    from ..core.parameters import normalize

    ms_norm = float(normalize("Ms", Ms_A_per_m, est.bounds))
    from .ood import ood_check

    draws = est.sample(np.asarray(image_uint8)[None], [ms_norm], n_draws, seed=stream_seed(seed, "posterior", "predict"))[0]
    summary = summarize(draws, est.names, est.bounds)
    result = {"Ms": float(Ms_A_per_m), "estimator": "posterior", "draws": int(n_draws),
              "ood": ood_check(est, np.asarray(image_uint8), [ms_norm])}
    from .calibration import widen

    widening = (est.metadata.get("conformal") or {}).get("widening", {})
    for name, row in summary["parameters"].items():
        result[name] = {"value": row["median_value"], "normalized": row["median"], "mean_normalized": row["mean"],
                        "interval_68": row["value_68"], "interval_90": row["value_90"],
                        "interval_68_normalized": row["interval_68"], "interval_90_normalized": row["interval_90"]}
        for tag in ("68", "90"):  # conformalized on the calibration split (learn/calibration.py), when fitted
            q = widening.get(tag, {}).get(name)
            if q is None:
                continue
            lo, hi = (float(v) for v in widen(*row[f"interval_{tag}"], q))
            result[name][f"interval_{tag}_conformal_normalized"] = [lo, hi]
            result[name][f"interval_{tag}_conformal"] = [float(denormalize(name, lo, est.bounds)),
                                                         float(denormalize(name, hi, est.bounds))]
    result["posterior_correlation"] = summary["correlation"]
    return result


# ---------------------------------------------------------------- the workflow stage
def split_diagnostics(est: PosteriorEstimator, data, u, splits: dict, draws: int, seed: int) -> dict:
    """Where a miscalibration comes from, per split and parameter: the KS p-value of the randomized
    PIT of the truth (uniform when calibrated; uniform on train but not on held-out splits is an
    overfit to the training families) with its counts per fifth, and the truths' marginal in the
    flow's coordinates (``prior``: uniform under the draw prior; the screening and the split's own
    sampling tilt it) with the two-sample KS p-value of train against the held-out splits: a training
    marginal unlike the held-out one is what a posterior that learns little from the image returns."""
    from scipy import stats

    from .calibration import sbc_ks_pvalues, sbc_ranks

    out = {"pit": {}, "coordinates_marginal": {}}
    v_of = {}
    for k, name in enumerate(SPLITS):
        idx = np.asarray(splits[name])
        if len(idx) < 2:
            continue
        samples = est.sample(data.images[idx], data.ms_norm[idx], draws, seed=stream_seed(seed, "posterior", "diagnose", k))
        ranks = sbc_ranks(samples, u[idx])
        p = sbc_ks_pvalues(ranks, draws, stream_rng(seed, "posterior", "diagnose_pit", k))
        v = est.to_coordinates(u[idx], data.ms_norm[idx])
        v_of[name] = v
        out["pit"][name] = {n: {"ks_p": float(p[j]), "per_fifth": np.histogram(ranks[:, j] / draws, bins=5,
                                                                               range=(0, 1))[0].tolist()}
                            for j, n in enumerate(est.names)}
        out["coordinates_marginal"][name] = {n: {"ks_p_uniform": float(stats.kstest(v[:, j], "uniform").pvalue),
                                                 "per_fifth": np.histogram(v[:, j], bins=5, range=(0, 1))[0].tolist()}
                                             for j, n in enumerate(est.names)}
    held = [v_of[n] for n in SPLITS if n != "train" and n in v_of]
    if "train" in v_of and held:
        held = np.concatenate(held)
        out["train_vs_held_out_ks_p"] = {n: float(stats.ks_2samp(v_of["train"][:, j], held[:, j]).pvalue)
                                         for j, n in enumerate(est.names)}
    return out


def _regression_summary(history: dict) -> dict | None:
    """Best epoch, epochs run and validation MSE (standardized logits) of the summary regression."""
    if "regression_best_epoch" not in history:
        return None
    best = int(history["regression_best_epoch"])
    return {"best_epoch": best, "epochs_run": len(history["regression_val_mse"]),
            "validation_mse": float(history["regression_val_mse"][best])}


def gated_recalibration_record(pit, names, gate_alpha: float, **record) -> dict:
    """The recalibration record of held-out PITs: every parameter's fitted Beta map (``beta_fitted``), its
    likelihood-ratio p-value against the identity, and under ``beta`` only the maps that test supports at
    ``gate_alpha`` (``learn.calibration.gate_recalibration``): ``beta`` is what the model applies."""
    from .calibration import fit_recalibration, gate_recalibration, recalibration_likelihood_ratio

    fitted = fit_recalibration(pit, names)
    p_values = recalibration_likelihood_ratio(pit, fitted, names)
    return {"method": "Beta quantile recalibration (Kuleshov et al. 2018), fitted by maximum likelihood, "
                      "applied where its likelihood-ratio test against the identity gives p < gate_alpha",
            **record, "n": int(len(pit)), "gate_alpha": float(gate_alpha),
            "beta": gate_recalibration(fitted, p_values, gate_alpha), "beta_fitted": fitted,
            "likelihood_ratio_p": p_values}


def fit_held_out_recalibration(est: PosteriorEstimator, data, u, splits: dict, draws: int, seed: int,
                               gate_alpha: float) -> dict:
    """Quantile recalibration of ``est`` (``learn.calibration``) fitted on the PITs of the validation and
    calibration splits, the held-out families the flow's weights never saw (validation only chose the
    epoch; on it alone the flow looks narrower than it is, so both splits are pooled); a map is applied
    only where its likelihood-ratio test gives p < ``gate_alpha`` (``gated_recalibration_record``)."""
    from .calibration import probability_integral_transform

    held_out = np.union1d(splits["validation"], splits["calibration"])
    raw = est.sample(data.images[held_out], data.ms_norm[held_out], draws,
                     seed=stream_seed(seed, "posterior", "recalibration_draws"), recalibrated=False)
    pit = probability_integral_transform(raw, u[held_out])
    return gated_recalibration_record(pit, est.names, gate_alpha, fitted_on="validation + calibration splits")


def train_posterior(data, settings: dict | None, learning: dict | None, seed: int, model_path, metrics_path,
                    figure_path, log=print) -> dict:
    """Fit the posterior on the workflow's train split (validation for early stopping), calibrate it on
    the test split; write the model, metrics.json and the calibration figure (all atomically)."""
    from .calibration import (RECALIBRATION_MIN_SAMPLES, calibration_figure, calibration_metrics,
                              conformal_coverage, conformal_widening, recalibrated_calibration)

    settings = posterior_settings(settings)
    learning = {**defaults("learning"), **(learning or {})}
    names = tuple(settings["parameters"])
    missing = [n for n in names if n not in data.values]
    if missing:
        raise DatasetError(f"the dataset has no column for {', '.join(missing)}")
    n = len(data)
    if n < learning["min_samples"]:
        raise DatasetError(f"the dataset has {n} FORC families; the posterior needs at least {learning['min_samples']}")
    splits = assign_splits(data.sample_id, seed, learning["split"], learning["protocol"])
    empty = [k for k in SPLITS if len(splits[k]) == 0]
    if empty:
        raise DatasetError(f"the {', '.join(empty)} split(s) of {n} FORC families are empty; raise n_samples")
    train, val, test = splits["train"], splits["validation"], splits["test"]
    u = np.stack([data.target(name) for name in names], axis=1)
    log(f"posterior: {len(names)} parameters, {len(train)} training / {len(val)} validation / {len(test)} test samples")
    started = time.perf_counter()
    est = fit_posterior(data.images, data.ms_norm, u, train, val, names=names, settings=settings, seed=seed,
                        embedding="cnn", bounds=data.bounds, log=log)
    train_s = time.perf_counter() - started
    from .ood import fit_ood_reference, ood_check

    # calibrated on validation + calibration families (held out from the flow, never test): with ~20 each
    # the conformal p-value can reach 1/42, below the Bonferroni level 0.025 of two scores at alpha 0.05
    est.metadata["ood"] = fit_ood_reference(est, data.images, data.ms_norm, train,
                                            np.union1d(val, splits["calibration"]))
    test_ood = ood_check(est, data.images[test], data.ms_norm[test])
    started = time.perf_counter()
    draws = int(settings["draws"])
    levels = [float(a) for a in settings["levels"]]
    recalibration = None
    if settings["recalibrate"] and learning["protocol"] == "holdout":
        n_held_out = len(np.union1d(splits["validation"], splits["calibration"]))
        if n_held_out < RECALIBRATION_MIN_SAMPLES:
            log(f"posterior not recalibrated: {n_held_out} validation + calibration families, fewer than "
                f"{RECALIBRATION_MIN_SAMPLES}")
        else:
            est.metadata["recalibration"] = recalibration = fit_held_out_recalibration(
                est, data, u, splits, draws, seed, settings["recalibration_gate_alpha"])
            log(f"posterior recalibration fitted on {recalibration['n']} held-out families (Beta a, b; likelihood-"
                f"ratio p; applied below {recalibration['gate_alpha']:g}): "
                + ", ".join(f"{n} {a:.2f} {b:.2f} p {recalibration['likelihood_ratio_p'][n]:.3f}"
                            + (" applied" if n in recalibration["beta"] else " not applied")
                            for n, (a, b) in recalibration["beta_fitted"].items()))
    samples = est.sample(data.images[test], data.ms_norm[test], draws, seed=stream_seed(seed, "posterior", "test_draws"),
                         recalibrated=False)
    # scored recalibrated, the flow alone on the same test draws reported beside it
    calibration, flow_only, samples = recalibrated_calibration(
        samples, u[test], names, (recalibration or {}).get("beta"),
        lambda: stream_rng(seed, "posterior", "calibration"), levels)
    # the calibration split is held out from the posterior too (only Alice's conformal step uses it):
    # test + calibration doubles the samples behind the SBC and coverage figures (reported apart), and
    # the calibration split alone conformalizes the reported intervals (measured on test)
    held_out = np.union1d(test, splits["calibration"])
    pooled, conformal = None, None
    if learning["protocol"] == "holdout" and len(held_out) > len(test):
        cal = splits["calibration"]
        extra = est.sample(data.images[cal], data.ms_norm[cal], draws,
                           seed=stream_seed(seed, "posterior", "calibration_draws"))
        both = np.concatenate([test, cal])
        pooled = calibration_metrics(np.concatenate([samples, extra]), u[both], names,
                                     stream_rng(seed, "posterior", "calibration_pooled"), levels)
        pooled = {"n": int(len(both)), "per_parameter": pooled["per_parameter"], "joint": pooled["joint"]["tarp"]}
        widening = conformal_widening(extra, u[cal], levels)
        conformal = {"n_calibration": int(len(cal)),
                     "widening": {f"{int(round(a * 100))}": {n_: float(q[j]) for j, n_ in enumerate(names)}
                                  for a, q in widening.items()}}
        for level, (cov, width) in conformal_coverage(samples, u[test], widening).items():
            tag = f"{int(round(level * 100))}"
            for j, name in enumerate(names):
                calibration["per_parameter"][name][f"coverage_{tag}_conformal"] = float(cov[j])
                calibration["per_parameter"][name][f"width_{tag}_conformal"] = float(width[j])
    diagnostics = split_diagnostics(est, data, u, splits, draws, seed) if learning["protocol"] == "holdout" else None
    calibration_s = time.perf_counter() - started
    metrics = {"format": FORMAT, "reported_on": "validation (paper protocol)" if learning["protocol"] == "paper" else "test",
               "n_train": int(len(train)), "n_validation": int(len(val)), "n_test": int(len(test)),
               "parameters": list(names), "log_scale": [p for p in names if p in LOG_SCALE], "units": "normalized u in [0, 1]",
               "bounded_support": BOUNDED_SUPPORT, "estimator": "zuko NSF conditioned on a CNN embedding and M_s",
               "coverage": "central (equal-tailed) marginal credible intervals; joint: TARP",
               "coverage_binomial_band": {f"{int(round(a * 100))}": binomial_band(len(test), a) for a in levels},
               "targets": {"sbc_ks_p_above": 0.01, "coverage_90_within": [0.85, 0.95]},
               "best_epoch": int(est.best_epoch), "epochs_run": len(est.history["val_nll"]),
               "validation_nll": float(est.history["val_nll"][est.best_epoch]), "config_hash": data.config_hash,
               "summary": settings["summary"], "summary_regression": _regression_summary(est.history),
               "test_and_calibration_splits": pooled,
               "split_diagnostics": diagnostics,
               "conformal": conformal,
               "recalibration": recalibration, "flow_without_recalibration": flow_only,
               "sample_id_test": [int(s) for s in data.sample_id[test]],
               "ood_test_flagged_fraction": float(np.mean([r["out_of_distribution"] for r in test_ood])),
               "ood_alpha": est.metadata["ood"]["alpha"],
               "settings": settings, "wall_s": {"train": train_s, "calibration": calibration_s}, **calibration}
    metrics["wall_s"]["total"] = train_s + calibration_s
    fitted = np.union1d(train, val) if recalibration is None else np.union1d(np.union1d(train, val), splits["calibration"])
    fitted_ids = np.sort(np.asarray(data.sample_id[fitted], dtype=np.int64)).tolist()
    est.save(model_path, config_hash=data.config_hash, seed=int(seed), settings=settings, sample_ids_fitted=fitted_ids,
             summary={k: metrics[k] for k in ("n_train", "n_validation", "n_test", "best_epoch")},
             per_parameter=metrics["per_parameter"], ood=est.metadata["ood"], conformal=conformal,
             recalibration=recalibration)
    io.write_json(metrics_path, metrics)
    calibration_figure(metrics, figure_path)
    for name, row in metrics["per_parameter"].items():
        log(f"posterior {name}: MAE mean {row['mae_mean']:.3f} median {row['mae_median']:.3f}; SBC KS p {row['sbc_ks_p']:.3f}; "
            f"coverage 50/68/90 {row.get('coverage_50', float('nan')):.2f}/{row.get('coverage_68', float('nan')):.2f}/"
            f"{row.get('coverage_90', float('nan')):.2f}; width 90 {row.get('width_90', float('nan')):.3f}")
    if diagnostics and "train_vs_held_out_ks_p" in diagnostics:
        log("posterior split diagnostics (train vs held-out marginal KS p; PIT KS p train/validation/calibration/test): "
            + "; ".join(f"{n} {diagnostics['train_vs_held_out_ks_p'][n]:.3f} ("
                        + "/".join(f"{diagnostics['pit'][k][n]['ks_p']:.3f}" for k in SPLITS if k in diagnostics["pit"])
                        + ")" for n in names))
    return metrics


__all__ = ["FORMAT", "BOUNDED_SUPPORT", "posterior_settings", "to_latent", "from_latent", "PosteriorNet",
           "PosteriorEstimator", "fit_posterior", "gated_recalibration_record", "fit_held_out_recalibration",
           "summarize", "posterior_prediction",
           "split_diagnostics", "train_posterior"]
