"""Synthetic terrain and ground texture (``carto.framework.simulation.terrain``,
``carto.framework.simulation.texture``).

Truth is independent of the code under test: ground distances from pyproj's geodesic on the
WGS84 ellipsoid, slopes from ``numpy.gradient`` over those distances, flat areas from the raw
heights, Lambertian shading from incidence angles worked out here, planes evaluated
analytically (through pyproj for a UTM plane), local contrast and correlation with OpenCV.
"""

from __future__ import annotations

import hashlib
import math
import subprocess
import sys

import attrs
import cv2
import numpy as np
import pyproj
import pytest
from rasterio.transform import Affine

from carto.framework.errors import InputError
from carto.framework.raster.dem import DEM, EGM96
from carto.framework.simulation.terrain import (
    TERRAINS,
    TerrainPreset,
    geographic_grid,
    make_terrain,
    terrain_from_dem,
    uniform_mask_from_dem,
)
from carto.framework.simulation.texture import Texture, add_point_targets, make_texture

GEOD = pyproj.Geod(ellps="WGS84")
LAT0 = 20.0


def _box(size_m: float, lon0: float = 78.0, lat0: float = LAT0) -> tuple[float, ...]:
    """A square of about ``size_m`` metres with its south-west corner at (lon0, lat0)."""
    dlat = size_m / 110_700.0
    dlon = size_m / (111_320.0 * math.cos(math.radians(lat0 + 0.5 * dlat)))
    return (lon0, lat0, lon0 + dlon, lat0 + dlat)


BOX_2KM = _box(2000.0)


def _spacing_m(transform: Affine, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """East-west and north-south ground spacing (m) of each row, from pyproj's geodesic."""
    lat = transform.f + transform.e * (np.arange(n_rows) + 0.5)
    lon = np.full(n_rows, transform.c)
    dx = GEOD.inv(lon, lat, lon + transform.a, lat)[2]
    dy = GEOD.inv(lon, lat + 0.5 * transform.e, lon, lat - 0.5 * transform.e)[2]
    return np.asarray(dx), np.asarray(dy)


def _slopes_deg(dem: DEM) -> np.ndarray:
    dx, dy = _spacing_m(dem.transform, dem.shape[0])
    d_row, d_col = np.gradient(dem.heights)
    return np.degrees(np.arctan(np.hypot(d_col / dx[:, None], d_row / dy[:, None])))


def _local_std(image: np.ndarray, size: int = 9) -> np.ndarray:
    image = image.astype(np.float64)
    mean = cv2.blur(image, (size, size))
    return np.sqrt(np.maximum(cv2.blur(image * image, (size, size)) - mean * mean, 0.0))


@pytest.fixture(scope="module")
def dems() -> dict[str, DEM]:
    """Every preset over 2 km x 2 km at 5 m posting."""
    return {name: make_terrain(name, BOX_2KM, 5.0, seed=1) for name in TERRAINS}


@pytest.fixture(scope="module")
def coastal_texture(dems: dict[str, DEM]) -> Texture:
    return make_texture(dems["flat-coastal"], 1.0, seed=3)


@pytest.fixture(scope="module")
def plains_texture(dems: dict[str, DEM]) -> Texture:
    return make_texture(dems["plains"], 1.0, seed=3)


# ----------------------------------------------------------------------------- presets, grid
def test_presets_cover_the_sites_of_the_paper():
    expected = {
        "flat-coastal": (0.0, 50.0),
        "plains": (200.0, 300.0),
        "mixed": (500.0, 700.0),
        "hilly": (200.0, 800.0),
        "mountains": (4000.0, 6000.0),
    }
    assert set(expected) <= set(TERRAINS)
    for name, (h_min, h_max) in expected.items():
        preset = TERRAINS[name]
        assert preset.name == name
        assert (preset.h_min_m, preset.h_max_m) == (h_min, h_max)
        assert preset.description
    assert TERRAINS["flat-coastal"].uniform_fraction >= 0.25
    assert TERRAINS["mountains"].ridge_weight > 0.0
    with pytest.raises(attrs.exceptions.FrozenInstanceError):
        TERRAINS["plains"].h_max_m = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        TERRAINS["new"] = TERRAINS["plains"]  # type: ignore[index]


@pytest.mark.parametrize("lat0", [-33.0, 0.0, 20.0, 62.0])
def test_grid_posting_is_the_ground_distance_at_the_centre_latitude(lat0: float):
    bounds = _box(3000.0, lon0=10.0, lat0=lat0)
    dem = make_terrain("plains", bounds, 7.5, seed=0)
    t = dem.transform
    assert dem.crs.equals("EPSG:4326")
    assert dem.is_ellipsoidal
    assert (t.b, t.d) == (0.0, 0.0)
    assert t.a > 0.0 > t.e
    lat_c = 0.5 * (bounds[1] + bounds[3])
    east_west = GEOD.inv(10.0, lat_c, 10.0 + t.a, lat_c)[2]
    north_south = GEOD.inv(10.0, lat_c - 0.5 * abs(t.e), 10.0, lat_c + 0.5 * abs(t.e))[2]
    assert east_west == pytest.approx(7.5, rel=1e-7)
    assert north_south == pytest.approx(7.5, rel=1e-7)
    # first pixel centre on the north-west corner; the centres cover the bounds by < 1 pixel
    west, south, east, north = dem.bounds_lonlat
    assert west == pytest.approx(bounds[0], abs=1e-12)
    assert north == pytest.approx(bounds[3], abs=1e-12)
    assert bounds[2] <= east < bounds[2] + t.a
    assert bounds[1] - abs(t.e) < south <= bounds[1]
    assert geographic_grid(bounds, 7.5) == (t, dem.shape)


# ----------------------------------------------------------------------------- heights
@pytest.mark.parametrize("name", list(TERRAINS))
def test_heights_stay_in_the_preset_range_and_span_most_of_it(name: str):
    preset = TERRAINS[name]
    dem = make_terrain(name, _box(20_000.0), 50.0, seed=5)  # 400 x 400 pixels
    heights = dem.heights
    assert np.isfinite(heights).all()
    assert heights.min() >= preset.h_min_m
    assert heights.max() <= preset.h_max_m
    assert np.ptp(heights) >= 0.7 * (preset.h_max_m - preset.h_min_m)


def test_same_seed_gives_identical_heights_and_another_seed_other_heights(dems):
    again = make_terrain("hilly", BOX_2KM, 5.0, seed=1)
    assert np.array_equal(again.heights, dems["hilly"].heights)
    assert again.transform == dems["hilly"].transform
    other = make_terrain("hilly", BOX_2KM, 5.0, seed=2)
    assert np.mean(np.abs(other.heights - again.heights)) > 20.0


def test_results_are_identical_across_processes():
    """Bit-identical heights and texture in a fresh interpreter (no hidden global state)."""
    code = (
        "import hashlib, sys\n"
        "from carto.framework.simulation.terrain import make_terrain\n"
        "from carto.framework.simulation.texture import make_texture\n"
        "dem = make_terrain('flat-coastal', (78.0, 20.0, 78.01, 20.01), 10.0, seed=7)\n"
        "tex = make_texture(dem, 2.5, seed=7)\n"
        "print(hashlib.sha256(dem.heights.tobytes()).hexdigest(),"
        " hashlib.sha256(tex.reflectance.tobytes()).hexdigest())\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    dem = make_terrain("flat-coastal", (78.0, 20.0, 78.01, 20.01), 10.0, seed=7)
    tex = make_texture(dem, 2.5, seed=7)
    here = (
        hashlib.sha256(dem.heights.tobytes()).hexdigest(),
        hashlib.sha256(tex.reflectance.tobytes()).hexdigest(),
    )
    assert tuple(out.stdout.split()) == here


def test_mountains_are_steeper_than_hills_than_plains(dems):
    p50 = {name: np.percentile(_slopes_deg(dem), 50) for name, dem in dems.items()}
    assert p50["plains"] < p50["mixed"] < p50["hilly"] < p50["mountains"]
    plains = _slopes_deg(dems["plains"])
    assert np.percentile(plains, 99) < 5.0
    mountains = _slopes_deg(dems["mountains"])
    assert 12.0 < np.percentile(mountains, 50) < 32.0
    # steep slopes, up to 35-45 degrees in places
    assert np.percentile(mountains, 99) > 30.0
    assert 40.0 < mountains.max() < 75.0


def test_terrain_is_stationary_and_its_edges_do_not_wrap(dems):
    h = dems["mountains"].heights
    neighbour = np.mean(np.abs(np.diff(h, axis=1)))
    assert np.mean(np.abs(h[:, 0] - h[:, -1])) > 20.0 * neighbour
    assert np.mean(np.abs(h[0, :] - h[-1, :])) > 20.0 * neighbour
    # the roughness near the edges is that of the middle (no padding artefacts)
    band = h.shape[0] // 10
    edge = np.concatenate([np.diff(h[:band], axis=1).ravel(), np.diff(h[-band:], axis=1).ravel()])
    middle = np.diff(h[4 * band : 6 * band], axis=1).ravel()
    assert 0.6 < np.sqrt(np.mean(edge**2)) / np.sqrt(np.mean(middle**2)) < 1.6


def test_flat_coastal_has_large_flat_areas():
    fractions = []
    for seed in (1, 2, 3):
        dem = make_terrain("flat-coastal", _box(12_000.0), 40.0, seed=seed)
        flat = dem.heights == TERRAINS["flat-coastal"].h_min_m
        fractions.append(flat.mean())
        largest = np.bincount(cv2.connectedComponents(flat.astype(np.uint8))[1].ravel())[1:]
        assert largest.max() * 40.0**2 > 1e6  # a flat area of more than 1 km2
        mask = uniform_mask_from_dem(dem)  # exactly flat 3 x 3 windows: flat but thin slivers
        assert not (mask & ~flat).any()
        assert mask.sum() >= 0.97 * flat.sum()
    assert 0.2 < np.mean(fractions) < 0.5
    plains = make_terrain("plains", _box(12_000.0), 40.0, seed=1)
    assert (plains.heights == 200.0).mean() < 0.1
    mountains = make_terrain("mountains", _box(12_000.0), 40.0, seed=1)
    assert not uniform_mask_from_dem(mountains).any()


# ----------------------------------------------------------------------------- terrain_from_dem
def test_terrain_from_dem_reproduces_a_geographic_plane():
    # plane in lon/lat on a 0.001-degree grid: bilinear interpolation is exact
    transform = Affine(0.001, 0.0, 77.99, 0.0, -0.001, 20.03)
    rows, cols = np.meshgrid(np.arange(60) + 0.5, np.arange(60) + 0.5, indexing="ij")
    lon, lat = 77.99 + 0.001 * cols, 20.03 - 0.001 * rows
    plane = DEM.from_array(300.0 + 2000.0 * (lon - 78.0) - 3000.0 * (lat - 20.0), transform, 4326)
    dem = terrain_from_dem(plane, BOX_2KM, 5.0)
    assert dem.transform == geographic_grid(BOX_2KM, 5.0)[0]
    lon_c = dem.transform.c + dem.transform.a * (np.arange(dem.shape[1]) + 0.5)
    lat_c = dem.transform.f + dem.transform.e * (np.arange(dem.shape[0]) + 0.5)
    lon_c = np.minimum(lon_c, BOX_2KM[2])  # the overhang is sampled at the bound
    lat_c = np.maximum(lat_c, BOX_2KM[1])
    truth = 300.0 + 2000.0 * (lon_c[None, :] - 78.0) - 3000.0 * (lat_c[:, None] - 20.0)
    np.testing.assert_allclose(dem.heights, truth, atol=1e-9)


def test_terrain_from_dem_reproduces_a_utm_plane():
    # plane in UTM 44N metres; truth evaluated at the grid nodes through pyproj
    to_utm = pyproj.Transformer.from_crs(4326, 32644, always_xy=True)
    e0, n0 = to_utm.transform(77.995, 20.025)
    transform = Affine(30.0, 0.0, e0, 0.0, -30.0, n0)
    rows, cols = np.meshgrid(np.arange(120) + 0.5, np.arange(120) + 0.5, indexing="ij")
    east, north = e0 + 30.0 * cols, n0 - 30.0 * rows
    plane = DEM.from_array(500.0 + 0.02 * (east - e0) + 0.05 * (north - n0), transform, 32644)
    bounds = _box(1000.0)
    dem = terrain_from_dem(plane, bounds, 10.0)
    lon_c = dem.transform.c + dem.transform.a * (np.arange(dem.shape[1]) + 0.5)
    lat_c = dem.transform.f + dem.transform.e * (np.arange(dem.shape[0]) + 0.5)
    lon2, lat2 = np.meshgrid(np.minimum(lon_c, bounds[2]), np.maximum(lat_c, bounds[1]))
    e, n = to_utm.transform(lon2, lat2)
    np.testing.assert_allclose(dem.heights, 500.0 + 0.02 * (e - e0) + 0.05 * (n - n0), atol=1e-6)


def test_terrain_from_dem_errors():
    small = DEM.constant(100.0, bounds=(78.0, 20.0, 78.01, 20.01))
    with pytest.raises(InputError, match=r"does not cover|no height"):
        terrain_from_dem(small, BOX_2KM, 5.0)
    geoid = DEM.constant(100.0, bounds=(77.0, 19.0, 79.0, 21.0), vertical=EGM96)
    with pytest.raises(InputError, match="ellipsoidal"):
        terrain_from_dem(geoid, BOX_2KM, 5.0)
    holes = np.full((50, 50), 100.0)
    holes[25, 25] = np.nan
    dem = DEM.from_array(holes, Affine(0.001, 0, 77.99, 0, -0.001, 20.03), 4326)
    with pytest.raises(InputError, match=r"nodata|no height"):
        terrain_from_dem(dem, BOX_2KM, 5.0)
    # a DEM covering exactly the bounds is enough
    exact = DEM.constant(100.0, bounds=BOX_2KM)
    assert np.all(terrain_from_dem(exact, BOX_2KM, 5.0).heights == 100.0)


# ----------------------------------------------------------------------------- texture
def test_texture_grid_values_and_determinism(dems, plains_texture):
    tex = plains_texture
    dem = dems["plains"]
    assert tex.crs.equals("EPSG:4326")
    assert tex.reflectance.dtype == np.float32
    assert not tex.reflectance.flags.writeable
    assert tex.reflectance.min() >= 0.0
    assert tex.reflectance.max() <= 1.0
    t = tex.transform
    lat_c = 0.5 * (BOX_2KM[1] + BOX_2KM[3])
    assert GEOD.inv(78.0, lat_c, 78.0 + t.a, lat_c)[2] == pytest.approx(1.0, rel=1e-3)
    # same first pixel centre as the DEM; covers the DEM's centres by less than a pixel
    dw, ds, de, dn = dem.bounds_lonlat
    w, s, e, n = tex.bounds_lonlat
    assert (w, n) == pytest.approx((dw, dn), abs=1e-12)
    assert de <= e < de + t.a
    assert ds - abs(t.e) < s <= ds
    # value(): bilinear between pixel centres, NaN outside
    r, c = 700, 900
    lon = t.c + t.a * (c + 0.5 + 0.25)
    lat = t.f + t.e * (r + 0.5)
    expected = 0.75 * tex.reflectance[r, c] + 0.25 * tex.reflectance[r, c + 1]
    assert tex.value(lon, lat) == pytest.approx(expected, abs=1e-6)
    assert np.isnan(tex.value(w - t.a, n))
    # determinism
    again = make_texture(dem, 1.0, seed=3)
    assert np.array_equal(again.reflectance, tex.reflectance)
    other = make_texture(dem, 1.0, seed=4)
    assert np.mean(np.abs(other.reflectance - tex.reflectance)) > 0.02


def test_texture_has_contrast_over_land_and_almost_none_over_water(dems, coastal_texture):
    tex = coastal_texture
    dem = dems["flat-coastal"]
    # truth: texture pixels whose four surrounding DEM nodes are all exactly at h_min (0 m)
    t, d = tex.transform, dem.transform
    rows = (t.f + t.e * (np.arange(tex.shape[0]) + 0.5) - d.f) / d.e - 0.5
    cols = (t.c + t.a * (np.arange(tex.shape[1]) + 0.5) - d.c) / d.a - 0.5
    r0 = np.clip(np.floor(rows).astype(int), 0, dem.shape[0] - 2)
    c0 = np.clip(np.floor(cols).astype(int), 0, dem.shape[1] - 2)
    flat = dem.heights == 0.0
    cell = flat[:-1, :-1] & flat[1:, :-1] & flat[:-1, 1:] & flat[1:, 1:]
    water = cell[np.ix_(r0, c0)].astype(np.uint8)
    kernel = np.ones((21, 21), np.uint8)
    inner_water = cv2.erode(water, kernel).astype(bool)
    inner_land = cv2.erode(1 - water, kernel).astype(bool)
    assert inner_water.mean() > 0.1
    assert inner_land.mean() > 0.1
    std9 = _local_std(tex.reflectance)
    assert np.median(std9[inner_land]) > 0.012
    assert np.percentile(std9[inner_land], 10) > 0.004
    assert np.median(std9[inner_water]) < 0.003
    assert np.percentile(std9[inner_water], 99) < 0.005
    # the texture's own mask agrees with the DEM's flat areas
    assert abs(tex.uniform_fraction - water.mean()) < 0.02
    assert tex.uniform_mask[inner_water].all()
    assert not tex.uniform_mask[inner_land].any()
    # contrast at the scale of parcels: std of 33 x 33 block means
    land = tex.reflectance[:1980, 1000:1990]
    blocks = land.reshape(60, 33, 30, 33).mean(axis=(1, 3))
    assert blocks.std() > 0.03


def test_texture_is_not_periodic_and_matches_only_where_it_should(plains_texture):
    image = plains_texture.reflectance.astype(np.float64)
    land = ~plains_texture.uniform_mask
    # two different 128 x 128 patches: low normalised cross-correlation
    rng = np.random.default_rng(0)
    correlations = []
    while len(correlations) < 40:
        (r1, r2), (c1, c2) = rng.integers(0, 1850, size=(2, 2))
        a, b = image[r1 : r1 + 128, c1 : c1 + 128], image[r2 : r2 + 128, c2 : c2 + 128]
        if max(abs(r1 - r2), abs(c1 - c2)) < 128 or a.shape != b.shape:
            continue
        if not (
            land[r1 : r1 + 128, c1 : c1 + 128].all() and land[r2 : r2 + 128, c2 : c2 + 128].all()
        ):
            continue
        a, b = a - a.mean(), b - b.mean()
        correlations.append(float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b))))
    assert np.mean(np.abs(correlations)) < 0.25
    assert np.max(np.abs(correlations)) < 0.75
    # no period: the autocorrelation of the high-passed texture has no peak beyond 50 pixels
    high = image - cv2.blur(image, (33, 33))
    for r, c in [(1000, 1000), (200, 1200)]:
        region = high[r : r + 512, c : c + 512] - high[r : r + 512, c : c + 512].mean()
        spectrum = np.fft.rfft2(region, s=(1024, 1024))
        auto = np.fft.fftshift(np.fft.irfft2(np.abs(spectrum) ** 2, s=(1024, 1024)))
        auto /= auto[512, 512]
        lag = np.hypot(*np.indices(auto.shape) - 512)
        assert auto[(lag > 50) & (lag < 256)].max() < 0.2
    # a 25 x 25 pixel template is found at its own place, and nowhere else nearly as well
    for r, c in [(400, 300), (1000, 1500), (1600, 900)]:
        template = plains_texture.reflectance[r : r + 25, c : c + 25]
        search = plains_texture.reflectance[r - 100 : r + 125, c - 100 : c + 125]
        score = cv2.matchTemplate(search, template, cv2.TM_CCOEFF_NORMED)
        best = np.unravel_index(np.argmax(score), score.shape)
        assert best == (100, 100)
        score[90:111, 90:111] = -1.0
        assert score.max() < 0.8


def test_shading_is_lambertian_with_the_given_sun():
    # two planes of 20 deg slope, one facing the sun (south-east), one facing away
    transform, shape = geographic_grid(BOX_2KM, 10.0)
    dx, dy = _spacing_m(transform, shape[0])
    rows, cols = np.indices(shape, dtype=np.float64)
    tilt = math.tan(math.radians(20.0))
    east_m, north_m = cols * dx[:, None], -rows * dy[:, None]
    aspects = {"towards": 135.0, "away": 315.0}  # downslope direction, clockwise from north
    values = {}
    for key, aspect in aspects.items():
        a = math.radians(aspect)
        heights = 1000.0 - tilt * (east_m * math.sin(a) + north_m * math.cos(a))
        dem = DEM.from_array(heights, transform, 4326)
        tex = make_texture(dem, 2.0, seed=1, sun_elevation_deg=40.0, sun_azimuth_deg=135.0)
        values[key] = tex.reflectance.astype(np.float64)
    # same albedo (same seed, same slope), so the ratio is the ratio of the shading:
    # incidence angle = sun zenith -/+ slope, shading 0.2 + 0.8 cos(i) / sin(elevation)
    sin_el = math.sin(math.radians(40.0))
    towards = 0.2 + 0.8 * math.cos(math.radians(50.0 - 20.0)) / sin_el
    away = 0.2 + 0.8 * math.cos(math.radians(50.0 + 20.0)) / sin_el
    ok = (values["towards"] > 0.02) & (values["towards"] < 0.99) & (values["away"] > 0.02)
    ratio = values["away"][ok] / values["towards"][ok]
    assert np.percentile(ratio, [1, 50, 99]) == pytest.approx(away / towards, rel=5e-3)


def test_point_targets_are_centred_on_the_ground_points(plains_texture):
    tex = plains_texture
    t = tex.transform
    rng = np.random.default_rng(2)
    rows = rng.uniform(200, 1700, 6)
    cols = rng.uniform(200, 1700, 6)
    lon = t.c + t.a * (cols + 0.5)  # fractional centre index -> lon/lat, from the transform
    lat = t.f + t.e * (rows + 0.5)
    radius = 2.5  # metres: about 2.5 texture pixels
    out = add_point_targets(tex, lon, lat, radius, 0.6)
    assert not np.shares_memory(out.reflectance, tex.reflectance)
    assert out.transform == tex.transform
    for r, c in zip(rows, cols, strict=True):
        r0, c0 = round(r), round(c)
        window = out.reflectance[r0 - 10 : r0 + 11, c0 - 10 : c0 + 11].astype(np.float64)
        rr, cc = np.mgrid[r0 - 10 : r0 + 11, c0 - 10 : c0 + 11]
        inside = np.hypot(rr - r, cc - c) <= 9.5  # within the flat pad (4 radii ~ 10 px)
        weight = np.where(inside, window - window[inside].min(), 0.0)
        assert np.sum(weight * rr) / weight.sum() == pytest.approx(r, abs=0.05)
        assert np.sum(weight * cc) / weight.sum() == pytest.approx(c, abs=0.05)
        assert window.max() - window[inside].min() == pytest.approx(0.6, abs=0.03)
    # on a constant texture the blob is exactly the Gaussian
    flat = Texture(np.full((200, 200), 0.2, np.float32), t, np.zeros((200, 200), bool), 1.0)
    r, c = 101.3, 97.8
    one = add_point_targets(flat, t.c + t.a * (c + 0.5), t.f + t.e * (r + 0.5), 3.0, 0.5)
    blob = one.reflectance.astype(np.float64) - 0.2
    rr, cc = np.indices(blob.shape)
    assert np.sum(blob * rr) / blob.sum() == pytest.approx(r, abs=0.01)
    assert np.sum(blob * cc) / blob.sum() == pytest.approx(c, abs=0.01)
    with pytest.raises(InputError, match="not inside"):
        add_point_targets(flat, t.c, t.f, 3.0, 0.5)
    with pytest.raises(InputError, match="not inside"):
        add_point_targets(flat, [t.c + t.a * 100, np.nan], t.f + t.e * 100, 3.0, 0.5)
    with pytest.raises(InputError, match="contrast"):
        add_point_targets(flat, t.c + t.a * 100, t.f + t.e * 100, 3.0, 1.5)
    with pytest.raises(InputError, match="radius_m"):
        add_point_targets(flat, t.c + t.a * 100, t.f + t.e * 100, 0.0, 0.5)


# ----------------------------------------------------------------------------- errors
def test_unknown_terrain_names_the_known_ones():
    with pytest.raises(InputError, match=r"unknown terrain 'alps'.*flat-coastal.*mountains"):
        make_terrain("alps", BOX_2KM, 5.0, seed=0)


@pytest.mark.parametrize(
    ("bounds", "posting", "seed", "match"),
    [
        ((78.1, 20.0, 78.0, 20.1), 5.0, 0, "west < east"),
        ((78.0, 20.0, 78.1, float("nan")), 5.0, 0, "finite"),
        ((78.0, 20.0, 78.1), 5.0, 0, "4 numbers"),
        ((78.0, 86.0, 78.1, 86.1), 5.0, 0, "-85..85"),
        ((78.0, 20.0, 90.0, 20.1), 5.0, 0, "10 degrees"),
        (BOX_2KM, 0.0, 0, "posting_m"),
        (BOX_2KM, float("inf"), 0, "posting_m"),
        (BOX_2KM, "5 m", 0, "posting_m"),
        ((78.0, 20.0, 79.0, 21.0), 0.5, 0, "grid of"),
        (BOX_2KM, 5.0, -1, "seed"),
        (BOX_2KM, 5.0, 1.5, "seed"),
        (BOX_2KM, 5.0, True, "seed"),
    ],
)
def test_bad_arguments_raise_input_errors(bounds, posting, seed, match):
    with pytest.raises(InputError, match=match):
        make_terrain("plains", bounds, posting, seed)


def test_bad_presets_and_texture_arguments(dems):
    with pytest.raises(InputError, match="h_min_m < h_max_m"):
        TerrainPreset("x", "", 10.0, 5.0, correlation_length_m=1000.0, spectral_exponent=4.0)
    with pytest.raises(InputError, match="spectral_exponent"):
        TerrainPreset("x", "", 0.0, 5.0, correlation_length_m=1000.0, spectral_exponent=1.0)
    custom = TerrainPreset("x", "", 0.0, 5.0, correlation_length_m=500.0, spectral_exponent=4.0)
    assert np.ptp(make_terrain(custom, _box(500.0), 10.0, seed=0).heights) > 0.0
    dem = dems["plains"]
    with pytest.raises(InputError, match="sun_elevation_deg"):
        make_texture(dem, 1.0, 0, sun_elevation_deg=0.0)
    with pytest.raises(InputError, match="uniform_mask"):
        make_texture(dem, 1.0, 0, uniform_mask=np.zeros((3, 3), bool))
    with pytest.raises(InputError, match="posting_m"):
        make_texture(dem, -1.0, 0)
    utm = DEM.from_array(np.zeros((10, 10)), Affine(30, 0, 500000, 0, -30, 2200000), 32644)
    with pytest.raises(InputError, match="EPSG:4326"):
        make_texture(utm, 1.0, 0)


def test_urban_has_flat_roofs_vertical_walls_and_the_share_of_buildings():
    """Truth from the heights alone: a building is where the ground stands at least the
    lowest building height above the 7 x 7 minimum (the street next to it)."""
    from scipy import ndimage

    preset = TERRAINS["urban"]
    dem = make_terrain("urban", BOX_2KM, 2.5, seed=4)  # 800 x 800 nodes, 25 blocks a side
    h = dem.heights
    ground = ndimage.minimum_filter(h, size=int(preset.block_m / 2.5))
    building = h - ground >= preset.building_heights_m[0] - 0.5
    assert 0.2 < building.mean() < 0.45  # 0.35 expected, the draws vary
    # walls: height steps between neighbours of at least the lowest building
    steps = np.abs(np.diff(h, axis=1))
    assert (steps > preset.building_heights_m[0]).mean() > 0.01
    # roofs are flat: inside a building the relief of the plains only (cm per node)
    inner = (
        ndimage.binary_erosion(building, iterations=2)[:, :-1]
        & ndimage.binary_erosion(building, iterations=2)[:, 1:]
    )
    assert np.percentile(steps[inner], 99) < 0.2
    assert h.max() <= preset.h_max_m
    assert h.min() >= preset.h_min_m
    heights_of_buildings = (h - ground)[building]
    assert heights_of_buildings.max() > 0.8 * preset.building_heights_m[1]
