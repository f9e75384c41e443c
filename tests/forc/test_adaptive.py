"""The adaptive slew-rate LLG protocol on a tiny film, against the quasi-static path."""

import numpy as np
import pytest

from forcdecode.forc import quasistatic_family
from forcdecode.forc.adaptive import SlewRate, adaptive_family
from forcdecode.micromag import GAMMA_LL, FilmMaterial, Mesh, disordered_film

P = FilmMaterial(Ms=8e5, A_ex=1.2e-11, K_u=8e5, D=1.0e-3, sigma_K=0.1, sigma_theta_rad=np.radians(5.0), n_pin=2)


@pytest.fixture(scope="module")
def families():
    mesh = Mesh(16, 16, 1, 2e-9, 2e-9, 4e-9)
    film, m0, _ = disordered_film(mesh, P, np.random.default_rng(0), pinning="slaved", n_grains=8)
    llg = adaptive_family(film, m0, n_fields=8, settings=SlewRate(rate_max_T_per_s=2e9))
    film_q, m0_q, _ = disordered_film(mesh, P, np.random.default_rng(0), pinning="full", n_grains=8)
    return llg, quasistatic_family(film_q, m0_q, n_fields=8)


def test_switching_rate_and_effective_damping(families):
    llg, _ = families
    tau = llg.stats["tau_z_max_per_s"]
    assert not llg.stats["tau_fallback"]
    # |dm_z/dt| at m_z = 0 cannot exceed the macrospin bound γ α'/(1+α'²) B with α' ≤ 1: γB/2
    assert 0 < tau < GAMMA_LL * 0.5 * 2.0
    assert 0 < llg.stats["alpha_prime"] <= 1.0


def test_recorded_points_respect_the_update_rule(families):
    llg, _ = families
    for fields, mz in llg.raw_curves:
        assert np.all(np.diff(fields) > 0)
        # between records the field moves at most one field step (0.02 T) plus a sub-step
        assert np.all(np.diff(fields) <= 0.02 + 0.002 + 1e-9)


def test_adaptive_family_agrees_with_quasistatic_path(families):
    llg, quasi = families
    assert llg.curves_mz.shape == quasi.curves_mz.shape == (8, 8)
    np.testing.assert_allclose(llg.descending_mz[[0, -1]], quasi.descending_mz[[0, -1]], atol=0.02)
    assert np.nanmean(np.abs(llg.curves_mz - quasi.curves_mz)) < 0.1


def test_slew_rate_options_are_the_configs_with_the_schemas_defaults():
    """The three callers of the llg protocol (dataset, re-simulation, information bench) read SlewRate from
    one helper: an empty protocol section gives the schema's defaults, which are the dataclass's own, and a
    config's values reach it."""
    import dataclasses

    from forcdecode.forc.adaptive import SlewRate
    from forcdecode.micromag.build import slew_rate_options

    assert SlewRate(**slew_rate_options({})) == SlewRate()
    given = {"protocol": {"name": "llg", "alpha": 1.0, "safety": 0.2, "rate_min_T_per_s": 1e8}}
    settings = dataclasses.asdict(SlewRate(**slew_rate_options(given)))
    assert (settings["alpha"], settings["safety"], settings["rate_min_T_per_s"], settings["rate_max_T_per_s"]) == \
        (1.0, 0.2, 1e8, 1e9)
