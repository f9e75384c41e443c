"""The merged dataset as the networks see it: uint8 FORC images, normalized M_s, normalized targets.

Normalization uses the bounds of the configuration that drew the dataset (stored in dataset.h5),
on a log scale where the draw is log (K_u): never data maxima. The prior class the dataset was drawn
from (``prior`` of its stored config; absent: paper) travels with the data into every model.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import h5py
import numpy as np

from ..core.errors import InputFileError
from ..core.parameters import DEFAULT_BOUNDS, DEFAULT_PRIOR_CLASS, TARGETS, UNITS, normalize, prior_class

__all__ = ["TARGETS", "UNITS", "PAPER_FIGURES", "LearningData", "load_dataset"]
# TARGETS (parameters with their own network; M_s is an input) and UNITS: core.parameters

PAPER_FIGURES = {"N_pin": {"mae": 0.11, "pearson_r": 0.84}, "A_ex": {"mae": 0.07, "pearson_r": 0.92},
                 "K_u": {"mae": 0.04, "pearson_r": 0.97}, "D": {"mae": 0.07, "pearson_r": 0.90}}
"""The seed paper's validation-set figures (normalized MAE and Pearson r)."""


@dataclass
class LearningData:
    images: np.ndarray          # (n, side, side) uint8
    ms_norm: np.ndarray         # (n,) M_s normalized by its bounds
    values: dict                # name -> (n,) SI values
    sample_id: np.ndarray
    bounds: dict
    config_hash: str
    fields_T: np.ndarray
    prior_class: str = DEFAULT_PRIOR_CLASS  # the class the dataset was drawn from (core.parameters.PRIOR_CLASSES)

    def __len__(self) -> int:
        return int(self.images.shape[0])

    def take(self, index) -> "LearningData":
        """The families at ``index`` (positions), same bounds and configuration."""
        index = np.asarray(index, dtype=np.int64)
        return LearningData(images=self.images[index], ms_norm=self.ms_norm[index],
                            values={k: v[index] for k, v in self.values.items()}, sample_id=self.sample_id[index],
                            bounds=self.bounds, config_hash=self.config_hash, fields_T=self.fields_T,
                            prior_class=self.prior_class)

    def target(self, name: str) -> np.ndarray:
        """Normalized target u ∈ [0, 1] of one parameter."""
        return np.clip(normalize(name, self.values[name], self.bounds), 0.0, 1.0)


def load_dataset(path) -> LearningData:
    """Read dataset.h5 (written by ``forcdecode dataset merge``); InputFileError if it cannot be opened."""
    try:
        h5 = h5py.File(path, "r")
    except OSError as error:
        raise InputFileError(f"cannot open dataset {path}: {error}") from None
    with h5:
        columns = list(h5["parameters"].attrs["columns"])
        parameters = h5["parameters"][:]
        cfg = json.loads(h5.attrs["config_json"])
        data = LearningData(images=h5["images"][:], ms_norm=np.zeros(0), values={c: parameters[:, k] for k, c in enumerate(columns)},
                            sample_id=h5["sample_id"][:], bounds={**DEFAULT_BOUNDS, **cfg.get("bounds", {})},
                            config_hash=str(h5.attrs["config_hash"]), fields_T=h5["fields_T"][:],
                            prior_class=prior_class(cfg))
    data.ms_norm = normalize("Ms", data.values["Ms"], data.bounds)
    return data
