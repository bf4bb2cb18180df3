"""The ortho-images on a fused DEM, made as tile tasks of the engine (issue 33): the same
image as one orthorectification of the whole window, in this process and on worker
processes."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.imaging.preparation import prepared_sources
from carto.framework.parallel.engine import open_engine
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.workflows import fused_orthos


@pytest.mark.parametrize("workers", [1, 2])
def test_tiles_on_the_engine_make_the_whole_window_s_ortho_image(
    cartosat1_scene, tmp_path, monkeypatch, workers
):
    scene = Scene.open(cartosat1_scene)
    sensor = scene.truth_sensors()["fore"]
    dem = DEM.open(cartosat1_scene / "truth" / "dem.tif")
    grid = OrthoGrid.covering(sensor, dem, 2.5)
    window = fused_orthos.image_window(grid, sensor, dem)
    monkeypatch.setattr(fused_orthos, "ORTHO_TILE_PX", 96)  # several tiles, some partial
    with open_engine(workers, quiet=True) as engine:
        source = prepared_sources(
            {"fore": scene.raster("fore")}, {"fore": sensor}, dem, tmp_path / "p", engine
        )["fore"]
        layer = fused_orthos._tiled_ortho(
            engine, source, sensor, window, cartosat1_scene / "truth" / "dem.tif", tmp_path / "t"
        )
    assert len(layer.pieces) == -(-window.shape[0] // 96) * -(-window.shape[1] // 96)
    tiled = layer.read(slice(None), slice(None))
    whole = orthorectify(source, sensor, window, dem)
    assert tiled.shape == whole.shape == window.shape
    both = np.isfinite(tiled) & np.isfinite(whole)
    assert both.mean() > 0.5
    assert np.array_equal(np.isfinite(tiled), np.isfinite(whole))
    assert np.max(np.abs(tiled[both] - whole[both])) < 1e-3 * np.ptp(whole[both])
