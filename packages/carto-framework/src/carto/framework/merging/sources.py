"""The rasters a mosaic or a fusion joins, read once at the boundary and checked together.

:func:`open_sources` reads every file's header (never its pixels): CRS, grid, bands, nodata
and, for heights, the vertical reference (:func:`~carto.framework.raster.dem_file.vertical_of`).
:func:`check_together` refuses what cannot be joined as it is, one line naming the files and
the field: rasters in different horizontal CRSs (unless a target CRS is given to warp them
to), heights above different references (unless a geoid is given to bring them all to the
ellipsoid), heights mixed with images, different band counts, rotated grids.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import attrs
from affine import Affine

from carto.framework.errors import InputError

__all__ = ["RasterSource", "check_together", "open_sources"]


@attrs.frozen
class RasterSource:
    """One input raster's header.

    Attributes:
        path: the file.
        crs_wkt: its horizontal CRS (the vertical part split off), WKT.
        transform: pixel corners to map coordinates.
        width, height: pixels.
        count: bands.
        nodata: the declared nodata value (None: NaN or none).
        vertical: the heights' vertical reference (``"ellipsoid"``, ``"geoid:EGM96"``) for a
            raster of heights, None for an image.
        descriptions: band descriptions.
    """

    path: Path
    crs_wkt: str
    transform: Affine
    width: int
    height: int
    count: int
    nodata: float | None
    vertical: str | None
    descriptions: tuple[str, ...]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) in the source's CRS."""
        t = self.transform
        xs = (t.c, t.c + t.a * self.width)
        ys = (t.f, t.f + t.e * self.height)
        return min(xs), min(ys), max(xs), max(ys)

    @property
    def resolution(self) -> tuple[float, float]:
        """(x, y) pixel size, positive, in CRS units."""
        return abs(self.transform.a), abs(self.transform.e)


def open_sources(paths: Sequence[str | os.PathLike[str]]) -> tuple[RasterSource, ...]:
    """Every raster's header (see the module docstring).

    Raises:
        InputError: a missing or unreadable file, one without a CRS or georeferencing.
    """
    return tuple(_open_one(Path(p)) for p in paths)


def _open_one(path: Path) -> RasterSource:
    import pyproj
    import rasterio
    from rasterio.errors import RasterioError

    from carto.framework.raster.dem_file import dataset_states_vertical, vertical_of
    from carto.framework.raster.gdal_errors import gdal_cause
    from carto.framework.raster.vertical_reference import split_vertical

    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with rasterio.open(path) as ds:
            if ds.crs is None or ds.transform.is_identity:
                raise InputError(f"{path}: no CRS or georeferencing (field crs/transform)")
            if ds.transform.b != 0 or ds.transform.d != 0:
                raise InputError(f"{path}: a rotated grid (field transform) cannot be joined")
            horizontal, file_vertical = split_vertical(pyproj.CRS.from_user_input(ds.crs))
            heights = dataset_states_vertical(ds) or _is_heights(ds)
            vertical = vertical_of(ds, None, file_vertical, path) if heights else None
            return RasterSource(
                path=path,
                crs_wkt=horizontal.to_wkt(),
                transform=ds.transform,
                width=ds.width,
                height=ds.height,
                count=ds.count,
                nodata=ds.nodata,
                vertical=vertical,
                descriptions=tuple(d or "" for d in ds.descriptions),
            )
    except RasterioError as exc:
        raise InputError(f"{path}: cannot read it: {gdal_cause(exc)}") from exc


def _is_heights(ds: Any) -> bool:
    """A one-band raster in metres is heights even without a vertical reference."""
    units = [u.lower() for u in ds.units if u]
    return ds.count == 1 and bool(units) and units[0] in ("m", "metre", "meter", "metres")


def check_together(
    sources: Sequence[RasterSource], *, target_crs: Any = None, geoid: Any = None
) -> None:
    """Refuse rasters that cannot be joined as they are (see the module docstring).

    Args:
        sources: the rasters.
        target_crs: the CRS they will be warped to (then their own CRSs may differ).
        geoid: the geoid that brings every height to the ellipsoid (then their vertical
            references may differ).
    """
    import pyproj

    if len(sources) < 1:
        raise InputError("nothing to join: give at least one raster")
    first = sources[0]
    for other in sources[1:]:
        if (first.vertical is None) != (other.vertical is None):
            raise InputError(
                f"{first.path} and {other.path}: one holds heights, the other an image"
            )
        if other.count != first.count:
            raise InputError(
                f"{first.path} has {first.count} band(s), {other.path} {other.count} (field count)"
            )
        same_crs = pyproj.CRS.from_wkt(other.crs_wkt).equals(pyproj.CRS.from_wkt(first.crs_wkt))
        if target_crs is None and not same_crs:
            raise InputError(
                f"{first.path} and {other.path} are in different CRSs (field crs): give "
                "--t_srs to warp them all to one"
            )
        if geoid is None and other.vertical != first.vertical:
            raise InputError(
                f"{first.path} heights are above {first.vertical}, {other.path} above "
                f"{other.vertical} (field vertical reference): give --geoid to bring them "
                "all to the ellipsoid"
            )
