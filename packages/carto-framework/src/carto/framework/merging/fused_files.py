"""The fusion of pairs' DEM folders into one DEM folder, tile by tile.

Each pair's folder holds ``dem.tif`` and, from generators that give them, the ``sigma_m``
band of ``quality.tif`` (predicted height sigma) and the ``filled`` band of
``quality_flags.tif``. :func:`fuse_dem_folders` reads them on the union grid of the pairs'
DEMs window by window (:func:`~carto.framework.merging.grid.read_window`), fuses every window
(:func:`~carto.framework.merging.fusion.fuse_heights`; each pair's weight ramps up over
``feather_posts`` from the edge of its heights, read with that halo) and writes:

- ``dem.tif``: the fused heights (the pairs' vertical reference);
- ``quality.tif``: ``sigma_m`` (fused height sigma) and ``spread_m`` (max - min of the pairs'
  heights kept);
- ``quality_counts.tif``: ``pairs`` (pairs whose measured height was kept);
- ``quality_flags.tif``: ``filled`` (no pair measured the node).

A pair without a sigma layer gets :data:`DEFAULT_SIGMA_M` everywhere; without a filled layer,
every height it has counts as measured.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.errors import InputError
from carto.framework.merging.fusion import FusedHeights, FusionSettings, fuse_heights
from carto.framework.merging.grid import GridWindow, MosaicGrid, read_window, union_grid
from carto.framework.merging.mosaic import feather_weights
from carto.framework.merging.sources import RasterSource, check_together, open_sources

__all__ = ["DEFAULT_SIGMA_M", "HeightCorrection", "PairLayers", "fuse_dem_folders", "pair_layers"]

HeightCorrection = Callable[[MosaicGrid, GridWindow, np.ndarray], np.ndarray]
"""A pair's height error on a window of the fusion's grid, from its heights there (m; the
fusion subtracts it), e.g. its views' along-track errors
(:class:`~carto.framework.workflows.view_jitter.PairHeightCorrection`)."""

DEFAULT_SIGMA_M = 1.0
"""The sigma of a pair's heights when its generator gives none (equal weights)."""


@attrs.frozen
class PairLayers:
    """One pair's DEM and, when present, its sigma and filled bands (file, band)."""

    dem: RasterSource
    sigma: tuple[RasterSource, int] | None
    filled: tuple[RasterSource, int] | None


def _band(folder: Path, name: str, description: str) -> tuple[RasterSource, int] | None:
    path = folder / name
    if not path.is_file():
        return None
    (source,) = open_sources([path])
    if description not in source.descriptions:
        return None
    return source, source.descriptions.index(description) + 1


def pair_layers(folder: Path) -> PairLayers:
    """The layers of one pair's DEM folder.

    Raises:
        InputError: the folder has no ``dem.tif``.
    """
    path = folder / "dem.tif"
    if not path.is_file():
        raise InputError(f"{folder}: no dem.tif")
    (dem,) = open_sources([path])
    return PairLayers(
        dem,
        _band(folder, "quality.tif", "sigma_m"),
        _band(folder, "quality_flags.tif", "filled"),
    )


def _feathered(sigma: np.ndarray, has: np.ndarray, feather_posts: int) -> np.ndarray:
    """``sigma`` divided by the square root of the pair's edge ramp
    (:func:`~carto.framework.merging.mosaic.feather_weights`): its weight ``1/sigma^2``
    times the ramp."""
    if feather_posts <= 0:
        return sigma
    ramp = feather_weights(has, feather_posts)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ramp > 0, sigma / np.sqrt(ramp), np.nan)


def _window_stack(
    pairs: Sequence[PairLayers],
    grid: MosaicGrid,
    window: GridWindow,
    feather_posts: int,
    offsets_m: np.ndarray,
    corrections: Sequence[HeightCorrection | None],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    heights, sigmas, measured = [], [], []
    for pair, offset, correction in zip(pairs, offsets_m, corrections, strict=True):
        h = read_window(pair.dem, grid, window)
        if correction is not None:
            h = h - correction(grid, window, h)
        h = h + offset
        if pair.sigma is not None:
            s = read_window(pair.sigma[0], grid, window, band=pair.sigma[1])
        else:
            s = np.full(h.shape, DEFAULT_SIGMA_M)
        if pair.filled is not None:
            flag = read_window(
                pair.filled[0], grid, window, band=pair.filled[1], resampling="nearest"
            )
            m = np.isfinite(h) & ~(flag >= 0.5)
        else:
            m = np.isfinite(h)
        heights.append(h)
        sigmas.append(_feathered(s, np.isfinite(h), feather_posts))
        measured.append(m)
    return np.stack(heights), np.stack(sigmas), np.stack(measured)


@attrs.frozen
class _Writers:
    dem: Any
    quality: Any
    counts: Any
    flags: Any

    @classmethod
    def opened(cls, stack: Any, out: Path, grid: MosaicGrid, vertical: Any) -> _Writers:
        """The COG writers of the fused DEM's files in ``out``, entered into ``stack`` (an
        :class:`contextlib.ExitStack`)."""
        from carto.framework.raster.cog import cog_writer

        def writer(name: str, bands: int, dtype: str, nodata: float, **options: Any) -> Any:
            profile = grid.profile(bands, dtype, nodata)
            return stack.enter_context(cog_writer(out / name, profile, **options))

        nearest = {"overview_resampling": "nearest"}  # counts and flags: no averaging
        return cls(
            writer("dem.tif", 1, "float32", np.nan, what="DEM", vertical=vertical),
            writer("quality.tif", 2, "float32", np.nan, what="quality layers"),
            writer("quality_counts.tif", 1, "uint16", 65535, what="quality counts", **nearest),
            writer("quality_flags.tif", 1, "uint8", 255, what="quality flags", **nearest),
        )

    def write(self, window: GridWindow, fused: FusedHeights) -> None:
        from rasterio.windows import Window

        w = Window(window.col0, window.row0, window.n_cols, window.n_rows)
        self.dem.write(fused.height_m.astype(np.float32), 1, window=w)
        self.quality.write(fused.sigma_m.astype(np.float32), 1, window=w)
        self.quality.write(fused.spread_m.astype(np.float32), 2, window=w)
        has = np.isfinite(fused.height_m)
        self.counts.write(np.where(has, fused.count, 65535).astype(np.uint16), 1, window=w)
        flags = np.where(has, fused.filled, 255).astype(np.uint8)
        self.flags.write(flags, 1, window=w)


def fuse_dem_folders(
    folders: Sequence[Path],
    out: Path,
    settings: FusionSettings,
    *,
    tile_px: int = 1024,
    offsets_m: Sequence[float] | None = None,
    corrections: Sequence[HeightCorrection | None] | None = None,
    advance: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Fuse the pairs' DEM folders into ``out`` (see the module docstring), each pair's
    heights less its correction (``corrections``: per pair, None or a
    :data:`HeightCorrection`) plus its ``offsets_m`` (default 0: see :func:`pair_offsets`);
    returns the fused DEM's figures for the report (grid size, share of nodes by number of
    pairs)."""
    import contextlib

    pairs = [pair_layers(Path(f)) for f in folders]
    check_together([p.dem for p in pairs])
    grid = union_grid([p.dem for p in pairs])
    vertical = pairs[0].dem.vertical
    offsets = np.zeros(len(pairs)) if offsets_m is None else np.asarray(offsets_m, float)
    fixes = [None] * len(pairs) if corrections is None else list(corrections)
    tally = np.zeros(len(pairs) + 2, np.int64)  # nodes by pairs kept; last: filled
    with contextlib.ExitStack() as stack:
        writers = _Writers.opened(stack, out, grid, vertical)
        for window in grid.windows(tile_px):
            outer = window.grown(settings.feather_posts, grid.height, grid.width)
            stack = _window_stack(pairs, grid, outer, settings.feather_posts, offsets, fixes)
            fused = _cropped(fuse_heights(*stack, settings), window.inner(outer))
            writers.write(window, fused)
            _count(tally, fused)
            if advance is not None:
                advance()
        _describe(writers)
    return _summary(grid, tally, vertical)


def _cropped(fused: FusedHeights, inner: tuple[slice, slice]) -> FusedHeights:
    return FusedHeights(*(np.asarray(v)[inner] for v in attrs.astuple(fused, recurse=False)))


def _count(tally: np.ndarray, fused: FusedHeights) -> None:
    has = np.isfinite(fused.height_m)
    tally[: len(tally) - 1] += np.bincount(
        fused.count[has & ~fused.filled], minlength=len(tally) - 1
    )[: len(tally) - 1]
    tally[-1] += int((has & fused.filled).sum())


def _describe(writers: _Writers) -> None:
    writers.dem.set_band_description(1, "height")
    writers.dem.update_tags(CARTO_PRODUCT="dem", CARTO_GENERATOR="fusion")
    writers.quality.set_band_description(1, "sigma_m")
    writers.quality.set_band_description(2, "spread_m")
    writers.quality.update_tags(
        BAND_1="predicted standard deviation of the fused height, m",
        BAND_2="max - min of the pairs' heights kept, m",
        CARTO_PRODUCT="quality",
    )
    writers.counts.set_band_description(1, "pairs")
    writers.counts.update_tags(
        BAND_1="pairs whose measured height was kept", CARTO_PRODUCT="quality"
    )
    writers.flags.set_band_description(1, "filled")
    writers.flags.update_tags(
        BAND_1="1: no pair measured the node (a pair's filled height), 0: measured",
        CARTO_PRODUCT="quality",
    )


def _summary(grid: MosaicGrid, tally: np.ndarray, vertical: str | None) -> dict[str, Any]:
    total = int(tally.sum())
    by_pairs = {str(k): int(n) for k, n in enumerate(tally[:-1]) if k > 0}
    return {
        "grid": {"width": grid.width, "height": grid.height, "posting": abs(grid.transform.a)},
        "vertical_reference": vertical,
        "nodes": total,
        "nodes_by_pairs": by_pairs,
        "nodes_filled": int(tally[-1]),
        "measured_fraction": (total - int(tally[-1])) / total if total else None,
    }
