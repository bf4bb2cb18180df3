"""The ortho-images of a multi-view ``carto dem``: one per image on the fused DEM, at the
pairs' ortho posting, over the image's own footprint (:func:`image_window`), made tile by
tile as tasks of the command's engine (its worker processes, or a cluster) that each read the
fused DEM's rows under their tile from its file and write their tile: memory of a tile per
worker, not of the strip (a strip's fused DEM is 260 MB of heights: sent with every task, it
took the workers to 1.35 GB each)."""

from __future__ import annotations

import functools
import math
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor

__all__ = ["IMAGE_MARGIN_PX", "ORTHO_TILE_PX", "engine_options", "image_window", "orthos_on_fused"]

IMAGE_MARGIN_PX = 8
"""Pixels of the fused grid kept around an image's footprint in its ortho-image."""
ORTHO_TILE_PX = 2048
"""Side of the tiles an ortho-image on the fused DEM is made of, pixels."""


def engine_options(dem_options: Mapping[str, Any]) -> dict[str, Any]:
    """The engine arguments (``workers``, ``scheduler``, ``quiet``) among a DEM run's
    options, for :func:`~carto.framework.parallel.engine.open_engine`."""
    return {
        "workers": dem_options.get("workers"),
        "scheduler": dem_options.get("scheduler"),
        "quiet": bool(dem_options.get("quiet", False)),
    }


def orthos_on_fused(
    stage: Path,
    sensors: Mapping[str, Sensor],
    rasters: Mapping[str, Path],
    pair_ortho: Path,
    engine: Mapping[str, Any],
    quiet: bool,
) -> dict[str, str]:
    """One ortho-image per image of ``sensors`` (raw images ``rasters``) on the fused DEM
    ``stage / "dem.tif"``, at the posting of ``pair_ortho`` (a pair's ortho-image), written
    into ``stage`` as ``ortho_NAME.tif``; the files by key ``ortho_NAME``. Tiles run on an
    engine opened with ``engine`` (:func:`engine_options`)."""
    from carto.framework.imaging.ortho import write_ortho
    from carto.framework.imaging.preparation import prepared_sources
    from carto.framework.parallel.engine import open_engine
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows.dem import radiometry
    from carto.framework.workflows.reporting import progress

    dem = DEM.open(stage / "dem.tif")
    grid = _ortho_grid(dem, pair_ortho)
    work = stage / "work"
    files = {}
    with open_engine(**engine) as tiles:
        sources = prepared_sources(rasters, sensors, dem, folder=work / "prepared", engine=tiles)
        for name in sorted(sensors):
            progress("dem", f"ortho-image of {name} on the fused DEM", quiet)
            own = image_window(grid, sensors[name], dem)
            layer = _tiled_ortho(
                tiles, sources[name], sensors[name], own, stage / "dem.tif", work / "ortho" / name
            )
            files[f"ortho_{name}"] = write_ortho(
                stage / f"ortho_{name}.tif",
                layer,
                own,
                out_dtype=radiometry(rasters[name]),
                tags={"CARTO_PRODUCT": "ortho", "CARTO_IMAGE": name},
            ).name
    shutil.rmtree(work, ignore_errors=True)
    return files


def _ortho_grid(dem: Any, pair_ortho: Path) -> Any:
    """The fused DEM's extent at the posting of a pair's ortho-image."""
    import rasterio
    from affine import Affine

    from carto.framework.imaging.ortho_grid import OrthoGrid

    with rasterio.open(pair_ortho) as ds:
        step = abs(ds.transform.a)
    t = dem.transform
    rows = math.ceil(dem.shape[0] * abs(t.e) / step - 1e-9)
    cols = math.ceil(dem.shape[1] * abs(t.a) / step - 1e-9)
    return OrthoGrid(dem.crs, Affine(step, 0.0, t.c, 0.0, -step, t.f), (rows, cols))


def image_window(grid: Any, sensor: Sensor, dem: Any) -> Any:
    """The part of ``grid`` (pixels of the same lattice) that covers ``sensor``'s footprint
    on ``dem``, :data:`IMAGE_MARGIN_PX` around it: one image of a strip or of a paint-brush
    set sees a part of the fused DEM, and its ortho-image covers that part, not the whole
    strip (whose orthos would otherwise grow with the square of its length)."""
    from carto.framework.imaging.ortho_grid import footprint_box

    _, (left, bottom, right, top) = footprint_box(sensor, dem, crs=grid.crs)
    t, (rows, cols) = grid.transform, grid.shape
    c0 = max(0, math.floor((left - t.c) / t.a) - IMAGE_MARGIN_PX)
    c1 = min(cols, math.ceil((right - t.c) / t.a) + IMAGE_MARGIN_PX)
    r0 = max(0, math.floor((top - t.f) / t.e) - IMAGE_MARGIN_PX)
    r1 = min(rows, math.ceil((bottom - t.f) / t.e) + IMAGE_MARGIN_PX)
    if c1 <= c0 or r1 <= r0:
        raise InputError(f"image {getattr(sensor, 'name', '?')}: its footprint is off the DEM")
    return grid.window(r0, c0, r1 - r0, c1 - c0)


def _tiled_ortho(
    engine: Any, source: Any, sensor: Sensor, grid: Any, dem_file: Path, folder: Path
) -> Any:
    """The ortho-image of ``source`` on ``grid`` over the DEM in ``dem_file``, as tiles of
    :data:`ORTHO_TILE_PX`, each a task of ``engine`` that reads the DEM's rows under it
    and writes its tile into ``folder``."""
    from carto.framework.parallel.engine import TaskFailure
    from carto.framework.raster.tiled_layer import TiledLayer

    folder.mkdir(parents=True, exist_ok=True)
    rows, cols = grid.shape
    step = ORTHO_TILE_PX
    corners = [(r0, c0) for r0 in range(0, rows, step) for c0 in range(0, cols, step)]
    tasks = [
        functools.partial(
            _ortho_tile,
            source,
            sensor,
            grid.window(r0, c0, min(step, rows - r0), min(step, cols - c0)),
            dem_file,
            folder,
            (r0, c0),
        )
        for r0, c0 in corners
    ]
    name = getattr(sensor, "name", folder.name)
    keys = [f"tile {r},{c}" for r, c in corners]
    pieces = engine.run(tasks, desc=f"ortho-image of {name}", keys=keys)
    failed = [p for p in pieces if isinstance(p, TaskFailure)]
    if failed:
        raise InputError(
            f"ortho-image of {name}: {len(failed)} of {len(tasks)} tiles failed ({failed[0]})"
        )
    return TiledLayer.of(grid.shape, pieces)


DEM_MARGIN_PX = 32
"""Ortho-image pixels of DEM rows read beyond a tile's edges: the orthorectification computes
its mapping on a lattice of 16 pixels that may end past the tile, and samples the DEM
bilinearly there."""


def dem_rows_under(window: Any, dem_file: Path) -> tuple[int, int]:
    """The rows ``start, stop`` of the DEM in ``dem_file`` (north up, any CRS) under the grid
    ``window``, :data:`DEM_MARGIN_PX` beyond its edges."""
    import rasterio
    from rasterio.warp import transform_bounds

    w = window.transform
    margin = DEM_MARGIN_PX * abs(w.a)
    left, top = w.c - margin, w.f + margin
    right = w.c + w.a * window.shape[1] + margin
    bottom = w.f + w.e * window.shape[0] - margin
    with rasterio.open(dem_file) as ds:
        t, crs = ds.transform, ds.crs
    _, south, _, north = transform_bounds(window.crs, crs, left, bottom, right, top, densify_pts=21)
    return math.floor((north - t.f) / t.e) - 1, math.ceil((south - t.f) / t.e) + 2


def _ortho_tile(
    source: Any, sensor: Sensor, window: Any, dem_file: Path, folder: Path, corner: tuple[int, int]
) -> Any:
    """One tile of an ortho-image (a task): orthorectified on the DEM's rows under it (read
    from ``dem_file``, not the whole DEM in every task), written into ``folder``; its
    :class:`~carto.framework.raster.tiled_layer.TilePiece`."""
    from carto.framework.imaging.ortho import orthorectify
    from carto.framework.raster.dem import DEM
    from carto.framework.raster.tiled_layer import TilePiece, piece_path

    dem = DEM.open(dem_file, rows=dem_rows_under(window, dem_file))
    values = orthorectify(source, sensor, window, dem)
    path = piece_path(folder, *corner)
    np.savez(path, ortho=values)
    return TilePiece(path, "ortho", corner[0], corner[1], values.shape)
