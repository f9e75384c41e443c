"""Training one Alice network (one parameter): splits, Adadelta, early stopping on validation.

``fit_alice`` fits on the training indices and keeps the weights of the epoch with the lowest
validation loss; the test set is never looked at here (splits: ``splits.py``). Settings left None
take the schema's learning defaults (``forcdecode.config.defaults("learning")``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import functools
import time

import numpy as np
import torch

from ..config import defaults
from .encoding import encode, readout
from .models import build_network, image_tensor


@dataclass
class Alice:
    """A fitted network for one normalized parameter."""

    net: torch.nn.Module
    history: dict = field(default_factory=dict)
    best_epoch: int = -1

    def outputs(self, images, ms_norm, batch_size: int = 256) -> np.ndarray:
        self.net.eval()
        chunks = []
        with torch.no_grad():
            for start in range(0, len(images), batch_size):
                x = image_tensor(images[start:start + batch_size])
                ms = torch.as_tensor(np.asarray(ms_norm[start:start + batch_size]), dtype=torch.float32)
                chunks.append(self.net(x, ms).numpy())
        return np.concatenate(chunks) if chunks else np.zeros((0, 11))

    def predict(self, images, ms_norm, method: str = "parabola") -> np.ndarray:
        """Normalized parameter u ∈ [0, 1] per image."""
        return readout(self.outputs(images, ms_norm), method)

    def mc_dropout(self, images, ms_norm, n_passes: int = 30, seed: int = 0, method: str = "parabola"):
        """Monte-Carlo dropout: ``n_passes`` readouts with dropout left on; (mean, std) per image."""
        torch.manual_seed(seed)
        self.net.train()
        x = image_tensor(images)
        ms = torch.as_tensor(np.asarray(ms_norm), dtype=torch.float32)
        with torch.no_grad():
            draws = np.stack([readout(self.net(x, ms).numpy(), method) for _ in range(n_passes)])
        self.net.eval()
        return draws.mean(axis=0), draws.std(axis=0, ddof=1)



def with_float32_default(function):
    """Run ``function`` with torch's default dtype float32, restored afterwards. A package imported
    earlier in the same process may have changed it for the whole process (magnum.np sets float64 on
    import): the networks are then built, trained and compared in float32 whatever the caller's state
    (in a test session that imported magnum.np first, Bob trained in float64 collapsed to a constant)."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        previous = torch.get_default_dtype()
        torch.set_default_dtype(torch.float32)
        try:
            return function(*args, **kwargs)
        finally:
            torch.set_default_dtype(previous)

    return wrapper


@dataclass(frozen=True)
class AliceSettings:
    """How one Alice network is built and trained; fields left None take the schema's learning defaults
    (``forcdecode.config.defaults("learning")``, resolved by :meth:`resolved`).

    - ``model``: the network's dense head, ``"small"`` or ``"paper"`` (``learn.models``);
    - ``width``: units of the small head's hidden dense layer;
    - ``epochs``: the most passes over the training indices;
    - ``batch_size``: samples per optimizer step;
    - ``lr``: Adadelta's learning rate (dimensionless; the paper's is 0.01);
    - ``patience``: epochs without a lower validation loss before training stops;
    - ``seed``: seed of the weights (``torch.manual_seed``) and of the batch order;
    - ``dropout``: dropout probability of the dense block (0–1)."""

    model: str | None = None
    width: int | None = None
    epochs: int | None = None
    batch_size: int | None = None
    lr: float | None = None
    patience: int | None = None
    seed: int = 0
    dropout: float = 0.5

    def resolved(self) -> AliceSettings:
        """These settings with every None replaced by the schema's learning default."""
        learning = defaults("learning")
        return replace(self, **{name: learning[name] for name in ("model", "width", "epochs", "batch_size", "lr",
                                                                  "patience") if getattr(self, name) is None})


def fit_alice(images, ms_norm, target_norm, train_idx, val_idx, settings: AliceSettings = AliceSettings(), *,
              log=None) -> Alice:
    """Adadelta (ρ 0.9, no weight decay; the paper's lr is 0.01), MSE on the 11 raw outputs against
    the encoding; keeps the weights of the epoch with the lowest validation loss."""
    settings = settings.resolved()
    model, width, epochs, batch_size = settings.model, settings.width, settings.epochs, settings.batch_size
    lr, patience, seed, dropout = settings.lr, settings.patience, settings.seed, settings.dropout
    if len(train_idx) == 0 or len(val_idx) == 0:
        raise ValueError(f"training needs non-empty train and validation sets (got {len(train_idx)} and {len(val_idx)})")
    torch.manual_seed(seed)
    net = build_network(model, width=width, image_size=int(np.shape(images)[-1]), dropout=dropout)
    optimizer = torch.optim.Adadelta(net.parameters(), lr=lr, rho=0.9, weight_decay=0.0)
    x_all = image_tensor(images)
    ms_all = torch.as_tensor(np.asarray(ms_norm), dtype=torch.float32)
    t_all = torch.as_tensor(encode(target_norm), dtype=torch.float32)
    with torch.no_grad():  # start from the mean encoded target: the steps go to what varies
        net.dense2.bias.copy_(t_all[torch.as_tensor(np.asarray(train_idx))].mean(dim=0))
    generator = torch.Generator().manual_seed(seed)
    train_idx = torch.as_tensor(np.asarray(train_idx))
    val_idx = torch.as_tensor(np.asarray(val_idx))
    history = {"train_loss": [], "val_loss": []}
    best, best_state, best_epoch, waited = np.inf, None, -1, 0
    started, samples_seen = time.perf_counter(), 0
    for epoch in range(epochs):
        net.train()
        permutation = train_idx[torch.randperm(len(train_idx), generator=generator)]
        total = 0.0
        for start in range(0, len(permutation), batch_size):
            batch = permutation[start:start + batch_size]
            optimizer.zero_grad()
            loss = torch.nn.functional.mse_loss(net(x_all[batch], ms_all[batch]), t_all[batch])
            loss.backward()
            optimizer.step()
            total += loss.item() * len(batch)
            samples_seen += len(batch)
        net.eval()
        with torch.no_grad():
            val = float(torch.nn.functional.mse_loss(net(x_all[val_idx], ms_all[val_idx]), t_all[val_idx]))
        history["train_loss"].append(total / len(train_idx))
        history["val_loss"].append(val)
        if log is not None:
            log(f"epoch {epoch + 1}/{epochs}: train {history['train_loss'][-1]:.4f}, validation {val:.4f}")
        if val < best:
            best, best_epoch, waited = val, epoch, 0
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        else:
            waited += 1
            if waited >= patience:
                break
    history["train_seconds"] = time.perf_counter() - started
    history["samples_seen"] = samples_seen
    net.load_state_dict(best_state)
    net.eval()
    return Alice(net, history, best_epoch)
