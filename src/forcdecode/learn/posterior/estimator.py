"""The trained posterior (``learn.posterior``): ``PosteriorEstimator`` draws u ∈ [0, 1] per observation
(an ensemble's equal mixture, recalibrated when the model carries a recalibration) and gives the
flow's density; ``summarize`` and ``posterior_prediction`` turn draws into medians, intervals (SI)
and correlations."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ...core.errors import ConfigError, OutOfDomainError
from ...core.parameters import DEFAULT_PRIOR_CLASS, denormalize, normalize
from ...core.streams import stream_seed
from ...dataset.params import draw_log_density
from ..answer import posterior_flags
from ..calibration import recalibrate_draws, widen
from ..combinations import summarize_draws
from ..models import image_tensor
from ..ood import ood_check
from .file_format import read_estimator, save_estimator
from .flow import SQUEEZE, PosteriorNet, _float32, from_coordinates, from_latent, to_coordinates, to_latent

RECALIBRATION_REFERENCE_DRAWS = 1000
"""Draws behind each observation's marginal CDFs when a recalibrated sample of fewer is asked."""


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
    prior_class: str = DEFAULT_PRIOR_CLASS
    """The prior class of the training data (``core.parameters.PRIOR_CLASSES``): the draw prior of the
    "prior" coordinates and of the density; files written before it: paper."""

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
        return to_coordinates(u, self._Ms(ms_norm), self.names, self.bounds, self.coordinates, self.prior_class)

    def from_coordinates(self, v, ms_norm) -> np.ndarray:
        return from_coordinates(v, self._Ms(ms_norm), self.names, self.bounds, self.coordinates, self.prior_class)

    def coordinates_log_jacobian(self, u, ms_norm) -> np.ndarray:
        """log |dv/du| per row (the draw prior's log density for "prior" coordinates, 0 for "box")."""
        u = np.atleast_2d(u)
        if self.coordinates == "box":
            return np.zeros(len(u))

        return draw_log_density(u, self.names, self._Ms(ms_norm), self.bounds or None, prior=self.prior_class)

    def save(self, path, **metadata) -> None:
        """Atomic write of the weights, architecture, names, bounds and ``metadata`` (plain values;
        ``file_format.save_estimator``)."""
        save_estimator(self, path, **metadata)

    @classmethod
    @_float32
    def load(cls, path) -> "PosteriorEstimator":
        """ModelFileError when the file is missing, unreadable or not a posterior model."""
        return cls(**read_estimator(path))


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
    ``predict_parameters``, Bob's fields absent; ``combinations``: the derived combinations of the draws
    (``learn.combinations.summarize_draws``: median and intervals, SI); per parameter and combination
    ``read_from_image`` and its ``basis`` (``learn.answer.posterior_flags``: None for a model saved
    before the flag)."""

    ms_norm = float(normalize("Ms", Ms_A_per_m, est.bounds))

    draws = est.sample(np.asarray(image_uint8)[None], [ms_norm], n_draws, seed=stream_seed(seed, "posterior", "predict"))[0]
    summary = summarize(draws, est.names, est.bounds)
    result = {"Ms": float(Ms_A_per_m), "estimator": "posterior", "draws": int(n_draws),
              "ood": ood_check(est, np.asarray(image_uint8), [ms_norm])}

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

    # the derived combinations (σ_w, δ_w, D/D_c, Q; core.parameters) as transforms of the same draws
    result["combinations"] = summarize_draws(draws, est.names, ms_norm, est.bounds)

    # read from the image, or prior only: the validation figures saved with the model (learn.answer)
    return posterior_flags(est.metadata, result, est.bounds)
