"""Cloud-optimised GeoTIFF outputs, validated by rio-cogeo (an independent implementation of
the COG rules: tiles, overviews, IFD and data order) and read back with rasterio."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine
from pyproj.transformer import TransformerGroup
from rio_cogeo.cogeo import cog_validate

from carto.framework.errors import InputError
from carto.framework.imaging.ortho import write_ortho
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.raster.cog import cog_writer
from carto.framework.raster.dem import DEM

TRANSFORM = Affine(2.5, 0.0, 640_000.0, 0.0, -2.5, 4_910_000.0)


def _grid(rows: int, cols: int) -> OrthoGrid:
    return OrthoGrid(pyproj.CRS.from_epsg(32631), TRANSFORM, (rows, cols))


def _valid(path: Path) -> None:
    is_valid, errors, warnings = cog_validate(str(path), strict=True)
    assert is_valid, (errors, warnings)
    with rasterio.open(path) as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert ds.block_shapes[0] == (256, 256)


def test_an_ortho_image_is_a_cog_with_overviews(tmp_path: Path):
    rng = np.random.default_rng(0)
    image = rng.uniform(0, 4000, (1300, 1100)).astype(np.uint16)
    path = write_ortho(tmp_path / "ortho.tif", image, _grid(1300, 1100), nodata=0)
    _valid(path)
    with rasterio.open(path) as ds:
        assert ds.overviews(1) == [2, 4, 8]  # down to one 256 px tile
        assert ds.nodata == 0
        assert ds.dtypes == ("uint16",)
        assert ds.compression.name == "deflate"
        np.testing.assert_array_equal(ds.read(1), image)
        assert ds.crs.to_epsg() == 32631  # no vertical part: not heights
    assert sorted(os.listdir(tmp_path)) == ["ortho.tif"]  # nothing left beside it


def test_float_orthos_in_the_inputs_uint16_radiometry(tmp_path: Path):
    """Resampled float values (cubic overshoots included) written as the input's uint16:
    rounded, clipped, NaN as nodata 0, a valid 0 kept apart from nodata."""
    rng = np.random.default_rng(2)
    image = rng.uniform(-50.0, 70_000.0, (300, 280)).astype(np.float32)
    image[10:20, 30:40] = np.nan
    image[0, 0], image[0, 1], image[0, 2] = 0.2, 1.6, 65_534.6
    path = write_ortho(tmp_path / "o.tif", image, _grid(300, 280), out_dtype="uint16")
    _valid(path)
    with rasterio.open(path) as ds:
        assert ds.dtypes == ("uint16",)
        assert ds.nodata == 0
        got = ds.read(1)
    expected = np.clip(np.rint(np.nan_to_num(image, nan=0.0)), 0, 65535).astype(np.uint16)
    expected[expected == 0] = 1  # a valid value of 0 is not nodata
    expected[np.isnan(image)] = 0
    np.testing.assert_array_equal(got, expected)
    assert (got[10:20, 30:40] == 0).all()
    assert got[0, 0] == 1
    assert got[0, 1] == 2
    assert got[0, 2] == 65535


def test_bands_keep_their_descriptions_tags_and_values(tmp_path: Path):
    rng = np.random.default_rng(1)
    bands = [rng.normal(size=(300, 260)).astype(np.float32) for _ in range(3)]
    bands[0][5:9, 7:20] = np.nan
    path = write_ortho(
        tmp_path / "quality.tif",
        bands,
        _grid(300, 260),
        tags={"BAND_1": "what the first band is"},
        band_descriptions=["confidence", "count", "sigma_m"],
        overview_resampling="nearest",
    )
    _valid(path)
    with rasterio.open(path) as ds:
        assert ds.descriptions == ("confidence", "count", "sigma_m")
        assert ds.tags()["BAND_1"] == "what the first band is"
        np.testing.assert_array_equal(ds.read(), np.stack(bands))


def test_heights_carry_the_vertical_crs(tmp_path: Path):
    heights = np.linspace(100, 900, 600 * 520).reshape(600, 520)
    dem = DEM.from_array(heights, TRANSFORM, "EPSG:32631", vertical="geoid:EGM96")
    path = dem.write(tmp_path / "dem.tif")
    _valid(path)
    ortho = write_ortho(
        tmp_path / "dem2.tif", heights.astype(np.float32), _grid(600, 520), vertical="ellipsoid"
    )
    _valid(ortho)
    with rasterio.open(path) as a, rasterio.open(ortho) as b:
        assert pyproj.CRS.from_wkt(a.crs.to_wkt()).sub_crs_list[1].to_epsg() == 5773
        ellipsoidal = pyproj.CRS.from_wkt(b.crs.to_wkt())
        egm96 = pyproj.CRS.from_wkt(a.crs.to_wkt())
        assert b.units == ("metre",)
    # ellipsoidal heights: the projected CRS made 3-D on EPSG:4979, so that PROJ finds the
    # geoid grid's transformation to EGM96 heights (not a ballpark one that ignores it)
    assert not ellipsoidal.is_compound
    assert len(ellipsoidal.axis_info) == 3
    assert ellipsoidal.geodetic_crs.to_epsg() == 4979
    assert ellipsoidal.to_2d().to_epsg() == 32631
    group = TransformerGroup(ellipsoidal, egm96)
    found = [t.description for t in group.transformers] + [
        o.name for o in group.unavailable_operations
    ]
    assert any("WGS 84 to EGM96 height (1)" in f for f in found), found


def test_a_failed_write_keeps_the_earlier_file(tmp_path: Path):
    path = write_ortho(tmp_path / "o.tif", np.ones((40, 50), np.float32), _grid(40, 50))
    before = path.read_bytes()
    profile = {"width": 50, "height": 40, "count": 1, "dtype": "float32", "crs": "EPSG:32631"}

    def interrupted() -> None:
        with cog_writer(path, profile) as dst:
            dst.write(np.zeros((40, 50), np.float32), 1)
            raise RuntimeError("stopped midway")

    with pytest.raises(RuntimeError, match="stopped"):
        interrupted()
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["o.tif"]


def test_an_unwritable_folder_is_a_clear_error(tmp_path: Path):
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    with pytest.raises(InputError):
        write_ortho(blocked / "o.tif", np.ones((40, 50), np.float32), _grid(40, 50))
    with pytest.raises(InputError, match="overview resampling"):
        write_ortho(tmp_path / "o.tif", np.ones((4, 5)), _grid(4, 5), overview_resampling="cubic")
