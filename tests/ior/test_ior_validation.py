"""The IOR generator's input checks (issue #15): every bad setting, grid, image or initial DEM
is a one-line InputError naming the option or file and the value; voids of the initial DEM are
filled for the starting surface (truth: the same scene without the void)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework import get_registry
from carto.framework.errors import InputError
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.raster.images import read_raster
from carto.ior.generator import ior_product
from carto.ior.refine import IORSettings, _grids, refine_dem, starting_surface
from tests.scenes import simulate


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return Scene.open(
        simulate(
            "cartosat1-pair",
            tmp_path_factory.mktemp("iorval"),
            seed=4,
            size=(300, 300),
            n_checkpoints=5,
            terrain="hilly",
        )
    )


@pytest.fixture(scope="module")
def pair(scene):
    truth = scene.truth_sensors()
    init = DEM.open(scene.path("init_dem.tif"))
    images = [truth[n].prepare_raw(read_raster(scene.raster(n)), init) for n in ("aft", "fore")]
    return images, [truth["aft"], truth["fore"]], init


def _refused(call, *fragments: str) -> str:
    with pytest.raises(InputError) as err:
        call()
    message = str(err.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


def _with_void(dem: DEM, rows: slice, cols: slice) -> DEM:
    heights = dem.heights.copy()
    heights[rows, cols] = np.nan
    return DEM.from_array(heights, dem.transform, dem.crs, vertical=dem.vertical, source="void")


# ----------------------------------------------------------------------------- settings
@pytest.mark.parametrize(
    ("options", "fragments"),
    [
        ({"posting_m": 0.0}, ("posting_m (--posting)", "> 0", "got 0.0")),
        ({"posting_m": -1.0}, ("posting_m", "got -1.0")),
        ({"posting_m": float("nan")}, ("posting_m", "got nan")),
        ({"posting_m": float("inf")}, ("posting_m", "got inf")),
        ({"posting_m": "10"}, ("posting_m", "got '10'")),
        ({"posting_m": True}, ("posting_m", "got True")),
        ({"ortho_res_m": 0.0}, ("ortho_res_m (--ortho-res)", "got 0.0")),
        ({"ortho_res_m": 20.0}, ("ortho_res_m", "at most the posting (10 m)", "got 20")),
        ({"max_iterations": 0}, ("max_iterations (--max-iterations)", "1..50", "got 0")),
        ({"max_iterations": 2.5}, ("max_iterations", "whole number", "got 2.5")),
        ({"max_iterations": "3"}, ("max_iterations", "got '3'")),
        ({"max_iterations": 51}, ("max_iterations", "got 51")),
        ({"threshold_px": 0.0}, ("threshold_px", "got 0.0")),
        ({"min_improvement": 2.0}, ("min_improvement", "<= 1", "got 2.0")),
        ({"window": 1}, ("window", "got 1")),
        ({"min_init_coverage": -0.1}, ("min_init_coverage", "got -0.1")),
        ({"crs": "EPSG:4326"}, ("crs (--crs)", "'EPSG:4326' is geographic", "projected CRS")),
        ({"crs": "EPSG:2263"}, ("crs", "'EPSG:2263' is in US survey foot", "metres")),
        ({"crs": "no such crs"}, ("crs", "'no such crs' is not a CRS")),
    ],
)
def test_bad_settings_are_one_line_errors(options, fragments):
    _refused(lambda: IORSettings(**options), "ior: option", *fragments)


def test_good_settings_are_converted():
    s = IORSettings(posting_m=5, max_iterations=4.0, crs="EPSG:32643")
    assert s.posting_m == 5.0
    assert s.max_iterations == 4
    assert isinstance(s.max_iterations, int)
    assert s.crs.to_epsg() == 32643


# ----------------------------------------------------------------------------- grids
def test_grids_too_large_or_too_small_are_refused_before_allocating(pair):
    _, (left, right), init = pair
    message = _refused(
        lambda: _grids(left, right, init, IORSettings(posting_m=0.001)),
        "posting_m (--posting) 0.001 m",
        "over a footprint of",
        "cells, more than 4e+08",
    )
    assert "use a posting_m (--posting) of at least" in message
    _refused(
        lambda: _grids(left, right, init, IORSettings(posting_m=1e9)),
        "posting_m (--posting) 1e+09 m is larger than the images' common footprint",
        "2 x 2 nodes",
    )
    _refused(
        lambda: _grids(left, right, init, IORSettings(posting_m=10.0, ortho_res_m=1e-5)),
        "ortho_res_m (--ortho-res) 1e-05 m",
        "cells, more than",
    )
    _refused(
        lambda: _grids(left, right, init, IORSettings(posting_m=200.0, ortho_res_m=100.0)),
        "ortho_res_m (--ortho-res) 100 m gives",
        "at least 16 x 16",
    )
    dem_grid, ortho_grid, k = _grids(left, right, init, IORSettings(posting_m=10.0))
    assert dem_grid.resolution == (10.0, 10.0)
    assert ortho_grid.shape == (dem_grid.shape[0] * k, dem_grid.shape[1] * k)


def test_a_model_that_does_not_locate_its_image_centre_is_refused(pair):
    """A model giving NaN at the image centre (outside its validity domain): a one-line error
    naming the image, not ``round(nan)`` (an internal error)."""
    _, (left, _), init = pair

    class Lost:
        image_shape = left.image_shape

        def image_to_ground(self, line, sample, h):
            nan = np.full(np.shape(line), np.nan)
            return nan, nan

    _refused(
        lambda: _grids(left, Lost(), init, IORSettings(posting_m=10.0)),
        "the centre of the right image does not locate on the ground",
    )


# ----------------------------------------------------------------------------- generator inputs
def test_generator_refuses_unusable_images_and_dems(pair):
    images, sensors, init = pair
    generator = get_registry().get("dem-generator", "ior")
    nan = np.full_like(images[0], np.nan)
    _refused(
        lambda: generator.generate([nan, images[1]], sensors, init_dem=init),
        "ior: left image",
        "no valid pixels",
    )
    flat = np.full_like(images[1], 312.0)
    _refused(
        lambda: generator.generate([images[0], flat], sensors, init_dem=init),
        "ior: right image",
        "no texture (constant value 312)",
    )
    one = DEM.from_array(np.full((1, 1), 400.0), init.transform, init.crs, source="one.tif")
    _refused(
        lambda: generator.generate(images, sensors, init_dem=one),
        "one.tif",
        "1 x 1 posts",
        "at least 2 x 2",
    )
    void = _with_void(init, slice(None), slice(None))
    _refused(lambda: generator.generate(images, sensors, init_dem=void), "no valid height")
    geoidal = DEM.from_array(init.heights, init.transform, init.crs, vertical="geoid:EGM96")
    _refused(lambda: generator.generate(images, sensors, init_dem=geoidal), "--geoid GTX")
    _refused(
        lambda: generator.generate(images, sensors, init_dem=init, crs="EPSG:4326"),
        "crs (--crs)",
        "projected CRS in metres",
    )


def test_an_initial_dem_covering_too_little_is_refused(pair):
    """A half-void (or misnamed) tile: the message says how much it covers, not that the
    images do not overlap."""
    images, (left, right), init = pair
    n_cols = init.shape[1]
    half = _with_void(init, slice(None), slice(n_cols // 2, None))
    _refused(
        lambda: refine_dem(*images, left, right, half, IORSettings(max_iterations=1)),
        "initial DEM void covers",
        "% of the images' footprint",
        "at least 75 % needed",
    )


def test_voids_of_the_initial_dem_are_filled(pair):
    """Truth: the same scene without the void. The filled starting heights agree with the
    original ones to a few metres, and the refined DEMs agree within the matching noise."""
    images, (left, right), init = pair
    n_rows, n_cols = init.shape
    holed = _with_void(init, slice(n_rows // 2 - 1, n_rows // 2 + 1), slice(n_cols // 2 - 1, None))
    settings = IORSettings(posting_m=10.0, max_iterations=3)
    grid, _, _ = _grids(left, right, init, settings)
    full = starting_surface(init, grid, (left, right))
    start = starting_surface(holed, grid, (left, right))
    assert full.filled == 0.0
    assert full.coverage == 1.0
    assert 0.02 < start.filled < 0.25
    assert start.coverage == pytest.approx(1.0 - start.filled)
    assert np.isfinite(start.heights).all()
    d_start = start.heights - full.heights
    assert np.abs(d_start).max() < 15.0
    assert np.abs(d_start).mean() < 3.0

    lines: list[str] = []
    one = refine_dem(*images, left, right, init, settings)
    two = refine_dem(*images, left, right, holed, settings, progress=lines.append)
    assert any("filled" in line for line in lines)
    assert two.init_filled == pytest.approx(start.filled)
    both = np.isfinite(one.dem.heights) & np.isfinite(two.dem.heights)
    assert both.sum() > 0.95 * np.isfinite(one.dem.heights).sum()
    d = (two.dem.heights - one.dem.heights)[both]
    assert np.median(np.abs(d)) < 0.5
    assert np.percentile(np.abs(d), 95) < 3.0
    product = ior_product(two)
    assert product.extras["init_dem_filled_percent"] == pytest.approx(100 * start.filled, 0.01)
    assert product.extras["init_dem_coverage_percent"] > 75.0
    for record in product.iterations:  # the matched share of every iteration
        assert 0.0 < record.measures["matched_percent"] <= 100.0


def test_heights_of_1e30_in_some_cells_break_nothing(pair):
    images, (left, right), init = pair
    heights = init.heights.copy()
    heights[init.shape[0] // 2, init.shape[1] // 2] = 1e30
    heights[1, 1] = np.nan
    odd = DEM.from_array(heights, init.transform, init.crs, source="odd.tif")
    result = refine_dem(*images, left, right, odd, IORSettings(posting_m=10.0, max_iterations=1))
    assert np.nanmax(result.dem.heights) < 2000.0
    assert np.isfinite(result.dem.heights).mean() > 0.5


def test_a_coarse_initial_dem_starts_without_kinks(pair):
    """Truth: an analytic curved surface sampled on the initial DEM's coarse nodes. On the
    10 m grid the starting heights follow the surface far better than bilinear sampling and
    their slope has no kink at the coarse cell edges (second differences like the surface's;
    bilinear ones spike there)."""
    _images, (left, right), init = pair
    n_rows, n_cols = init.shape
    rows, cols = np.mgrid[0:n_rows, 0:n_cols]
    lon0, lat0 = init.transform.c, init.transform.f

    def surface(lon, lat):
        x, y = (lon - lon0) * 8.0e4, (lat - lat0) * 1.1e5  # metres, roughly
        return 300.0 + 60.0 * np.sin(x / 900.0) * np.cos(y / 1300.0)

    t = init.transform
    lon_n, lat_n = t.c + t.a * (cols + 0.5), t.f + t.e * (rows + 0.5)
    smooth_init = DEM.from_array(surface(lon_n, lat_n), init.transform, init.crs)
    grid, _, _ = _grids(left, right, smooth_init, IORSettings(posting_m=10.0))
    g_rows, g_cols = np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]]
    lon, lat = grid.lonlat(g_rows, g_cols)
    inside = np.isfinite(smooth_init.height(lon, lat))
    truth = surface(lon, lat)
    start = starting_surface(smooth_init, grid, (left, right)).heights
    bilinear = smooth_init.height(lon, lat)
    err_start = np.abs(start - truth)[inside]
    err_bilinear = np.abs(bilinear - truth)[inside]
    assert err_start.max() < 0.3 * err_bilinear.max()
    second = np.abs(np.diff(start, 2, axis=1))[inside[:, 2:]]
    second_truth = np.abs(np.diff(truth, 2, axis=1))[inside[:, 2:]]
    second_bilinear = np.abs(np.diff(bilinear, 2, axis=1))[inside[:, 2:]]
    assert second.max() < 2.0 * second_truth.max() < second_bilinear.max()
