"""What heights are measured from, in Carto's words and in a file's CRS.

Carto names a vertical reference ``"ellipsoid"`` (heights above the WGS84 ellipsoid, what
sensors take) or ``"geoid:<NAME>"`` (orthometric heights above a geoid model, e.g.
``"geoid:EGM96"`` for SRTM). A raster of heights carries it twice, so that every reader
knows it:

- in its CRS (:func:`with_vertical`), which GDAL, QGIS and PROJ read without knowing Carto.
  Geoid heights make a compound CRS: EGM96, EGM2008 and EGM84 heights are the EPSG vertical
  CRSs 5773, 3855 and 5798. Ellipsoidal heights make the horizontal CRS three-dimensional
  (``CRS.to_3d()``: EPSG:4979 for longitude and latitude, a projected CRS on EPSG:4979's
  base): PROJ then finds "WGS 84 to EGM96 height (1)" (its geoid grid) between a Carto DEM
  and EGM96 heights, where a compound CRS with a user-defined "WGS 84 ellipsoidal height"
  (as Carto wrote until issue 34) left it a ballpark transformation that ignores the geoid.
  GeoTIFF keys cannot hold a projected 3-D CRS (GDAL keeps such a CRS in a ``.aux.xml``
  sidecar only: OSGeo/gdal#9741), so a GeoTIFF of ellipsoidal heights on a projected CRS
  carries the compound CRS in its keys, which any reader understands, and the 3-D CRS in
  its sidecar, which GDAL reads first (:func:`geotiff_crs`); EPSG:4979 fits in the keys;
- in the ``VERTICAL_REFERENCE`` metadata tag (``"ellipsoid WGS84"``, ``"geoid EGM96"``), as
  earlier Carto files did.

:func:`split_vertical` gives a file's CRS back as its horizontal part and the Carto name of
its vertical part.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from carto.framework.errors import InputError

if TYPE_CHECKING:
    import pyproj

__all__ = [
    "EGM96",
    "ELLIPSOID",
    "VERTICAL_TAG",
    "geotiff_crs",
    "normalise_vertical",
    "split_vertical",
    "vertical_tag",
    "with_vertical",
]

ELLIPSOID = "ellipsoid"
"""Vertical reference of ellipsoidal heights (WGS84): the Carto convention."""
EGM96 = "geoid:EGM96"
"""Vertical reference of EGM96 orthometric heights (SRTM)."""
VERTICAL_TAG = "VERTICAL_REFERENCE"
"""GeoTIFF metadata tag holding the vertical reference of a written DEM."""

GEOID_EPSG = {"EGM96": 5773, "EGM2008": 3855, "EGM84": 5798}
"""EPSG codes of the vertical CRSs of the geoid models users meet."""

ELLIPSOIDAL_HEIGHT_NAME = "WGS 84 ellipsoidal height"

_ELLIPSOIDAL_HEIGHT_WKT = (
    f'VERTCRS["{ELLIPSOIDAL_HEIGHT_NAME}",VDATUM["World Geodetic System 1984"],'
    'CS[vertical,1],AXIS["ellipsoidal height (h)",up,LENGTHUNIT["metre",1]]]'
)


def normalise_vertical(value: str) -> str:
    """Canonical vertical reference: ``"ellipsoid"`` or ``"geoid:<NAME>"`` (upper-case name).

    Accepts ``"ellipsoid"``, ``"ellipsoid WGS84"``, ``"WGS84"``, ``"geoid:EGM96"``,
    ``"geoid EGM96"``, ``"EGM96"``, ``"EGM2008"`` (case-insensitive).
    """
    words = str(value).replace(":", " ").split()
    lowered = [w.lower() for w in words]
    if lowered in (["ellipsoid"], ["ellipsoid", "wgs84"], ["wgs84"]):
        return ELLIPSOID
    if len(words) == 2 and lowered[0] == "geoid":
        return f"geoid:{words[1].upper()}"
    if len(words) == 1 and lowered[0].startswith("egm"):
        return f"geoid:{words[0].upper()}"
    raise InputError(
        f"vertical reference {value!r} not understood; use 'ellipsoid' (WGS84) or "
        "'geoid:<NAME>' such as 'geoid:EGM96'"
    )


def vertical_tag(vertical: str) -> str:
    """The ``VERTICAL_REFERENCE`` tag of a vertical reference."""
    vertical = normalise_vertical(vertical)
    return "ellipsoid WGS84" if vertical == ELLIPSOID else vertical.replace(":", " ")


def vertical_crs(vertical: str) -> pyproj.CRS:
    """The vertical CRS of a vertical reference (see the module docstring); a geoid model
    without an EPSG code gets a vertical CRS of its name ("<NAME> height")."""
    import pyproj

    vertical = normalise_vertical(vertical)
    if vertical == ELLIPSOID:
        return pyproj.CRS.from_wkt(_ELLIPSOIDAL_HEIGHT_WKT)
    model = vertical.split(":", 1)[1]
    if model in GEOID_EPSG:
        return pyproj.CRS.from_epsg(GEOID_EPSG[model])
    return pyproj.CRS.from_wkt(
        f'VERTCRS["{model} height",VDATUM["{model} geoid"],'
        'CS[vertical,1],AXIS["gravity-related height (H)",up,LENGTHUNIT["metre",1]]]'
    )


def with_vertical(horizontal: Any, vertical: str) -> pyproj.CRS:
    """The CRS of heights above ``vertical`` on a horizontal CRS (anything pyproj reads; a
    compound or 3-D one is reduced to its horizontal part first): the 3-D CRS for ellipsoidal
    heights, the compound CRS for geoid heights (see the module docstring)."""
    import pyproj
    from pyproj.crs import CompoundCRS

    crs = pyproj.CRS.from_user_input(horizontal)
    crs = split_vertical(crs)[0]
    if normalise_vertical(vertical) == ELLIPSOID:
        return crs.to_3d()
    vert = vertical_crs(vertical)
    return pyproj.CRS.from_wkt(CompoundCRS(f"{crs.name} + {vert.name}", [crs, vert]).to_wkt())


def geotiff_crs(horizontal: Any, vertical: str) -> tuple[pyproj.CRS, pyproj.CRS | None]:
    """The CRS a GeoTIFF of heights above ``vertical`` carries in its keys, and the one its
    ``.aux.xml`` sidecar carries (None: the keys hold :func:`with_vertical` whole). A
    projected CRS with ellipsoidal heights is the one case GeoTIFF keys cannot encode (see
    the module docstring): its keys get the compound CRS of a user-defined "WGS 84
    ellipsoidal height", its sidecar the 3-D CRS."""
    import pyproj
    from pyproj.crs import CompoundCRS

    crs = with_vertical(horizontal, vertical)
    if not (crs.is_projected and normalise_vertical(vertical) == ELLIPSOID):
        return crs, None
    flat, vert = crs.to_2d(), vertical_crs(ELLIPSOID)
    keys = pyproj.CRS.from_wkt(CompoundCRS(f"{flat.name} + {vert.name}", [flat, vert]).to_wkt())
    return keys, crs


def split_vertical(crs: pyproj.CRS) -> tuple[pyproj.CRS, str | None]:
    """Horizontal part of a CRS and the vertical reference of its vertical part, if any
    (``None``: a 2-D CRS, or a vertical CRS Carto cannot name)."""
    if crs.is_compound:
        horizontal, vert = crs.sub_crs_list[0], crs.sub_crs_list[1]
        name = vert.name.upper().replace(" ", "")
        if "ELLIPSOIDALHEIGHT" in name:
            return horizontal, ELLIPSOID
        for model in ("EGM2008", "EGM96", "EGM84"):
            if model in name:
                return horizontal, f"geoid:{model}"
        return horizontal, None
    if len(crs.axis_info) == 3:  # EPSG:4979, or a projected CRS made 3-D: ellipsoidal heights
        return crs.to_2d(), ELLIPSOID
    return crs, None
