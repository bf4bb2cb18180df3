"""A sensor on its reduced image against the same sensor on the full one, and the reduced
image against OpenCV's area resampling (an independent implementation of block means)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry.decimated import DecimatedSensor
from carto.framework.geometry.rpc.sensor import RPCSensor
from carto.framework.raster.image_source import ArrayImage, DecimatedImage
from tests.framework.geometry.rpc.test_model import synthetic_rpc


@pytest.mark.parametrize("factor", [2, 4])
def test_coordinates_divide_by_the_factor_and_locate_the_same_ground(factor):
    full = RPCSensor(synthetic_rpc())
    reduced = DecimatedSensor(full, factor)
    n_l, n_s = full.image_shape
    assert reduced.image_shape == (n_l // factor, n_s // factor)
    rng = np.random.default_rng(0)
    line, sample = rng.uniform(0, n_l, 50), rng.uniform(0, n_s, 50)
    h = rng.uniform(0.0, 500.0, 50)
    lon, lat = full.image_to_ground(line, sample, h)
    lon_r, lat_r = reduced.image_to_ground(line / factor, sample / factor, h)
    np.testing.assert_allclose(lon_r, lon, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lat_r, lat, rtol=0, atol=1e-12)
    l_r, s_r = reduced.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(l_r * factor, line, atol=1e-6)
    np.testing.assert_allclose(s_r * factor, sample, atol=1e-6)
    l_p, s_p, inside = reduced.project(lon, lat, h)
    np.testing.assert_allclose(l_p, l_r, atol=1e-9)
    np.testing.assert_allclose(s_p, s_r, atol=1e-9)
    assert inside.all()


def test_reduced_image_is_the_block_mean():
    rng = np.random.default_rng(1)
    image = rng.uniform(0, 4000, (203, 158)).astype(np.float32)
    reduced = DecimatedImage(ArrayImage(image), 4)
    assert reduced.shape == (50, 39)
    area = cv2.resize(image[:200, :156], (39, 50), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(reduced[0:50, 0:39], area, rtol=1e-5)
    # a window reads the same pixels as the whole (strips of rows inside)
    np.testing.assert_allclose(reduced[7:44, 5:30], area[7:44, 5:30], rtol=1e-5)
    holed = image.copy()
    holed[10, 10] = np.nan
    assert np.isnan(DecimatedImage(ArrayImage(holed), 4)[2:3, 2:3]).all()


@pytest.mark.parametrize("factor", [0, 1.5, True])
def test_bad_factors_are_refused(factor):
    with pytest.raises(InputError, match="factor"):
        DecimatedImage(ArrayImage(np.zeros((8, 8))), factor)
    with pytest.raises(InputError, match="factor"):
        DecimatedSensor(RPCSensor(synthetic_rpc()), factor)
