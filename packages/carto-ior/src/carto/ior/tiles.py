"""One IOR tile of one iteration (:func:`refine_tile`) and the task that runs it on any worker:
:func:`run_tile` reads its windows (the current DEM grid from a ``.npy`` file, the images through
their :class:`~carto.framework.raster.image_source.ImageSource`) and writes its result to one
``.npz`` file per tile, so a task carries paths, a window and settings, never whole arrays, and
its memory depends on the tile size only."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.files.atomic import atomic_output
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.matching.base import DenseSettings, Matcher
from carto.framework.raster.dem import DEM, ELLIPSOID
from carto.framework.raster.tiled_layer import piece_path
from carto.ior.rays import RayField, intersect_offsets
from carto.ior.settings import IORSettings

__all__ = ["NODE_LAYERS", "ORTHO_LAYERS", "TileJob", "TileResult", "refine_tile", "run_tile"]

FloatArray = NDArray[np.float64]

NODE_LAYERS = ("new_height", "d_row_px", "d_col_px", "covered")
"""The arrays of a tile file on the DEM grid (the tile's interior nodes)."""
ORTHO_LAYERS = ("ortho_left", "ortho_right", "score", "valid")
"""The arrays of a tile file on the ortho grid (the tile's interior pixels)."""


def _dem_on(grid: OrthoGrid, heights: FloatArray) -> DEM:
    return DEM.from_array(
        np.where(np.isfinite(heights), heights, np.nanmedian(heights)),
        grid.transform,
        grid.crs.to_wkt(),
        vertical=ELLIPSOID,
    )


def _block_mean(values: NDArray, k: int, shape: tuple[int, int]) -> FloatArray:
    """Mean of the finite values of each ``k x k`` block (NaN for an empty block)."""
    v = np.asarray(values, np.float64)[: shape[0] * k, : shape[1] * k]
    blocks = v.reshape(shape[0], k, shape[1], k)
    finite = np.isfinite(blocks)
    count = finite.sum(axis=(1, 3))
    total = np.where(finite, blocks, 0.0).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


@attrs.frozen(eq=False)
class TileResult:
    """What :func:`refine_tile` returns for its interior nodes: the height each matched node
    should have (NaN: no valid match), the node offsets right minus left (ortho pixels, rows
    and columns), whether both images cover the node, and the ortho-images and matching
    layers of the tile interior."""

    rows: slice
    cols: slice
    new_height: FloatArray
    d_row_px: FloatArray
    d_col_px: FloatArray
    covered: NDArray[np.bool_]
    ortho_left: NDArray[np.float32]
    ortho_right: NDArray[np.float32]
    score: NDArray[np.float32]
    valid: NDArray[np.bool_]


def _default_matcher() -> Matcher:
    from carto.framework.matching.ncc_matcher import NCCMatcher

    return NCCMatcher()


def refine_tile(
    images: tuple[NDArray, NDArray],
    sensors: tuple[Sensor, Sensor],
    heights: FloatArray,
    dem_grid: OrthoGrid,
    k: int,
    rows: slice,
    cols: slice,
    overlap: int,
    settings: IORSettings,
    levels: int | None = None,
    guess: tuple[float, float] = (0.0, 0.0),
    matcher: Matcher | None = None,
    h_range: tuple[float, float] | None = None,
    base: tuple[float, float] | None = None,
) -> TileResult:
    """One tile of one iteration: orthos on the current DEM, dense matching, intersection.

    ``images``: the prepared raw images (arrays or
    :class:`~carto.framework.raster.image_source.ImageSource`: only the windows the tile's
    ortho-images map into are read). ``heights`` is the whole current DEM grid (an array or a
    memory map: the tile reads its window plus ``overlap`` nodes around it); the result
    covers ``rows, cols`` (DEM node slices) only. ``h_range``: the lowest and highest height
    of the whole grid (an intersection more than 500 m beyond gives no height; default:
    from ``heights``). The two rays of a node are intersected by the tile's local ray model
    (:mod:`carto.ior.rays`). ``base``: the stereo base, ``(d_row, d_col)`` of the ortho
    grid, for matchers that search along it.
    """
    from scipy import ndimage

    n_r, n_c = dem_grid.shape
    r0, r1 = max(0, rows.start - overlap), min(n_r, rows.stop + overlap)
    c0, c1 = max(0, cols.start - overlap), min(n_c, cols.stop + overlap)
    sub = dem_grid.window(r0, c0, r1 - r0, c1 - c0)
    window = np.asarray(heights[r0:r1, c0:c1], np.float64)
    dem = _dem_on(sub, window)
    t = sub.transform
    from affine import Affine

    ogrid = OrthoGrid(
        sub.crs, Affine(t.a / k, 0.0, t.c, 0.0, t.e / k, t.f), ((r1 - r0) * k, (c1 - c0) * k)
    )
    ortho = [orthorectify(img, s, ogrid, dem) for img, s in zip(images, sensors, strict=True)]
    field = (matcher or _default_matcher()).match_dense(
        ortho[0],
        ortho[1],
        settings=DenseSettings(
            levels=settings.levels if levels is None else levels,
            guess=guess,
            window=settings.window,
            min_score=settings.min_score,
            base=base,
        ),
    )
    # node offsets: the mean of the valid offsets of the node's k x k ortho pixels
    shape = (r1 - r0, c1 - c0)
    d_row = _block_mean(field.d_row, k, shape)
    d_col = _block_mean(field.d_col, k, shape)
    covered = np.isfinite(_block_mean(ortho[0], k, shape)) & np.isfinite(
        _block_mean(ortho[1], k, shape)
    )
    ok = np.isfinite(d_row) & np.isfinite(d_col) & covered
    nr, nc = np.nonzero(ok)
    # left ray: through the node's ground point on the current DEM; right ray: through the
    # matched position on the current DEM; intersected by the tile's local ray model
    surface = np.asarray(dem.heights, np.float64)
    h_node = surface[nr, nc]
    rr = (nr + 0.5) * k - 0.5 + d_row[nr, nc]  # ortho pixel index of the match
    cc = (nc + 0.5) * k - 0.5 + d_col[nr, nc]
    x_r, y_r = ogrid.xy(rr, cc)
    h_r = ndimage.map_coordinates(
        surface, [(rr + 0.5) / k - 0.5, (cc + 0.5) / k - 0.5], order=1, mode="nearest"
    )
    rays = RayField.sample(sensors, sub, surface)
    x_p, y_p, h_p = intersect_offsets(rays, nr, nc, h_node, x_r, y_r, h_r)
    if h_range is None:
        h_range = (float(np.nanmin(heights)), float(np.nanmax(heights)))
    h_p = np.where((h_p >= h_range[0] - 500.0) & (h_p <= h_range[1] + 500.0), h_p, np.nan)
    # back to the node: the intersection lies a little off the node (horizontally); remove
    # the height change of that offset along the current surface
    x_n, y_n = sub.xy(nr, nc)
    g_row, g_col = np.gradient(window)
    px, py = sub.resolution
    slope_x = g_col[nr, nc] / px
    slope_y = -g_row[nr, nc] / py
    new = np.full(shape, np.nan)
    new[nr, nc] = h_p - slope_x * (x_p - x_n) - slope_y * (y_p - y_n)
    ir = slice(rows.start - r0, rows.stop - r0)
    ic = slice(cols.start - c0, cols.stop - c0)
    orr = slice(ir.start * k, ir.stop * k)
    occ = slice(ic.start * k, ic.stop * k)
    return TileResult(
        rows,
        cols,
        new[ir, ic],
        d_row[ir, ic],
        d_col[ir, ic],
        covered[ir, ic],
        ortho[0][orr, occ],
        ortho[1][orr, occ],
        field.score[orr, occ],
        field.valid[orr, occ],
    )


@attrs.frozen(eq=False)
class TileJob:
    """What the tile tasks of one iteration share: the images (read by windows), their
    models, the ``.npy`` file of the iteration's DEM grid heights, the grids, the matching
    settings of the iteration and the folder of the tile files."""

    images: tuple[Any, Any]
    sensors: tuple[Sensor, Sensor]
    heights_path: Path
    dem_grid: OrthoGrid
    k: int
    overlap: int
    settings: IORSettings
    levels: int
    guess: tuple[float, float]
    matcher: Matcher | None
    h_range: tuple[float, float]
    folder: Path
    base: tuple[float, float] | None = None


def run_tile(job: TileJob, rows: slice, cols: slice) -> Path:
    """Refine one tile (:func:`refine_tile`) and write its result to its file in
    ``job.folder`` (written under a temporary name and renamed: a file that exists is
    complete); return the file. A tile whose file exists is not computed again (a resumed
    run)."""
    path = piece_path(job.folder, rows.start, cols.start)
    if path.is_file():
        return path
    heights = np.load(job.heights_path, mmap_mode="r")
    result = refine_tile(
        job.images,
        job.sensors,
        heights,
        job.dem_grid,
        job.k,
        rows,
        cols,
        job.overlap,
        job.settings,
        job.levels,
        job.guess,
        job.matcher,
        h_range=job.h_range,
        base=job.base,
    )
    arrays = {name: getattr(result, name) for name in NODE_LAYERS + ORTHO_LAYERS}
    with atomic_output(path) as tmp, open(tmp, "wb") as stream:
        np.savez(stream, **arrays)
    return path


def tile_arrays(path: str | os.PathLike[str], names: tuple[str, ...]) -> dict[str, NDArray]:
    """Some arrays of a tile file."""
    with np.load(path) as data:
        return {name: data[name] for name in names}
