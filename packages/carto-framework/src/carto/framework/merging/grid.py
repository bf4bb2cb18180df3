"""The one grid a mosaic is written on, and how every source's pixels are read onto it.

:func:`union_grid` covers every source: their bounds brought into the mosaic's CRS, the
finest source posting (or the one asked for), corners snapped to multiples of it so that two
runs over the same area share one grid (as ``carto dem --te`` does). :func:`read_window`
gives one source's band on a window of that grid, with a halo: an aligned source (same CRS,
same posting, origin on the grid) is read directly, any other one through GDAL's warper
(bilinear, nearest for flags). Heights above a geoid are brought to the ellipsoid on the way
when a geoid is given. Only the window's pixels are read: memory depends on the window,
never on the strip's length.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Any

import attrs
import numpy as np
from affine import Affine

from carto.framework.arrays import FloatArray
from carto.framework.errors import InputError
from carto.framework.merging.sources import RasterSource
from carto.framework.raster.grid_window import GridWindow

__all__ = [
    "GridWindow",
    "MosaicGrid",
    "bounds_in",
    "node_lon_lat",
    "read_window",
    "same_crs",
    "union_grid",
]


MAX_MOSAIC_PIXELS = 2**34
"""A grid larger than this (a wrong --tr or CRS) is refused before any work."""


@attrs.frozen
class MosaicGrid:
    """A north-up map grid: CRS (WKT), pixel-corner transform and size."""

    crs_wkt: str
    transform: Affine
    width: int
    height: int

    def profile(self, count: int, dtype: str, nodata: float | None) -> dict[str, Any]:
        """The rasterio creation profile of a raster of ``count`` bands on this grid."""
        from rasterio.crs import CRS as RioCRS

        return {
            "width": self.width,
            "height": self.height,
            "count": count,
            "dtype": dtype,
            "crs": RioCRS.from_wkt(self.crs_wkt),
            "transform": self.transform,
            "nodata": nodata,
        }

    def windows(self, tile_px: int) -> list[GridWindow]:
        """The grid cut into tiles of ``tile_px`` (smaller at the right and bottom)."""
        return GridWindow(0, 0, self.height, self.width).tiles(tile_px)

    def pixel_box(self, bounds: Sequence[float]) -> GridWindow | None:
        """The grid's pixels inside map ``bounds`` (xmin, ymin, xmax, ymax), or None."""
        inverse = ~self.transform
        cols, rows = zip(
            *(inverse @ (x, y) for x in bounds[0::2] for y in bounds[1::2]), strict=True
        )
        r0, r1 = max(math.floor(min(rows) + 1e-6), 0), min(math.ceil(max(rows) - 1e-6), self.height)
        c0, c1 = max(math.floor(min(cols) + 1e-6), 0), min(math.ceil(max(cols) - 1e-6), self.width)
        if r1 <= r0 or c1 <= c0:
            return None
        return GridWindow(r0, c0, r1 - r0, c1 - c0)


def union_grid(
    sources: Sequence[RasterSource], *, crs_wkt: str | None = None, resolution: float | None = None
) -> MosaicGrid:
    """The grid covering every source (see the module docstring)."""
    crs_wkt = crs_wkt or sources[0].crs_wkt
    boxes, postings = zip(*(_in_crs(s, crs_wkt) for s in sources), strict=True)
    step = float(resolution) if resolution is not None else min(postings)
    if not (math.isfinite(step) and step > 0):
        raise InputError(f"mosaic posting {step!r}: give a positive --tr")
    xmin = math.floor(min(b[0] for b in boxes) / step + 1e-9) * step
    ymin = math.floor(min(b[1] for b in boxes) / step + 1e-9) * step
    xmax = math.ceil(max(b[2] for b in boxes) / step - 1e-9) * step
    ymax = math.ceil(max(b[3] for b in boxes) / step - 1e-9) * step
    width, height = round((xmax - xmin) / step), round((ymax - ymin) / step)
    if width * height > MAX_MOSAIC_PIXELS:
        raise InputError(
            f"mosaic grid of {width} x {height} pixels at {step:g}: too large (a wrong --tr "
            "or --t_srs?)"
        )
    return MosaicGrid(crs_wkt, Affine(step, 0.0, xmin, 0.0, -step, ymax), width, height)


@functools.lru_cache(maxsize=64)
def same_crs(a_wkt: str, b_wkt: str) -> bool:
    """Whether two CRSs (WKT) are the same (PROJ's comparison, cached: tile loops ask it
    for every window)."""
    import pyproj

    return a_wkt == b_wkt or pyproj.CRS.from_wkt(a_wkt).equals(pyproj.CRS.from_wkt(b_wkt))


def bounds_in(source: RasterSource, crs_wkt: str) -> tuple[float, ...]:
    """A source's bounds (xmin, ymin, xmax, ymax) in ``crs_wkt``."""
    if same_crs(source.crs_wkt, crs_wkt):
        return source.bounds
    from rasterio.crs import CRS as RioCRS
    from rasterio.warp import transform_bounds

    src, dst = RioCRS.from_wkt(source.crs_wkt), RioCRS.from_wkt(crs_wkt)
    return tuple(transform_bounds(src, dst, *source.bounds, densify_pts=21))


def _in_crs(source: RasterSource, crs_wkt: str) -> tuple[tuple[float, ...], float]:
    """A source's bounds and posting in ``crs_wkt``."""
    if same_crs(source.crs_wkt, crs_wkt):
        return source.bounds, min(source.resolution)
    from rasterio.crs import CRS as RioCRS
    from rasterio.warp import calculate_default_transform

    transform, _, _ = calculate_default_transform(
        RioCRS.from_wkt(source.crs_wkt),
        RioCRS.from_wkt(crs_wkt),
        source.width,
        source.height,
        *source.bounds,
    )
    return bounds_in(source, crs_wkt), min(abs(transform.a), abs(transform.e))


def _aligned(source: RasterSource, grid: MosaicGrid) -> tuple[int, int] | None:
    """The grid pixel of the source's corner when the source sits on the grid's pixels."""
    s, g = source.transform, grid.transform
    if not (math.isclose(s.a, g.a, rel_tol=1e-9) and math.isclose(s.e, g.e, rel_tol=1e-9)):
        return None
    col, row = (~g) @ (s.c, s.f)
    if abs(col - round(col)) > 1e-6 or abs(row - round(row)) > 1e-6:
        return None
    if not same_crs(source.crs_wkt, grid.crs_wkt):
        return None
    return round(row), round(col)


def read_window(
    source: RasterSource,
    grid: MosaicGrid,
    window: GridWindow,
    *,
    band: int = 1,
    resampling: str = "bilinear",
    geoid: Any = None,
) -> FloatArray:
    """One band of ``source`` on ``window`` of ``grid``, float64, NaN where it has no value
    (see the module docstring)."""
    import rasterio

    with rasterio.open(source.path) as ds:
        corner = _aligned(source, grid)
        if corner is not None:
            values = _read_aligned(ds, band, corner, window)
        else:
            values = _read_warped(ds, band, grid, window, resampling)
    if source.nodata is not None and not math.isnan(source.nodata):
        values[values == source.nodata] = np.nan
    if geoid is not None and source.vertical not in (None, "ellipsoid"):
        values = values + _undulation(grid, window, geoid)
    return values


def _read_aligned(ds: Any, band: int, corner: tuple[int, int], window: GridWindow) -> FloatArray:
    from rasterio.windows import Window

    row, col = window.row0 - corner[0], window.col0 - corner[1]
    fill = ds.nodata if ds.nodata is not None else np.nan
    data = ds.read(
        band,
        window=Window(col, row, window.n_cols, window.n_rows),
        boundless=True,
        fill_value=fill,
        out_dtype="float64",
    )
    return np.asarray(data, np.float64)


def _read_warped(
    ds: Any, band: int, grid: MosaicGrid, window: GridWindow, resampling: str
) -> FloatArray:
    import rasterio
    from rasterio.crs import CRS as RioCRS
    from rasterio.warp import Resampling, reproject

    out = np.full((window.n_rows, window.n_cols), np.nan, np.float64)
    transform = grid.transform @ Affine.translation(window.col0, window.row0)
    reproject(
        source=rasterio.band(ds, band),
        destination=out,
        src_nodata=ds.nodata if ds.nodata is not None else np.nan,
        dst_transform=transform,
        dst_crs=RioCRS.from_wkt(grid.crs_wkt),
        dst_nodata=np.nan,
        resampling=Resampling[resampling],
    )
    return out


def node_lon_lat(grid: MosaicGrid, rows: Any, cols: Any) -> tuple[FloatArray, FloatArray]:
    """WGS84 longitude and latitude (degrees) of the centres of ``grid``'s nodes at ``rows``,
    ``cols`` (the CRS's transformer cached)."""
    from carto.framework.imaging.ortho_grid import lonlat_transformer

    x, y = grid.transform @ (np.asarray(cols) + 0.5, np.asarray(rows) + 0.5)
    lon, lat = lonlat_transformer(grid.crs_wkt).transform(x, y)
    return np.asarray(lon, np.float64), np.asarray(lat, np.float64)


def _undulation(grid: MosaicGrid, window: GridWindow, geoid: Any) -> FloatArray:
    """The geoid undulation at the window's pixel centres, m."""
    rows, cols = np.mgrid[0 : window.n_rows, 0 : window.n_cols]
    lon, lat = node_lon_lat(grid, rows + window.row0, cols + window.col0)
    return np.asarray(geoid.undulation(lon, lat), np.float64)
