"""The starting surface of IOR: the initial DEM on the DEM grid, its voids filled, and how much
of the images' common footprint it covers (:func:`starting_surface`)."""

from __future__ import annotations

import math
import warnings

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import FloatArray, InputError
from carto.framework.sdk.dem import (
    DEM,
    OrthoGrid,
    bilinear_sample,
    cubic_sample,
    dem_pixel_size_m,
    fill_voids,
)
from carto.framework.sdk.sensors import Sensor

__all__ = [
    "InitialCoverage",
    "StartingSurface",
    "initial_coverage",
    "seen_by_both",
    "starting_surface",
    "values_on_grid",
]


@attrs.frozen
class StartingSurface:
    """The starting heights on the DEM grid and what the initial DEM gave.

    Attributes:
        heights: heights of every DEM node (no NaN): the initial DEM's, its voids filled.
        coverage: share of the images' common footprint where the initial DEM has a height.
        filled: share of the footprint whose starting height was filled (interpolated).
        footprint: share of the DEM grid's nodes that both images see.
    """

    heights: FloatArray = attrs.field(eq=False)
    coverage: float
    filled: float
    footprint: float


def seen_by_both(
    sensors: tuple[Sensor, Sensor], lon: FloatArray, lat: FloatArray, h: FloatArray
) -> NDArray[np.bool_]:
    """Whether both images see the ground points (inside both images' extents)."""
    inside = np.ones(lon.shape, bool)
    for sensor in sensors:
        n_l, n_s = sensor.image_shape
        with warnings.catch_warnings(), np.errstate(invalid="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            line, sample = sensor.ground_to_image(lon, lat, h)
            line, sample = np.asarray(line), np.asarray(sample)
            inside &= (line >= 0) & (line <= n_l) & (sample >= 0) & (sample <= n_s)
    return inside


def _nearest_post_valid(dem: DEM, lon: FloatArray, lat: FloatArray) -> NDArray[np.bool_]:
    """Whether the post of ``dem`` nearest to each point exists and holds a height."""
    row, col = dem.lonlat_to_pixel(lon, lat)
    n_rows, n_cols = dem.shape
    with np.errstate(invalid="ignore"):
        inside = (row > -0.5) & (row < n_rows - 0.5) & (col > -0.5) & (col < n_cols - 0.5)
    r = np.clip(np.rint(np.where(inside, row, 0)), 0, n_rows - 1).astype(np.intp)
    c = np.clip(np.rint(np.where(inside, col, 0)), 0, n_cols - 1).astype(np.intp)
    return inside & np.isfinite(dem.heights[r, c])


_FOOTPRINT_SAMPLES = 250_000  # nodes at most on which the footprint and coverage are measured
_BLOCK_ROWS = 256  # grid rows located at once


def _dem_pixels(
    dem: DEM, grid: OrthoGrid, rows: FloatArray, cols: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The DEM's fractional centre indices of the grid's nodes: the two affine maps composed
    when both are in one projected CRS, through WGS84 lon/lat otherwise."""
    if dem.crs.is_projected and dem.crs == grid.crs:
        x, y = grid.xy(rows, cols)
        inv = ~dem.transform
        return inv.d * x + inv.e * y + inv.f - 0.5, inv.a * x + inv.b * y + inv.c - 0.5
    return dem.lonlat_to_pixel(*grid.lonlat(rows, cols))


def values_on_grid(dem: DEM, grid: OrthoGrid, *, smooth: bool = True) -> FloatArray:
    """The DEM's heights at every node of ``grid`` (NaN off the DEM), block by block of rows
    (memory of the result only): bilinear, or from a DEM more than twice as coarse as the
    grid, cubic convolution (:func:`~carto.framework.raster.grid_sampling.cubic_sample`: continuous
    slope; bilinear everywhere without ``smooth``). A kink of bilinear heights at a coarse
    DEM's cell edges (SRTM's 90 m cells on a 1 m grid) would outlive the iterations as a
    seam in the refined DEM. Where the cubic height is missing (a void among its 4 x 4
    nodes) or wild (a node of 1e30), the bilinear one stays."""
    n_r, n_c = grid.shape
    dx, dy = dem_pixel_size_m(dem)
    coarse = max(float(np.max(dx)), float(np.max(dy))) > 2.0 * abs(grid.transform.a)
    cubic = smooth and coarse
    out = np.empty((n_r, n_c))
    for r0 in range(0, n_r, _BLOCK_ROWS):
        rows, cols = np.mgrid[r0 : min(n_r, r0 + _BLOCK_ROWS), 0:n_c]
        at = _dem_pixels(dem, grid, rows, cols)
        block = bilinear_sample(dem.heights, *at)  # DEM.height
        if cubic:
            smooth = cubic_sample(dem.heights, *at)
            with np.errstate(invalid="ignore", over="ignore"):
                keep = np.isfinite(smooth) & (np.abs(smooth - block) < 1e4)
            block = np.where(keep, smooth, block)
        out[r0 : r0 + rows.shape[0]] = block
    return out


@attrs.frozen
class InitialCoverage:
    """What the initial DEM gives over the images' common footprint (measured on a lattice
    of at most ``_FOOTPRINT_SAMPLES`` nodes): the share where it has a height
    (``coverage``), the share that must be filled (``filled``), and the share of the grid's
    nodes both images see (``footprint``)."""

    coverage: float
    filled: float
    footprint: float


def initial_coverage(
    init_dem: DEM,
    grid: OrthoGrid,
    sensors: tuple[Sensor, Sensor],
    min_coverage: float = 0.75,
) -> InitialCoverage:
    """How much of the images' common footprint on ``grid`` the initial DEM covers, from a
    lattice of nodes (the cost does not grow with the grid).

    Raises:
        InputError: less than ``min_coverage`` (mostly void, or a tile of another place).
    """
    n_r, n_c = grid.shape
    step = max(1, math.ceil(math.sqrt(n_r * n_c / _FOOTPRINT_SAMPLES)))
    lon_p, lat_p = grid.lonlat(*np.mgrid[0:n_r:step, 0:n_c:step])
    h_p = init_dem.height(lon_p, lat_p)
    h_mid = (
        float(np.nanmedian(h_p))
        if np.isfinite(h_p).any()
        else float(np.nanmedian(init_dem.heights))
    )
    seen = seen_by_both(sensors, lon_p, lat_p, np.where(np.isfinite(h_p), h_p, h_mid))
    if not seen.any():  # a sliver: measure over the whole grid
        seen = np.ones_like(seen)
    # coverage: the nearest post has a height (bilinear sampling would also lose the ring of
    # cells around each void, which overstates a void of a coarse DEM)
    post = _nearest_post_valid(init_dem, lon_p, lat_p)
    coverage = float(post[seen].mean())
    if coverage < min_coverage:
        raise InputError(
            f"dem: initial DEM {init_dem.name} covers {100.0 * coverage:.0f} % of the images' "
            f"footprint (at least {100.0 * min_coverage:.0f} % needed: a DEM mostly void, or "
            "a tile of another place; check the file, or start from --init-height M)"
        )
    filled = float((~post & seen).sum()) / max(int(seen.sum()), 1)
    return InitialCoverage(coverage, filled, float(seen.mean()))


def starting_surface(
    init_dem: DEM,
    grid: OrthoGrid,
    sensors: tuple[Sensor, Sensor],
    min_coverage: float = 0.75,
) -> StartingSurface:
    """The starting heights of IOR on ``grid``: the initial DEM, its voids (and the nodes just
    outside it) filled by GDAL's inverse-distance interpolation
    (:func:`~carto.framework.raster.dem_measures.fill_voids`), so the
    first ortho-images have no holes and the first heights no jumps.

    Raises:
        InputError: the initial DEM gives a height at less than ``min_coverage`` of the
            images' common footprint (mostly void, or a tile of another place).
    """
    cover = initial_coverage(init_dem, grid, sensors, min_coverage)
    raw = values_on_grid(init_dem, grid)
    covered = np.isfinite(raw)
    h_mid = float(np.nanmedian(raw)) if covered.any() else float(np.nanmedian(init_dem.heights))
    heights = raw
    if not covered.all():
        n_r, n_c = grid.shape
        edge_r = np.r_[np.zeros(n_c), np.full(n_c, n_r - 1), np.arange(n_r), np.arange(n_r)]
        edge_c = np.r_[np.arange(n_c), np.arange(n_c), np.zeros(n_r), np.full(n_r, n_c - 1)]
        lon_e, lat_e = grid.lonlat(edge_r, edge_c)
        bounds = (float(lon_e.min()), float(lat_e.min()), float(lon_e.max()), float(lat_e.max()))
        filled_dem, _ = fill_voids(init_dem, bounds)
        heights = np.where(covered, raw, values_on_grid(filled_dem, grid))
        still = ~np.isfinite(heights)
        if still.any():  # beyond the initial DEM: fill on the grid itself
            from rasterio.fill import fillnodata

            heights = fillnodata(
                np.where(still, 0.0, heights),
                mask=(~still).astype(np.uint8),
                max_search_distance=float(math.hypot(*heights.shape)) + 1.0,
                smoothing_iterations=0,
            )
        heights = np.where(np.isfinite(heights), heights, h_mid)
    return StartingSurface(
        np.asarray(heights, np.float64), cover.coverage, cover.filled, cover.footprint
    )
