"""Seamless mosaics of DEMs and ortho-images: swaths side by side, scenes of a strip.

Like ASP's ``dem_mosaic`` (its default blending) and GDAL's feathered cutlines:

- every source's pixel is weighted by its distance to the source's own edge of data
  (nodata or the raster's border), growing linearly from 0 to 1 over ``feather_px``
  pixels, so that where two sources overlap the mosaic passes from one to the other
  smoothly and no seam is left at an edge, and a hole in one source is filled from the other
  without a step;
- for DEMs, :func:`seam_steps` measures the vertical step between every two overlapping
  sources (median and NMAD of their difference over the overlap, in bounded memory by
  :class:`~carto.framework.evaluation.difference_histogram.DifferenceHistogram`) and
  :func:`step_offsets` finds one constant per source that cancels the steps in the least
  squares sense (the first source of each connected group held), applied when asked;
- the mosaic is written tile by tile (:func:`write_mosaic`): a tile reads each source's
  window with a halo of ``feather_px`` (:func:`~carto.framework.merging.grid.read_window`),
  so memory depends on the tile size, never on the strip's length.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.arrays import FloatArray
from carto.framework.merging.grid import GridWindow, MosaicGrid, bounds_in, read_window
from carto.framework.merging.sources import RasterSource
from carto.framework.settings import checked

__all__ = [
    "MosaicSettings",
    "SeamStep",
    "blend_window",
    "feather_weights",
    "seam_steps",
    "step_offsets",
    "write_mosaic",
]


@attrs.frozen
class MosaicSettings:
    """How sources are joined.

    Attributes:
        feather_px: width of the blend at a source's edge, mosaic pixels (0: no blend, the
            last source wins where they overlap, as ``gdal_merge``).
        tile_px: side of the tiles the mosaic is written in, pixels.
        resampling: how a source not on the mosaic's grid is resampled.
    """

    feather_px: int = attrs.field(
        default=32,
        validator=checked(lambda v: 0 <= v <= 4096, "feather {!r} px: give 0 to 4096 pixels"),
    )
    tile_px: int = attrs.field(
        default=1024,
        validator=checked(
            lambda v: 64 <= v <= 16384, "mosaic tile {!r} px: give 64 to 16384 pixels"
        ),
    )
    resampling: str = attrs.field(
        default="bilinear",
        validator=checked(
            lambda v: v in ("nearest", "bilinear", "cubic"),
            "resampling {!r}: use nearest, bilinear or cubic",
        ),
    )


@attrs.frozen
class SeamStep:
    """The vertical step between two overlapping DEMs: ``second - first`` over their
    overlap, m (median and NMAD), and how many pixels it rests on."""

    first: int
    second: int
    median_m: float
    nmad_m: float
    pixels: int


def feather_weights(valid: NDArray[np.bool_], feather_px: int) -> FloatArray:
    """Blend weights of one source on a window: its pixels' distance to the nearest pixel
    without data (the window's border counts as data: the window is read with a halo of
    ``feather_px``), over ``feather_px``, clipped to (0, 1]; 0 where no data."""
    if feather_px <= 0:
        return valid.astype(np.float64)
    import cv2

    padded = np.pad(valid.astype(np.uint8), 1, mode="edge")
    distance = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    return np.where(valid, np.clip(distance / feather_px, 1.0 / feather_px, 1.0), 0.0)


def blend_window(values: Sequence[FloatArray], feather_px: int) -> tuple[FloatArray, FloatArray]:
    """The feathered blend of sources' values on one window (NaN = no data), and how many
    sources had a value at each pixel. With no feather, the last source with a value wins."""
    count = np.zeros(values[0].shape, np.float64)
    if feather_px <= 0:
        out = np.full(values[0].shape, np.nan)
        for v in values:
            has = np.isfinite(v)
            out[has] = v[has]
            count += has
        return out, count
    total = np.zeros(values[0].shape, np.float64)
    weight = np.zeros(values[0].shape, np.float64)
    for v in values:
        has = np.isfinite(v)
        w = feather_weights(has, feather_px)
        total += w * np.where(has, v, 0.0)
        weight += w
        count += has
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight > 0, total / weight, np.nan), count


def _footprints(sources: Sequence[RasterSource], grid: MosaicGrid) -> list[GridWindow | None]:
    """Each source's pixel box on the grid (None: outside it)."""
    return [grid.pixel_box(bounds_in(s, grid.crs_wkt)) for s in sources]


def _overlaps(sources: Sequence[RasterSource], grid: MosaicGrid) -> dict[tuple[int, int], Any]:
    """Every two sources whose footprints on the grid meet: their common pixel box."""
    boxes = _footprints(sources, grid)
    pairs = {}
    for i, j in itertools.combinations(range(len(sources)), 2):
        a, b = boxes[i], boxes[j]
        if a is None or b is None:
            continue
        r0, c0 = max(a.row0, b.row0), max(a.col0, b.col0)
        r1 = min(a.row0 + a.n_rows, b.row0 + b.n_rows)
        c1 = min(a.col0 + a.n_cols, b.col0 + b.n_cols)
        if r1 > r0 and c1 > c0:
            pairs[(i, j)] = GridWindow(r0, c0, r1 - r0, c1 - c0)
    return pairs


def seam_steps(
    sources: Sequence[RasterSource],
    grid: MosaicGrid,
    settings: MosaicSettings,
    *,
    geoid: Any = None,
    advance: Callable[[], None] | None = None,
) -> list[SeamStep]:
    """The step between every two overlapping DEMs (see the module docstring); pairs whose
    footprints meet but share no pixel with heights in both are left out."""
    from carto.framework.evaluation.difference_histogram import DifferenceHistogram

    steps = []
    for (i, j), box in _overlaps(sources, grid).items():
        histogram = DifferenceHistogram()
        for window in box.tiles(settings.tile_px):
            a = read_window(sources[i], grid, window, resampling=settings.resampling, geoid=geoid)
            b = read_window(sources[j], grid, window, resampling=settings.resampling, geoid=geoid)
            both = np.isfinite(a) & np.isfinite(b)
            histogram.add(b[both] - a[both])
            if advance is not None:
                advance()
        if histogram.count:
            stats = histogram.statistics()
            steps.append(SeamStep(i, j, stats["median_m"], stats["nmad_m"], histogram.count))
    return steps


def seam_windows(sources: Sequence[RasterSource], grid: MosaicGrid, tile_px: int) -> int:
    """How many windows :func:`seam_steps` reads (for a progress bar)."""
    return sum(len(box.tiles(tile_px)) for box in _overlaps(sources, grid).values())


def step_offsets(steps: Sequence[SeamStep], n_sources: int, held: int | None = None) -> FloatArray:
    """One height offset per source (m, added to it) that cancels the seams' steps in the
    least squares sense, each step weighted by the square root of its pixels; ``held`` (or,
    in a group of sources joined by seams without it, the group's first source) is held
    at 0."""
    offsets = np.zeros(n_sources)
    if not steps:
        return offsets
    groups = _groups(steps, n_sources)
    rows, rhs = [], []
    for step in steps:  # o_second - o_first = -step
        row = np.zeros(n_sources)
        row[step.second], row[step.first] = 1.0, -1.0
        weight = np.sqrt(step.pixels)
        rows.append(weight * row)
        rhs.append(-weight * step.median_m)
    for group in groups:  # the group's first source held
        row = np.zeros(n_sources)
        row[held if held in group else min(group)] = 1e6
        rows.append(row)
        rhs.append(0.0)
    solution, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    joined = sorted(set().union(*groups))
    offsets[joined] = solution[joined]
    return offsets


def _groups(steps: Sequence[SeamStep], n_sources: int) -> list[set[int]]:
    parent = list(range(n_sources))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for step in steps:
        parent[root(step.second)] = root(step.first)
    members: dict[int, set[int]] = {}
    for step in steps:
        for k in (step.first, step.second):
            members.setdefault(root(k), set()).add(k)
    return list(members.values())


def write_mosaic(
    sources: Sequence[RasterSource],
    grid: MosaicGrid,
    path: str | Path,
    settings: MosaicSettings,
    *,
    offsets_m: Sequence[float] | None = None,
    geoid: Any = None,
    vertical: str | None = None,
    counts_path: str | Path | None = None,
    advance: Callable[[], None] | None = None,
) -> None:
    """Write the mosaic of ``sources`` on ``grid`` to the COG ``path``, tile by tile (see
    the module docstring); every band of the sources, float32, NaN = no data.

    Args:
        offsets_m: a constant added to each source's values (DEM step correction).
        geoid: brings geoid heights to the ellipsoid while reading.
        vertical: the heights' vertical reference (None for images).
        counts_path: also write how many sources cover each pixel (uint16 COG) there.
        advance: called after each tile (progress).
    """
    from carto.framework.raster.cog import cog_writer

    offsets = np.zeros(len(sources)) if offsets_m is None else np.asarray(offsets_m, float)
    profile = grid.profile(sources[0].count, "float32", float("nan"))
    boxes = _footprints(sources, grid)
    descriptions = sources[0].descriptions
    with cog_writer(path, profile, what="mosaic", vertical=vertical) as dst:
        counts_writer = _counts_writer(counts_path, grid)
        with counts_writer as counts_dst:
            for window in grid.windows(settings.tile_px):
                for band in range(1, sources[0].count + 1):
                    blended, count = _tile(
                        sources, boxes, grid, window, band, settings, offsets, geoid
                    )
                    dst.write(blended.astype(np.float32), band, window=_rio(window))
                    if counts_dst is not None and band == 1:
                        counts_dst.write(count.astype(np.uint16), 1, window=_rio(window))
                if advance is not None:
                    advance()
            for k, text in enumerate(descriptions, 1):
                if text:
                    dst.set_band_description(k, text)


def _tile(
    sources: Sequence[RasterSource],
    boxes: Sequence[GridWindow | None],
    grid: MosaicGrid,
    window: GridWindow,
    band: int,
    settings: MosaicSettings,
    offsets: FloatArray,
    geoid: Any,
) -> tuple[FloatArray, FloatArray]:
    """The blended values of one tile, read with a halo of the feather width."""
    outer = window.grown(settings.feather_px, grid.height, grid.width)
    inner = window.inner(outer)
    values = []
    for source, box, offset in zip(sources, boxes, offsets, strict=True):
        if box is None or not _meets(box, outer):
            continue
        v = read_window(source, grid, outer, band=band, resampling=settings.resampling, geoid=geoid)
        values.append(v + offset)
    if not values:
        empty = np.full((window.n_rows, window.n_cols), np.nan)
        return empty, np.zeros_like(empty)
    blended, count = blend_window(values, settings.feather_px)
    return blended[inner], count[inner]


def _meets(a: GridWindow, b: GridWindow) -> bool:
    return (
        a.row0 < b.row0 + b.n_rows
        and b.row0 < a.row0 + a.n_rows
        and a.col0 < b.col0 + b.n_cols
        and b.col0 < a.col0 + a.n_cols
    )


def _counts_writer(path: str | Path | None, grid: MosaicGrid) -> Any:
    import contextlib

    from carto.framework.raster.cog import cog_writer

    if path is None:
        return contextlib.nullcontext(None)
    profile = grid.profile(1, "uint16", None)
    return cog_writer(path, profile, overview_resampling="nearest", what="mosaic counts")


def _rio(window: GridWindow) -> Any:
    from rasterio.windows import Window

    return Window(window.col0, window.row0, window.n_cols, window.n_rows)
