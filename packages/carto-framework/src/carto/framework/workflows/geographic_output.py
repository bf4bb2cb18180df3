"""Geographic output of ``carto dem`` (``--t_srs EPSG:4326`` or ``EPSG:4979``, issue 34 item
4): the DEM generator works on a projected grid in metres (the UTM zone); its products are
then warped onto a longitude/latitude grid, as ``gdalwarp -t_srs EPSG:4326 -tr RES RES -tap``
would.

With a geographic ``--t_srs``, ``--tr``/``--posting`` and ``--te`` are in degrees, as in GDAL.
The generator's posting is the output's in metres along a meridian (1 degree ~ 110.6 km), so
the DEM is computed at least as finely as it is delivered. The grid is snapped to multiples of
the resolution (target-aligned: two runs share one grid). Heights and measures are resampled
bilinearly, counts and flags by nearest neighbour; each file is warped window by window
(:class:`rasterio.vrt.WarpedVRT`), so memory does not grow with the scene.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs

from carto.framework.errors import UsageError

__all__ = ["METRES_PER_DEGREE_LAT", "GeographicOutput", "geographic_output"]

METRES_PER_DEGREE_LAT = 110_574.0
"""Length of one degree of latitude near the equator (WGS84), metres: the generator's posting
for a resolution in degrees (110.6-111.7 km from equator to pole: never coarser)."""

DEFAULT_POSTING_M = 10.0
WINDOW_PX = 2048


@attrs.frozen
class GeographicOutput:
    """The longitude/latitude grid the products are delivered on."""

    crs: str
    resolution_deg: float
    bounds: tuple[float, float, float, float] | None = None

    def grid(self, bounds: tuple[float, float, float, float]) -> tuple[Any, int, int]:
        """Transform, width and height of the grid over ``bounds`` (or the asked ``--te``),
        snapped outwards to multiples of the resolution."""
        from affine import Affine

        left, bottom, right, top = self.bounds or bounds
        res = self.resolution_deg
        x0, x1 = math.floor(left / res + 1e-9) * res, math.ceil(right / res - 1e-9) * res
        y0, y1 = math.floor(bottom / res + 1e-9) * res, math.ceil(top / res - 1e-9) * res
        width, height = max(round((x1 - x0) / res), 1), max(round((y1 - y0) / res), 1)
        return Affine(res, 0.0, x0, 0.0, -res, y1), width, height

    def apply(self, folder: Path, report: Mapping[str, Any]) -> dict[str, Any]:
        """Warp the rasters of ``report["files"]`` in ``folder`` onto the grid (each file
        replaced); the report with the delivered grid."""
        import rasterio
        from rasterio.warp import transform_bounds

        files = dict(report.get("files") or {})
        with rasterio.open(folder / files["dem"]) as ds:
            box = transform_bounds(ds.crs, "EPSG:4326", *ds.bounds, densify_pts=21)
            dem_res_m = abs(ds.transform.a)
        transform, width, height = self.grid(box)
        for key, name in files.items():
            if not name.endswith(".tif"):
                continue
            with rasterio.open(folder / name) as ds:  # the ortho grid: k pixels a node
                k = max(1, round(dem_res_m / abs(ds.transform.a)))
            nearest = key.endswith(("_counts", "_flags"))  # counts and flags: nearest
            fine = transform * transform.scale(1.0 / k)
            _warp_file(folder / name, self.crs, fine, width * k, height * k, nearest)
        out = dict(report)
        out["dem_grid"] = {
            "crs": self.crs,
            "resolution_deg": self.resolution_deg,
            "shape": [height, width],
            "computed_on": report.get("dem_grid"),
        }
        return out


def geographic_output(settings: dict[str, Any]) -> GeographicOutput | None:
    """For a geographic ``crs`` in ``settings`` (the ``carto dem`` options): take it, and
    ``bounds`` in degrees, out of them, turn ``posting_m`` (degrees here) into metres for
    the generator; None (``settings`` unchanged) for any other CRS."""
    import pyproj

    value = settings.get("crs")
    if value is None:
        return None
    try:
        crs = pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError:
        return None  # the generator names the option in its message
    if not crs.is_geographic:
        return None
    flat = crs.to_2d() if len(crs.axis_info) == 3 else crs
    if flat.to_epsg() != 4326:
        raise UsageError(
            f"--t_srs {value}: the geographic output is WGS84 longitude and latitude "
            "(EPSG:4326, or EPSG:4979 with its heights); for another datum, warp the DEM "
            "with gdalwarp"
        )
    settings.pop("crs")
    degrees = settings.get("posting_m")
    if degrees is None:
        degrees = DEFAULT_POSTING_M / METRES_PER_DEGREE_LAT
    if not 0.0 < float(degrees) <= 0.1:
        raise UsageError(
            f"--tr {degrees:g}: with a geographic --t_srs, the posting is in degrees "
            "(e.g. 0.0001 for about 11 m), at most 0.1"
        )
    settings["posting_m"] = float(degrees) * METRES_PER_DEGREE_LAT
    bounds = settings.pop("bounds", None)
    return GeographicOutput(
        "EPSG:4326", float(degrees), tuple(map(float, bounds)) if bounds is not None else None
    )


def _warp_file(
    path: Path, crs: str, transform: Any, width: int, height: int, nearest: bool
) -> None:
    """``path`` replaced by its warp onto the grid, window by window, with its tags, band
    descriptions, units, nodata and vertical reference."""
    import rasterio
    from rasterio.crs import CRS
    from rasterio.enums import Resampling
    from rasterio.vrt import WarpedVRT
    from rasterio.windows import Window

    from carto.framework.raster.cog import cog_writer
    from carto.framework.raster.vertical_reference import VERTICAL_TAG

    staged = path.with_name(f".{path.stem}.projected{path.suffix}")
    path.replace(staged)
    Path(f"{path}.aux.xml").unlink(missing_ok=True)
    try:
        with rasterio.open(staged) as src:
            tags = src.tags()
            vertical = tags.get(VERTICAL_TAG)
            nodata = src.nodata
            profile = {
                "driver": "GTiff",
                "width": width,
                "height": height,
                "count": src.count,
                "dtype": src.dtypes[0],
                "crs": CRS.from_user_input(crs),
                "transform": transform,
                "nodata": nodata,
            }
            resampling = Resampling.nearest if nearest else Resampling.bilinear
            with (
                WarpedVRT(
                    src, crs=profile["crs"], transform=transform, width=width, height=height,
                    resampling=resampling, src_nodata=nodata, nodata=nodata,
                ) as vrt,
                cog_writer(
                    path, profile, what=path.name,
                    vertical=_carto_vertical(vertical),
                    overview_resampling="nearest" if nearest else "average",
                ) as dst,
            ):  # fmt: skip
                for row in range(0, height, WINDOW_PX):
                    for col in range(0, width, WINDOW_PX):
                        w = Window(
                            col, row, min(WINDOW_PX, width - col), min(WINDOW_PX, height - row)
                        )
                        dst.write(vrt.read(window=w), window=w)
                dst.update_tags(**{k: v for k, v in tags.items() if k != VERTICAL_TAG})
                dst.descriptions = src.descriptions
                if vertical is None:
                    dst.units = src.units
    finally:
        staged.unlink(missing_ok=True)
        Path(f"{staged}.aux.xml").unlink(missing_ok=True)


def _carto_vertical(tag: str | None) -> str | None:
    if tag is None:
        return None
    from carto.framework.raster.vertical_reference import normalise_vertical

    return normalise_vertical(tag)
