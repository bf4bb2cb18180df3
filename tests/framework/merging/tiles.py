"""DEM tiles cut from one analytic surface (the truth) for the mosaic tests."""

from __future__ import annotations

import numpy as np
import rasterio
from affine import Affine
from rasterio.crs import CRS

UTM = CRS.from_epsg(32643)
X0, Y0 = 500000.0, 2000000.0


def surface(x, y):
    return 800 + 40 * np.sin((x - X0) / 300) + 25 * np.cos((y - Y0) / 450)


def write_tile(
    path,
    col0,
    row0,
    n_cols,
    n_rows,
    *,
    step=10.0,
    offset=0.0,
    vertical="ellipsoid",
    crs=UTM,
    holes=None,
):
    transform = Affine(step, 0, X0 + col0 * 10.0, 0, -step, Y0 - row0 * 10.0)
    rows, cols = np.mgrid[0:n_rows, 0:n_cols]
    x, y = transform @ (cols + 0.5, rows + 0.5)
    z = (surface(x, y) + offset).astype(np.float32)
    if holes is not None:
        z[holes] = np.nan
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n_cols,
        height=n_rows,
        count=1,
        dtype="float32",
        crs=crs,
        transform=transform,
        nodata=np.nan,
    ) as ds:
        ds.write(z, 1)
        if vertical:
            ds.update_tags(VERTICAL_REFERENCE=vertical)
        ds.units = ("metre",)
    return path


def truth_on(path):
    with rasterio.open(path) as ds:
        rows, cols = np.mgrid[0 : ds.height, 0 : ds.width]
        x, y = ds.transform @ (cols + 0.5, rows + 0.5)
        return ds.read(1), surface(x, y)
