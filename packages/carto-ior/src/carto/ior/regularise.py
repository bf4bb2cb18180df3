"""The regularised DEM update of an IOR iteration (:func:`regularise`), computed by bands of
DEM rows with the halo every filter needs, so that the coordinator of a whole scene holds the
DEM grids and one band of temporaries, not a dozen grid-sized arrays. Any band size gives the
same result (tested). Which nodes keep a height in the end: :mod:`carto.ior.filling`."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import FloatArray
from carto.framework.sdk.dem import focal_nanmedian, gaussian_nearest, gaussian_nearest_at
from carto.ior.settings import IORSettings

__all__ = ["BAND_NODES", "BAND_ROWS", "FILL_TILE", "regularise"]


BAND_ROWS = 512
"""DEM rows per band, at least."""
BAND_NODES = 1 << 21
"""DEM nodes per band, at most, where more than :data:`BAND_ROWS` rows fit: a narrow grid in
one band does not filter its halo of rows (a few hundred) twice."""
FILL_TILE = 512
"""Side (nodes) of the tiles on which the wider Gaussians that fill holes run: only those
holding a hole, each with the filter's reach around it (``gaussian_nearest_at``)."""

_MEDIAN_RADIUS = 2  # the 5 x 5 neighbourhood of the outlier test
_FILL_FACTORS = (3.0, 9.0)  # the wider Gaussians that fill holes, in smoothing sigmas


def _reach(sigma: float) -> int:
    """Rows a Gaussian of ``sigma`` reaches (scipy's default truncation at 4 sigma)."""
    return int(4.0 * float(sigma) + 0.5)


def _bands(n_rows: int, band_rows: int, halo: int) -> Iterator[tuple[slice, slice, slice]]:
    """``(rows, rows with halo, rows within the halo band)`` of each band."""
    step = max(1, int(band_rows))
    for r0 in range(0, n_rows, step):
        r1 = min(n_rows, r0 + step)
        a, b = max(0, r0 - halo), min(n_rows, r1 + halo)
        yield slice(r0, r1), slice(a, b), slice(r0 - a, r1 - a)


def regularise(
    heights: FloatArray,
    new_height: FloatArray,
    settings: IORSettings,
    band_rows: int | None = None,
    fill_tile: int = FILL_TILE,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The DEM update: height changes ``new - heights`` at matched nodes, outliers against
    the 5 x 5 local median removed (more than ``max(outlier_m, 4 NMAD)`` from it, the NMAD of
    all the residuals), then a normalised Gaussian convolution (sigma ``smoothing_nodes``)
    that smooths the noise and fills the holes from their neighbours, with wider Gaussians
    (3 and 9 sigma, in float32: they only fill holes) where the narrow one has no support
    (nodes far from any match keep their height). Returns the new heights and the inliers.
    ``band_rows`` (by default :data:`BAND_ROWS`, or more up to :data:`BAND_NODES`) and
    ``fill_tile`` (:data:`FILL_TILE`) change the work's layout, not its result."""
    n_rows, n_cols = heights.shape
    if band_rows is None:
        band_rows = max(BAND_ROWS, BAND_NODES // max(n_cols, 1))
    valid_any = False
    # pass 1: residuals against the local median (float32: the outlier test needs no more)
    resid = np.empty(heights.shape, np.float32)
    for rows, wide, inner in _bands(n_rows, band_rows, _MEDIAN_RADIUS):
        dh = new_height[wide] - heights[wide]  # NaN where no match
        valid_any = valid_any or bool(np.isfinite(dh[inner]).any())
        resid[rows] = (dh - focal_nanmedian(dh, _MEDIAN_RADIUS))[inner]
    if not valid_any:
        return np.array(heights, np.float64), np.zeros(heights.shape, bool)
    r = resid[np.isfinite(resid)].astype(np.float64)
    nmad = 1.4826 * float(np.median(np.abs(r - np.median(r)))) if r.size else 0.0
    del r
    limit = max(settings.outlier_m, 4.0 * nmad)
    sigma = settings.smoothing_for(1)  # refine_dem resolves it for its posting
    halo = _reach(sigma) + sum(_reach(f * sigma) for f in _FILL_FACTORS)
    out = np.empty(heights.shape, np.float64)
    inliers = np.empty(heights.shape, bool)
    for rows, wide, inner in _bands(n_rows, band_rows, halo):
        with np.errstate(invalid="ignore"):
            inlier = np.abs(resid[wide]) <= limit  # False at NaN
        dh = new_height[wide] - heights[wide]
        dh[~inlier] = 0.0
        num = gaussian_nearest(dh, sigma)
        den = gaussian_nearest(inlier.astype(np.float64), sigma)
        for factor in _FILL_FACTORS:
            missing = den < 0.05
            if not missing.any():
                break
            wider = factor * sigma
            num = gaussian_nearest_at(num, missing, wider, fill_tile, np.float32)
            den = gaussian_nearest_at(den, missing, wider, fill_tile, np.float32)
        with np.errstate(invalid="ignore", divide="ignore"):
            update = np.where(den > 1e-3, num / den, 0.0)
        out[rows] = heights[rows] + update[inner]
        inliers[rows] = inlier[inner]
    return out, inliers
