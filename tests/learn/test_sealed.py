"""The sealed set's scoring (learn/sealed.py): disjoint ids, baselines fitted on the training dataset,
skill that shows where the image carries the parameter and not where it does not, scored once.

The predictors here are exact rules on the synthetic images of test_pipeline (the bright bar's height is
u): one reads the bar, one answers the training median. The networks' own path (a trained model file
scored on a sealed draw) is tests/learn/test_pipeline.py::test_the_sealed_set_is_scored_by_the_frozen_model."""

import numpy as np
import pytest

from forcdecode.core.errors import DatasetError
from forcdecode.learn.pipeline import DEFAULT_SETTINGS
from forcdecode.learn.sealed import alice_sealed_metrics, attach_sealed, check_disjoint

from test_pipeline import synthetic_dataset


class BarReader:
    """u read from the image: the fraction of bright rows (exact on the informative families), a ±0.1
    interval; ``constant``: the same answer for every image."""

    def __init__(self, constant=None):
        self.name, self.constant = "D", constant

    def predict(self, images, ms):
        images = np.asarray(images)
        side = images.shape[-1]
        u = (images[..., :-8] > 127).mean(axis=(-1, -2)) * side / (side - 1) - 1 / (side - 1)
        u = np.clip(u, 0, 1) if self.constant is None else np.full(len(images), self.constant)
        return {"normalized": u, "normalized_90": (u - 0.1, u + 0.1)}


def sealed_draw(n=80, first_id=10_000):
    data = synthetic_dataset(n=n, seed=11)
    data.sample_id = first_id + np.arange(n)
    return data


def test_the_image_shows_on_the_sealed_set_and_a_constant_does_not():
    training, sealed = synthetic_dataset(n=200, seed=0), sealed_draw()
    settings = {**DEFAULT_SETTINGS, "split": [0.6, 0.2, 0.1, 0.1]}
    reader = alice_sealed_metrics({"D": BarReader()}, training, sealed, seed=3, settings=settings, n_boot=300)
    row = reader["parameters"]["D"]
    assert reader["n_sealed"] == 80 and reader["sample_id_range"] == [10_000, 10_079]
    assert row["skill_vs_best_trivial_ci90"][0] > 0.3 and row["mae"] < row["baselines"]["images_shuffled"]
    assert row["best_trivial"] in ("prior", "ms_only") and row["baselines"]["ms_only_k"] >= 1
    constant = alice_sealed_metrics({"D": BarReader(constant=0.5)}, training, sealed, seed=3, settings=settings,
                                    n_boot=300)["parameters"]["D"]
    assert constant["skill_vs_best_trivial_ci90"][0] < 0.05 < row["skill_vs_best_trivial_ci90"][0]
    assert constant["skill_vs_images_shuffled"] == pytest.approx(0.0, abs=1e-12)  # a constant ignores the image


def test_a_sealed_id_in_the_training_dataset_is_refused():
    training = synthetic_dataset(n=50, seed=0)  # ids 0, 3, 6, ...
    overlapping = sealed_draw(n=20, first_id=30)
    with pytest.raises(DatasetError, match="also in the training dataset"):
        check_disjoint(training, overlapping)
    other_physics = sealed_draw(n=20)
    other_physics.config_hash = "another"
    with pytest.raises(DatasetError, match="another configuration"):
        check_disjoint(training, other_physics)


def test_the_sealed_figures_are_attached_once():
    metrics = attach_sealed({"parameters": {"D": {"mae": 0.1}}}, {"n_sealed": 3})
    assert metrics["sealed"] == {"n_sealed": 3} and "looked at during development" in metrics["test_vs_sealed"]
    with pytest.raises(DatasetError, match="scored once"):
        attach_sealed(metrics, {"n_sealed": 3})
