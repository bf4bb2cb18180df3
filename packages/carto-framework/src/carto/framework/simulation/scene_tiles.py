"""The simulator's products written window by window, in memory bounded by a band.

:func:`carto.framework.simulation.simulate.simulate_scene` never holds a whole-scene grid: the
terrain (:class:`~carto.framework.simulation.terrain.ProceduralTerrain`) and the ground texture
(:class:`~carto.framework.simulation.texture.GroundTexture`) are computed for the windows each
step needs, with the same value at a node whatever the window, and every raster is written
into its tiled, compressed GeoTIFF through windows:

* :func:`write_truth_dem`: the true DEM by strips of rows, with its height range and largest
  slope (the bounds of the renderer's ray search, the same for every band);
* :func:`render_image`: an image by bands of lines, each from the DEM and texture windows
  under the band's footprint;
* :func:`write_init_dem` and :func:`write_true_ortho`: the SRTM-like initial DEM and the true
  ortho-image by strips.
"""

from __future__ import annotations

import math
import types
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.files.atomic import atomic_output
from carto.framework.geometry import frames
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.parallel.progress import stage_bar
from carto.framework.raster.crs import utm_crs

FloatArray = NDArray[np.float64]
Bounds = tuple[float, float, float, float]
DEM_STRIP_ROWS = 256
"""Rows of the truth DEM computed and written at a time."""
ORTHO_STRIP_ROWS = 256
"""Rows of the true ortho-image computed and written at a time."""
ORTHO_BLOCK_COLS = 2048
"""Columns of the true ortho-image resampled from one texture window."""
ORTHO_MARGIN_PX = 64
"""How far beyond the images' ground the true ortho-image is resampled (pixels)."""


@contextmanager
def raster_writer(path: Path, height: int, width: int, dtype: Any, **profile: Any) -> Iterator[Any]:
    """An open rasterio dataset (tiled 256 x 256, deflate) written atomically: write it by
    windows inside the block (images without CRS are allowed)."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    base = {
        "driver": "GTiff",
        "height": int(height),
        "width": int(width),
        "count": 1,
        "dtype": dtype,
        "compress": "deflate",
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
    }
    base.update(profile)
    base = {k: v for k, v in base.items() if v is not None}
    tags = base.pop("tags", {})
    with atomic_output(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(tmp, "w", **base) as dst:
            if tags:
                dst.update_tags(**tags)
            yield dst


def _window(r0: int, r1: int, c0: int, c1: int) -> Any:
    from rasterio.windows import Window

    return Window(c0, r0, c1 - c0, r1 - r0)


def grid_window(
    transform: Any, shape: tuple[int, int], bounds: Bounds, pad: int
) -> tuple[int, int, int, int] | None:
    """``(r0, r1, c0, c1)``: the nodes of a north-up grid covering ``bounds`` (lon/lat)
    with ``pad`` more on every side, clipped to the grid; None when outside it."""
    west, south, east, north = bounds
    t = transform
    r0 = math.floor((north - t.f) / t.e - 0.5) - pad
    r1 = math.ceil((south - t.f) / t.e - 0.5) + pad + 1
    c0 = math.floor((west - t.c) / t.a - 0.5) - pad
    c1 = math.ceil((east - t.c) / t.a - 0.5) + pad + 1
    r0, r1 = max(r0, 0), min(r1, shape[0])
    c0, c1 = max(c0, 0), min(c1, shape[1])
    if r0 >= r1 or c0 >= c1:
        return None
    return r0, r1, c0, c1


def _sub_transform(transform: Any, r0: int, c0: int) -> Any:
    from affine import Affine

    return transform @ Affine.translation(c0, r0)


# ----------------------------------------------------------------------------- truth DEM
def write_truth_dem(path: Path, terrain: Any, *, quiet: bool = False) -> tuple[float, float, float]:
    """Write the terrain's grid as the truth DEM (float32, as :meth:`DEM.write`) by strips;
    return its ``(h_min, h_max, max_slope)``, the slope as
    :func:`~carto.framework.geometry.linescan.raycast.max_terrain_slope` of the whole grid."""
    from rasterio.crs import CRS

    n_rows, n_cols = terrain.shape
    t = terrain.transform
    lat_c = t.f + t.e * n_rows / 2
    m_lat = math.radians(1.0) * frames.WGS84_A_M
    m_lon = m_lat * math.cos(math.radians(lat_c))
    h_min, h_max, grad = math.inf, -math.inf, 0.0
    profile: dict[str, Any] = {
        "crs": CRS.from_epsg(4326),
        "transform": t,
        "nodata": np.nan,
        "predictor": 3,
        "tags": {"VERTICAL_REFERENCE": "ellipsoid WGS84", "AREA_OR_POINT": "Area"},
    }
    if n_rows < 256 or n_cols < 256:
        profile.update(tiled=False, blockxsize=None, blockysize=None)
    strips = range(0, n_rows, DEM_STRIP_ROWS)
    with (
        raster_writer(path, n_rows, n_cols, "float32", **profile) as dst,
        stage_bar(len(strips), "truth DEM", quiet=quiet, unit="strip") as bar,
    ):
        for r0 in strips:
            r1 = min(r0 + DEM_STRIP_ROWS, n_rows)
            e0, e1 = max(r0 - 1, 0), min(r1 + 1, n_rows)  # one row of halo for the slope
            h = terrain.window(e0, e1, 0, n_cols)
            inner = h[r0 - e0 : r1 - e0]
            dst.write(inner.astype(np.float32), 1, window=_window(r0, r1, 0, n_cols))
            h_min, h_max = min(h_min, float(inner.min())), max(h_max, float(inner.max()))
            if h.shape[0] > 1 and n_cols > 1:
                gy, gx = np.gradient(h, abs(t.e) * m_lat, abs(t.a) * m_lon)
                grad = max(grad, float(np.hypot(gx, gy)[r0 - e0 : r1 - e0].max()))
            bar.advance()
        dst.units = ("metre",)
    return h_min, h_max, grad * 1.5 + 0.05


# ----------------------------------------------------------------------------- images
def band_footprint(
    sensor: LineScanner,
    lines: tuple[int, int],
    samples: tuple[int, int],
    h_range: tuple[float, float],
    margin_m: float,
) -> Bounds:
    """Lon/lat bounds of the ground seen by the block of ``lines`` x ``samples`` (and the
    staggered array: 8 lines either side) at the heights of ``h_range``, plus ``margin_m``."""
    lines0, lines1 = lines[0] - 8.0, lines[1] + 8.0
    s0, s1 = float(samples[0]), float(samples[1])
    across = np.linspace(s0, s1, 17)
    side = np.linspace(lines0, lines1, 9)
    line = np.concatenate([np.full(17, lines0), np.full(17, lines1), side, side])
    sample = np.concatenate([across, across, np.full(9, s0), np.full(9, s1)])
    lons, lats = [], []
    for h in (h_range[0] - 2.0, h_range[1] + 2.0):
        lon, lat = sensor.image_to_ground(line, sample, np.full(line.size, h))
        lons.append(lon)
        lats.append(lat)
    lon, lat = np.concatenate(lons), np.concatenate(lats)
    m_lat = margin_m / 111_000.0
    m_lon = m_lat / math.cos(math.radians(float(np.nanmean(lat))))
    return (
        float(np.nanmin(lon) - m_lon),
        float(np.nanmin(lat) - m_lat),
        float(np.nanmax(lon) + m_lon),
        float(np.nanmax(lat) + m_lat),
    )


def render_image(
    path: Path,
    sensor: LineScanner,
    terrain: Any,
    ground: Any,
    *,
    h_range: tuple[float, float],
    max_slope: float,
    supersample: int,
    band_lines: int,
    band_samples: int,
    to_dn: Callable[[NDArray[np.float32]], NDArray[np.uint16]],
    tags: dict[str, str],
    quiet: bool = False,
) -> Path:
    """Render ``sensor``'s image by bands of ``band_lines`` lines (DN from ``to_dn``, called
    on consecutive bands in order) into a tiled uint16 GeoTIFF; each band in blocks of
    ``band_samples`` samples, each from the DEM and texture windows under it (so the memory
    does not grow with the image width either)."""
    from carto.framework.simulation.render import render_band

    n_lines, n_cols = sensor.image_shape
    bands = range(0, n_lines, band_lines)
    margin_m = 4.0 * max(abs(terrain.transform.e), abs(ground.transform.e)) * 111_000.0 + 20.0
    with (
        raster_writer(path, n_lines, n_cols, "uint16", tags=tags) as dst,
        stage_bar(len(bands), f"render {sensor.name}", quiet=quiet, unit="band") as bar,
    ):
        for first in bands:
            last = min(first + band_lines, n_lines)
            refl = np.full((last - first, n_cols), np.nan, np.float32)
            for s0 in range(0, n_cols, band_samples):
                s1 = min(s0 + band_samples, n_cols)
                bounds = band_footprint(sensor, (first, last), (s0, s1), h_range, margin_m)
                dem_win = grid_window(terrain.transform, terrain.shape, bounds, 2)
                tex_win = grid_window(ground.transform, ground.shape, bounds, 3)
                if dem_win is None or tex_win is None:
                    continue
                dem = types.SimpleNamespace(
                    heights=terrain.window(*dem_win),
                    transform=_sub_transform(terrain.transform, dem_win[0], dem_win[2]),
                    crs="EPSG:4326",
                )
                values, _ = ground.window(*tex_win)
                tex = types.SimpleNamespace(
                    reflectance=values,
                    transform=_sub_transform(ground.transform, tex_win[0], tex_win[2]),
                )
                refl[:, s0:s1] = render_band(
                    sensor,
                    (first, last),
                    dem,
                    tex,
                    samples=(s0, s1),
                    h_range=h_range,
                    max_slope=max_slope,
                    supersample=supersample,
                )
                del dem, tex, values
            dst.write(to_dn(refl), 1, window=_window(first, last, 0, n_cols))
            bar.advance()
    return path


# ----------------------------------------------------------------------------- products
def write_init_dem(path: Path, terrain: Any, rng: np.random.Generator) -> Path:
    """SRTM-like coarse DEM: the truth averaged to 3 arc-seconds (~90 m), plus a bias and
    correlated noise; ellipsoidal heights (as the truth). The truth is sampled by bands of
    cells."""
    import cv2
    from affine import Affine

    from carto.framework.raster.dem import DEM

    west, south, east, north = terrain.bounds_lonlat
    step = 3.0 / 3600.0
    # one cell beyond the truth on every side, so bilinear sampling covers all of it
    x0 = (math.floor(west / step) - 1) * step
    y0 = (math.ceil(north / step) + 1) * step
    nx = math.ceil((east - x0) / step) + 1
    ny = math.ceil((y0 - south) / step) + 1
    # block average of the truth: sample it on a fine sub-grid of each 3" cell
    k = 9
    sub = (np.arange(k) + 0.5) / k
    xs = x0 + (np.arange(nx)[:, None] + sub[None, :]).ravel() * step
    coarse = np.empty((ny, nx))
    band = 8
    for a in range(0, ny, band):
        b = min(a + band, ny)
        ys = y0 - (np.arange(a, b)[:, None] + sub[None, :]).ravel() * step
        gx, gy = np.meshgrid(xs, ys)
        fine = terrain.height(gx.ravel(), gy.ravel()).reshape((b - a) * k, nx * k)
        blocks = fine.reshape(b - a, k, nx, k)
        valid = np.isfinite(blocks).sum(axis=(1, 3))
        coarse[a:b] = np.where(
            valid > 0, np.nansum(blocks, axis=(1, 3)) / np.maximum(valid, 1), np.nan
        )
    if np.isnan(coarse).any():  # cells beyond the truth: nearest valid cell (SRTM covers all)
        from scipy import ndimage

        _, (iy, ix) = ndimage.distance_transform_edt(np.isnan(coarse), return_indices=True)
        coarse = coarse[iy, ix]
    noise = cv2.GaussianBlur(rng.normal(0.0, 1.0, coarse.shape).astype(np.float32), (0, 0), 1.0)
    noise *= 2.5 / max(float(noise.std()), 1e-6)
    bias = float(rng.normal(0.0, 4.0))
    heights = coarse + bias + noise.astype(np.float64)
    init = DEM.from_array(
        heights, Affine(step, 0.0, x0, 0.0, -step, y0), "EPSG:4326", vertical="ellipsoid"
    )
    return init.write(path)


def _block_bounds(
    to_lonlat: Any, grid: tuple[float, float, float], block: tuple[int, int, int, int]
) -> Bounds:
    """Lon/lat bounds of the outline (17 x 9 points) of the pixels ``block = (r0, r1, c0,
    c1)`` of a UTM grid ``(x0, y1, gsd_m)`` (its west and north edges and pixel size)."""
    x0, y1, gsd_m = grid
    r0, r1, c0, c1 = block
    ex = x0 + gsd_m * np.linspace(c0, c1, 17)
    ey = y1 - gsd_m * np.linspace(r0, r1, 9)
    px = np.concatenate([ex, ex, np.full(ey.size, ex[0]), np.full(ey.size, ex[-1])])
    py = np.concatenate([np.full(ex.size, ey[0]), np.full(ex.size, ey[-1]), ey, ey])
    lon, lat = to_lonlat.transform(px, py)
    return float(np.min(lon)), float(np.min(lat)), float(np.max(lon)), float(np.max(lat))


def footprint_outlines(
    sensors: dict[str, LineScanner], h_range: tuple[float, float]
) -> list[tuple[FloatArray, FloatArray]]:
    """Lon/lat outlines of the ground each image sees: per image, its border's 100 points at
    the lowest and at the highest height of ``h_range``. A pixel's ground at any height between
    lies on the segment between its two points, so within the convex hull of its image's
    outline."""
    outlines = []
    for sensor in sensors.values():
        n_lines, n_samples = sensor.image_shape
        along = np.linspace(-8.0, n_lines + 8.0, 17)
        across = np.linspace(0.0, float(n_samples), 33)
        line = np.concatenate([np.full(33, along[0]), along, np.full(33, along[-1]), along[::-1]])
        sample = np.concatenate(
            [across, np.full(17, across[-1]), across[::-1], np.full(17, across[0])]
        )
        h = np.repeat([h_range[0] - 2.0, h_range[1] + 2.0], line.size)
        lon, lat = sensor.image_to_ground(np.tile(line, 2), np.tile(sample, 2), h)
        outlines.append((lon, lat))
    return outlines


def _covered_blocks(
    to_utm: Any,
    grid: tuple[float, float, float],
    shape: tuple[int, int],
    outlines: list[tuple[FloatArray, FloatArray]],
    margin_px: int,
) -> NDArray[np.bool_]:
    """Which blocks (``ORTHO_STRIP_ROWS`` x ``ORTHO_BLOCK_COLS``) of a UTM grid ``(x0, y1,
    gsd_m)`` of ``shape`` come within ``margin_px`` of an outline's convex hull: the hulls
    drawn and filled on cells of 1/8 block, grown by the margin, then pooled."""
    import cv2

    x0, y1, gsd_m = grid
    cell = (ORTHO_STRIP_ROWS // 8, ORTHO_BLOCK_COLS // 8)
    n_blocks = (-(-shape[0] // ORTHO_STRIP_ROWS), -(-shape[1] // ORTHO_BLOCK_COLS))
    cells = np.zeros((n_blocks[0] * 8, n_blocks[1] * 8), np.uint8)
    for lon, lat in outlines:
        ok = np.isfinite(lon) & np.isfinite(lat)
        if not ok.any():
            return np.ones(n_blocks, bool)  # an outline off the Earth: keep every block
        x, y = to_utm.transform(lon[ok], lat[ok])
        # cell (i, j) is [i, i + 1) x [j, j + 1) here, centred on (i, j) for OpenCV
        col = (np.asarray(x) - x0) / gsd_m / cell[1] - 0.5
        row = (y1 - np.asarray(y)) / gsd_m / cell[0] - 0.5
        points = np.round(np.stack([col, row], axis=1) * 16).astype(np.int32)  # 4 bits
        hull = cv2.convexHull(points)
        cv2.fillConvexPoly(cells, hull, 1, shift=4)
        cv2.polylines(cells, [hull], True, 1, shift=4)
    # at least one cell: OpenCV's rounding of the outline's pixels
    grow = (max(1, math.ceil(margin_px / cell[1])), max(1, math.ceil(margin_px / cell[0])))
    kernel = np.ones((2 * grow[1] + 1, 2 * grow[0] + 1), np.uint8)
    cells = cv2.dilate(cells, kernel)
    return cells.reshape(n_blocks[0], 8, n_blocks[1], 8).any(axis=(1, 3))


def _ortho_grid(bounds: Bounds, gsd_m: float) -> tuple[Any, Any, tuple[float, float, int, int]]:
    """The UTM CRS of ``bounds``' centre, the lon/lat -> UTM transformer and ``(x0, y1, nx,
    ny)``: the west and north edges (multiples of ``gsd_m``) and the size of the grid covering
    ``bounds``."""
    import pyproj

    west, south, east, north = bounds
    crs = utm_crs(0.5 * (west + east), 0.5 * (south + north))
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    xs, ys = to_utm.transform([west, east, west, east], [south, south, north, north])
    x0 = math.floor(min(xs) / gsd_m) * gsd_m
    y1 = math.ceil(max(ys) / gsd_m) * gsd_m
    nx = math.ceil((max(xs) - x0) / gsd_m)
    ny = math.ceil((y1 - min(ys)) / gsd_m)
    return crs, to_utm, (x0, y1, nx, ny)


def _true_ortho_block(
    ground: Any,
    to_lonlat: Any,
    grid: tuple[float, float, float],
    block: tuple[int, int, int, int],
    wkt: str,
) -> NDArray[np.float32]:
    """The pixels ``block = (r0, r1, c0, c1)`` of the true ortho's UTM grid ``(x0, y1,
    gsd_m)``: the texture window under them averaged by GDAL (NaN off the texture)."""
    import os

    from affine import Affine
    from rasterio.warp import Resampling, reproject

    x0, y1, gsd_m = grid
    r0, r1, c0, c1 = block
    out = np.full((r1 - r0, c1 - c0), np.nan, np.float32)
    win = grid_window(ground.transform, ground.shape, _block_bounds(to_lonlat, grid, block), 4)
    if win is None:
        return out
    values, _ = ground.window(*win)
    reproject(
        values,
        out,
        src_transform=_sub_transform(ground.transform, win[0], win[2]),
        src_crs="EPSG:4326",
        dst_transform=Affine(gsd_m, 0.0, x0 + c0 * gsd_m, 0.0, -gsd_m, y1 - r0 * gsd_m),
        dst_crs=wkt,
        resampling=Resampling.average,
        src_nodata=np.nan,
        dst_nodata=np.nan,
        num_threads=os.cpu_count() or 1,
    )
    return out


def write_true_ortho(
    path: Path,
    ground: Any,
    bounds: Bounds,
    gsd_m: float,
    *,
    outlines: list[tuple[FloatArray, FloatArray]] | None = None,
    quiet: bool = False,
) -> Path:
    """The texture (reflectance) resampled (average) to a UTM grid at the GSD over
    ``bounds``, by strips of rows, each from the texture window under it; GDAL warps and
    compresses on every core (the same pixels and bytes as on one).

    With ``outlines`` (:func:`footprint_outlines`), only the blocks within
    ``ORTHO_MARGIN_PX`` of the images' ground are resampled, the others left without
    value: a narrow window across a tilted track no longer pays for its whole bounding box
    (a 12000 x 80 px window: about 20 times its footprint)."""
    import os

    import pyproj
    from affine import Affine

    crs, to_utm, (x0, y1, nx, ny) = _ortho_grid(bounds, gsd_m)
    to_lonlat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    dst_transform = Affine(gsd_m, 0.0, x0, 0.0, -gsd_m, y1)
    strips = range(0, ny, ORTHO_STRIP_ROWS)
    wkt = crs.to_wkt()
    tags = {
        "CARTO_PRODUCT": "ortho",
        "CARTO_CONTENT": "true ground reflectance (no terrain shading "
        "beyond the texture's), ortho on truth",
    }
    threads = os.cpu_count() or 1
    covered = (
        np.ones((len(strips), -(-nx // ORTHO_BLOCK_COLS)), bool)
        if outlines is None
        else _covered_blocks(to_utm, (x0, y1, gsd_m), (ny, nx), outlines, ORTHO_MARGIN_PX)
    )
    with (
        raster_writer(
            path,
            ny,
            nx,
            "float32",
            crs=wkt,
            transform=dst_transform,
            nodata=np.nan,
            tags=tags,
            num_threads=str(threads),
        ) as dst,
        stage_bar(len(strips), "true ortho", quiet=quiet, unit="strip") as bar,
    ):
        for i, r0 in enumerate(strips):
            r1 = min(r0 + ORTHO_STRIP_ROWS, ny)
            data = np.full((r1 - r0, nx), np.nan, np.float32)
            for j, c0 in enumerate(range(0, nx, ORTHO_BLOCK_COLS)):
                c1 = min(c0 + ORTHO_BLOCK_COLS, nx)
                if not covered[i, j]:
                    continue
                data[:, c0:c1] = _true_ortho_block(
                    ground, to_lonlat, (x0, y1, gsd_m), (r0, r1, c0, c1), wkt
                )
            dst.write(data, 1, window=_window(r0, r1, 0, nx))
            bar.advance()
    return path
