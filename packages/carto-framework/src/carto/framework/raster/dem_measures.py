"""Measures of a DEM grid: ground pixel size, height gradient and slope (any CRS); its voids
filled (:func:`fill_voids`); a function of lon/lat sampled at its nodes band by band
(:func:`values_at_nodes`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.raster.dem import DEM, Bounds

FloatArray = NDArray[np.float64]

NODE_BAND_NODES = 1 << 20
"""Nodes per band of :func:`values_at_nodes` (the lon/lat of a band and their transform's
copies take about 50 MB)."""


def dem_pixel_size_m(dem: DEM) -> tuple[FloatArray, FloatArray]:
    """Ground size of the pixels of ``dem`` in metres: ``(along a row, along a column)``.

    The first figure is the distance between the centres of two neighbouring columns (the
    x step, ``hypot(a, d)`` of the transform), the second between two neighbouring rows. For a
    projected CRS they are constants (in metres whatever the CRS unit; the map projection's
    scale factor is ignored); for a geographic CRS the degrees are converted to metres on the
    CRS ellipsoid at each pixel's latitude (meridian and prime-vertical radii of curvature).

    Returns:
        two float64 arrays that broadcast to the grid shape (0-d for a projected CRS).
    """
    t = dem.transform
    if not dem.crs.is_geographic:
        unit = dem.crs.axis_info[0].unit_conversion_factor if dem.crs.axis_info else 1.0
        unit = float(unit or 1.0)
        return np.asarray(math.hypot(t.a, t.d) * unit), np.asarray(math.hypot(t.b, t.e) * unit)
    n_rows, n_cols = dem.shape
    rows = np.arange(n_rows, dtype=np.float64)[:, None] + 0.5
    cols = np.arange(n_cols, dtype=np.float64)[None, :] + 0.5
    lat = np.radians(t.e * rows + t.f + (t.d * cols if t.d != 0.0 else 0.0))
    ellipsoid = dem.crs.ellipsoid
    a = float(ellipsoid.semi_major_metre) if ellipsoid is not None else 6378137.0
    inv_f = float(ellipsoid.inverse_flattening) if ellipsoid is not None else 298.257223563
    f = 1.0 / inv_f if inv_f else 0.0
    e2 = f * (2.0 - f)
    w = np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    east_per_deg = np.radians(a / w * np.cos(lat))  # metres per degree of longitude
    north_per_deg = np.radians(a * (1.0 - e2) / w**3)  # metres per degree of latitude
    dx = np.hypot(t.a * east_per_deg, t.d * north_per_deg)
    dy = np.hypot(t.b * east_per_deg, t.e * north_per_deg)
    return dx, dy


MAX_TERRAIN_POSTING_M = 1000.0
"""The coarsest DEM of the terrain a run starts from, metres between posts: 30 arc-seconds
(GTOPO30, GMTED: about 900 m) still is one; a geoid grid (``egm96_15.gtx``: 15 arc-minutes,
28 km, +-100 m) is not, and taken as the starting DEM it gave a DEM 575 m off with NMAD
162 m and exit 0 (issue 31)."""


def check_terrain_posting(dem: DEM, what: str) -> None:
    """Refuse ``dem`` (named ``what``) as a DEM of the terrain when its posts are more than
    :data:`MAX_TERRAIN_POSTING_M` apart."""
    dx, dy = (float(np.median(v)) for v in dem_pixel_size_m(dem))
    posting = max(dx, dy)
    if posting > MAX_TERRAIN_POSTING_M:
        raise InputError(
            f"{what}: posts {posting / 1000.0:.1f} km apart; a DEM of the terrain needs at "
            f"most {MAX_TERRAIN_POSTING_M:g} m (SRTM: 30-90 m; a geoid or climate grid is not "
            "one)"
        )


def height_gradient(
    heights: FloatArray, dx_m: ArrayLike, dy_m: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Height gradient of a grid along its columns and rows, metres per metre.

    Central differences inside the grid, one-sided at its edges (:func:`numpy.gradient`);
    zero along an axis of one pixel. NaN next to nodata.

    Args:
        heights: ``(rows, cols)`` heights in metres.
        dx_m, dy_m: distance in metres between neighbouring columns / rows (scalars or arrays
            that broadcast to the grid).

    Returns:
        ``(dz/dx, dz/dy)``: x along increasing column, y along increasing row.
    """
    h = np.asarray(heights, dtype=np.float64)
    g_row = np.gradient(h, axis=0) if h.shape[0] > 1 else np.zeros_like(h)
    g_col = np.gradient(h, axis=1) if h.shape[1] > 1 else np.zeros_like(h)
    return g_col / np.asarray(dx_m, np.float64), g_row / np.asarray(dy_m, np.float64)


def slope_deg(dem: DEM) -> FloatArray:
    """Terrain slope of every pixel of ``dem`` in degrees (0 = flat); NaN next to nodata."""
    dx, dy = dem_pixel_size_m(dem)
    gx, gy = height_gradient(dem.heights, dx, dy)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def fill_voids(dem: DEM, bounds: Bounds | None = None) -> tuple[DEM, int]:
    """``dem`` with its voids filled, and the number of posts filled.

    GDAL's fill (:func:`rasterio.fill.fillnodata`: inverse-distance weighting from the
    valid posts around each void, searched in four directions; no smoothing) fills every
    void, at the edges too. With ``bounds`` (WGS84 ``(west, south, east, north)``), only
    the posts around them (two more on each side) are filled and returned: a DEM made to
    start from, not a measurement. A DEM without voids, or without any valid post in the
    window, is returned as it is (cropped to the window).
    """
    from rasterio.fill import fillnodata
    from rasterio.transform import Affine

    n_rows, n_cols = dem.shape
    r0, r1, c0, c1 = 0, n_rows, 0, n_cols
    if bounds is not None:
        west, south, east, north = (float(v) for v in bounds)
        t = np.linspace(0.0, 1.0, 17)
        lon = np.concatenate([west + t * (east - west), west + t * (east - west)])
        lon = np.concatenate([lon, np.full_like(t, west), np.full_like(t, east)])
        lat = np.concatenate([np.full_like(t, south), np.full_like(t, north)])
        lat = np.concatenate([lat, south + t * (north - south), south + t * (north - south)])
        row, col = dem.lonlat_to_pixel(lon, lat)
        ok = np.isfinite(row) & np.isfinite(col)
        if not ok.any():
            return dem, 0
        r0 = int(np.clip(math.floor(row[ok].min()) - 2, 0, n_rows))
        r1 = int(np.clip(math.ceil(row[ok].max()) + 3, 0, n_rows))
        c0 = int(np.clip(math.floor(col[ok].min()) - 2, 0, n_cols))
        c1 = int(np.clip(math.ceil(col[ok].max()) + 3, 0, n_cols))
        if r1 - r0 < 1 or c1 - c0 < 1:
            return dem, 0
    sub = dem.heights[r0:r1, c0:c1]
    valid = np.isfinite(sub)
    n_filled = 0
    if valid.any() and not valid.all():
        reach = float(math.hypot(*sub.shape)) + 1.0
        sub = fillnodata(
            np.where(valid, sub, 0.0),
            mask=valid.astype(np.uint8),
            max_search_distance=reach,
            smoothing_iterations=0,
        )
        n_filled = int((~valid & np.isfinite(sub)).sum())
    window = dem.transform @ Affine.translation(c0, r0)
    return attrs.evolve(dem, heights=sub, transform=window), n_filled


FLAT_TOLERANCE_M = 1.0
"""A DEM that departs from a smooth (quadratic) surface by less than this (1st to 99th
percentile of the residuals) is flat: a constant height above the ellipsoid, or above the
geoid (whose undulation rises 1.5 m across the 20 km of the Reunion products' RPC domain,
smoothly). It says nothing of the relief; a real DEM of the flattest plain departs from any
smooth surface by more in its noise alone."""


def is_flat(dem: DEM, tolerance_m: float = FLAT_TOLERANCE_M) -> bool:
    """Whether ``dem`` is a smooth surface within ``tolerance_m`` (or holds no height): a
    quadratic of its row and column fitted to about 10,000 of its posts."""
    rows, cols = np.nonzero(np.isfinite(dem.heights))
    if rows.size < 6:
        return True
    step = max(1, rows.size // 10_000)
    rows, cols = rows[::step], cols[::step]
    h = dem.heights[rows, cols]
    r = rows / max(float(rows.max()), 1.0)
    c = cols / max(float(cols.max()), 1.0)
    design = np.stack([np.ones_like(r), r, c, r * r, r * c, c * c], axis=1)
    residual = h - design @ np.linalg.lstsq(design, h, rcond=None)[0]
    low, high = np.percentile(residual, [1, 99])
    return bool(high - low < tolerance_m)


def values_at_nodes(dem: DEM, sample: Callable[[Any, Any], ArrayLike]) -> FloatArray:
    """``sample(lon_deg, lat_deg)`` at every node of ``dem`` (e.g. another DEM's
    :meth:`~carto.framework.raster.dem.DEM.height`), one grid of its shape (float64),
    computed band by band of rows: beside the result, memory of a band, not of the grid
    (on the whole grid at once, lon/lat, their copies and the sampling took 1.4 GB for a
    whole scene's pair DEM of 3266 x 3185 nodes; 0.1 GB in bands)."""
    n_rows, n_cols = dem.shape
    out = np.empty((n_rows, n_cols), np.float64)
    step = max(1, NODE_BAND_NODES // max(n_cols, 1))
    for start in range(0, n_rows, step):
        rows = slice(start, min(start + step, n_rows))
        out[rows] = sample(*dem.node_lonlat(rows))
    return out
