"""Reading image rasters (first band, float32, nodata as NaN) with rasterio."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError


def read_raster(path: Path) -> NDArray[np.float32]:
    """The first band of a raster as float32 (nodata as NaN)."""
    import rasterio

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(path) as ds:
                data = ds.read(1, masked=True)
    except rasterio.errors.RasterioError as exc:
        raise InputError(f"{path}: cannot read raster: {exc}") from None
    return np.ma.filled(data.astype(np.float32), np.nan)
