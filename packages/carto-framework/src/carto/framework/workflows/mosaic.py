"""``carto mosaic``: DEMs or ortho-images of neighbouring swaths and scenes on one grid.

The request is checked once (:class:`MosaicRequest`); the sources' headers are read and
checked together (same CRS and vertical reference, or told how to reconcile them); the grid
covers them all; for DEMs the step at every seam is measured and, with ``align``, one
constant per source cancels it; then the mosaic is written tile by tile into a staged output
folder that appears whole or not at all:

- ``dem.tif`` (heights, the sources' vertical reference or the ellipsoid when a geoid
  reconciled them) or ``ortho.tif`` (images), a COG;
- ``mosaic_counts.tif``: how many sources cover each pixel (uint16);
- ``dem_hillshade.png`` for DEMs;
- ``report.json`` (``carto-mosaic-report``): sources, grid, seams before and after the
  correction, offsets applied.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.errors import InputError
from carto.framework.merging.grid import MosaicGrid, union_grid
from carto.framework.merging.mosaic import (
    MosaicSettings,
    SeamStep,
    seam_steps,
    seam_windows,
    step_offsets,
    write_mosaic,
)
from carto.framework.merging.sources import RasterSource, check_together, open_sources
from carto.framework.parallel.progress import stage_bar
from carto.framework.workflows.reporting import progress
from carto.framework.workflows.run_record import record_run, utc_now

__all__ = ["MosaicRequest", "mosaic_product"]


@attrs.frozen
class MosaicRequest:
    """What ``carto mosaic`` is asked to do.

    Attributes:
        sources: the rasters (two or more DEMs, or two or more images).
        out_dir: the output folder.
        settings: feather, tile size, resampling.
        align: correct the constant step between DEMs (the first one of each group of
            neighbours held).
        target_crs: warp every source to this CRS (any PROJ/EPSG string) instead of
            requiring one CRS.
        resolution: the mosaic's posting in CRS units (default: the finest source's).
        geoid: a geoid grid file that brings every source's heights to the ellipsoid
            (then their vertical references may differ).
        quiet: no progress on stderr.
    """

    sources: tuple[Path, ...] = attrs.field(converter=lambda v: tuple(Path(p) for p in v))
    out_dir: Path = attrs.field(converter=Path)
    settings: MosaicSettings = attrs.field(factory=MosaicSettings)
    align: bool = False
    target_crs: str | None = None
    resolution: float | None = attrs.field(default=None)
    geoid: Path | None = attrs.field(default=None, converter=attrs.converters.optional(Path))
    quiet: bool = False

    @sources.validator
    def _check_sources(self, _attr: object, value: tuple[Path, ...]) -> None:
        if len(value) < 2:
            raise InputError(f"mosaic: {len(value)} raster(s); give two or more")
        if len(set(p.resolve() for p in value)) < len(value):
            raise InputError("mosaic: a raster is given twice")

    @resolution.validator
    def _check_resolution(self, _attr: object, value: float | None) -> None:
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"mosaic --tr {value!r}: give a positive posting")


def _target_wkt(target_crs: str | None) -> str | None:
    if target_crs is None:
        return None
    import pyproj

    try:
        return pyproj.CRS.from_user_input(target_crs).to_wkt()
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"mosaic --t_srs {target_crs!r}: not a CRS PROJ knows ({exc})") from exc


def _geoid(path: Path | None) -> Any:
    if path is None:
        return None
    from carto.framework.raster.dem import Geoid

    return Geoid.open(path)


def mosaic_product(request: MosaicRequest) -> dict[str, Any]:
    """Run ``carto mosaic`` (see the module docstring); returns the report."""
    from carto.framework.files.staging import staged_folder

    sources = open_sources(request.sources)
    geoid = _geoid(request.geoid)
    target = _target_wkt(request.target_crs)
    check_together(sources, target_crs=target, geoid=geoid)
    grid = union_grid(sources, crs_wkt=target, resolution=request.resolution)
    started = utc_now()
    with staged_folder(request.out_dir, "mosaic", inputs=request.sources) as stage:
        report = _mosaic_into(stage, request, sources, grid, geoid)
        report = record_run(stage / "report.json", report, request.sources, started, "mosaic")
    return report


def _mosaic_into(
    out: Path, request: MosaicRequest, sources: Sequence[RasterSource], grid: MosaicGrid, geoid: Any
) -> dict[str, Any]:
    heights = sources[0].vertical is not None
    vertical = ("ellipsoid" if geoid is not None else sources[0].vertical) if heights else None
    steps = _seams(request, sources, grid, geoid) if heights else []
    offsets = step_offsets(steps, len(sources)) if request.align else np.zeros(len(sources))
    name = "dem.tif" if heights else "ortho.tif"
    tiles = len(grid.windows(request.settings.tile_px))
    size = f"{grid.width} x {grid.height} px, {tiles} tile(s)"
    progress("mosaic", f"writing {name}: {size}", request.quiet)
    with stage_bar(tiles, "mosaic", quiet=request.quiet) as bar:
        write_mosaic(
            sources,
            grid,
            out / name,
            request.settings,
            offsets_m=offsets,
            geoid=geoid,
            vertical=vertical,
            counts_path=out / "mosaic_counts.tif",
            advance=bar.advance,
        )
    files = {"mosaic": name, "counts": "mosaic_counts.tif"}
    if heights:
        from carto.framework.raster.quicklook import hillshade_png

        files["hillshade"] = hillshade_png(out / name, out / "dem_hillshade.png", "mosaic").name
    return _report(request, sources, grid, steps, offsets, vertical, files)


def _seams(
    request: MosaicRequest, sources: Sequence[RasterSource], grid: MosaicGrid, geoid: Any
) -> list[SeamStep]:
    total = seam_windows(sources, grid, request.settings.tile_px)
    progress("mosaic", f"measuring the seams: {total} window(s)", request.quiet)
    with stage_bar(total, "seams", quiet=request.quiet) as bar:
        return seam_steps(sources, grid, request.settings, geoid=geoid, advance=bar.advance)


def _report(
    request: MosaicRequest,
    sources: Sequence[RasterSource],
    grid: MosaicGrid,
    steps: Sequence[SeamStep],
    offsets: np.ndarray,
    vertical: str | None,
    files: dict[str, str],
) -> dict[str, Any]:
    seams = [
        {
            "first": str(sources[s.first].path),
            "second": str(sources[s.second].path),
            "median_step_m": s.median_m,
            "nmad_m": s.nmad_m,
            "pixels": s.pixels,
            "median_step_after_m": s.median_m + offsets[s.second] - offsets[s.first],
        }
        for s in steps
    ]
    return {
        "sources": [str(p.resolve()) for p in request.sources],
        "kind": "dem" if vertical is not None else "image",
        "vertical_reference": vertical,
        "settings": {**attrs.asdict(request.settings), "align": request.align},
        "grid": {
            "crs": grid.crs_wkt,
            "transform": list(grid.transform)[:6],
            "width": grid.width,
            "height": grid.height,
        },
        "seams": seams,
        "median_abs_step_m": float(np.median([abs(s["median_step_m"]) for s in seams]))
        if seams
        else None,
        "offsets_m": {str(s.path): float(o) for s, o in zip(sources, offsets, strict=True)},
        "files": files,
    }
