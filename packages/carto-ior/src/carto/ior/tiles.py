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

from carto.framework.sdk.common import FloatArray, atomic_output
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
    "TileWork",
    "refine_tile",
    "run_tile",
]


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
    """What :func:`refine_tile` returns for the tile's nodes ``rows, cols``: its layers by
    name (what its tile file holds). On its interior nodes (:data:`NODE_LAYERS`, in that
    order): the height each matched node should have (the median of its matched points,
    :mod:`carto.ior.node_heights`; NaN: no valid match), the node offsets right minus left
    (mean of its pixels', ortho pixels, rows and columns), whether both images cover the
    node, the node's points (count), their spread (m) and mean correlation score, the
    predicted standard deviation of the height of the DEM the tile started from (m,
    :mod:`carto.ior.height_precision`); on its interior ortho pixels
    (:data:`ORTHO_LAYERS`): the ortho-images and matching layers."""

    rows: slice
    cols: slice
    layers: dict[str, NDArray]


def _default_matcher() -> Matcher:
    from carto.framework.sdk.matchers import SGMMatcher

    return SGMMatcher()


@attrs.frozen(eq=False)
class TileWork:
    """What every tile of one iteration is refined with (:func:`refine_tile`).

    ``images``: the prepared raw images (arrays or
    :class:`~carto.framework.raster.image_source.ImageSource`: only the windows the tile's
    ortho-images map into are read); ``sensors``: their models; ``dem_grid``: the whole DEM
    grid, ``k`` ortho pixels per node; ``overlap``: the nodes a tile reads around its own.
    ``levels``: the matcher's pyramid levels (default: ``settings.levels``); ``guess``: the
    offset the search starts from, ortho pixels. ``h_range``: the lowest and highest height
    of the whole grid (an intersection more than 500 m beyond gives no height; default:
    from the heights). ``base``: the stereo base, ``(d_row, d_col)`` of the ortho grid, for
    matchers that search along it. ``variance_factor``: the share of a node's measurement
    variance the regularised updates left in the current DEM
    (:func:`carto.ior.height_precision.smoothing_variance_factor`). ``precision``: the
    predicted height precision is computed (``sigma_m``; NaN without: an iteration whose
    tiles are not delivered, a coarse-to-fine stage's or one that cannot be the last)."""

    images: tuple[Any, Any]
    sensors: tuple[Sensor, Sensor]
    dem_grid: OrthoGrid
    k: int
    overlap: int
    settings: IORSettings
    levels: int | None = None
    guess: tuple[float, float] = (0.0, 0.0)
    matcher: Matcher | None = None
    h_range: tuple[float, float] | None = None
    base: tuple[float, float] | None = None
    variance_factor: float = 1.0
    precision: bool = True


def refine_tile(
    work: TileWork,
    heights: FloatArray,
    rows: slice,
    cols: slice,
    search_px: FloatArray | None = None,
) -> TileResult:
    """One tile of one iteration: orthos on the current DEM, dense matching, intersection.

    ``heights`` is the whole current DEM grid (an array or a memory map: the tile reads its
    window plus ``work.overlap`` nodes around it); the result covers ``rows, cols`` (DEM
    node slices) only. The two rays of a node are intersected by the tile's local ray model
    (:mod:`carto.ior.rays`). ``search_px``: the whole grid's per-node bound on the offset
    along the base from the guess, ortho pixels (NaN: none; None: none anywhere): the
    matcher's pyramid is no deeper than the tile's bounds need, and matches beyond their
    node's bound are refused.
    """
    k, h_range = work.k, work.h_range
    w = _tile_window(work.dem_grid, heights, rows, cols, work.overlap, k)
    ortho = [
        orthorectify(img, s, w.ortho_grid, w.dem)
        for img, s in zip(work.images, work.sensors, strict=True)
    ]
    direction = work.base if work.base is not None else (0.0, 1.0)
    field = _matched(ortho, w, work, direction, search_px)
    d_row, d_col, covered = _node_offsets(field, ortho, k, w.shape)
    # heights: every valid match intersected, carried to its node, the median per node
    surface = np.asarray(w.dem.heights, np.float64)
    rays = RayField.sample(work.sensors, w.grid, surface)
    if h_range is None:
        h_range = (float(np.nanmin(heights)), float(np.nanmax(heights)))
    nodes = node_heights(
        field.d_row, field.d_col, field.valid, field.score, surface, w.grid, k, rays, h_range
    )
    new = np.where(covered, nodes.height_m, np.nan)
    sigma = (
        _predicted_sigma(ortho, field, rays, direction, w, work)
        if work.precision
        else np.full(w.shape, np.nan, np.float32)
    )
    ir, ic, orr, occ = w.interior(rows, cols)
    on_nodes = (new, d_row, d_col, covered, nodes.count, nodes.spread_m, nodes.score, sigma)
    on_pixels = (ortho[0], ortho[1], field.score, field.valid)
    layers = {name: a[ir, ic] for name, a in zip(NODE_LAYERS, on_nodes, strict=True)}
    layers |= {name: a[orr, occ] for name, a in zip(ORTHO_LAYERS, on_pixels, strict=True)}
    return TileResult(rows, cols, layers)


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
    work: TileWork,
    direction: tuple[float, float],
    search_px: FloatArray | None,
) -> OffsetField:
    """The dense offsets of the tile's right ortho-image against its left one: matched
    within the nodes' search bounds (``search_px``: the whole grid's; the pyramid no deeper
    than they need), refined to sub-pixel along the base (``direction``), matches beyond
    their node's bound refused."""
    settings, guess = work.settings, work.guess
    depth = settings.levels if work.levels is None else work.levels
    bound = None
    if search_px is not None:  # per pixel: its node's bound
        k = w.k
        nodes = np.asarray(search_px[w.r0 : w.r1, w.c0 : w.c1], np.float32)
        bound = np.repeat(np.repeat(np.where(np.isnan(nodes), np.inf, nodes), k, 0), k, 1)
        depth = min(depth, levels_for_reach(float(bound.max())))
    field = (work.matcher or _default_matcher()).match_dense(
        ortho[0],
        ortho[1],
        settings=DenseSettings(
            levels=depth,
            guess=guess,
            window=settings.window,
            min_score=settings.min_score,
            base=work.base,
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
    direction: tuple[float, float],
    w: _TileWindow,
    work: TileWork,
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
        work.settings.window,
        direction,
        w.k,
        w.ortho_grid.resolution[0],
        bh,
        work.variance_factor,
    )
    return sigma


@attrs.frozen(eq=False)
class TileJob:
    """What the tile tasks of one iteration share: what they are refined with, the ``.npy``
    file of the iteration's DEM grid heights, the folder of the tile files and the ``.npy``
    file of the per-node search bounds (None: none anywhere)."""

    work: TileWork
    heights_path: Path
    folder: Path
    search_path: Path | None = None


def run_tile(job: TileJob, rows: slice, cols: slice) -> Path:
    """Refine one tile (:func:`refine_tile`) and write its result to its file in
    ``job.folder`` (written under a temporary name and renamed: a file that exists is
    complete); return the file. A tile whose file exists is not computed again (a resumed
    run), unless that file holds another extent (a work folder of a version that cut the
    grid otherwise)."""
    path = piece_path(job.folder, rows.start, cols.start)
    if path.is_file() and _holds(path, (rows.stop - rows.start, cols.stop - cols.start)):
        return path
    heights = np.load(job.heights_path, mmap_mode="r")
    search_px = None if job.search_path is None else np.load(job.search_path, mmap_mode="r")
    result = refine_tile(job.work, heights, rows, cols, search_px)
    with atomic_output(path) as tmp, open(tmp, "wb") as stream:
        np.savez(stream, **result.layers)
    return path


def _holds(path: Path, shape: tuple[int, int]) -> bool:
    """Whether the tile file at ``path`` holds nodes of ``shape``."""
    with np.load(path) as data:
        return tuple(data["new_height"].shape) == shape


def tile_arrays(path: str | os.PathLike[str], names: tuple[str, ...]) -> dict[str, NDArray]:
    """Some arrays of a tile file."""
    with np.load(path) as data:
        return {name: data[name] for name in names}
