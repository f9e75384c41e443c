"""Trained Alice–Bob pairs loaded from their model files: a FORC image and M_s in, each parameter with
its predicted error and conformal intervals out (SI units and normalized)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.errors import InputFileError, ModelFileError, OutOfDomainError
from ..core.parameters import denormalize, normalize, prior_class
from ..forc.raster import measurement_on_grid, quantize
from ..measured import read_forc
from .answer import PREDATES
from .encoding import readout
from .models import build_network, image_tensor
from .prediction import Prediction, answer_table, basis_lines
from .prior_class import prior_class_line
from .uncertainty import ConformalIntervals, quantile_to_error


@dataclass
class ParameterModel:
    name: str
    alice: torch.nn.Module
    bob: torch.nn.Module
    payload: dict
    conformal: ConformalIntervals

    @classmethod
    def load(cls, path) -> "ParameterModel":
        path = Path(path)
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except (OSError, RuntimeError, EOFError) as error:
            raise ModelFileError(f"cannot load model {path}: {error}") from None
        if not isinstance(payload, dict) or payload.get("format") != "forcdecode-alice-bob/1":
            found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
            raise ModelFileError(f"{path} is not a forcdecode model file (format {found!r})")
        arch = payload["architecture"]
        nets = []
        for key in ("alice_state", "bob_state"):
            net = build_network(arch["model"], width=arch["width"], image_size=arch["image_size"])
            net.load_state_dict(payload[key])
            nets.append(net.eval())
        c = payload["conformal"]
        conformal = ConformalIntervals(tuple(c["levels"]), {float(k): v for k, v in c["quantiles"].items()}, c["sigma_floor"])
        return cls(payload["parameter"], nets[0], nets[1], payload, conformal)

    @property
    def bounds(self) -> dict:
        return self.payload["bounds"]

    @property
    def prior_class(self) -> str:
        """The prior class of the training data (``core.parameters.PRIOR_CLASSES``; older files: paper)."""
        return prior_class(self.payload.get("prior_class"))

    @property
    def image_size(self) -> int:
        return int(self.payload["architecture"]["image_size"])

    def predict(self, images_uint8, Ms_A_per_m) -> dict:
        """Arrays (one entry per image) of the normalized prediction, Bob's error, intervals and SI values."""
        images = np.asarray(images_uint8)
        if images.ndim == 2:
            images = images[None]
        if images.shape[-2:] != (self.image_size, self.image_size):
            raise ValueError(f"{self.name} model expects {self.image_size}×{self.image_size} images, got {images.shape[-2:]}")
        ms = np.broadcast_to(np.asarray(Ms_A_per_m, dtype=float), (images.shape[0],))
        ms_norm = torch.as_tensor(normalize("Ms", ms, self.bounds), dtype=torch.float32)
        x = image_tensor(images)
        with torch.no_grad():
            u = readout(self.alice(x, ms_norm).numpy(), self.payload["readout"])
            q = readout(self.bob(x, ms_norm).numpy(), self.payload["readout"])
        error = quantile_to_error(q, self.payload["validation_errors"])
        out = {"normalized": u, "bob_quantile": q, "bob_error": error, "value": denormalize(self.name, u, self.bounds)}
        for level in self.conformal.levels:
            low, high = self.conformal.interval(u, error, level)
            tag = int(round(level * 100))
            out[f"normalized_{tag}"] = (low, high)
            out[f"value_{tag}"] = (denormalize(self.name, low, self.bounds), denormalize(self.name, high, self.bounds))
        return out


def load_models(directory, names=None) -> dict:
    """All ``<parameter>.pt`` model files of a directory (or those of ``names``)."""
    directory = Path(directory)
    paths = sorted(directory.glob("*.pt")) if names is None else [directory / f"{n}.pt" for n in names]
    missing = [str(p) for p in paths if not p.exists()]
    if missing or not paths:
        raise ModelFileError(f"no trained model in {directory} ({', '.join(missing) or 'no *.pt file'}); "
                         "train them with the workflow (snakemake) first")
    models = {}
    for path in paths:
        model = ParameterModel.load(path)
        models[model.name] = model
    return models


def models_prior_class(models: dict) -> str:
    """The one prior class of a set of Alice models (ModelFileError when they were trained on several)."""
    classes = sorted({m.prior_class for m in models.values()})
    if len(classes) != 1:
        raise ModelFileError("the models were trained on different prior classes ("
                             + ", ".join(f"{n}: {m.prior_class}" for n, m in models.items()) + "); use one training run's models")
    return classes[0]


def predict_parameters(models: dict, image_uint8, Ms_A_per_m: float) -> dict:
    """One image → {parameter: {value, normalized, error_normalized, interval_68, interval_90, ...}} (SI)."""
    result = {"Ms": float(Ms_A_per_m)}
    for name, model in models.items():
        p = model.predict(image_uint8, Ms_A_per_m)
        entry = {"value": float(p["value"][0]), "normalized": float(p["normalized"][0]),
                 "bob_error_normalized": float(p["bob_error"][0]), "bob_quantile": float(p["bob_quantile"][0])}
        for level in model.conformal.levels:
            tag = int(round(level * 100))
            entry[f"interval_{tag}"] = [float(p[f"value_{tag}"][0][0]), float(p[f"value_{tag}"][1][0])]
            entry[f"interval_{tag}_normalized"] = [float(p[f"normalized_{tag}"][0][0]), float(p[f"normalized_{tag}"][1][0])]
        result[name] = entry
    return result


def hamiltonian(prediction: dict, defaults: dict | None = None) -> dict:
    """Predicted parameters as the simulator's parameter dict (N_pin rounded to a count)."""

    return Prediction.from_dict(prediction).hamiltonian(defaults)


def image_from_input(path, size: int, sample_id=None, B_max_T: float = 1.0, force: bool = False):
    """(uint8 image, out-of-domain note or None) from a .npy image (uint8, or m in [−1, 1]), a sample
    of a dataset.h5, or a measured FORC file put on the training grid (±``B_max_T``, ``size`` fields).
    InputFileError for a missing or unusable input; OutOfDomainError for a FORC file outside the
    training domain unless ``force``."""

    p = Path(path)
    if not p.exists():
        raise InputFileError(f"{path} does not exist")
    if p.suffix == ".npy":
        image = np.load(p)
        if image.shape != (size, size):
            raise InputFileError(f"{path}: image has shape {image.shape}, the models expect ({size}, {size})")
        if image.dtype != np.uint8:
            if np.nanmin(image) < -1.001 or np.nanmax(image) > 1.001:
                raise InputFileError(f"{path}: a float image must hold m in [-1, 1] "
                                     f"(found {np.nanmin(image):.3g}..{np.nanmax(image):.3g})")
            image = quantize(image)
        return image, None
    if p.suffix in (".h5", ".hdf5"):
        import h5py

        if sample_id is None:
            raise InputFileError(f"{path}: a dataset input needs a sample id (--sample-id)")
        with h5py.File(p, "r") as h5:
            ids = list(h5["sample_id"][:])
            if sample_id not in ids:
                raise InputFileError(f"sample {sample_id} is not in {path}")
            return h5["images"][ids.index(sample_id)], None
    image, _, note, _ = measurement_on_grid(read_forc(p), B_max_T, size)
    if note is not None and not force:
        raise OutOfDomainError(f"{path} is out of the training domain: {note} (use --force to predict anyway)")
    return image, note


def prediction_lines(result: dict, source: str, Ms_kA_m: float, ms_note: str = "given") -> list[str]:
    """The prediction as a table: value, 68 % and 90 % intervals, Bob's error, unit and whether it is read
    from the image per parameter; a parameter whose validation skill does not show it read from the image
    (``learn.answer``) is printed "not read from the image: prior only" with its prior range instead of a
    number; then the derived combinations (value, intervals, defined fraction, the same flag) and how
    their intervals were made, and the basis of each flag. After the source, the prior class the model
    was trained on, when the result names it (``learn.prior_class``)."""
    lines = [f"{source}  (M_s = {Ms_kA_m:g} kA/m {ms_note})"]
    if result.get("prior_class"):
        lines.append(prior_class_line(result["prior_class"], result.get("prior_check")))
    prediction = Prediction.from_dict(result)
    table = answer_table(prediction)
    lines += table[1:] if table and table[0] == "" else table
    bases = basis_lines(prediction)
    lines += bases
    if any(PREDATES in line for line in bases):
        lines.append("  (retrain the models to get the flag: the model files predate it)")
    if result.get("out_of_domain"):
        lines.append(f"warning: out of the training domain: {result['out_of_domain']}")
    check = result.get("prior_check")
    if check and check.get("forced"):
        lines.append(f"WARNING (decoded with --force): {check['reason']}")
    ood = result.get("ood")
    if ood:
        prefix = "WARNING: " if ood.get("out_of_distribution") else ""
        lines.append(f"{prefix}looks like the training data? {ood['verdict']}")
    return lines
