"""What a raster file says of the heights it holds, checked before it is read as a DEM: its
band (one, or one named), its unit (metres), carto's own product tag (a DEM, not an
ortho-image or a quality layer) and its vertical reference (a tag, an SRTM tile or a compound
CRS; :func:`states_vertical` tells a file that says none, read as ellipsoidal)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from carto.framework.errors import InputError
from carto.framework.raster.vertical_reference import (
    EGM96,
    ELLIPSOID,
    VERTICAL_TAG,
    normalise_vertical,
    split_vertical,
)

MIN_DEM_POSTS = 2
"""A DEM needs at least 2 x 2 posts: bilinear sampling and gradients need two per axis."""


HEIGHT_UNITS = ("m", "metre", "meter", "metres", "meters")
"""Band units (GDAL's ``units``) of heights in metres; a band with another stated unit (feet,
or a carto product's correlation scores) is not a DEM of Carto's."""


def check_heights_band(ds: Any, band: int, path: Path) -> None:
    """Refuse a raster that says it is not a DEM in metres: a carto ortho-image or quality
    layer (tag ``CARTO_PRODUCT``), or a band whose stated unit is not metres. An outside
    probe evaluated ortho-images and quality layers as DEMs (issue 31)."""
    product = ds.tags().get("CARTO_PRODUCT")
    if product not in (None, "dem"):
        raise InputError(
            f"DEM {path}: a carto {product} raster (tag CARTO_PRODUCT), not a DEM; give dem.tif"
        )
    unit = (ds.units[band - 1] or "").strip()
    if unit and unit.lower() not in HEIGHT_UNITS:
        raise InputError(
            f"DEM {path}: band {band} is in {unit!r}, not metres (field units); convert the "
            "heights to metres (e.g. gdal_calc.py), or clear the unit if it is wrong"
        )


def states_vertical(path: str | os.PathLike[str]) -> bool:
    """Whether a raster says what its heights are above (a ``VERTICAL_REFERENCE`` tag, the
    vertical part of a compound CRS, or an SRTM tile, whose heights are EGM96's): one that
    does not is read as ellipsoidal (the Carto convention), which a geoid-height DEM saved
    as a plain GeoTIFF is not (tens of metres off)."""
    import rasterio

    with rasterio.open(path) as ds:
        return dataset_states_vertical(ds)


def dataset_states_vertical(ds: Any) -> bool:
    """:func:`states_vertical` of an open rasterio dataset."""
    import pyproj

    if ds.tags().get(VERTICAL_TAG) or ds.driver == "SRTMHGT":
        return True
    return ds.crs is not None and split_vertical(pyproj.CRS.from_user_input(ds.crs))[1] is not None


def check_dem_file(ds: Any, band: int | None, path: Path) -> int:
    """The band of heights of an open raster (``band``, else its only one), or an
    InputError: no CRS or georeferencing, several bands and none named, a band that is not
    heights in metres (:func:`check_heights_band`), too few posts."""
    if ds.crs is None:
        raise InputError(f"DEM {path}: no CRS (field crs)")
    if ds.transform.is_identity:
        raise InputError(f"DEM {path}: no georeferencing (field transform)")
    if band is None and ds.count > 1:
        names = ", ".join(d or f"band {k}" for k, d in enumerate(ds.descriptions, 1))
        raise InputError(f"DEM {path}: {ds.count} bands ({names}); a DEM is one band of heights")
    band = 1 if band is None else band
    if not 1 <= band <= ds.count:
        raise InputError(f"DEM {path}: band {band} does not exist ({ds.count} bands)")
    check_heights_band(ds, band, path)
    if min(ds.width, ds.height) < MIN_DEM_POSTS:
        raise InputError(
            f"DEM {path}: {ds.width} x {ds.height} pixels; a DEM needs at least "
            f"{MIN_DEM_POSTS} x {MIN_DEM_POSTS} posts"
        )
    return band


def vertical_of(ds: Any, vertical: str | None, file_vertical: str | None, path: Path) -> str:
    """What an open raster's heights are above: ``vertical`` when given, else its
    ``VERTICAL_REFERENCE`` tag, EGM96 for an SRTM tile, the vertical part of its compound
    CRS (``file_vertical``), else the ellipsoid (the Carto convention)."""
    if vertical is not None:
        return normalise_vertical(vertical)
    tag = ds.tags().get(VERTICAL_TAG)
    if tag:
        try:
            return normalise_vertical(tag)
        except InputError as exc:
            raise InputError(f"DEM {path}: tag {VERTICAL_TAG}: {exc}") from exc
    if ds.driver == "SRTMHGT":
        return EGM96
    return file_vertical or ELLIPSOID
