import numpy as np
import pytest

from forcdecode.dataset.simulate import hysteresis_area
from forcdecode.forc.raster import quantize, rasterize_grid_family, resample_curves


def test_quantize_maps_minus_one_to_zero_and_one_to_255():
    np.testing.assert_array_equal(quantize([-1.0, 0.0, 1.0, 2.0]), [0, 128, 255, 255])


def test_below_diagonal_holds_the_reversal_point_value():
    n = 8
    curves = np.full((n, n), np.nan)
    for i in range(n):
        curves[i, i:] = np.linspace(-1 + 0.1 * i, 1, n - i)
    image = rasterize_grid_family(curves)
    assert image.shape == (n, n) and image.dtype == np.uint8
    for i in range(n):
        assert np.all(image[i, :i] == image[i, i])
    np.testing.assert_array_equal(image[:-1, -1], 255)


def test_missing_values_above_the_diagonal_are_an_error():
    curves = np.full((4, 4), np.nan)
    with pytest.raises(ValueError, match="missing"):
        rasterize_grid_family(curves)


def test_resampling_a_grid_family_is_exact():
    n = 16
    grid = np.linspace(-1, 1, n)
    curves = [(grid[i:], np.tanh(3 * grid[i:]) + 0.01 * i) for i in range(n)]
    out = resample_curves(grid, curves, 1.0, n)
    for i in range(n):
        np.testing.assert_allclose(out[i, i:], curves[i][1])
        assert np.all(np.isnan(out[i, :i]))


def test_hysteresis_area_of_a_square_loop():
    """Square loop with coercive field 0.2 T, m = ±1: area = 2 · 2 · 0.2 = 0.8 T."""
    fields = np.linspace(-1, 1, 2001)
    descending = np.where(fields > -0.2, 1.0, -1.0)
    assert hysteresis_area(fields, descending) == pytest.approx(0.8, abs=2e-3)


def test_measured_family_inside_the_window_is_in_domain():
    from forcdecode.forc.raster import measured_image

    grid = np.linspace(-1, 1, 64)
    curves = [(np.linspace(hr, 1, 40), 2e-6 * np.tanh(5 * (np.linspace(hr, 1, 40) - 0.2)) / np.tanh(4)) for hr in grid]
    image, family, note = measured_image(grid, curves, 2e-6)
    assert note is None and image.shape == (64, 64) and image.dtype == np.uint8
    np.testing.assert_allclose(family[10, 10:], np.tanh(5 * (grid[10:] - 0.2)) / np.tanh(4), atol=5e-3)  # linear interpolation of 40 points


def test_measured_family_outside_the_window_is_flagged():
    from forcdecode.forc.raster import measured_image

    grid = np.linspace(-0.2, 0.2, 30)  # a rock-magnetic measurement: ±0.2 T, unsaturated
    curves = [(np.linspace(hr, 0.2, 20), 1e-6 * np.tanh(3 * np.linspace(hr, 0.2, 20))) for hr in grid]
    _, _, note = measured_image(grid, curves, 1e-6)
    # the curves are reversible (they coincide) but still rise: the physical rule says not saturated
    assert note is not None and "lower branch closed" in note and "not saturated" in note
