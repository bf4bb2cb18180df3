"""The compiled focal median against NumPy's nanmedian over sliding windows (an independent
implementation), with voids, edges and infinities."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from carto.framework.errors import InputError
from carto.framework.raster.focal import focal_nanmedian


def reference(values: np.ndarray, radius: int) -> np.ndarray:
    side = 2 * radius + 1
    padded = np.pad(values, radius, mode="edge")
    windows = sliding_window_view(padded, (side, side)).reshape(*values.shape, side * side)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(windows, axis=-1)


@pytest.mark.parametrize("radius", [0, 1, 2, 3])
def test_equals_nanmedian_of_windows(radius):
    rng = np.random.default_rng(radius)
    values = rng.normal(size=(57, 43))
    values[rng.random(values.shape) < 0.3] = np.nan
    values[10:20, 5:15] = np.nan  # a void larger than the window
    values[0, 0] = np.inf
    np.testing.assert_array_equal(focal_nanmedian(values, radius), reference(values, radius))


def test_errors_and_empty():
    assert focal_nanmedian(np.empty((0, 5))).shape == (0, 5)
    with pytest.raises(InputError, match="2-D"):
        focal_nanmedian(np.zeros(5))
    with pytest.raises(InputError, match="radius"):
        focal_nanmedian(np.zeros((3, 3)), -1)


@pytest.mark.parametrize("sigma", [0.4, 1.0, 3.0, 27.0])
@pytest.mark.parametrize("shape", [(60, 45), (3, 50), (1, 7), (40, 1)])
def test_gaussian_equals_scipy_with_nearest_edges(sigma, shape):
    from scipy import ndimage

    from carto.framework.raster.focal import gaussian_nearest

    values = np.random.default_rng(5).normal(size=shape)
    expected = ndimage.gaussian_filter(values, sigma, mode="nearest")
    np.testing.assert_allclose(gaussian_nearest(values, sigma), expected, rtol=0, atol=1e-12)


def test_gaussian_refuses_bad_arguments():
    from carto.framework.raster.focal import gaussian_nearest

    with pytest.raises(InputError, match="2-D"):
        gaussian_nearest(np.zeros(5), 1.0)
    with pytest.raises(InputError, match="sigma"):
        gaussian_nearest(np.zeros((5, 5)), 0.0)


@pytest.mark.parametrize("sigma", [1.0, 27.0])
def test_gaussian_in_float32_equals_scipy_to_its_precision(sigma):
    from scipy import ndimage

    from carto.framework.raster.focal import gaussian_nearest

    values = 100.0 + np.random.default_rng(6).normal(size=(80, 70))
    expected = ndimage.gaussian_filter(values, sigma, mode="nearest")
    got = gaussian_nearest(values, sigma, np.float32)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, expected, rtol=2e-6, atol=0)
    with pytest.raises(InputError, match="dtype"):
        gaussian_nearest(values, sigma, np.int32)


@pytest.mark.parametrize("n", [1, 2, 3, 9, 24, 25, 49])
def test_sorting_network_sorts(n):
    from carto.framework.raster.focal import sorting_network

    rng = np.random.default_rng(n)
    values = rng.integers(0, 4, size=(200, n)).astype(float)  # ties too
    for i, j in sorting_network(n):
        lo, hi = np.minimum(values[:, i], values[:, j]), np.maximum(values[:, i], values[:, j])
        values[:, i], values[:, j] = lo, hi
    assert (np.diff(values, axis=1) >= 0).all()
