import numpy as np
import pytest
import yaml
from pathlib import Path

from forcdecode.dataset.params import draw_parameters
from forcdecode.loop import observation_error, resimulate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cfg():
    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    cfg["pinning"].setdefault("treatment", "full")
    return cfg


def test_observation_error_counts_only_shared_points():
    a = np.array([[0.0, 1.0], [np.nan, 1.0]])
    b = np.array([[0.0, 0.5], [np.nan, 1.0]])
    result = observation_error(a, b)
    assert result["rms"] == pytest.approx(np.sqrt(0.25 / 3))
    np.testing.assert_allclose(result["per_curve"], [np.sqrt(0.125), 0.0])
    with pytest.raises(ValueError, match="shapes"):
        observation_error(a, b[:1])


def test_resimulation_is_reproducible_and_profiles_matter(cfg):
    params = draw_parameters(cfg["seed"], 3)
    params.update(N_pin=4, K_u=8e5, Ms=8e5, A_ex=1.2e-11)
    one = resimulate(cfg, params, n_profiles=1)
    again = resimulate(cfg, params, n_profiles=1)
    assert observation_error(one, again)["rms"] == 0.0
    averaged = resimulate(cfg, params, n_profiles=3)
    assert np.all(np.isfinite(np.diag(averaged)))
    assert np.nanmax(np.abs(averaged)) <= 1.0 + 1e-12
