"""The STAC Item of a ``carto dem`` output folder (``item.json``, issue 34 item 2): what
catalogues, STAC browsers and ``pystac``/``stackstac`` users read to find the DEM.

One Item (STAC 1.1) whose assets are the folder's files with their roles (``dem`` and the
ortho-images ``data``; quality layers ``metadata`` and ``quality``; ``report`` ``metadata``;
the hillshade ``overview``), relative hrefs, and three extensions:

* projection (v2.0.0): ``proj:code``, ``proj:wkt2`` (with the heights' vertical reference),
  ``proj:shape``, ``proj:transform`` and ``proj:bbox`` of the DEM grid on the Item, of their
  own grid on assets that differ (the ortho grid);
* raster (v1.1.0): per band ``data_type``, ``nodata``, ``unit``, ``spatial_resolution``;
* processing (v1.2.0): ``processing:software`` (carto and every plugin with its version),
  ``processing:lineage`` (the command line, or "library call"), ``processing:datetime``.

The Item is built from the files themselves (rasterio reads each GeoTIFF's grid), so it says
what is in the folder.
"""

from __future__ import annotations

import datetime
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["ITEM_FILE", "STAC_EXTENSIONS", "dem_item"]

ITEM_FILE = "item.json"
"""The STAC Item of an output folder."""

STAC_EXTENSIONS = {
    "projection": "https://stac-extensions.github.io/projection/v2.0.0/schema.json",
    "raster": "https://stac-extensions.github.io/raster/v1.1.0/schema.json",
    "processing": "https://stac-extensions.github.io/processing/v1.2.0/schema.json",
}

_ROLES = {
    "dem": ("data",),
    "ortho": ("data",),
    "quality": ("metadata", "quality"),
    "matching": ("metadata", "quality"),
}


def _roles(key: str) -> tuple[str, ...]:
    return next((r for prefix, r in _ROLES.items() if key.startswith(prefix)), ("metadata",))


def _raster_facts(path: Path) -> dict[str, Any]:
    """A GeoTIFF's grid (projection fields) and bands (raster fields)."""
    import pyproj
    import rasterio

    with rasterio.open(path) as ds:
        crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        flat = crs.to_2d() if len(crs.axis_info) == 3 else crs
        if flat.is_compound:
            flat = flat.sub_crs_list[0]
        code = flat.to_epsg()
        t = ds.transform
        nodata = ds.nodata
        if nodata is not None and nodata != nodata:
            nodata = "nan"
        bands = [
            {
                "data_type": dtype,
                **({"nodata": nodata} if nodata is not None else {}),
                **({"unit": unit} if unit else {}),
                "spatial_resolution": abs(t.a),
            }
            for dtype, unit in zip(ds.dtypes, ds.units, strict=True)
        ]
        return {
            "proj:code": f"EPSG:{code}" if code else None,
            "proj:wkt2": crs.to_wkt(),
            "proj:shape": [ds.height, ds.width],
            "proj:transform": [t.a, t.b, t.c, t.d, t.e, t.f],
            "proj:bbox": list(ds.bounds),
            "raster:bands": bands,
            "_bounds": ds.bounds,
            "_crs": ds.crs,
        }


def _footprint(facts: Mapping[str, Any]) -> tuple[dict[str, Any], list[float]]:
    """The grid's outline in longitude and latitude (densified edges) and its bbox."""
    from rasterio.warp import transform_geom

    left, bottom, right, top = facts["_bounds"]
    ring = [[left, bottom], [right, bottom], [right, top], [left, top], [left, bottom]]
    geometry = transform_geom(
        facts["_crs"], "EPSG:4326", {"type": "Polygon", "coordinates": [ring]}, precision=7
    )
    points = geometry["coordinates"][0]
    lons, lats = [p[0] for p in points], [p[1] for p in points]
    return dict(geometry), [min(lons), min(lats), max(lons), max(lats)]


def dem_item(folder: str | Path, report: Mapping[str, Any], item_id: str) -> dict[str, Any]:
    """The STAC Item (a JSON-ready dict) of the ``carto dem`` output ``folder`` whose report is
    ``report`` (see the module docstring)."""
    import pystac

    folder = Path(folder)
    files = dict(report.get("files") or {})
    dem_facts = _raster_facts(folder / files["dem"])
    geometry, bbox = _footprint(dem_facts)
    run = report.get("run") or {}
    started = run.get("started_utc") or datetime.datetime.now(datetime.UTC).isoformat()
    item = pystac.Item(
        id=item_id,
        geometry=geometry,
        bbox=bbox,
        datetime=datetime.datetime.fromisoformat(started),
        properties={
            "title": f"DEM {item_id} ({report.get('generator')}, {report.get('matcher')})",
            "created": run.get("ended_utc") or started,
            "processing:software": {
                "carto": run.get("carto_version"),
                **dict(run.get("plugins") or {}),
            },
            "processing:lineage": run.get("command_line") or "library call (carto workflows)",
            "processing:datetime": run.get("ended_utc") or started,
            **{k: v for k, v in dem_facts.items() if k.startswith("proj:")},
        },
        stac_extensions=list(STAC_EXTENSIONS.values()),
    )
    for key, name in files.items():
        path = folder / name
        if not path.is_file():
            continue
        item.add_asset(key, _asset(key, path, dem_facts))
    item.add_asset(
        "report",
        pystac.Asset(
            "./report.json", title="report (carto dem)", media_type="application/json",
            roles=["metadata"],
        ),
    )  # fmt: skip
    return item.to_dict(include_self_link=False)


def _asset(key: str, path: Path, dem_facts: Mapping[str, Any]) -> Any:
    import pystac

    href = f"./{path.name}"
    if path.suffix.lower() == ".png":
        return pystac.Asset(href, title=key, media_type=pystac.MediaType.PNG, roles=["overview"])
    facts = _raster_facts(path)
    extra: dict[str, Any] = {"raster:bands": facts["raster:bands"]}
    for field in ("proj:shape", "proj:transform", "proj:bbox"):
        if facts[field] != dem_facts[field]:  # another grid than the Item's (the ortho grid)
            extra[field] = facts[field]
    if facts["proj:wkt2"] != dem_facts["proj:wkt2"]:
        extra["proj:code"], extra["proj:wkt2"] = facts["proj:code"], facts["proj:wkt2"]
    return pystac.Asset(
        href,
        title=key,
        media_type=pystac.MediaType.COG,
        roles=list(_roles(key)),
        extra_fields=extra,
    )
