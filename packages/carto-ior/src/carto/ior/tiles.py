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

from carto.framework.sdk.common import atomic_output
from carto.framework.sdk.dem import DEM, ELLIPSOID, OrthoGrid, orthorectify, piece_path
from carto.framework.sdk.matchers import (
    DenseSettings,
    Matcher,
    OffsetField,
    levels_for_reach,
    limit_along_base,
    refine_along_base,
)
from carto.framework.sdk.sensors import Sensor
from carto.ior.height_precision import node_sigma_m
from carto.ior.node_heights import node_heights
from carto.ior.rays import RayField
from carto.ior.settings import IORSettings

__all__ = [
    "NODE_LAYERS",
    "NODE_QUALITY",
    "ORTHO_LAYERS",
    "TileJob",
    "TileResult",
    "refine_tile",
    "run_tile",
]

FloatArray = NDArray[np.float64]

NODE_LAYERS = (
    "new_height",
    "d_row_px",
    "d_col_px",
    "covered",
    "count",
    "spread_m",
    "node_score",
    "sigma_m",
)
"""The arrays of a tile file on the DEM grid (the tile's interior nodes)."""
NODE_QUALITY = ("count", "spread_m", "node_score", "sigma_m")
"""The node layers of a tile file that describe its matched points (quality layers)."""
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
    should have (the median of its matched points, :mod:`carto.ior.node_heights`; NaN: no
    valid match), the node offsets right minus left (mean of its pixels', ortho pixels, rows
    and columns), whether both images cover the node, the node's points (count), their
    spread (m) and mean correlation score, the predicted standard deviation of the height
    of the DEM the tile started from (m, :mod:`carto.ior.height_precision`), and the
    ortho-images and matching layers of the tile interior."""

    rows: slice
    cols: slice
    new_height: FloatArray
    d_row_px: FloatArray
    d_col_px: FloatArray
    covered: NDArray[np.bool_]
    count: NDArray[np.int32]
    spread_m: NDArray[np.float32]
    node_score: NDArray[np.float32]
    sigma_m: NDArray[np.float32]
    ortho_left: NDArray[np.float32]
    ortho_right: NDArray[np.float32]
    score: NDArray[np.float32]
    valid: NDArray[np.bool_]


def _default_matcher() -> Matcher:
    from carto.framework.sdk.matchers import SGMMatcher

    return SGMMatcher()


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
    variance_factor: float = 1.0,
    search_px: FloatArray | None = None,
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
    grid, for matchers that search along it. ``variance_factor``: the share of a node's
    measurement variance the regularised updates left in the current DEM
    (:func:`carto.ior.height_precision.smoothing_variance_factor`). ``search_px``: the whole
    grid's per-node bound on the offset along the base from the guess, ortho pixels (NaN:
    none; None: none anywhere): the matcher's pyramid is no deeper than the tile's bounds
    need, and matches beyond their node's bound are refused.
    """

    w = _tile_window(dem_grid, heights, rows, cols, overlap, k)
    ortho = [
        orthorectify(img, s, w.ortho_grid, w.dem) for img, s in zip(images, sensors, strict=True)
    ]
    direction = base if base is not None else (0.0, 1.0)
    field = _matched(ortho, w, settings, levels, guess, matcher, base, direction, search_px)
    d_row, d_col, covered = _node_offsets(field, ortho, k, w.shape)
    # heights: every valid match intersected, carried to its node, the median per node
    surface = np.asarray(w.dem.heights, np.float64)
    rays = RayField.sample(sensors, w.grid, surface)
    if h_range is None:
        h_range = (float(np.nanmin(heights)), float(np.nanmax(heights)))
    nodes = node_heights(
        field.d_row, field.d_col, field.valid, field.score, surface, w.grid, k, rays, h_range
    )
    new = np.where(covered, nodes.height_m, np.nan)
    sigma = _predicted_sigma(ortho, field, rays, settings.window, direction, w, variance_factor)
    ir, ic, orr, occ = w.interior(rows, cols)
    return TileResult(
        rows,
        cols,
        new[ir, ic],
        d_row[ir, ic],
        d_col[ir, ic],
        covered[ir, ic],
        nodes.count[ir, ic],
        nodes.spread_m[ir, ic],
        nodes.score[ir, ic],
        sigma[ir, ic],
        ortho[0][orr, occ],
        ortho[1][orr, occ],
        field.score[orr, occ],
        field.valid[orr, occ],
    )


@attrs.frozen(eq=False)
class _TileWindow:
    """What a tile reads of the DEM grid: nodes ``r0:r1, c0:c1`` (its own with the overlap
    around them, clipped to the grid), their grid, the ortho grid over them (``k`` ortho
    pixels per node) and the current DEM on them (its voids at the window's median)."""

    r0: int
    r1: int
    c0: int
    c1: int
    k: int
    grid: OrthoGrid
    ortho_grid: OrthoGrid
    dem: DEM

    @property
    def shape(self) -> tuple[int, int]:
        """The window's nodes, rows and columns."""
        return (self.r1 - self.r0, self.c1 - self.c0)

    def interior(self, rows: slice, cols: slice) -> tuple[slice, slice, slice, slice]:
        """The tile's own nodes ``rows, cols`` in the window (rows, columns), then its own
        ortho pixels (rows, columns)."""
        ir = slice(rows.start - self.r0, rows.stop - self.r0)
        ic = slice(cols.start - self.c0, cols.stop - self.c0)
        return (
            ir,
            ic,
            slice(ir.start * self.k, ir.stop * self.k),
            slice(ic.start * self.k, ic.stop * self.k),
        )


def _tile_window(
    dem_grid: OrthoGrid, heights: FloatArray, rows: slice, cols: slice, overlap: int, k: int
) -> _TileWindow:
    """The window of the tile ``rows, cols`` with ``overlap`` nodes around it, read from
    the whole grid's ``heights``."""
    from affine import Affine

    n_r, n_c = dem_grid.shape
    r0, r1 = max(0, rows.start - overlap), min(n_r, rows.stop + overlap)
    c0, c1 = max(0, cols.start - overlap), min(n_c, cols.stop + overlap)
    sub = dem_grid.window(r0, c0, r1 - r0, c1 - c0)
    window = np.asarray(heights[r0:r1, c0:c1], np.float64)
    t = sub.transform
    ogrid = OrthoGrid(
        sub.crs, Affine(t.a / k, 0.0, t.c, 0.0, t.e / k, t.f), ((r1 - r0) * k, (c1 - c0) * k)
    )
    return _TileWindow(r0, r1, c0, c1, k, sub, ogrid, _dem_on(sub, window))


def _matched(
    ortho: list[NDArray],
    w: _TileWindow,
    settings: IORSettings,
    levels: int | None,
    guess: tuple[float, float],
    matcher: Matcher | None,
    base: tuple[float, float] | None,
    direction: tuple[float, float],
    search_px: FloatArray | None,
) -> OffsetField:
    """The dense offsets of the tile's right ortho-image against its left one: matched
    within the nodes' search bounds (``search_px``: the whole grid's; the pyramid no deeper
    than they need), refined to sub-pixel along the base (``direction``), matches beyond
    their node's bound refused."""
    depth = settings.levels if levels is None else levels
    bound = None
    if search_px is not None:  # per pixel: its node's bound
        k = w.k
        nodes = np.asarray(search_px[w.r0 : w.r1, w.c0 : w.c1], np.float32)
        bound = np.repeat(np.repeat(np.where(np.isnan(nodes), np.inf, nodes), k, 0), k, 1)
        depth = min(depth, levels_for_reach(float(bound.max())))
    field = (matcher or _default_matcher()).match_dense(
        ortho[0],
        ortho[1],
        settings=DenseSettings(
            levels=depth,
            guess=guess,
            window=settings.window,
            min_score=settings.min_score,
            base=base,
            search_px=bound,
        ),
    )
    if settings.subpixel_steps:  # least-squares sub-pixel offsets along the base
        field = refine_along_base(
            ortho[0], ortho[1], field, settings.window, direction, settings.subpixel_steps
        )
    if bound is not None:
        field = limit_along_base(field, bound, guess, direction)
    return field


def _node_offsets(
    field: OffsetField, ortho: list[NDArray], k: int, shape: tuple[int, int]
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Per node of the window: the offsets (rows, columns) and whether both ortho-images
    cover it."""
    # node offsets: the mean of the valid offsets of the node's k x k ortho pixels
    d_row = _block_mean(field.d_row, k, shape)
    d_col = _block_mean(field.d_col, k, shape)
    covered = np.isfinite(_block_mean(ortho[0], k, shape)) & np.isfinite(
        _block_mean(ortho[1], k, shape)
    )
    return d_row, d_col, covered


def _predicted_sigma(
    ortho: list[NDArray],
    field: OffsetField,
    rays: RayField,
    window: int,
    direction: tuple[float, float],
    w: _TileWindow,
    variance_factor: float,
) -> NDArray[np.float32]:
    """Per node of the window, the predicted height standard deviation, m
    (:func:`~carto.ior.height_precision.node_sigma_m`)."""
    # the predicted precision: the matching's bound, checked across the base; local B/H
    t = rays.on_nodes(slice(0, w.shape[0]), slice(0, w.shape[1]))
    bh = np.hypot(t[0, 0] - t[1, 0], t[0, 1] - t[1, 1])
    sigma, _ = node_sigma_m(
        ortho[0],
        ortho[1],
        field,
        window,
        direction,
        w.k,
        w.ortho_grid.resolution[0],
        bh,
        variance_factor,
    )
    return sigma


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
    variance_factor: float = 1.0
    search_path: Path | None = None


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
        variance_factor=job.variance_factor,
        search_px=None if job.search_path is None else np.load(job.search_path, mmap_mode="r"),
    )
    arrays = {name: getattr(result, name) for name in NODE_LAYERS + ORTHO_LAYERS}
    with atomic_output(path) as tmp, open(tmp, "wb") as stream:
        np.savez(stream, **arrays)
    return path


def tile_arrays(path: str | os.PathLike[str], names: tuple[str, ...]) -> dict[str, NDArray]:
    """Some arrays of a tile file."""
    with np.load(path) as data:
        return {name: data[name] for name in names}
