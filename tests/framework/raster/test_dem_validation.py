"""Bad DEMs, geoids and images are refused with one-line messages naming the file and the value,
or read with their implausible heights as nodata (issue #15).

Truth is independent of the code under test: files written with rasterio (GeoTIFF, SRTM
``.hgt``) or byte by byte (GTX), analytic planes for the filled heights.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from carto.framework.errors import InputError
from carto.framework.imaging.ortho_grid import MAX_GRID_CELLS, check_dem, check_grid_size
from carto.framework.raster.dem import DEM, EGM96, Geoid
from carto.framework.raster.dem_measures import fill_voids, slope_deg
from carto.framework.raster.images import check_image, read_raster

GEO = Affine(0.01, 0.0, 5.0, 0.0, -0.01, 44.6)  # lon 5.0.., lat ..44.6, 0.01 degree posts


def _tif(path: Path, values: np.ndarray, *, nodata=np.nan, dtype="float32", crs="EPSG:4326"):
    profile = {
        "driver": "GTiff",
        "height": values.shape[0],
        "width": values.shape[1],
        "count": 1,
        "dtype": dtype,
        "transform": GEO,
    }
    if crs is not None:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(values.astype(dtype), 1)
    return path


def _plane(shape: tuple[int, int]) -> np.ndarray:
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    return 600.0 + 3.0 * cols - 2.0 * rows


def _refused(call, *fragments: str) -> str:
    with pytest.raises(InputError) as err:
        call()
    message = str(err.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


# ----------------------------------------------------------------------------- DEM files
def test_a_1_x_1_dem_is_refused(tmp_path: Path):
    path = _tif(tmp_path / "one.tif", np.full((1, 1), 500.0))
    _refused(lambda: DEM.open(path), str(path), "1 x 1 pixels", "at least 2 x 2 posts")
    row = _tif(tmp_path / "row.tif", np.full((1, 30), 500.0))
    _refused(lambda: DEM.open(row), str(row), "30 x 1 pixels")


@pytest.mark.parametrize(
    ("unit", "tags", "fragments"),
    [
        ("ft", {}, ("band 1 is in 'ft', not metres",)),
        ("US survey foot", {}, ("'US survey foot', not metres",)),
        (None, {"CARTO_PRODUCT": "ortho"}, ("a carto ortho raster", "give dem.tif")),
        (None, {"CARTO_PRODUCT": "quality"}, ("a carto quality raster",)),
    ],
)
def test_a_raster_that_says_it_is_not_heights_in_metres_is_refused(
    tmp_path: Path, unit, tags, fragments
):
    """An outside probe evaluated ortho-images and quality layers as DEMs (issue 31): the
    file's own unit or carto tag says what it holds (GDAL writes both)."""
    path = _tif(tmp_path / "x.tif", _plane((20, 20)))
    with rasterio.open(path, "r+") as ds:
        if unit:
            ds.units = (unit,)
        ds.update_tags(**tags)
    _refused(lambda: DEM.open(path), str(path), *fragments)


def test_a_raster_of_several_bands_is_refused_unless_one_is_named(tmp_path: Path):
    """carto evaluate read quality.tif's first band (confidence) as heights (issue 31)."""
    path = tmp_path / "two.tif"
    with rasterio.open(
        path, "w", driver="GTiff", height=20, width=20, count=2, dtype="float32",
        crs="EPSG:4326", transform=GEO,
    ) as ds:  # fmt: skip
        ds.write(np.stack([_plane((20, 20)), _plane((20, 20)) + 1.0]).astype("float32"))
        ds.set_band_description(1, "confidence")
    _refused(lambda: DEM.open(path), str(path), "2 bands (confidence, band 2)", "one band")
    assert np.allclose(DEM.open(path, band=2).heights, _plane((20, 20)) + 1.0)


def test_a_folder_or_a_loop_given_as_a_dem_is_named_so(tmp_path: Path):
    """An outside probe: both were reported as 'no such file' (issue 31, family 5)."""
    (tmp_path / "dem.tif").mkdir()
    _refused(lambda: DEM.open(tmp_path / "dem.tif"), "is a folder, not a file")
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    _refused(lambda: DEM.open(tmp_path / "a"), "a loop of symbolic links")
    _refused(lambda: Geoid.open(tmp_path / "dem.tif"), "geoid", "is a folder")
    _refused(lambda: DEM.open(tmp_path / "none.tif"), "none.tif: no such file")


@pytest.mark.parametrize("unit", ["m", "metre", "Meters"])
def test_heights_in_metres_read(tmp_path: Path, unit: str):
    path = _tif(tmp_path / "x.tif", _plane((20, 20)))
    with rasterio.open(path, "r+") as ds:
        ds.units = (unit,)
        ds.update_tags(CARTO_PRODUCT="dem")
    assert np.allclose(DEM.open(path).heights, _plane((20, 20)))


@pytest.mark.parametrize("fill", [1e30, -1e30, np.inf, 20000.0, -5000.0])
def test_a_dem_of_implausible_heights_only_is_refused(tmp_path: Path, fill: float):
    path = _tif(tmp_path / "huge.tif", np.full((5, 6), fill), nodata=None)
    _refused(lambda: DEM.open(path), str(path), "no valid height", "6 x 5", "-1000..10000 m")


def test_an_all_void_srtm_tile_is_refused(tmp_path: Path):
    path = tmp_path / "N44E005.hgt"
    np.full((1201, 1201), -32768, ">i2").tofile(path)
    with rasterio.open(path) as ds:  # the SRTM driver declares -32768 as nodata
        assert ds.driver == "SRTMHGT"
    _refused(lambda: DEM.open(path), str(path), "no valid height")


@pytest.mark.parametrize(
    ("void", "nodata"),
    [(-9999.0, None), (-32768.0, None), (-32768.0, 0.0), (-9999.0, -32768.0), (1e30, None)],
)
def test_undeclared_voids_are_nodata(tmp_path: Path, void: float, nodata):
    heights = _plane((12, 14))
    heights[3:6, 4:9] = void
    path = _tif(tmp_path / "voids.tif", heights, nodata=nodata)
    dem = DEM.open(path)
    assert np.isnan(dem.heights[3:6, 4:9]).all()
    valid = np.ones(heights.shape, bool)
    valid[3:6, 4:9] = False
    np.testing.assert_allclose(dem.heights[valid], heights[valid], atol=1e-3)
    lo, hi = dem.height_range
    assert 500.0 < lo < hi < 700.0


def test_int16_srtm_voids_without_declared_nodata(tmp_path: Path):
    heights = _plane((8, 8)).astype(np.int16)
    heights[2, 2] = -32768
    dem = DEM.open(_tif(tmp_path / "i16.tif", heights, nodata=None, dtype="int16"))
    assert np.isnan(dem.heights[2, 2])
    assert np.isfinite(dem.heights).sum() == 63


def test_heights_of_1e30_or_nan_in_some_cells_break_nothing():
    heights = _plane((20, 20))
    heights[4, 4] = 1e30
    heights[10, 11] = np.nan
    heights[15, 2] = -np.inf
    dem = DEM.from_array(heights, GEO, "EPSG:4326")
    assert np.isnan(dem.heights[[4, 10, 15], [4, 11, 2]]).all()
    lo, hi = dem.height_range
    assert 500.0 < lo < hi < 700.0
    lon = 5.0 + 0.01 * (np.arange(19) + 1.0)  # between the centres of columns i and i + 1
    h = dem.height(lon, np.full(19, 44.6 - 0.01 * 5.0))  # between rows 4 and 5
    assert np.isnan(h[3:5]).all()  # next to the 1e30 post (row 4, column 4)
    assert np.isfinite(np.delete(h, [3, 4])).all()
    slope = slope_deg(dem)
    assert np.nanmax(slope) < 1.0  # no wild slope next to the 1e30 cell
    filled, n = fill_voids(dem)
    assert n == 3
    assert np.isfinite(filled.heights).all()


def test_constant_height_must_be_plausible():
    _refused(lambda: DEM.constant(1e30), "1e+30", "-1000..10000 m")
    _refused(lambda: DEM.constant(float("nan")), "nan")
    assert DEM.constant(-400.0).height_range == (-400.0, -400.0)


# ----------------------------------------------------------------------------- filling
def test_filled_heights_of_a_plane_agree_with_the_plane():
    """The voids of a plane filled by GDAL's inverse-distance weighting stay close to it:
    within a few metres for a hole of 6 x 8 posts on a slope of 3 m per post."""
    truth = _plane((40, 50))
    holed = truth.copy()
    holed[15:21, 20:28] = np.nan
    holed[0:3, 0:3] = np.nan  # at a corner too
    dem = DEM.from_array(holed, GEO, "EPSG:4326")
    filled, n = fill_voids(dem)
    assert n == 48 + 9
    assert filled.shape == dem.shape
    assert np.isfinite(filled.heights).all()
    np.testing.assert_array_equal(filled.heights[np.isfinite(holed)], holed[np.isfinite(holed)])
    assert np.max(np.abs(filled.heights - truth)) < 5.0
    # a window: only the posts around the bounds, their voids filled the same way
    window, n_window = fill_voids(dem, bounds=(5.18, 44.35, 5.30, 44.45))
    assert window.shape[0] < 40
    assert window.shape[1] < 50
    assert n_window == 48
    lon, lat = np.meshgrid(np.linspace(5.19, 5.29, 11), np.linspace(44.36, 44.44, 9))
    np.testing.assert_allclose(window.height(lon, lat), filled.height(lon, lat), atol=2.0)


# ----------------------------------------------------------------------------- geoid
def _gtx(path: Path, dlat: float, dlon: float, values: np.ndarray) -> Path:
    """A GTX grid written byte by byte (header: lat0, lon0, dlat, dlon, rows, cols)."""
    rows, cols = values.shape
    with open(path, "wb") as f:
        f.write(struct.pack(">ddddii", 44.0, 5.0, dlat, dlon, rows, cols))
        f.write(values.astype(">f4").tobytes())
    return path


def test_a_geoid_of_zero_or_negative_spacing_is_refused(tmp_path: Path):
    good = _gtx(tmp_path / "good.gtx", 0.25, 0.25, np.full((4, 4), 48.0))
    assert Geoid.open(good).undulation(5.25, 44.25) == pytest.approx(48.0)
    zero = _gtx(tmp_path / "zero.gtx", 0.25, 0.0, np.full((4, 4), 48.0))
    _refused(lambda: Geoid.open(zero), str(zero), "grid spacing", "0 degrees of longitude")
    negative = _gtx(tmp_path / "neg.gtx", -0.25, 0.25, np.full((4, 4), 48.0))
    _refused(lambda: Geoid.open(negative), str(negative), "grid spacing", "-0.25")
    _refused(
        lambda: Geoid(np.zeros((3, 3)), Affine(np.nan, 0, 5, 0, -1, 45), source="mem"),
        "geoid mem",
        "nan degrees",
    )


@pytest.mark.parametrize("wild", [-9999.0, 160.0, 1e30, np.inf])
def test_a_geoid_of_implausible_undulations_is_refused(tmp_path: Path, wild: float):
    values = np.full((4, 4), 48.0)
    values[1, 2] = wild
    path = _gtx(tmp_path / "wild.gtx", 0.25, 0.25, values)
    _refused(lambda: Geoid.open(path), str(path), "undulation", "implausible", "150 m")


def test_geoid_heights_name_the_command_line_option(tmp_path: Path):
    path = tmp_path / "N44E005.hgt"
    tile = np.full((1201, 1201), 700, ">i2")
    tile[:10, :10] = -32768
    tile.tofile(path)
    dem = DEM.open(path)
    assert dem.vertical == EGM96
    assert np.isnan(dem.heights[:10, :10]).all()
    for call in (
        lambda: DEM.open(path, require_ellipsoidal=True),
        lambda: check_dem(dem),
        lambda: dem.check_ellipsoidal("ior"),
    ):
        message = _refused(call, str(path), "--geoid GTX", 'configuration key "geoid"')
        assert "to_ellipsoid" not in message
    geoid = Geoid(np.full((3, 3), 50.0), Affine(1.0, 0, 4.0, 0, -1.0, 46.0))
    converted = DEM.open(path, geoid=geoid, require_ellipsoidal=True)
    assert np.nanmedian(converted.heights) == pytest.approx(750.0)


# ----------------------------------------------------------------------------- images
def test_images_too_small_empty_or_constant_are_refused(tmp_path: Path):
    rng = np.random.default_rng(3)
    texture = rng.uniform(0, 1000, (40, 50))
    assert read_raster(_tif(tmp_path / "ok.tif", texture, crs=None)).shape == (40, 50)
    one = _tif(tmp_path / "one.tif", np.full((1, 1), 5.0), crs=None)
    _refused(lambda: read_raster(one), str(one), "1 x 1 pixels", "at least 16 x 16")
    small = _tif(tmp_path / "small.tif", texture[:15, :40], crs=None)
    _refused(lambda: read_raster(small), str(small), "40 x 15 pixels")
    empty = _tif(tmp_path / "empty.tif", np.full((20, 20), np.nan), crs=None)
    _refused(lambda: read_raster(empty), str(empty), "no valid pixels")
    nodata = _tif(tmp_path / "nd.tif", np.zeros((20, 20)), nodata=0.0, dtype="uint16", crs=None)
    _refused(lambda: read_raster(nodata), str(nodata), "no valid pixels")
    flat = _tif(
        tmp_path / "flat.tif", np.full((20, 20), 7.0), nodata=None, dtype="uint16", crs=None
    )
    _refused(lambda: read_raster(flat), str(flat), "no texture (constant value 7)")
    _refused(lambda: check_image(np.zeros(30), "vector"), "vector", "2-D")


# ----------------------------------------------------------------------------- grid size
def test_grid_size_is_checked_before_allocating():
    assert check_grid_size(1000.0, 500.0, 10.0) == (50, 100)
    message = _refused(
        lambda: check_grid_size(803.8, 1031.9, 0.001, what="ior", option="posting_m (--posting)"),
        "ior: posting_m (--posting) 0.001 m",
        "803.8 x 1031.9 m",
        "803800 x 1031900",
        f"{MAX_GRID_CELLS:.3g}",
    )
    assert "at least 0.0455 m" in message
    _refused(lambda: check_grid_size(10.0, 10.0, 0.0), "resolution 0.0")
    _refused(lambda: check_grid_size(10.0, 10.0, float("nan")), "resolution nan")
