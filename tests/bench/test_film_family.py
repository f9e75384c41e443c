"""``bench.film_family``: the informative film's family check (issue 62 item 1).

The fast tests pin the pieces of the verdict (switching interval, image distance, the floor rule) on
families whose answers are known by construction; the slow test runs the check itself, candidate
against reference, on the smallest film with two layers (``laptop_8nm``), where a family costs seconds.
"""

from __future__ import annotations

import numpy as np
import pytest

from forcdecode.bench import film_family


def _family(shift=0.0, n=64):
    """A family of tanh curves on an n-field grid: curve i reversed at field i, m_z(B) = 0.9 tanh(8(B − H_s)),
    H_s (switching field) = ``shift``; NaN below the diagonal."""
    fields = np.linspace(-1.0, 1.0, n)
    curves = np.full((n, n), np.nan)
    for i in range(n):
        curves[i, i:] = 0.9 * np.tanh(8.0 * (fields[i:] - shift))  # no clipping at ±1
    return fields, curves


def test_switching_interval_is_the_first_sign_change():
    fields = np.linspace(-1.0, 1.0, 64)
    mz = np.tanh(5.0 * (fields - 0.1))
    k = film_family.switching_interval(mz)
    assert fields[k] < 0.1 <= fields[k + 1]
    assert film_family.switching_interval(np.ones(10)) == -1


def test_image_distance_counts_grey_levels():
    _, curves = _family()
    same = film_family.image_distance(curves, curves)
    assert same == {"image_mean_abs_m": 0.0, "image_p99_levels": 0.0, "image_max_levels": 0}
    shifted = curves + 4.0 / 127.5  # four grey levels everywhere the family is defined
    far = film_family.image_distance(shifted, curves)
    assert far["image_max_levels"] == 4 and far["image_p99_levels"] == 4.0
    # below the diagonal each image repeats its curve's first point: shifted too
    assert far["image_mean_abs_m"] == pytest.approx(4 * 2.0 / 255.0)


def test_tolerances_are_the_issues():
    assert film_family.MEAN_TOL_M == 0.003 and film_family.P99_TOL_LEVELS == 1
    fine = {"image_mean_abs_m": 0.003, "image_p99_levels": 1.0}
    assert film_family._agrees(fine, True)
    assert not film_family._agrees(fine, False)  # a moved switching field fails whatever the image
    assert not film_family._agrees({**fine, "image_p99_levels": 2.0}, True)
    assert not film_family._agrees({**fine, "image_mean_abs_m": 0.0031}, True)


@pytest.mark.slow
def test_fourier_candidate_on_the_two_layer_laptop_film():
    """The check itself, on two screened draws of the 64 × 64 × 2 film: the reference family is
    reproduced by a second reference run (no floor needed when the draw is not chaotic), the costs are
    recorded, and the verdict is a boolean per draw."""
    report = film_family.film_family_check(draws=2, film="laptop_8nm", with_floor="always", say=lambda s: None)
    assert report["n"] == 2
    for row in report["draws"]:
        assert row["reference"]["cpu_s"] > 0 and row["candidate"]["iterations"] > 0
        assert row["reference"]["unconverged"] == 0
        assert isinstance(row["passed"], bool)
        if row["reference_reproducible"]:
            # the floor is a second reference run: within the tolerance of the first
            assert row["floor_vs_reference"]["image_mean_abs_m"] <= film_family.MEAN_TOL_M
