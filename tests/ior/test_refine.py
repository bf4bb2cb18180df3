"""Iterative ortho-image refinement on a simulated Cartosat-1 pair (truth from the simulator)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework import get_registry
from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.raster.dem import DEM
from carto.framework.raster.images import read_raster
from carto.ior.refine import (
    IORSettings,
    b_over_h,
    first_order_height_change,
    refine_dem,
    regularise,
)


def _horizontal_shift(sensor, lon, lat, h, e):
    """Where the line of sight through (lon, lat, h + e) meets height h, metres east/north."""
    line, sample = sensor.ground_to_image(lon, lat, h + e)
    lo, la = sensor.image_to_ground(line, sample, h)
    d = frames.geodetic_to_ecef(lo, la, h) - frames.geodetic_to_ecef(lon, lat, h)
    return (frames.enu_basis(lon, lat) @ np.ravel(d))[:2]


def test_first_order_height_from_mismatch_matches_the_geometry(hilly):
    """A DEM 10 m too high shifts the two orthos by e B/H along the base; the formula
    dh = -dr / (B/H) gives the -10 m back (the paper's dr * B/H would give -3.9 m)."""
    truth = hilly.truth_sensors()
    aft, fore = truth["aft"], truth["fore"]
    lon, lat = aft.image_to_ground(250.0, 250.0, 300.0)
    lon, lat = float(lon), float(lat)
    e = 10.0
    # a detail at the true place shows in each ortho at (place - shift of its ray)
    x_left = -_horizontal_shift(aft, lon, lat, 300.0, e)
    x_right = -_horizontal_shift(fore, lon, lat, 300.0, e)
    bh = b_over_h(aft, fore, lon, lat, 300.0)
    assert 0.55 < bh < 0.7  # Cartosat-1
    # t: horizontal displacement of a line of sight per metre of height, going up
    t_l = -_horizontal_shift(aft, lon, lat, 300.0, 1.0)
    t_r = -_horizontal_shift(fore, lon, lat, 300.0, 1.0)
    base = (t_r - t_l) / np.linalg.norm(t_r - t_l)
    dr = float((x_right - x_left) @ base)
    assert dr == pytest.approx(e * bh, rel=0.01)
    assert float(first_order_height_change(dr, bh)) == pytest.approx(-e, rel=0.01)
    with pytest.raises(InputError):
        first_order_height_change(1.0, 0.0)


def test_regularise_removes_outliers_and_fills_holes():
    heights = np.full((40, 40), 100.0)
    new = heights + 2.0  # everywhere 2 m higher...
    new[10, 10] = 180.0  # ... but one wild match
    new[20:26, 20:26] = np.nan  # and a hole
    out, inlier = regularise(heights, new, IORSettings())
    assert not inlier[10, 10]
    assert np.allclose(out, 102.0, atol=1e-6)  # the hole takes its neighbours' change


def test_ior_refines_the_coarse_dem(hilly):
    truth = hilly.truth_sensors()
    init = DEM.open(hilly.path("init_dem.tif"))
    true_dem = DEM.open(hilly.path("truth/dem.tif"))
    images = [truth[n].prepare_raw(read_raster(hilly.raster(n)), init) for n in ("aft", "fore")]
    lines = []
    result = refine_dem(
        images[0],
        images[1],
        truth["aft"],
        truth["fore"],
        init,
        IORSettings(posting_m=10.0),
        progress=lines.append,
    )
    g = result.dem_grid
    rows, cols = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
    lon, lat = g.lonlat(rows, cols)
    ref = true_dem.height(lon, lat)
    d = (result.dem.heights - ref)[np.isfinite(result.dem.heights)]
    d0 = (init.height(lon, lat) - ref)[np.isfinite(result.dem.heights)]
    rmse, rmse0 = np.sqrt(np.mean(d**2)), np.sqrt(np.mean(d0**2))
    nmad = 1.4826 * np.median(np.abs(d - np.median(d)))
    # measured (true models, hilly, seed 2): RMSE 0.31-0.32 m, 11.0 times below the initial
    # DEM's 3.49 m, NMAD 0.198 m; seeds 1-5 of this setup: RMSE 0.22-0.34 m, 11-24 times
    # below, NMAD 0.15-0.20 m. Bounds about 1.3x the worst: the old ones (the benchmark's
    # targets, NMAD < 1.5 m, RMSE 2x better) passed with the least-squares sub-pixel
    # refinement switched off (NMAD 0.28 m, RMSE 0.42 m)
    assert rmse < 0.45
    assert rmse < rmse0 / 7.0
    assert nmad < 0.26
    assert result.converged
    assert len(result.iterations) <= 7
    first, last = result.iterations[0], result.iterations[-1]
    assert last.median_abs_mismatch_px < first.median_abs_mismatch_px
    assert len(lines) == len(result.iterations)
    # the final orthos agree: matched in most of the common area
    assert result.valid.mean() > 0.5
    assert result.ortho_left.shape == result.ortho_grid.shape


def test_generator_is_registered_and_checks_its_options(hilly):
    generator = get_registry().get("dem-generator", "ior")
    sensors = list(hilly.sensors().values())
    images = [np.zeros(s.image_shape) for s in sensors]
    with pytest.raises(InputError, match="init_dem"):
        generator.generate(images, sensors)
    with pytest.raises(InputError, match="unknown option"):
        generator.generate(images, sensors, init_dem=DEM.constant(0.0), colour="red")
    with pytest.raises(InputError, match="two images"):
        generator.generate(images[:1], sensors[:1], init_dem=DEM.constant(0.0))
    with pytest.raises(InputError, match="posting"):
        IORSettings(posting_m=-1.0)


def test_tiles_on_threads_give_the_dem_of_one_tile(hilly):
    """The work of an iteration is split into tiles (with overlap) that a scheduler may run
    anywhere (here any callable that runs tasks: a pool of two threads): small tiles agree
    with one big tile."""
    from concurrent.futures import ThreadPoolExecutor

    def on_threads(tasks):
        with ThreadPoolExecutor(2) as pool:
            return list(pool.map(lambda task: task(), tasks))

    truth = hilly.truth_sensors()
    init = DEM.open(hilly.path("init_dem.tif"))
    images = [truth[n].prepare_raw(read_raster(hilly.raster(n)), init) for n in ("aft", "fore")]
    args = (images[0], images[1], truth["aft"], truth["fore"], init)
    one = refine_dem(*args, IORSettings(posting_m=10.0, max_iterations=2))
    tiled = refine_dem(
        *args,
        IORSettings(posting_m=10.0, max_iterations=2, tile_px=256, overlap_px=96),
        scheduler=on_threads,
    )
    assert tiled.dem.heights.shape == one.dem.heights.shape
    d = tiled.dem.heights - one.dem.heights
    assert np.nanmedian(np.abs(d)) < 0.05
    assert np.nanpercentile(np.abs(d), 99) < 1.0
