"""Film construction from (config, parameters) lives beside the engine (micromag.build) and builds
the same films as the dataset always did: disorder from SeedSequence([seed, sample_id, 1])."""

import numpy as np
import pytest

from forcdecode.config import load_config, shipped_config
from forcdecode.dataset.params import draw_parameters
from forcdecode.micromag.build import build_film


@pytest.fixture(scope="module")
def cfg():
    return load_config(shipped_config("test"))


def test_disorder_is_the_datasets_original_stream(cfg):
    params = {**draw_parameters(cfg["seed"], 3, cfg["bounds"]), "N_pin": 4}
    _, _, disorder = build_film(cfg, params, 3)
    original = np.random.default_rng(np.random.SeedSequence([cfg["seed"], 3, 1]))
    _, _, same = build_film(cfg, params, rng=original)
    for field in ("K_u", "easy_axis", "grain_labels", "pinning_mask", "pinning_initial"):
        assert np.array_equal(getattr(disorder, field), getattr(same, field)), field
    # pinned numbers (test config, seed 7, sample 3)
    assert disorder.K_u.ravel()[0] == pytest.approx(1107165.0736266566, rel=1e-15)
    assert disorder.easy_axis.reshape(3, -1)[:, 0] == pytest.approx(
        [-0.024262134640330644, -0.02963961282874749, 0.9992661518204529], rel=1e-14)
    assert np.flatnonzero(disorder.pinning_mask).tolist() == [8, 16, 196, 234]
    assert int(disorder.grain_labels.max()) == 7


def test_another_sample_or_stream_gives_another_film(cfg):
    params = draw_parameters(cfg["seed"], 3, cfg["bounds"])
    _, _, a = build_film(cfg, params, 3)
    _, _, b = build_film(cfg, params, 4)
    assert not np.array_equal(a.easy_axis, b.easy_axis)
    with pytest.raises(TypeError, match="sample_id"):
        build_film(cfg, params)


def test_old_import_path_still_works():
    from forcdecode.dataset import simulate

    assert simulate.build_film is build_film
