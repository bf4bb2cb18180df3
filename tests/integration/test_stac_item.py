"""The STAC Item of a ``carto dem`` output (issue 34 item 2), validated by pystac against the
STAC 1.1 schemas (bundled with pystac) and the extensions' schemas (tests/data)."""

from __future__ import annotations

import json
from pathlib import Path

import pyproj
import pystac
import pytest
import rasterio
from pystac.validation import JsonSchemaSTACValidator, set_validator, validate_dict

from carto.framework.products.stac import STAC_EXTENSIONS
from carto.framework.workflows.dem import StereoInputs, dem_product

SCHEMAS = Path(__file__).resolve().parent.parent / "data" / "stac-schemas"


@pytest.fixture(scope="module")
def dem_folder(cartosat1_scene, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("stac") / "dem-stac"
    dem_product(
        out,
        StereoInputs(cartosat1_scene, models=cartosat1_scene / "truth"),
        options={"posting_m": 30.0, "max_iterations": 2},
        workers=1,
        quiet=True,
    )
    return out


@pytest.fixture
def offline_validator():
    validator = JsonSchemaSTACValidator()
    for name, uri in STAC_EXTENSIONS.items():
        (path,) = SCHEMAS.glob(f"{name}-v*.json")
        assert uri.split("/")[-2] in path.name  # the version the Item declares
        validator.schema_cache[uri] = json.loads(path.read_text())
    set_validator(validator)
    yield validator
    set_validator(JsonSchemaSTACValidator())


def test_the_item_validates_and_names_every_product(dem_folder, offline_validator):
    document = json.loads((dem_folder / "item.json").read_text())
    validated = validate_dict(document)
    assert set(STAC_EXTENSIONS.values()) <= set(validated)
    item = pystac.Item.from_dict(document)
    assert item.id == "dem-stac"
    roles = {key: asset.roles for key, asset in item.assets.items()}
    assert roles["dem"] == ["data"]
    assert roles["ortho_left"] == roles["ortho_right"] == ["data"]
    assert roles["quality"] == roles["quality_flags"] == ["metadata", "quality"]
    assert roles["report"] == ["metadata"]
    assert roles["hillshade"] == ["overview"]
    for asset in item.assets.values():  # relative hrefs to the folder's files
        assert asset.href.startswith("./")
        assert (dem_folder / asset.href[2:]).is_file()
    assert item.assets["dem"].media_type == pystac.MediaType.COG
    # the validation is real: a band type the raster extension does not know fails it
    document["assets"]["dem"]["raster:bands"][0]["data_type"] = "float99"
    with pytest.raises(pystac.STACValidationError):
        validate_dict(document)


def test_the_item_says_what_the_files_hold(dem_folder):
    item = json.loads((dem_folder / "item.json").read_text())
    props = item["properties"]
    with rasterio.open(dem_folder / "dem.tif") as ds:
        assert props["proj:shape"] == [ds.height, ds.width]
        assert props["proj:transform"] == pytest.approx(list(ds.transform)[:6])
        horizontal = pyproj.CRS.from_wkt(ds.crs.to_wkt()).to_2d()
    assert props["proj:code"] == f"EPSG:{horizontal.to_epsg()}"
    assert "ellipsoidal height" in props["proj:wkt2"]  # the heights' reference
    dem_band = item["assets"]["dem"]["raster:bands"][0]
    assert dem_band == {
        "data_type": "float32",
        "nodata": "nan",
        "unit": "metre",
        "spatial_resolution": 30.0,
    }
    assert item["assets"]["quality_counts"]["raster:bands"][0]["data_type"] == "uint16"
    # the ortho-images are on their own grid
    with rasterio.open(dem_folder / "ortho_left.tif") as ds:
        assert item["assets"]["ortho_left"]["proj:shape"] == [ds.height, ds.width]
    assert props["processing:software"]["carto-ior"]
    lon_min, lat_min, lon_max, lat_max = item["bbox"]
    assert lon_min < lon_max
    assert lat_min < lat_max
