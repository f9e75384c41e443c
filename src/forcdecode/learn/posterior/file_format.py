"""The posterior's model file (``learn.posterior``): one ``torch.save`` of plain values (format
``FORMAT``): the architecture, the parameter names and bounds, the prior class of the training data
(``prior_class``; a file without it: paper), the best epoch, the state dict of each
member of the ensemble and the metadata (OOD reference, recalibration, conformal widening, ...).
Read back with ``weights_only=True``: no class is pickled, so the file does not depend on where the
code lives."""

from __future__ import annotations

import pickle
from pathlib import Path

import torch

from ...core import io
from ...core.errors import ModelFileError
from ...core.parameters import prior_class
from .flow import PosteriorNet

FORMAT = "forcdecode-posterior/1"


def save_estimator(est, path, **metadata) -> None:
    """Atomic write of ``est``'s weights, architecture, names, bounds and ``metadata`` (plain values)."""
    payload = {"format": FORMAT, "architecture": dict(est.architecture), "names": list(est.names),
               "bounds": {k: [float(v[0]), float(v[1])] for k, v in est.bounds.items()},
               "best_epoch": int(est.best_epoch), "state": est.net.state_dict(),
               "member_states": [m.state_dict() for m in est.members],
               "prior_class": str(getattr(est, "prior_class", "paper")), "metadata": metadata}
    with io.atomic_path(path) as tmp:
        torch.save(payload, tmp)


def read_estimator(path) -> dict:
    """The fields of a ``PosteriorEstimator`` read from ``path`` (its networks in eval mode);
    ModelFileError when the file is missing, unreadable or not a posterior model."""
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
    return {"net": nets[0], "architecture": payload["architecture"], "names": tuple(payload["names"]),
            "bounds": payload["bounds"], "best_epoch": payload["best_epoch"], "metadata": payload.get("metadata", {}),
            "members": nets[1:], "prior_class": prior_class(payload.get("prior_class"))}


__all__ = ["FORMAT", "read_estimator", "save_estimator"]
