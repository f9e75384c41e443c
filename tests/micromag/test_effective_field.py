"""The field of every term is minus the energy gradient: B = −(1/(M_s V)) ∂E/∂m."""

import numpy as np
import pytest

from forcdecode.micromag import TERMS, Film, Mesh

from .field_checks import field_by_finite_difference


@pytest.fixture(scope="module")
def textured_film():
    mesh = Mesh(12, 10, 2, 2e-9, 2.5e-9, 3e-9)
    rng = np.random.default_rng(7)
    K = 5e5 * (1 + 0.3 * rng.random(mesh.shape))
    axis = rng.normal(size=mesh.vector_shape) * 0.2 + np.array([0, 0, 1.0])[:, None, None, None]
    film = Film(mesh, Ms=7e5, A_ex=1.2e-11, K_u=K, easy_axis=axis, D=2e-3, K_2=1.5e5, B_bias_T=(0.01, 0.0, 0.02))
    m = rng.normal(size=mesh.vector_shape)
    m /= np.linalg.norm(m, axis=0)
    return film, np.ascontiguousarray(m)


@pytest.mark.parametrize("term", TERMS)
def test_field_is_energy_gradient(textured_film, term):
    film, m = textured_film
    single = film.with_terms((term,))
    B_ext = np.array([0.1, -0.2, 0.3])
    B = single.effective_field(m, B_ext)
    scale = film.Ms * film.mesh.cell_volume
    rng = np.random.default_rng(3)
    for _ in range(6):
        index = (rng.integers(3), rng.integers(2), rng.integers(10), rng.integers(12))
        expected = field_by_finite_difference(single.energy, m, index, scale, B_ext)
        assert expected == pytest.approx(B[index], rel=1e-6, abs=1e-9)


def test_total_energy_is_sum_of_terms(textured_film):
    film, m = textured_film
    energies = film.energies(m, 0.25)
    assert energies["total"] == pytest.approx(sum(v for k, v in energies.items() if k != "total"), rel=1e-12)


def test_bad_input_is_rejected():
    mesh = Mesh(4, 4, 1, 2e-9, 2e-9, 2e-9)
    with pytest.raises(ValueError, match="Ms"):
        Film(mesh, Ms=-1.0, A_ex=1e-11)
    with pytest.raises(ValueError, match="unknown energy terms"):
        Film(mesh, Ms=1e5, A_ex=1e-11, terms=("exchange", "magic"))
    with pytest.raises(ValueError, match="cell size"):
        Mesh(4, 4, 1, 2.0, 2e-9, 2e-9)  # metres, not nanometres
    film = Film(mesh, Ms=1e5, A_ex=1e-11)
    with pytest.raises(ValueError, match="shape"):
        film.effective_field(np.zeros((3, 4, 4)))
