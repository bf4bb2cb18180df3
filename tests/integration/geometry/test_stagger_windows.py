"""The stagger merge by windows of lines (:func:`merge_staggered_rows`, what whole scenes use)
against the whole-image merge (:func:`merge_staggered`), on raw images of simulated scenes
read through :class:`~carto.framework.raster.image_source.RasterImage`."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.stagger import merge_staggered, merge_staggered_rows
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.raster.image_source import RasterImage
from carto.framework.raster.images import read_raster

from ...scenes import simulate


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return simulate(
        "cartosat1-pair",
        tmp_path_factory.mktemp("stagger-windows"),
        seed=5,
        size=(300, 260),
        terrain="mountains",
        n_gcps=0,
        n_checkpoints=0,
    )


@pytest.mark.parametrize("name", ["fore", "aft"])
@pytest.mark.parametrize("method", ["cubic", "lanczos"])
def test_windows_equal_the_whole_merge(scene, name, method):
    folder = Scene.open(scene)
    sensor = LineScanner.load(scene / "truth" / f"{name}.model.json")
    dem = DEM.open(scene / "truth" / "dem.tif")
    path = folder.raster(name)
    whole = merge_staggered(read_raster(path), sensor, dem, step=8, method=method).image
    source = RasterImage.open(path)
    n = sensor.n_lines
    # windows that start and end on and off the field's nodes, at both image ends
    bounds = [0, 1, 8, 37, 64, 65, 150, n - 9, n - 1, n]
    pieces = [
        merge_staggered_rows(source, sensor, dem, slice(a, b), step=8, method=method)
        for a, b in itertools.pairwise(bounds)
    ]
    stitched = np.concatenate(pieces)
    assert stitched.shape == whole.shape
    np.testing.assert_array_equal(np.isnan(stitched), np.isnan(whole))
    np.testing.assert_allclose(stitched, whole, rtol=0, atol=1e-4, equal_nan=True)


def test_window_errors(scene):
    sensor = LineScanner.load(scene / "truth" / "fore.model.json")
    dem = DEM.open(scene / "truth" / "dem.tif")
    source = RasterImage.open(Scene.open(scene).raster("fore"))
    with pytest.raises(InputError, match="empty window"):
        merge_staggered_rows(source, sensor, dem, slice(10, 10))
    with pytest.raises(InputError, match="method"):
        merge_staggered_rows(source, sensor, dem, slice(0, 10), method="bogus")  # type: ignore[arg-type]
    small = np.zeros((10, 10), np.float32)
    with pytest.raises(InputError, match="differs"):
        merge_staggered_rows(small, sensor, dem, slice(0, 5))
