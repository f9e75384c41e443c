"""The posterior-predictive closed loop on the tiny film: a posterior that returns the truth puts every
draw exactly on the floor (draw k and the floor share realisation k: common random numbers), a biased
one puts the draws above it; failures are recorded, not fatal."""

from dataclasses import dataclass

import numpy as np
import pytest

from forcdecode.config import load_config, shipped_config
from forcdecode.core.parameters import DEFAULT_BOUNDS, denormalize, normalize
from forcdecode.core.streams import stream_rng
from forcdecode.learn.data import LearningData
from forcdecode.infer.posterior_predictive import draws_as_hamiltonians, posterior_closed_loop
from forcdecode.infer.resimulate import simulate_family

NAMES = ("N_pin", "A_ex", "K_u", "D", "sigma_theta_deg", "sigma_K")
# weak disorder (no pinning site), so a new realisation changes the family little (a small floor)
TRUTHS = [dict(Ms=6e5, N_pin=0, A_ex=1.0e-11, K_u=5e5, D=1e-3, sigma_theta_deg=3.0, sigma_K=0.05),
          dict(Ms=8e5, N_pin=0, A_ex=1.4e-11, K_u=8e5, D=0.5e-3, sigma_theta_deg=3.0, sigma_K=0.05)]


@dataclass
class FixedPosterior:
    """A stand-in for the flow: draws = the truth in u, shifted by ``shift`` (per parameter)."""
    truth_u: np.ndarray
    shift: np.ndarray
    names: tuple = NAMES

    def sample(self, images, ms_norm, n_draws, seed):
        idx = [int(i) for i in images[:, 0, 0]]  # the test images carry their row index
        return np.clip(self.truth_u[idx][:, None, :] + self.shift, 0, 1).repeat(n_draws, axis=1)


@pytest.fixture(scope="module")
def setup():
    cfg = load_config(shipped_config("test"))
    n = len(TRUTHS)
    images = np.zeros((n, 16, 16), np.uint8)
    images[:, 0, 0] = np.arange(n)
    values = {k: np.array([t[k] for t in TRUTHS], float) for k in TRUTHS[0]}
    for name in NAMES:  # the truths as the u -> SI map gives them back (so a truthful draw is the truth, bit for bit)
        values[name] = denormalize(name, np.clip(normalize(name, values[name]), 0, 1))
    truths = [{k: (int(round(values[k][i])) if k == "N_pin" else float(values[k][i])) for k in values} for i in range(2)]
    data = LearningData(images=images, ms_norm=normalize("Ms", values["Ms"]), values=values, sample_id=np.array([5, 9]),
                        bounds=dict(DEFAULT_BOUNDS), config_hash="t", fields_T=np.linspace(-1, 1, 16))
    curves = {int(s): simulate_family(cfg, truths[k], stream_rng(7, "disorder", int(s))) for k, s in enumerate(data.sample_id)}
    truth_u = np.stack([np.clip(normalize(n_, values[n_]), 0, 1) for n_ in NAMES], axis=1)
    return cfg, data, curves, truth_u


def test_truthful_draws_sit_on_the_floor(setup):
    cfg, data, curves, truth_u = setup
    table, summary = posterior_closed_loop(cfg, FixedPosterior(truth_u, np.zeros(6)), data, [0, 1], curves, draws=2,
                                           max_samples=2, seed=7)
    assert (table["failures"] == "").all()
    assert np.allclose(table["ratio_draws_floor"], 1.0, atol=1e-12)
    assert summary["fraction_draws_within_floor"] == pytest.approx(1.0)
    assert summary["rms_floor_median"] > 0


def test_biased_draws_sit_above_the_floor(setup):
    cfg, data, curves, truth_u = setup
    shift = np.zeros(6)
    shift[NAMES.index("K_u")] = -0.1  # a lower anisotropy: switching at lower fields
    table, summary = posterior_closed_loop(cfg, FixedPosterior(truth_u, shift), data, [0, 1], curves, draws=2,
                                           max_samples=2, seed=7)
    print(table[["sample_id", "rms_draws_median", "rms_floor", "ratio_draws_floor"]])
    assert summary["median_rms_draws_over_floor"] > 1.5


def test_draws_become_hamiltonians_with_a_pinning_count():
    u = np.full((3, 6), 0.5)
    params = draws_as_hamiltonians(u, NAMES, 7e5, DEFAULT_BOUNDS)
    assert len(params) == 3 and all(isinstance(p["N_pin"], int) and p["Ms"] == 7e5 for p in params)
