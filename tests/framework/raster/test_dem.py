"""DEM reading, bilinear sampling, geoid conversion, writing, and location on a DEM.

Truth is independent of the code under test: analytic surfaces written to GeoTIFF with rasterio
directly, pyproj for the UTM coordinates, the raw SRTM and EGM96 grids read with rasterio, and
an analytic oblique sensor whose intersection with a plane has a closed form.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import Affine

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.geometry.surface import dem_surface_locate
from carto.framework.raster.dem import (
    DEM,
    EGM96,
    ELLIPSOID,
    VERTICAL_TAG,
    Geoid,
    normalise_vertical,
)

# a 0.01-degree grid of 60 x 80 pixels whose first pixel corner is at (5.0E, 44.6N)
GEO_TRANSFORM = Affine(0.01, 0.0, 5.0, 0.0, -0.01, 44.6)
GEO_SHAPE = (60, 80)


def _write_tif(path: Path, heights: np.ndarray, transform: Affine, crs: str, **tags: str) -> Path:
    """Write a float64 GeoTIFF with rasterio directly (independent of DEM.write)."""
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=heights.shape[0],
        width=heights.shape[1],
        count=1,
        dtype="float64",
        crs=crs,
        transform=transform,
        nodata=np.nan,
    ) as dst:
        dst.write(heights, 1)
        if tags:
            dst.update_tags(**tags)
    return path


def _centres(transform: Affine, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    x = transform.c + (cols + 0.5) * transform.a
    y = transform.f + (rows + 0.5) * transform.e
    return x, y


def _inside_points(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Random lon/lat strictly inside the span of the pixel centres of GEO_TRANSFORM."""
    x, y = _centres(GEO_TRANSFORM, GEO_SHAPE)
    lon = rng.uniform(x.min(), x.max(), n)
    lat = rng.uniform(y.min(), y.max(), n)
    return lon, lat


# ----------------------------------------------------------------------------- sampling
def _plane(lon, lat):
    return 812.5 + 1500.0 * (lon - 5.0) - 2300.0 * (lat - 44.0)


def test_plane_in_geographic_geotiff_is_sampled_exactly(tmp_path: Path):
    x, y = _centres(GEO_TRANSFORM, GEO_SHAPE)
    path = _write_tif(tmp_path / "plane.tif", _plane(x, y), GEO_TRANSFORM, "EPSG:4326")
    dem = DEM.open(path)
    assert dem.shape == GEO_SHAPE
    assert dem.vertical == ELLIPSOID  # the Carto convention for untagged files
    assert dem.crs.equals("EPSG:4326")
    lon, lat = _inside_points(np.random.default_rng(0), 10_000)
    np.testing.assert_allclose(dem.height(lon, lat), _plane(lon, lat), rtol=0, atol=1e-9)
    # the pixel-centre convention: the value of pixel (row 3, col 7) stands at its centre
    assert dem.height(5.0 + 7.5 * 0.01, 44.6 - 3.5 * 0.01) == pytest.approx(
        _plane(5.075, 44.565), abs=1e-9
    )
    # broadcasting and shape
    assert dem.height(np.full((2, 3), 5.3), 44.3).shape == (2, 3)


def test_quadratic_surface_has_the_exact_bilinear_error(tmp_path: Path):
    """Bilinear interpolation of x^2 between nodes x0, x1 adds (x - x0)(x1 - x); xy is exact."""
    c, d, e = 1.5e4, -1.0e4, 2.5e4  # heights 500..7750 m: within the plausible range

    def quad(lon, lat):
        return 500.0 + c * (lon - 5.3) ** 2 + d * (lon - 5.3) * (lat - 44.3) + e * (lat - 44.3) ** 2

    x, y = _centres(GEO_TRANSFORM, GEO_SHAPE)
    dem = DEM.open(_write_tif(tmp_path / "quad.tif", quad(x, y), GEO_TRANSFORM, "EPSG:4326"))
    lon, lat = _inside_points(np.random.default_rng(1), 5_000)
    # enclosing pixel-centre nodes, by hand
    x0 = 5.005 + np.floor((lon - 5.005) / 0.01) * 0.01
    y0 = 44.595 - np.floor((44.595 - lat) / 0.01) * 0.01  # the node above (north)
    x1, y1 = x0 + 0.01, y0 - 0.01
    expected = quad(lon, lat) + c * (lon - x0) * (x1 - lon) + e * (y0 - lat) * (lat - y1)
    got = dem.height(lon, lat)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-8)
    assert np.max(np.abs(got - quad(lon, lat))) > 0.1  # the error term is really exercised


def test_plane_in_utm_geotiff_via_pyproj(tmp_path: Path):
    transform = Affine(30.0, 0.0, 640_000.0, 0.0, -30.0, 4_910_000.0)
    shape = (50, 70)
    x, y = _centres(transform, shape)

    def plane(e, n):
        return 400.0 + 0.25 * (e - 640_000.0) - 0.1 * (n - 4_900_000.0)

    dem = DEM.open(_write_tif(tmp_path / "utm.tif", plane(x, y), transform, "EPSG:32631"))
    assert dem.crs.equals("EPSG:32631")
    rng = np.random.default_rng(2)
    e = rng.uniform(x.min(), x.max(), 5_000)
    n = rng.uniform(y.min(), y.max(), 5_000)
    lon, lat = pyproj.Transformer.from_crs(32631, 4326, always_xy=True).transform(e, n)
    np.testing.assert_allclose(dem.height(lon, lat), plane(e, n), rtol=0, atol=1e-6)
    west, south, east, north = dem.bounds_lonlat
    # a window read by lon/lat bounds: fewer pixels, same heights
    inner = (lon.min() + 0.002, lat.min() + 0.002, lon.min() + 0.008, lat.min() + 0.006)
    window = DEM.open(tmp_path / "utm.tif", bounds=inner)
    assert window.shape[0] < shape[0]
    assert window.shape[1] < shape[1]
    in_window = (lon > inner[0]) & (lon < inner[2]) & (lat > inner[1]) & (lat < inner[3])
    assert in_window.sum() > 20
    np.testing.assert_allclose(
        window.height(lon[in_window], lat[in_window]), plane(e, n)[in_window], atol=1e-6
    )
    with pytest.raises(InputError, match="does not cover"):
        DEM.open(tmp_path / "utm.tif", bounds=(west - 0.01, south, east, north))
    assert west <= lon.min()
    assert east >= lon.max()
    assert south <= lat.min()
    assert north >= lat.max()


def test_rotated_transform(tmp_path: Path):
    transform = Affine.translation(5.0, 44.6) @ Affine.rotation(20.0) @ Affine.scale(0.01, -0.01)
    rows, cols = np.meshgrid(np.arange(40), np.arange(40), indexing="ij")
    x, y = transform @ (cols + 0.5, rows + 0.5)
    dem = DEM.from_array(_plane(x, y), transform, "EPSG:4326")
    r = np.random.default_rng(3).uniform(0.5, 39.5, (2, 1000))
    lon, lat = transform @ (r[1], r[0])
    np.testing.assert_allclose(dem.height(lon, lat), _plane(lon, lat), rtol=0, atol=1e-9)


def test_outside_nodata_and_strict(tmp_path: Path):
    x, y = _centres(GEO_TRANSFORM, GEO_SHAPE)
    heights = _plane(x, y)
    heights[10, 20] = np.nan
    path = _write_tif(tmp_path / "holes.tif", heights, GEO_TRANSFORM, "EPSG:4326")
    dem = DEM.open(path)
    hole_lon, hole_lat = 5.0 + 20.5 * 0.01, 44.6 - 10.5 * 0.01
    lon = np.array([hole_lon + 0.004, hole_lon - 0.009, 5.0 + 3 * 0.01, 4.9, 5.0025, 5.3])
    lat = np.array([hole_lat - 0.004, hole_lat, 44.4, 44.3, 44.3, 44.3])
    h = dem.height(lon, lat)
    # next to the hole, outside, and in the outer half pixel (no extrapolation) -> NaN
    assert np.isnan(h[[0, 1, 3, 4]]).all()
    assert np.isfinite(h[[2, 5]]).all()
    np.testing.assert_array_equal(dem.covers(lon, lat), np.isfinite(h))
    assert dem.bounds_lonlat == pytest.approx((5.005, 44.005, 5.795, 44.595), abs=1e-12)

    with pytest.raises(InputError) as err:
        dem.height(lon, lat, strict=True)
    message = str(err.value)
    assert str(path) in message
    assert "\n" not in message
    assert "lon 4.900000..5.209000" in message
    assert "lat 44.300000..44.495000" in message
    assert np.isfinite(dem.height(lon[[2, 5]], lat[[2, 5]], strict=True)).all()
    assert np.isnan(dem.height(np.nan, 44.3, strict=True))  # NaN input is not "uncovered"


def test_sampling_a_million_points_is_bilinear():
    """A million points in one call, against scipy's bilinear interpolator (the speed is
    ``benchmarks/``' business, not a test's)."""
    from scipy.interpolate import RegularGridInterpolator

    heights = np.random.default_rng(4).normal(500, 50, (1201, 1201))
    dem = DEM.from_array(
        heights,
        Affine(1 / 1200, 0, 5 - 1 / 2400, 0, -1 / 1200, 45 + 1 / 2400),
        "EPSG:4326",
    )
    rng = np.random.default_rng(5)
    lon, lat = rng.uniform(5, 6, 1_000_000), rng.uniform(44, 45, 1_000_000)
    h = dem.height(lon, lat)
    centres_lat = 45 - np.arange(1201) / 1200  # pixel centres, north to south
    centres_lon = 5 + np.arange(1201) / 1200
    reference = RegularGridInterpolator((centres_lat[::-1], centres_lon), heights[::-1])
    np.testing.assert_allclose(h, reference(np.stack([lat, lon], axis=1)), atol=1e-6)


def test_constant_dem_everywhere_and_wraps():
    dem = DEM.constant(123.5)
    lon = np.array([-180.0, -179.9, 0.0, 179.99, 180.0, 359.0, -540.0])
    lat = np.array([-90.0, -45.0, 0.0, 45.0, 90.0, 10.0, 0.0])
    np.testing.assert_array_equal(dem.height(lon, lat), 123.5)
    assert dem.height_range == (123.5, 123.5)
    local = DEM.constant(10.0, bounds=(5.0, 44.0, 6.0, 45.0))
    assert np.isnan(local.height(6.5, 44.5))
    assert local.height(5.5, 44.5) == 10.0


def test_from_array_validation():
    heights = np.array([[1.0, -9999.0], [3.0, 4.0]])
    dem = DEM.from_array(heights, GEO_TRANSFORM, "EPSG:4326", nodata=-9999.0)
    assert np.isnan(dem.heights[0, 1])
    assert heights[0, 1] == -9999.0
    with pytest.raises(ValueError, match="read-only"):
        dem.heights[0, 0] = 2.0
    with pytest.raises(InputError, match="vertical reference"):
        DEM.from_array(heights, GEO_TRANSFORM, "EPSG:4326", vertical="feet")
    with pytest.raises(InputError, match="2-D"):
        DEM.from_array(np.zeros(3), GEO_TRANSFORM, "EPSG:4326")
    with pytest.raises(InputError, match="crs"):
        DEM.from_array(heights, GEO_TRANSFORM, "EPSG:999999")
    assert normalise_vertical("ellipsoid WGS84") == ELLIPSOID
    assert normalise_vertical("geoid egm96") == EGM96 == normalise_vertical("EGM96")
    compound = DEM.from_array(heights, GEO_TRANSFORM, "EPSG:4326+5773", vertical="geoid:EGM96")
    assert compound.crs.equals("EPSG:4326")


# ----------------------------------------------------------------------------- SRTM and geoid
SRTM = "pleiades-ventoux-pair/N44E005.hgt"
GTX = "geoid/egm96_15.gtx"


def _raw_gtx_value(path: Path, lon: float, lat: float) -> float:
    """The undulation stored at a node of the GTX grid, read with rasterio directly."""
    with rasterio.open(path) as ds:
        row, col = ds.index(lon, lat)
        return float(ds.read(1)[row, col])


@pytest.mark.realdata
def test_srtm_tile_with_and_without_geoid(shared_data: Path):
    path = shared_data / SRTM
    with rasterio.open(path) as ds:
        raw = ds.read(1)
    geoidal = DEM.open(path)
    assert geoidal.vertical == EGM96
    assert not geoidal.is_ellipsoidal
    assert geoidal.shape == (1201, 1201)
    assert geoidal.bounds_lonlat == pytest.approx((5.0, 44.0, 6.0, 45.0), abs=1e-9)
    # node (row i, col j) of a 3" tile is at (5 + j/1200, 45 - i/1200)
    i, j = 900, 300  # lon 5.25, lat 44.25: also a node of the 15' EGM96 grid
    assert geoidal.height(5.25, 44.25) == pytest.approx(float(raw[i, j]), abs=1e-9)
    assert np.isnan(geoidal.heights[raw == -32768]).all()

    ellipsoidal = DEM.open(path, geoid=shared_data / GTX)
    assert ellipsoidal.vertical == ELLIPSOID
    undulation = ellipsoidal.height(5.25, 44.25) - geoidal.height(5.25, 44.25)
    assert undulation == pytest.approx(_raw_gtx_value(shared_data / GTX, 5.25, 44.25), abs=1e-5)
    assert 45.0 < undulation < 55.0  # EGM96 in south-eastern France: about +50 m
    # the undulation is smooth over the tile: every valid node moved by 40..60 m
    delta = ellipsoidal.heights - geoidal.heights
    assert np.nanmin(delta) > 40.0
    assert np.nanmax(delta) < 60.0


@pytest.mark.realdata
def test_srtm_window_and_uncovered_bounds(shared_data: Path):
    path = shared_data / SRTM
    full = DEM.open(path)
    window = DEM.open(path, bounds=(5.1, 44.1, 5.3, 44.3))
    assert window.shape[0] < 300
    assert window.shape[1] < 300
    rng = np.random.default_rng(6)
    lon, lat = rng.uniform(5.1, 5.3, 2000), rng.uniform(44.1, 44.3, 2000)
    np.testing.assert_allclose(window.height(lon, lat), full.height(lon, lat), atol=1e-6)
    corners = window.height([5.1, 5.3, 5.1, 5.3], [44.1, 44.1, 44.3, 44.3], strict=True)
    assert np.isfinite(corners).all()
    with pytest.raises(InputError) as err:
        DEM.open(path, bounds=(4.5, 44.1, 5.3, 44.3))
    message = str(err.value)
    assert str(path) in message
    assert "does not cover" in message
    assert "lon 4.500000" in message


@pytest.mark.realdata
def test_geoid_bilinear_and_wrap_around(shared_data: Path):
    gtx = shared_data / GTX
    geoid = Geoid.open(gtx)
    nodes = {
        (lon, lat): _raw_gtx_value(gtx, lon, lat) for lon in (5.0, 5.25) for lat in (44, 44.25)
    }
    assert geoid.undulation(5.25, 44.0) == pytest.approx(nodes[(5.25, 44.0)], abs=1e-6)
    # at (5.05, 44.2): weights 0.8/0.2 in lon and 0.2/0.8 in lat, by hand
    expected = (
        0.8 * 0.2 * nodes[(5.0, 44.0)]
        + 0.2 * 0.2 * nodes[(5.25, 44.0)]
        + 0.8 * 0.8 * nodes[(5.0, 44.25)]
        + 0.2 * 0.8 * nodes[(5.25, 44.25)]
    )
    assert geoid.undulation(5.05, 44.2) == pytest.approx(expected, abs=1e-6)
    # wrap-around: between the last column (179.75) and the first one (-180 == 180)
    east, west = _raw_gtx_value(gtx, 179.75, 10.0), _raw_gtx_value(gtx, -180.0, 10.0)
    assert geoid.undulation(179.9, 10.0) == pytest.approx(0.4 * east + 0.6 * west, abs=1e-6)
    assert geoid.undulation(-180.1, 10.0) == pytest.approx(0.4 * east + 0.6 * west, abs=1e-6)
    assert geoid.undulation(540.0, 10.0) == pytest.approx(west, abs=1e-6)
    assert np.isfinite(geoid.undulation([0.0, 10.0], [90.0, -90.0])).all()


def test_geoid_on_a_lonlat_grid_is_the_pointwise_undulation(shared_data: Path):
    geoid = Geoid.open(shared_data / GTX)
    # across the antimeridian (wrap-around) and over a pole's row
    for lon0, lat0 in ((179.3, 10.2), (55.6, -21.1), (-10.0, 89.9)):
        lon = lon0 + 0.013 * np.arange(90)
        lat = lat0 - 0.011 * np.arange(7)
        grid = geoid.undulation_grid(lon, lat)
        lon2, lat2 = np.meshgrid(lon, lat)
        np.testing.assert_allclose(grid, geoid.undulation(lon2, lat2), rtol=0, atol=1e-9)
    # a DEM on a lon/lat grid converts separably, a projected one point by point: the same
    dem = DEM.from_array(np.full((40, 60), 10.0), GEO_TRANSFORM, "EPSG:4326", vertical=EGM96)
    np.testing.assert_allclose(
        dem.to_ellipsoid(geoid).heights - 10.0,
        geoid.undulation(*dem.node_lonlat()),
        rtol=0,
        atol=1e-9,
    )


def test_separable_bilinear_sampling_equals_the_pointwise_one():
    from carto.framework.raster.grid_sampling import bilinear_sample, bilinear_sample_grid

    grid = np.random.default_rng(4).normal(size=(9, 12))
    grid[6, 3] = np.nan  # only its neighbours are NaN
    row = np.r_[-0.5, 0.0, np.linspace(0.2, 7.9, 25), 8.0, 8.5]
    col = np.r_[-1.0, np.linspace(0.0, 11.0, 31), 11.2]
    for g in (grid, np.nan_to_num(grid), grid[:1], grid[:, :1]):
        expected = bilinear_sample(g, *np.meshgrid(row, col, indexing="ij"))
        got = bilinear_sample_grid(g, row, col)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert got.shape == (row.size, col.size)


def test_geoid_bad_files(tmp_path: Path):
    with pytest.raises(InputError, match="no such file"):
        Geoid.open(tmp_path / "missing.gtx")
    bad = tmp_path / "bad.gtx"
    bad.write_text("this is not a geoid grid\n")
    with pytest.raises(InputError) as err:
        Geoid.open(bad)
    assert str(bad) in str(err.value)
    assert "\n" not in str(err.value)
    utm = _write_tif(
        tmp_path / "utm.tif", np.zeros((3, 3)), Affine(30, 0, 6e5, 0, -30, 5e6), "EPSG:32631"
    )
    with pytest.raises(InputError, match="not geographic"):
        Geoid.open(utm)


def test_geoid_conversion_of_an_array_dem():
    geoid = Geoid(np.full((3, 5), 48.0), Affine(1.0, 0, 3.5, 0, -1.0, 46.5))  # lon 4..8, lat 44..46
    dem = DEM.from_array(np.full((4, 4), 100.0), GEO_TRANSFORM, "EPSG:4326", vertical="EGM96")
    converted = dem.to_ellipsoid(geoid)
    assert converted.is_ellipsoidal
    np.testing.assert_allclose(converted.heights, 148.0)
    assert converted.to_ellipsoid(geoid) is converted
    far = DEM.from_array(
        np.full((2, 2), 1.0), Affine(1, 0, 20, 0, -1, 10), "EPSG:4326", vertical=EGM96
    )
    with pytest.raises(InputError, match="does not cover"):
        far.to_ellipsoid(geoid)


# ----------------------------------------------------------------------------- writing
@pytest.mark.parametrize(("vertical", "epsg"), [(EGM96, 5773), ("geoid:EGM2008", 3855)])
def test_geoid_heights_are_written_with_the_epsg_vertical_crs(tmp_path: Path, vertical, epsg):
    """Orthometric heights: the compound CRS's vertical part is the geoid model's EPSG CRS;
    without the tag, the CRS alone tells DEM.open the vertical reference."""
    transform = Affine(25.0, 0.0, 640_000.0, 0.0, -25.0, 4_910_000.0)
    dem = DEM.from_array(np.full((8, 9), 120.0), transform, "EPSG:32631", vertical=vertical)
    path = dem.write(tmp_path / "geoid.tif")
    plain = tmp_path / "untagged.tif"  # as a tool that drops our tag would copy it
    with rasterio.open(path) as src:
        crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        assert crs.sub_crs_list[1].to_epsg() == epsg
        assert src.tags()[VERTICAL_TAG] == vertical.replace(":", " ")
        with rasterio.open(plain, "w", **{**src.profile, "driver": "GTiff"}) as dst:
            dst.write(src.read())
    with rasterio.open(plain) as copy:
        assert VERTICAL_TAG not in copy.tags()
    back = DEM.open(plain)
    assert back.vertical == vertical
    assert back.crs.to_epsg() == 32631


def test_write_read_round_trip_utm(tmp_path: Path):
    transform = Affine(25.0, 0.0, 640_000.0, 0.0, -25.0, 4_910_000.0)
    heights = np.random.default_rng(7).normal(800.0, 100.0, (20, 30))
    heights[4, 5] = np.nan
    dem = DEM.from_array(heights, transform, "EPSG:32631", vertical=ELLIPSOID)
    path = dem.write(tmp_path / "out.tif")
    # no temporary file left behind; the 3-D CRS's sidecar
    assert sorted(os.listdir(tmp_path)) == ["out.tif", "out.tif.aux.xml"]
    with rasterio.open(path) as ds:
        assert ds.dtypes == ("float32",)
        assert math.isnan(ds.nodata)
        # GDAL reads the sidecar: the projected CRS made 3-D on EPSG:4979
        crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        assert not crs.is_compound
        assert crs.to_2d().to_epsg() == 32631
        assert crs.geodetic_crs.to_epsg() == 4979
        assert ds.tags()[VERTICAL_TAG] == "ellipsoid WGS84"
        assert ds.units == ("metre",)
        assert ds.transform.almost_equals(transform)
    back = DEM.open(path)
    assert back.crs.equals(dem.crs)
    assert back.vertical == ELLIPSOID
    assert back.transform.almost_equals(transform)
    np.testing.assert_array_equal(np.isnan(back.heights), np.isnan(heights))
    np.testing.assert_allclose(back.heights, heights.astype(np.float32), rtol=0, atol=0)
    # the keys alone (the sidecar lost in a copy): compound, the horizontal CRS and the
    # ellipsoidal heights' vertical CRS, which GDAL, PROJ and QGIS read without our tag
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path) as ds:
        keys = pyproj.CRS.from_wkt(ds.crs.to_wkt())
    assert keys.is_compound
    assert keys.sub_crs_list[0].to_epsg() == 32631
    assert keys.sub_crs_list[1].name == "WGS 84 ellipsoidal height"
    (tmp_path / "out.tif.aux.xml").unlink()
    assert DEM.open(path).vertical == ELLIPSOID
    # rewritten above a geoid, the file keeps no stale sidecar (it would override its keys)
    DEM.from_array(heights, transform, "EPSG:32631", vertical=EGM96).write(path)
    dem.write(path)
    DEM.from_array(heights, transform, "EPSG:32631", vertical=EGM96).write(path)
    assert not (tmp_path / "out.tif.aux.xml").exists()
    assert DEM.open(path).vertical == EGM96

    geoidal = DEM.from_array(heights, GEO_TRANSFORM, "EPSG:4326", vertical=EGM96)
    again = DEM.open(geoidal.write(tmp_path / "geoid.tif"))
    assert again.vertical == EGM96
    assert again.crs.equals("EPSG:4326")
    assert DEM.open(tmp_path / "geoid.tif", vertical="ellipsoid").vertical == ELLIPSOID


def test_write_creates_folders_and_open_errors(tmp_path: Path):
    dem = DEM.constant(1.0, bounds=(0.0, 0.0, 1.0, 1.0))
    written = dem.write(tmp_path / "new" / "folder" / "dem.tif")
    assert DEM.open(written).height(0.5, 0.5) == pytest.approx(1.0)
    assert [p.name for p in written.parent.iterdir()] == ["dem.tif"]  # no temporary left
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="cannot write DEM"):
        dem.write(tmp_path / "file" / "dem.tif")  # parent is a file
    with pytest.raises(InputError, match="no such file"):
        DEM.open(tmp_path / "missing.tif")
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"not a tiff")
    with pytest.raises(InputError, match=r"junk\.tif"):
        DEM.open(junk)
    bad_tag = _write_tif(
        tmp_path / "tag.tif", np.zeros((2, 2)), GEO_TRANSFORM, "EPSG:4326", VERTICAL_REFERENCE="?"
    )
    with pytest.raises(InputError, match=f"{bad_tag}.*{VERTICAL_TAG}"):
        DEM.open(bad_tag)


# ----------------------------------------------------------------------------- location
M_PER_DEG = 111_000.0  # the test sensor's own flat-Earth scale (exactly invertible)


class ObliqueSensor(Sensor):
    """Parallel oblique projection: a ground point moves ``tan_east * h`` metres east per metre
    of height in the image; 1 px = ``gsd`` metres; (lon0, lat0) at (line, sample) = (0, 0)."""

    def __init__(self, tan_east: float, tan_north: float = 0.0, gsd: float = 5.0):
        self.tx, self.ty, self.gsd = tan_east, tan_north, gsd
        self.lon0, self.lat0 = 5.0, 44.6
        self.m_lon = M_PER_DEG * math.cos(math.radians(44.3))

    @property
    def image_shape(self) -> tuple[int, int]:
        return (10_000, 10_000)

    def ground_to_image(self, lon_deg, lat_deg, h_m):
        lon, lat, h = as_float_arrays(lon_deg, lat_deg, h_m)
        east = (lon - self.lon0) * self.m_lon - self.tx * h
        north = (lat - self.lat0) * M_PER_DEG - self.ty * h
        return -north / self.gsd, east / self.gsd

    def image_to_ground(self, line, sample, h_m):
        line, sample, h = as_float_arrays(line, sample, h_m)
        east = sample * self.gsd + self.tx * h
        north = -line * self.gsd + self.ty * h
        return self.lon0 + east / self.m_lon, self.lat0 + north / M_PER_DEG


def test_locate_on_a_steep_plane_matches_the_closed_form():
    """Plane h = h0 + g * east facing the sensor with g * tan = -3: fixed-point iteration
    h <- DEM(h) diverges there (|derivative| 3 > 1), the bracketed search does not."""
    sensor = ObliqueSensor(tan_east=1.0)
    g, h0 = -3.0, 2000.0
    transform = Affine(1 / 3600, 0, 5.0, 0, -1 / 3600, 44.6)  # 1", about 22 x 31 m
    x, _ = _centres(transform, (40, 60))
    dem = DEM.from_array(h0 + g * (x - sensor.lon0) * sensor.m_lon, transform, "EPSG:4326")
    rng = np.random.default_rng(8)
    line = rng.uniform(10, 200, 3000)
    sample = rng.uniform(0, 260, 3000)
    lon, lat, h = dem_surface_locate(sensor, line, sample, dem, tol_m=1e-4)
    east_image = sample * sensor.gsd
    expected_h = (h0 + g * east_image) / (1.0 - g * sensor.tx)  # h = h0 + g (E_img + tan h)
    inside = np.isfinite(dem.height(*sensor.image_to_ground(line, sample, expected_h)))
    assert inside.mean() > 0.8
    np.testing.assert_allclose(h[inside], expected_h[inside], rtol=0, atol=1e-4)
    # consistent triple: the point projects back to the image point
    back_line, back_sample = sensor.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(back_line[inside], line[inside], atol=1e-6)
    np.testing.assert_allclose(back_sample[inside], sample[inside], atol=1e-6)
    assert np.isnan(h[~inside]).all()  # these lines of sight leave the DEM


def _first_cut_by_brute_force(sensor, dem, line, sample):
    """Highest root of DEM(ground(h)) - h: a 0.5 m scan from the top, then bisection.

    Returns the root (NaN when none) and the largest depth under the terrain reached in the
    first run of scan levels below the terrain (small: the ray only grazes a ridge there).
    """
    levels = np.arange(dem.height_range[1] + 1.0, dem.height_range[0] - 1.0, -0.5)

    def f(h):
        return dem.height(*sensor.image_to_ground(line, sample, h)) - h

    values = f(levels[:, None] + 0 * line)
    below = np.isfinite(values) & (values >= 0)
    first = np.argmax(below, axis=0)
    cols = np.arange(line.size)
    found = below.any(axis=0) & np.isfinite(values[np.maximum(first - 1, 0), cols])
    first = np.where(found, first, 1)
    lo, hi = levels[first], levels[first - 1]  # f(lo) >= 0 > f(hi)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        under = f(mid) >= 0
        lo, hi = np.where(under, mid, lo), np.where(under, hi, mid)
    run = np.cumprod(
        below[first.min() :] | (np.arange(levels.size)[first.min() :, None] < first), 0
    )
    depth = np.where(run.astype(bool), values[first.min() :], -np.inf).max(axis=0)
    return np.where(found, 0.5 * (lo + hi), np.nan), depth


def test_locate_finds_the_visible_intersection_on_ridges():
    """Sinusoidal ridges (slopes up to 76 degrees) seen at 45 degrees: lines of sight cut the
    terrain several times; the answer is the first cut from above (truth by brute force)."""
    sensor = ObliqueSensor(tan_east=1.0, tan_north=0.3)
    transform = Affine(1 / 3600, 0, 5.0, 0, -1 / 3600, 44.6)  # 1", about 22 x 31 m
    x, y = _centres(transform, (300, 400))
    east = (x - sensor.lon0) * sensor.m_lon
    north = (y - sensor.lat0) * M_PER_DEG
    heights = 1000.0 + 400.0 * np.sin(2 * np.pi * east / 600.0) + 30.0 * np.cos(north / 300.0)
    dem = DEM.from_array(heights, transform, "EPSG:4326")
    rng = np.random.default_rng(9)
    line = rng.uniform(200, 1500, 400)
    sample = rng.uniform(600, 1400, 400)
    lon, lat, h = dem_surface_locate(sensor, line, sample, dem, tol_m=1e-4)

    truth, depth = _first_cut_by_brute_force(sensor, dem, line, sample)
    found = np.isfinite(truth)
    assert found.sum() > 300
    np.testing.assert_array_equal(np.isnan(h), ~found)
    np.testing.assert_allclose(h[found], dem.height(lon[found], lat[found]), atol=1e-4)
    # where the ray enters the terrain by more than a few metres, it is that first cut; where
    # it only grazes a ridge (shorter than the 1-pixel march step), a lower cut is accepted
    clear = found & (depth > 5.0)
    assert clear.sum() > 0.95 * found.sum()
    np.testing.assert_allclose(h[clear], truth[clear], rtol=0, atol=1e-3)
    assert (h[found & ~clear] <= truth[found & ~clear] + 1e-3).all()
    # several cuts exist: fixed-point iteration from an average height often finds a hidden one
    ridges_crossed = (truth - np.nanmin(dem.heights)) / 400.0
    assert (ridges_crossed[found] > 1.0).sum() > 100


def test_locate_requires_ellipsoidal_heights_and_handles_shapes():
    sensor = ObliqueSensor(tan_east=0.2)
    geoidal = DEM.constant(100.0, vertical=EGM96)
    with pytest.raises(InputError, match="ellipsoidal"):
        dem_surface_locate(sensor, 1.0, 2.0, geoidal)
    flat = DEM.constant(250.0)
    lon, lat, h = dem_surface_locate(sensor, np.full((2, 3), 100.0), np.arange(3.0), flat)
    assert lon.shape == lat.shape == h.shape == (2, 3)
    np.testing.assert_allclose(h, 250.0, atol=1e-3)
    expected = sensor.image_to_ground(100.0, np.arange(3.0), h)
    np.testing.assert_allclose(lon, expected[0], rtol=0, atol=1e-12)
    lon, lat, h = dem_surface_locate(sensor, np.nan, 1.0, flat)
    assert np.isnan(h)


def test_cubic_sample_reproduces_quadratics_and_keeps_voids():
    """Keys' cubic convolution is exact on quadratics (the analytic truth) away from the
    edges, passes through the nodes, and is NaN where a node of its 4 x 4 is void."""
    from carto.framework.raster.grid_sampling import bilinear_sample, cubic_sample

    rows, cols = np.mgrid[0:20, 0:30].astype(float)

    def quadratic(r, c):
        return 3.0 + 0.5 * r - 0.2 * c + 0.07 * r * r - 0.03 * r * c + 0.05 * c * c

    grid = quadratic(rows, cols)
    rng = np.random.default_rng(0)
    r = rng.uniform(1.0, 17.9, 500)
    c = rng.uniform(1.0, 27.9, 500)
    assert np.abs(cubic_sample(grid, r, c) - quadratic(r, c)).max() < 1e-9
    # bilinear is not exact on curvature (what the cubic is for)
    assert np.abs(bilinear_sample(grid, r, c) - quadratic(r, c)).max() > 0.01
    assert np.allclose(cubic_sample(grid, rows, cols), grid)  # through the nodes, edges too
    holed = grid.copy()
    holed[10, 10] = np.nan
    out = cubic_sample(holed, np.array([9.5, 11.5, 8.2, 5.0]), np.array([9.5, 10.5, 11.9, 5.0]))
    assert np.isnan(out[:3]).all()
    assert np.isfinite(out[3])
    assert np.isnan(cubic_sample(grid, np.array([-0.5, 19.5]), np.array([3.0, 3.0]))).all()


def test_values_at_nodes_band_by_band_match_pyproj(monkeypatch):
    """A function of lon/lat at every node of a rotated UTM grid, computed in bands of two
    rows, against the nodes' centres transformed by pyproj directly."""
    import pyproj

    from carto.framework.raster import dem_measures

    transform = Affine(10.0, 2.0, 500_000.0, 1.5, -10.0, 4_900_000.0)
    dem = DEM.from_array(np.zeros((7, 5)), transform, "EPSG:32631")
    monkeypatch.setattr(dem_measures, "NODE_BAND_NODES", 10)  # 2 rows of 5 per band
    calls: list[tuple[int, ...]] = []

    def sample(lon, lat):
        calls.append(np.shape(lon))
        return lon * 1000.0 + lat

    got = dem_measures.values_at_nodes(dem, sample)
    rows, cols = np.mgrid[0:7, 0:5] + 0.5
    x, y = transform * (cols, rows)
    lon, lat = pyproj.Transformer.from_crs(32631, 4326, always_xy=True).transform(x, y)
    np.testing.assert_allclose(got, lon * 1000.0 + lat, rtol=0, atol=1e-6)
    assert calls == [(2, 5), (2, 5), (2, 5), (1, 5)]
