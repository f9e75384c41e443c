"""core.physics against values known independently of our code."""

import math

import numpy as np
import pytest

from forcdecode.core import physics


def test_mu0_is_the_si_value():
    assert physics.MU0 == pytest.approx(1.25663706e-6, rel=1e-8)


def test_permalloy_exchange_length_is_the_textbook_5_7_nm():
    # Ms 800 kA/m, A 13 pJ/m (permalloy): l_ex = √(26e-12/(4πe-7·6.4e11)) = 5.69 nm, the textbook ≈ 5.7 nm
    assert physics.exchange_length(13e-12, 800e3) * 1e9 == pytest.approx(5.69, abs=0.01)


def test_k_eff_q_and_anisotropy_field_of_a_cofeb_like_film():
    Ms, K_u = 1.0e6, 1.0e6
    assert physics.shape_anisotropy(Ms) == pytest.approx(628318.53, rel=1e-7)
    assert physics.k_eff(K_u, Ms) == pytest.approx(1.0e6 - 628318.53, rel=1e-7)
    assert physics.quality_factor(K_u, Ms) == pytest.approx(1.0 / (math.pi * 0.2), rel=1e-9)  # 2/(4π·0.1)
    # μ0H_K,eff = 2K_eff/M_s
    assert physics.effective_anisotropy_field(K_u, Ms) == pytest.approx(2 * physics.k_eff(K_u, Ms) / Ms, rel=1e-12)


def test_wall_energy_vanishes_at_the_critical_dmi_and_is_nan_in_plane():
    A, K = 15e-12, 2.0e5
    d_c = physics.critical_dmi(A, K)
    assert physics.wall_energy(A, K, d_c) == pytest.approx(0.0, abs=1e-15)
    assert physics.wall_energy(A, K, 0.0) == pytest.approx(4 * math.sqrt(A * K), rel=1e-12)
    assert physics.wall_width(A, K) == pytest.approx(math.pi * physics.wall_parameter(A, K), rel=1e-12)
    assert math.isnan(physics.wall_energy(A, -1.0, 0.0)) and math.isnan(physics.wall_width(A, 0.0))
    out = physics.wall_energy(np.array([A, A]), np.array([K, -K]), np.array([0.0, 1e-3]))
    assert np.isfinite(out[0]) and np.isnan(out[1])


def test_spiral_period_is_4_pi_a_over_d():
    assert physics.spiral_period(10e-12, 2e-3) == pytest.approx(4 * math.pi * 10e-12 / 2e-3, rel=1e-12)
    assert physics.spiral_period(10e-12, 0.0) == math.inf


def test_the_engine_and_the_readers_share_the_one_constant():
    from forcdecode.measured.units import FIELD_TO_T
    from forcdecode.micromag.constants import MU0

    assert MU0 is physics.MU0 or MU0 == physics.MU0
    assert FIELD_TO_T["A/m"] == physics.MU0
