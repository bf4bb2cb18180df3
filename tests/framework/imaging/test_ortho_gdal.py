"""Orthorectification against GDAL: rasterio's ``reproject`` with an RPC and ``RPC_DEM``.

The real Pleiades image of La Reunion (``../shared/data/pleiades-reunion-pair/img_01.tif``, RPC00B
in the GeoTIFF) is orthorectified by :func:`orthorectify` and by GDAL's warper on the same DEM
file and output grid. To see which image position each method sampled, both resample two
coordinate ramps (``raw_row[r, c] = r``, ``raw_col[r, c] = c``) bilinearly: a bilinear
interpolation of a linear ramp returns the sampled position itself. Both conventions put the
first pixel centre at (0.5, 0.5) (GDAL's RPC transformer adds 0.5 to the RPC00B pixel, its warp
kernels subtract it, as ours does for ``cv2.remap``), so the ramps must agree without any offset.
``benchmarks/ortho_speed.py`` (section ``gdal_comparison``) does the same on whole images, with
timings.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.errors import NotGeoreferencedWarning
from rasterio.warp import Resampling, reproject

from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.raster.dem import DEM
from carto.framework.workflows.opening import open_sensor

UTM_40S = "EPSG:32740"
BORDER_PX = 2


@pytest.mark.realdata
def test_ortho_agrees_with_gdal_rpc_dem_reproject(shared_data, tmp_path):
    folder = shared_data / "pleiades-reunion-pair"
    image = folder / "img_01.tif"
    sensor = open_sensor(image, "rpc")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(image) as ds:
            rpcs = ds.rpcs
            shape = ds.shape
    assert tuple(sensor.image_shape) == shape

    # the reference DSM (0.5 m, UTM 40S, ellipsoidal), holes inpainted: one file for both
    with rasterio.open(folder / "reference_dsm.tif") as ds:
        dsm = ds.read(1).astype(np.float32)
        dsm_transform = ds.transform
        left, bottom, right, top = ds.bounds
    holes = ~np.isfinite(dsm)
    filled = cv2.inpaint(
        np.where(holes, 0.0, dsm).astype(np.float32), holes.astype(np.uint8), 5, cv2.INPAINT_TELEA
    )
    dem_path = DEM.from_array(filled, dsm_transform, UTM_40S).write(tmp_path / "dem.tif")
    dem = DEM.open(dem_path)

    # a 192 x 192 px window at 0.5 m around the DSM's centre (inside the image)
    res, n = 0.5, 192
    x0 = round((left + right) / 2 / res) * res - n * res / 2
    y0 = round((bottom + top) / 2 / res) * res + n * res / 2
    grid = OrthoGrid(UTM_40S, Affine(res, 0.0, x0, 0.0, -res, y0), (n, n))

    ramps = np.indices(shape, dtype=np.float32)  # (row index, column index) of every pixel
    ours = [orthorectify(ramp, sensor, grid, dem, resampling="linear") for ramp in ramps]
    gdal = []
    for ramp in ramps:
        out = np.full(grid.shape, np.nan, np.float32)
        reproject(
            ramp,
            out,
            rpcs=rpcs,
            src_crs="EPSG:4326",
            dst_crs=UTM_40S,
            dst_transform=grid.transform,
            dst_nodata=np.nan,
            resampling=Resampling.bilinear,
            RPC_DEM=str(dem_path),
        )
        gdal.append(out)

    valid = np.isfinite(ours[0]) & np.isfinite(ours[1])
    assert valid.all()  # the window is inside the image and the DEM
    assert (np.isfinite(gdal[0]) & np.isfinite(gdal[1])).all()
    # the window spans a real part of the image (the ramps are not constant)
    assert np.ptp(ours[0]) > 100
    assert np.ptp(ours[1]) > 100
    inside = np.ones(grid.shape, bool)
    for values, size in ((ours[0], shape[0]), (ours[1], shape[1])):
        inside &= (values >= BORDER_PX) & (values <= size - 1 - BORDER_PX)
    d_line = gdal[0][inside].astype(np.float64) - ours[0][inside]
    d_sample = gdal[1][inside].astype(np.float64) - ours[1][inside]
    # no half-pixel convention difference, and no systematic offset at all
    assert abs(d_line.mean()) < 0.005
    assert abs(d_sample.mean()) < 0.005
    assert np.hypot(d_line, d_sample).max() <= 0.05
