"""Reading image rasters (first band, float32, nodata as NaN) with rasterio, and the checks that
an image can be used at all (large enough, some valid pixels, some texture)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.raster.gdal_errors import gdal_cause

MIN_IMAGE_PX = 16
"""Smallest usable image side, pixels: an image must hold one correlation window of the
matchers (11 x 11 px by default) with a few pixels of search around it, and a line-scanner
model fitted to fewer lines or samples is not determined by its image. 16 is the smallest
power of two above 11 + 2 x 2."""


def check_image(values: ArrayLike, name: str, *, min_px: int = MIN_IMAGE_PX) -> None:
    """InputError (one line, naming ``name``) unless ``values`` is a 2-D image of at least
    ``min_px x min_px`` pixels with some valid (finite) pixels that do not all have the same
    value (a constant image has no texture to match)."""
    image = np.asarray(values)
    if image.ndim != 2:
        raise InputError(f"{name}: an image must be 2-D, got shape {image.shape}")
    n_rows, n_cols = image.shape
    if min(n_rows, n_cols) < min_px:
        raise InputError(
            f"{name}: {n_cols} x {n_rows} pixels; an image needs at least {min_px} x {min_px}"
        )
    if not np.issubdtype(image.dtype, np.number) or np.issubdtype(image.dtype, np.complexfloating):
        raise InputError(f"{name}: pixel type {image.dtype} is not a real number type")
    finite = np.isfinite(image)
    if not finite.any():
        raise InputError(f"{name}: no valid pixels (all {n_cols} x {n_rows} are nodata)")
    valid = image[finite]
    lo, hi = valid.min(), valid.max()
    if lo == hi:
        raise InputError(f"{name}: image has no texture (constant value {float(lo):g})")


def read_raster(path: Path) -> NDArray[np.float32]:
    """The first band of a raster as float32 (nodata as NaN).

    Raises:
        InputError: unreadable file; fewer than ``MIN_IMAGE_PX`` pixels a side, no valid
            pixel or a constant value (:func:`check_image`).
    """
    import rasterio

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(path) as ds:
                data = ds.read(1, masked=True)
    except rasterio.errors.RasterioError as exc:
        raise InputError(f"{path}: cannot read raster: {gdal_cause(exc)}") from None
    image = np.ma.filled(data.astype(np.float32), np.nan)
    check_image(image, str(path))
    return image
