"""Orthorectification against independent truth: the simulator's true ortho-image.

The simulator renders each raw image through its true model over the true DEM, and writes the
true ground reflectance resampled on a UTM grid at the GSD (``truth/ortho.tif``). Ortho-images
of the raw images made with the true models on the true DEM must coincide with it
geometrically. Raw Cartosat images interleave two staggered arrays five lines apart, which one
sensor model cannot describe; these scenes are rendered with single-array cameras
(``stagger_m = 0``), everything else as in the ``cartosat1-pair`` preset.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import attrs
import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine
from rasterio.errors import NotGeoreferencedWarning
from scipy import ndimage

from carto.framework import get_registry
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho import OrthoMapper, ortho_mapping, orthorectify, write_ortho
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.simulation.simulate import simulate_scene


def simulate_single_array(out: Path, **options) -> Scene:
    """A ``cartosat1-pair`` scene whose cameras have one (unstaggered) array."""
    opts = SimulationOptions(**options)
    plan = get_registry().get("scene-preset", "cartosat1-pair").plan(opts)
    segment = plan.segments[0]
    views = tuple(
        attrs.evolve(v, camera=attrs.evolve(v.camera, stagger_m=0.0)) for v in segment.views
    )
    plan = attrs.evolve(plan, segments=(attrs.evolve(segment, views=views),))
    simulate_scene(plan, out, opts, quiet=True)
    return Scene.open(out)


@pytest.fixture(scope="module")
def hilly(tmp_path_factory) -> Scene:
    return simulate_single_array(
        tmp_path_factory.mktemp("ortho_hilly"),
        seed=3,
        size=(400, 400),
        terrain="hilly",
        n_gcps=0,
        n_checkpoints=0,
    )


@pytest.fixture(scope="module")
def mountains(tmp_path_factory) -> Scene:
    return simulate_single_array(
        tmp_path_factory.mktemp("ortho_mountains"),
        seed=5,
        size=(300, 300),
        terrain="mountains",
        n_gcps=0,
        n_checkpoints=0,
    )


def read_raw(scene: Scene, name: str) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # raw images have no CRS
        with rasterio.open(scene.raster(name)) as ds:
            return ds.read(1)


def truth_grid(scene: Scene) -> tuple[OrthoGrid, np.ndarray]:
    with rasterio.open(scene.path("truth/ortho.tif")) as ds:
        return OrthoGrid(ds.crs.to_wkt(), ds.transform, ds.shape), ds.read(1).astype(float)


def exact_mapping(sensor: Sensor, grid: OrthoGrid, dem: DEM) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel reference, written independently of carto.framework.imaging.ortho."""
    rows, cols = np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]]
    t = grid.transform
    x = t.c + t.a * (cols + 0.5)
    y = t.f + t.e * (rows + 0.5)
    to_ll = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform(x, y)
    return sensor.ground_to_image(lon, lat, dem.height(lon, lat))


def lsm_shift(reference: np.ndarray, image: np.ndarray) -> np.ndarray:
    """``d`` (rows, cols) with ``image(x + d) = gain * reference(x) + offset``: least-squares
    matching (Gauss-Newton, cubic-spline resampling), independent of
    carto.framework.matching.lsm."""
    d = np.zeros(2)
    rows, cols = np.mgrid[0 : image.shape[0], 0 : image.shape[1]].astype(float)
    inner = np.zeros(image.shape, bool)
    inner[4:-4, 4:-4] = True
    for _ in range(20):
        warped = ndimage.map_coordinates(image, [rows + d[0], cols + d[1]], order=3)
        g_r, g_c = np.gradient(warped)
        a = np.stack([g_r[inner], g_c[inner], -reference[inner], -np.ones(inner.sum())], 1)
        step = np.linalg.lstsq(a, -warped[inner], rcond=None)[0][:2]
        d += step
        if np.hypot(*step) < 1e-6:
            break
    return d


def window_shifts(truth: np.ndarray, ortho: np.ndarray, size: int = 64) -> np.ndarray:
    """Shifts of ``ortho`` against ``truth`` on every complete ``size`` window of both."""
    valid = np.isfinite(truth) & np.isfinite(ortho)
    shifts = []
    for r in range(0, truth.shape[0] - size, size):
        for c in range(0, truth.shape[1] - size, size):
            if valid[r : r + size, c : c + size].all():
                window = np.s_[r : r + size, c : c + size]
                shifts.append(lsm_shift(truth[window], ortho[window]))
    return np.array(shifts)


class ShiftedSensor(Sensor):
    """A sensor whose image coordinates are off by ``delta`` pixels (a convention error)."""

    def __init__(self, sensor: Sensor, delta: float) -> None:
        self.sensor, self.delta = sensor, delta

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.sensor.image_shape

    def ground_to_image(self, lon_deg, lat_deg, h_m):
        line, sample = self.sensor.ground_to_image(lon_deg, lat_deg, h_m)
        return line + self.delta, sample + self.delta

    def image_to_ground(self, line, sample, h_m):
        return self.sensor.image_to_ground(
            np.asarray(line) - self.delta, np.asarray(sample) - self.delta, h_m
        )


# ----------------------------------------------------------------------------- grid
def test_grid_covering_one_and_two_footprints(hilly):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensors = hilly.truth_sensors()
    grids = {n: OrthoGrid.covering(s, dem, 2.5) for n, s in sensors.items()}
    both = OrthoGrid.covering(list(sensors.values()), dem, 2.5)
    to_map = pyproj.Transformer.from_crs("EPSG:4326", both.crs, always_xy=True)
    assert both.crs.to_epsg() == 32643  # UTM 43N at 77.95 E, 30.3 N
    for name, sensor in sensors.items():
        grid = grids[name]
        assert grid.resolution == (2.5, 2.5)
        t = grid.transform
        assert (t.c / 2.5).is_integer()  # snapped
        assert (t.f / 2.5).is_integer()
        n_l, n_s = sensor.image_shape
        edge = np.linspace(0, 1, 21)
        line = np.concatenate([0 * edge, edge * n_l, 0 * edge + n_l, edge * n_l])
        sample = np.concatenate([edge * n_s, 0 * edge, edge * n_s, 0 * edge + n_s])
        lon, lat, _ = sensor.locate_on_dem(line, sample, dem)
        x, y = to_map.transform(lon, lat)
        for g in (grid, both):
            left, bottom, right, top = g.bounds
            assert np.all((x >= left) & (x <= right) & (y >= bottom) & (y <= top))
        # tight: within one pixel of the footprint's box
        left, bottom, right, top = grid.bounds
        assert max(x.min() - left, right - x.max()) < 2.5
        assert max(y.min() - bottom, top - y.max()) < 2.5


def test_grid_from_bounds_is_snapped_outwards(hilly):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["aft"]
    grid = OrthoGrid.covering(sensor, dem, 5.0, crs="EPSG:32643", bounds=(1001, 2002, 1499, 2999))
    assert grid.bounds == (1000.0, 2000.0, 1500.0, 3000.0)
    assert grid.shape == (200, 100)
    sub = grid.window(10, 20, 5, 6)
    assert sub.xy(0, 0) == grid.xy(10, 20)
    assert sub.shape == (5, 6)
    # rowcol inverts lonlat (fractional pixel indices, centres at whole numbers)
    rows, cols = np.array([0.0, 10.25, 199.0]), np.array([0.0, 20.5, 99.75])
    lon, lat = grid.lonlat(rows, cols)
    back = grid.rowcol(lon, lat)
    np.testing.assert_allclose(back, (rows, cols), atol=1e-6)
    x, y = grid.map_xy(lon, lat)
    np.testing.assert_allclose((x, y), grid.xy(rows, cols), atol=1e-6)


# ----------------------------------------------------------------------------- mapping
def test_mapping_matches_exact_per_pixel_on_rough_terrain(mountains):
    """4000-6000 m mountains with 35-45 deg slopes, posting 4.5 m: the interpolated mapping
    (coarse step 16 and 64) stays within 0.01 px of the exact per-pixel mapping."""
    dem = DEM.open(mountains.path("truth/dem.tif"))
    for sensor in mountains.truth_sensors().values():
        grid = OrthoGrid.covering(sensor, dem, 2.5)
        ref_l, ref_s = exact_mapping(sensor, grid, dem)
        for step in (16, 64):
            mapper = OrthoMapper(sensor, grid, dem, coarse_step=step)
            line, sample = mapper.map()
            both = np.isfinite(line) & np.isfinite(ref_l)
            assert both.sum() > 0.5 * line.size
            # NaN exactly where the exact mapping is outside the image (tolerance at the edge)
            assert np.sum(np.isfinite(line) != np.isfinite(ref_l)) <= 1e-3 * line.size
            error = np.hypot(line - ref_l, sample - ref_s)[both]
            assert error.max() < 0.01, (step, error.max())
            assert mapper.stats.max_check_error_px < 0.01 or mapper.stats.cells_exact > 0


def test_mapping_with_a_projected_dem_and_a_geographic_grid(hilly):
    """Other CRSs: the DEM resampled on a UTM grid, the ortho on a lon/lat grid."""
    truth_dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["fore"]
    utm = OrthoGrid.covering(sensor, truth_dem, 5.0)
    rows, cols = np.mgrid[-20 : utm.shape[0] + 20, -20 : utm.shape[1] + 20]
    heights = truth_dem.height(*utm.lonlat(rows, cols))
    dem = DEM.from_array(heights, utm.transform @ Affine.translation(-20, -20), utm.crs)
    for grid in (
        OrthoGrid.covering(sensor, dem, 2.5),
        OrthoGrid.covering(sensor, dem, 2.5e-5, crs="EPSG:4326"),
    ):
        ref_l, ref_s = exact_mapping(sensor, grid, dem)
        line, sample = ortho_mapping(sensor, grid, dem)
        both = np.isfinite(line) & np.isfinite(ref_l)
        assert both.sum() > 0.5 * line.size
        assert np.hypot(line - ref_l, sample - ref_s)[both].max() < 0.01


def test_naive_interpolation_fails_where_the_dem_is_rough(mountains):
    """The reason for the height-aware scheme: image coordinates interpolated between exact
    nodes (each at its own DEM height) are off by far more than 0.01 px on this terrain."""
    dem = DEM.open(mountains.path("truth/dem.tif"))
    sensor = mountains.truth_sensors()["fore"]
    grid = OrthoGrid.covering(sensor, dem, 2.5)
    ref_l, _ = exact_mapping(sensor, grid, dem)
    step = 16
    nodes_r = np.arange(0, grid.shape[0], step)
    nodes_c = np.arange(0, grid.shape[1], step)
    coarse = ref_l[np.ix_(nodes_r, nodes_c)]
    naive = ndimage.zoom(coarse, step, order=1, grid_mode=False)[: nodes_r[-1], : nodes_c[-1]]
    exact = ref_l[: nodes_r[-1], : nodes_c[-1]]
    ours, _ = ortho_mapping(sensor, grid, dem)
    ours = ours[: nodes_r[-1], : nodes_c[-1]]
    ok = np.isfinite(naive) & np.isfinite(exact) & np.isfinite(ours)
    assert np.max(np.abs(naive - exact)[ok]) > 0.5
    assert np.max(np.abs(ours - exact)[ok]) < 0.01


def test_mapping_check_refines_where_interpolation_is_poor(hilly):
    """A huge coarse step makes bilinear interpolation of the geometry poor: the check at the
    cell centres sees it and the mapping is still within tolerance."""
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["fore"]
    grid, _ = truth_grid(hilly)
    ref_l, ref_s = exact_mapping(sensor, grid, dem)
    mapper = OrthoMapper(sensor, grid, dem, coarse_step=512, tol_px=1e-4)
    line, sample = mapper.map()
    assert mapper.stats.refinements > 0 or mapper.stats.cells_exact > 0
    both = np.isfinite(line) & np.isfinite(ref_l)
    assert np.hypot(line - ref_l, sample - ref_s)[both].max() < 1e-3


# ----------------------------------------------------------------------------- ortho
@pytest.mark.parametrize("name", ["fore", "aft"])
def test_ortho_of_true_model_matches_true_ortho(hilly, name):
    """Each 64 x 64 window of the ortho agrees with the true reflectance ortho to <= 0.1 px."""
    dem = DEM.open(hilly.path("truth/dem.tif"))
    grid, truth = truth_grid(hilly)
    sensor = hilly.truth_sensors()[name]
    ortho = orthorectify(read_raw(hilly, name), sensor, grid, dem).astype(float)
    shifts = window_shifts(truth, ortho)
    assert len(shifts) >= 20
    assert np.abs(shifts).max() <= 0.1, shifts
    assert np.hypot(*shifts.mean(axis=0)) <= 0.03
    valid = np.isfinite(ortho) & np.isfinite(truth)
    assert np.corrcoef(ortho[valid], truth[valid])[0, 1] > 0.95


def test_half_pixel_convention_error_would_show(hilly):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    grid, truth = truth_grid(hilly)
    sensor = hilly.truth_sensors()["aft"]
    raw = read_raw(hilly, "aft")
    wrong = orthorectify(raw, ShiftedSensor(sensor, 0.5), grid, dem).astype(float)
    shifts = window_shifts(truth, wrong)
    # half a raw pixel is ~0.4-0.5 ortho pixels in each direction (GSD 2.2-2.5 m / 2.22 m)
    assert np.all(np.abs(shifts.mean(axis=0)) > 0.3), shifts.mean(axis=0)


def test_nan_outside_image_and_dem(hilly):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["fore"]
    grid = OrthoGrid.covering(sensor, dem, 2.5)
    big = OrthoGrid(grid.crs, grid.transform @ Affine.translation(-40, -40), (533, 547))
    ref_l, ref_s = exact_mapping(sensor, big, dem)
    ortho = orthorectify(read_raw(hilly, "fore"), sensor, big, dem)
    n_l, n_s = sensor.image_shape
    outside = ~(
        (ref_l >= 0) & (ref_l <= n_l) & (ref_s >= 0) & (ref_s <= n_s)
    )  # NaN compare False: off the DEM counts as outside
    assert outside.sum() > 0.3 * outside.size
    assert np.all(np.isnan(ortho[outside]))
    well_inside = (ref_l > 2) & (ref_l < n_l - 2) & (ref_s > 2) & (ref_s < n_s - 2)
    assert np.all(np.isfinite(ortho[well_inside]))
    filled = orthorectify(read_raw(hilly, "fore"), sensor, big, dem, nodata=-1.0)
    assert np.all(filled[outside] == -1.0)


def test_tiles_join_seamlessly_and_resampling_methods(hilly):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["aft"]
    grid = OrthoGrid.covering(sensor, dem, 2.5)
    raw = read_raw(hilly, "aft")
    whole = orthorectify(raw, sensor, grid, dem, tile_size=4096)
    tiled = orthorectify(raw, sensor, grid, dem, tile_size=48)
    np.testing.assert_array_equal(np.isnan(whole), np.isnan(tiled))
    ok = np.isfinite(whole)
    assert np.max(np.abs(whole[ok] - tiled[ok])) < 0.5  # DN; coordinate rounding only
    for method in ("nearest", "linear", "lanczos"):
        other = orthorectify(raw, sensor, grid, dem, resampling=method)
        both = ok & np.isfinite(other)
        assert both.sum() > 0.9 * ok.sum()
        assert np.corrcoef(whole[both], other[both])[0, 1] > 0.97
    nearest = orthorectify(raw, sensor, grid, dem, resampling="nearest")
    assert set(np.unique(nearest[np.isfinite(nearest)])) <= set(np.unique(raw).astype(float))


def test_write_ortho_round_trip(hilly, tmp_path):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["aft"]
    grid = OrthoGrid.covering(sensor, dem, 2.5)
    ortho = orthorectify(read_raw(hilly, "aft"), sensor, grid, dem)
    path = write_ortho(tmp_path / "aft_ortho.tif", ortho, grid, tags={"CARTO_IMAGE": "aft"})
    with rasterio.open(path) as ds:
        assert ds.crs.to_epsg() == 32643
        assert ds.transform == grid.transform
        assert np.isnan(ds.nodata)
        assert ds.tags()["CARTO_IMAGE"] == "aft"
        np.testing.assert_array_equal(ds.read(1), ortho)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["aft_ortho.tif"]
    heights = dem.height(*grid.lonlat(*np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]]))
    h_path = write_ortho(tmp_path / "h.tif", heights.astype(np.float32), grid, vertical="ellipsoid")
    back = DEM.open(h_path)
    assert back.is_ellipsoidal
    np.testing.assert_allclose(back.heights, heights, atol=1e-3)
    with pytest.raises(InputError, match="does not match the grid"):
        write_ortho(tmp_path / "bad.tif", ortho[:-1], grid)
    assert not (tmp_path / "bad.tif").exists()


# ----------------------------------------------------------------------------- errors
def test_bad_inputs_raise_input_error(hilly):
    dem = DEM.open(hilly.path("truth/dem.tif"))
    sensor = hilly.truth_sensors()["aft"]
    grid = OrthoGrid.covering(sensor, dem, 10.0)
    raw = read_raw(hilly, "aft")
    geoid_dem = DEM.from_array(dem.heights, dem.transform, dem.crs, vertical="geoid:EGM96")
    cases = [
        lambda: orthorectify(raw[:-1], sensor, grid, dem),
        lambda: orthorectify(raw[None], sensor, grid, dem),
        lambda: orthorectify(raw, sensor, grid, dem, resampling="bicubic-spline"),
        lambda: orthorectify(raw, sensor, grid, dem, tile_size=0),
        lambda: orthorectify(raw, sensor, grid, dem, coarse_step=0),
        lambda: orthorectify(raw, sensor, grid, geoid_dem),
        lambda: ortho_mapping(sensor, grid, "dem.tif"),
        lambda: ortho_mapping("fore", grid, dem),
        lambda: OrthoGrid("EPSG:32643", (2.5, 0, 0, 0, 2.5, 0), (10, 10)),  # south-up
        lambda: OrthoGrid("EPSG:32643", (2.5, 0.1, 0, 0, -2.5, 0), (10, 10)),  # rotated
        lambda: OrthoGrid("EPSG:32643", (2.5, 0, 0, 0, -2.5, 0), (0, 10)),
        lambda: OrthoGrid("not a crs", (2.5, 0, 0, 0, -2.5, 0), (10, 10)),
        lambda: OrthoGrid.covering(sensor, dem, 0.0),
        lambda: OrthoGrid.covering(sensor, dem, 2.5, bounds=(10, 0, 0, 10)),
        lambda: OrthoGrid.covering([], dem, 2.5),
        lambda: OrthoMapper(sensor, grid, dem).map(0, 0, grid.shape[0] + 1, 1),
    ]
    for case in cases:
        with pytest.raises(InputError) as info:
            case()
        assert "\n" not in str(info.value)
