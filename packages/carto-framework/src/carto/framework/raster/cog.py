"""Cloud-optimised GeoTIFF output: what users open in QGIS, serve over HTTP or read by
windows from object storage.

:func:`cog_writer` hands out an ordinary tiled GeoTIFF to write (window by window, in a
temporary file beside the destination); when the block ends, GDAL's COG driver copies it
into the destination: 256 x 256 internal tiles, DEFLATE with the predictor that suits the
data type, overviews down to one tile (averaged, or nearest for flags), the header and the
overviews before the full-resolution tiles. Metadata tags, band descriptions and nodata
are carried over. The destination appears whole or not at all
(:func:`~carto.framework.files.atomic.atomic_output`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from carto.framework.errors import InputError, OutputError
from carto.framework.files.atomic import atomic_output
from carto.framework.raster.gdal_errors import gdal_cause

__all__ = ["COG_BLOCK_PX", "cog_writer"]

COG_BLOCK_PX = 256
"""Side of the internal tiles (and of the smallest overview), pixels."""

OVERVIEW_RESAMPLING = ("average", "nearest", "bilinear", "mode")


@contextlib.contextmanager
def cog_writer(
    path: str | os.PathLike[str],
    profile: Mapping[str, Any],
    *,
    overview_resampling: str = "average",
    what: str = "raster",
    vertical: str | None = None,
) -> Iterator[Any]:
    """A rasterio dataset open for writing; ``path`` becomes a COG of it when the block ends
    without an error (see the module docstring).

    Args:
        path: the COG to write.
        profile: rasterio creation profile (``width``, ``height``, ``count``, ``dtype``,
            ``crs``, ``transform``, ``nodata``); driver, tiling and compression are set
            here.
        overview_resampling: ``"average"`` (images, heights), ``"nearest"`` (flags,
            classes), ``"bilinear"`` or ``"mode"``.
        what: what the file is, for the error message (``"cannot write DEM to ..."``).
        vertical: for heights, their vertical reference (``"ellipsoid"``,
            ``"geoid:EGM96"``...): the CRS gets its vertical part
            (:func:`~carto.framework.raster.vertical_reference.geotiff_crs`: a projected
            CRS with ellipsoidal heights is compound in the keys and 3-D in a
            ``.aux.xml`` sidecar written beside ``path``), the ``VERTICAL_REFERENCE`` tag
            names it and the bands' unit is metres. A sidecar of an earlier file at
            ``path`` is removed (its CRS would override the new file's keys).

    Raises:
        OutputError: the file cannot be written (full disk, unwritable folder).
        InputError: a bad resampling name.
    """
    from rasterio.errors import RasterioError

    if overview_resampling not in OVERVIEW_RESAMPLING:
        raise InputError(
            f"overview resampling {overview_resampling!r}: use one of {OVERVIEW_RESAMPLING}"
        )
    path = Path(path)
    profile = dict(profile)
    sidecar = None
    if vertical is not None:
        from rasterio.crs import CRS as RioCRS

        from carto.framework.raster.vertical_reference import (
            VERTICAL_TAG,
            geotiff_crs,
            vertical_tag,
        )

        keys, sidecar = geotiff_crs(profile["crs"].to_wkt(), vertical)
        profile["crs"] = RioCRS.from_wkt(keys.to_wkt())
    try:
        with _staged_cog(path, profile, overview_resampling, what) as dst:
            yield dst
            if vertical is not None:
                dst.update_tags(**{VERTICAL_TAG: vertical_tag(vertical)})
                dst.units = ("metre",) * dst.count
    except (RasterioError, OSError) as exc:
        raise OutputError(f"cannot write {what} {path}: {gdal_cause(exc)}") from exc
    _write_sidecar(path, sidecar, what)


def _write_sidecar(path: Path, crs: Any, what: str) -> None:
    """The ``.aux.xml`` of ``path`` holding ``crs`` (GDAL's own sidecar format, read before
    the GeoTIFF keys), or none (an earlier one removed) when ``crs`` is None."""
    from xml.sax.saxutils import escape

    aux = Path(f"{path}.aux.xml")
    if crs is None:
        try:
            aux.unlink(missing_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot remove the stale {aux}: {exc.strerror or exc}") from exc
        return
    order = ",".join(str(k + 1) for k in range(len(crs.axis_info)))
    text = (
        "<PAMDataset>\n"
        f'  <SRS dataAxisToSRSAxisMapping="{order}">{escape(crs.to_wkt())}</SRS>\n'
        "</PAMDataset>\n"
    )
    with atomic_output(aux, f"{what} CRS sidecar") as tmp:
        tmp.write_text(text, encoding="utf-8")


@contextlib.contextmanager
def _staged_cog(
    path: Path, profile: Mapping[str, Any], overview_resampling: str, what: str
) -> Iterator[Any]:
    import rasterio
    import rasterio.shutil

    staging_profile = {
        **profile,
        "driver": "GTiff",
        "tiled": True,
        "blockxsize": COG_BLOCK_PX,
        "blockysize": COG_BLOCK_PX,
        "BIGTIFF": "IF_SAFER",
    }
    for key in ("compress", "predictor", "zlevel"):
        staging_profile.pop(key, None)
    with atomic_output(path, what) as final:
        staging = final.with_name(f"{final.stem}.staging.tif")
        try:
            with rasterio.open(staging, "w", **staging_profile) as dst:
                yield dst
            rasterio.shutil.copy(
                staging,
                final,
                driver="COG",
                COMPRESS="DEFLATE",
                PREDICTOR="YES",
                BLOCKSIZE=COG_BLOCK_PX,
                OVERVIEWS="AUTO",
                RESAMPLING=overview_resampling.upper(),
                BIGTIFF="IF_SAFER",
                NUM_THREADS="ALL_CPUS",
            )
        finally:
            staging.unlink(missing_ok=True)
            Path(f"{staging}.aux.xml").unlink(missing_ok=True)
