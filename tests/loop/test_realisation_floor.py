"""The structure test's disorder floor after a refit (``refit.realisation_floor``): the variance of m
between single disorder realisations, pooled from the refit's own profiles and the null films."""

import numpy as np
import pytest

from forcdecode.loop.refit import realisation_floor


@pytest.mark.parametrize("n_profiles,n_null", [(2, 0), (1, 3), (2, 3), (4, 10)])
def test_the_pooled_floor_is_the_single_realisation_variance(n_profiles, n_null):
    """Single realisations drawn with variance v = 0.3 at every point: the base and each null film are
    averages of P of them; the pooled estimate is unbiased for v (20,000 points: 1 % standard error
    at the fewest degrees of freedom, the tolerance 5 %)."""
    v, points = 0.3, 20_000
    rng = np.random.default_rng(1)
    profiles = rng.normal(scale=np.sqrt(v), size=(n_profiles, points))
    base = profiles.mean(axis=0)
    spread = profiles.var(axis=0, ddof=1) if n_profiles > 1 else np.zeros(points)
    squares = [(rng.normal(scale=np.sqrt(v), size=(n_profiles, points)).mean(axis=0) - base) ** 2
               for _ in range(n_null)]
    floor = realisation_floor(spread, n_profiles, squares)
    assert floor.mean() == pytest.approx(v, rel=0.05)


def test_no_profile_spread_and_no_null_film_is_no_floor():
    floor = realisation_floor(np.zeros((3, 3)), 1, [])
    assert np.array_equal(floor, np.zeros((3, 3)))


def test_a_reversal_field_where_the_profiles_disagree_gets_a_floor_of_order_one():
    """Two profiles, one switched (m = −1) and one not (+1) on a curve: the family is 0 there and a
    single film is ±1; the floor is the sample variance 2, so a residual of 1 is z = 1/√3."""
    one, other = np.array([[-1.0, -1.0], [np.nan, 1.0]]), np.array([[1.0, 1.0], [np.nan, 1.0]])
    spread = np.var([one, other], axis=0, ddof=1)
    floor = realisation_floor(spread, 2, [])
    assert floor[0].tolist() == [2.0, 2.0] and floor[1, 1] == 0.0 and np.isnan(floor[1, 0])
