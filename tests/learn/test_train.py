"""Alice on a synthetic task whose answer is in the image (synthetic_images.bar_images)."""

import numpy as np
import pytest

from forcdecode.learn.splits import assign_splits
from forcdecode.learn.train import AliceSettings, fit_alice
from synthetic_images import bar_images


def _three_way(n, seed):
    """train / validation / test indices of the hash split (no calibration part)."""
    splits = assign_splits(np.arange(n), seed, (0.7, 0.15, 0.0, 0.15))
    return splits["train"], splits["validation"], splits["test"]


@pytest.fixture(scope="module")
def trained():
    images, ms, u = bar_images()
    train, val, test = _three_way(len(u), 0)
    alice = fit_alice(images, ms, u, train, val,
                      AliceSettings(width=32, epochs=12, batch_size=32, lr=1.0, patience=4, seed=0))
    return alice, images, ms, u, test


@pytest.mark.slow  # the `trained` fixture: ~30 s of training on this 2-core machine
def test_alice_beats_the_median_baseline(trained):
    alice, images, ms, u, test = trained
    mae = np.abs(alice.predict(images[test], ms[test]) - u[test]).mean()
    baseline = np.abs(np.median(u) - u[test]).mean()
    assert mae < 0.5 * baseline, (mae, baseline)


@pytest.mark.slow  # the `trained` fixture: ~30 s of training on this 2-core machine
def test_best_epoch_is_the_lowest_validation_loss(trained):
    alice = trained[0]
    assert alice.best_epoch == int(np.argmin(alice.history["val_loss"]))


def test_training_is_deterministic():
    images, ms, u = bar_images(120, 1)
    train, val, _ = _three_way(len(u), 1)
    a = fit_alice(images, ms, u, train, val, AliceSettings(width=8, epochs=2, seed=5))
    b = fit_alice(images, ms, u, train, val, AliceSettings(width=8, epochs=2, seed=5))
    np.testing.assert_array_equal(a.outputs(images[:10], ms[:10]), b.outputs(images[:10], ms[:10]))


def test_training_runs_in_float32_whatever_the_process_default():
    """magnum.np sets torch's default dtype to float64 on import (a test session that imported it first
    trained Bob in float64, and Bob collapsed to a constant): training entry points run in float32 and
    restore the caller's default afterwards."""
    import torch

    from forcdecode.learn.train import with_float32_default

    seen = []
    wrapped = with_float32_default(lambda: seen.append(torch.get_default_dtype()) or torch.nn.Linear(2, 2).weight.dtype)
    previous = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        assert wrapped() == torch.float32 and seen == [torch.float32]
        assert torch.get_default_dtype() == torch.float64
    finally:
        torch.set_default_dtype(previous)
