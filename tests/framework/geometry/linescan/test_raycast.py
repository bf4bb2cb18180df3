"""The compiled ray caster's stages: table interpolation weights, the DEM search tuple,
location on a DEM against the model's own image -> ground, and the interpolated ray models
the renderer traces against the exact rays."""

from __future__ import annotations

import types

import numpy as np
import pytest
from affine import Affine

from carto.framework.errors import InputError
from carto.framework.geometry.linescan.raycast import (
    QUADRATIC_STEP,
    RAY_SIZE,
    STATE_SIZE,
    DemGrid,
    camera_states,
    dem_grid,
    interp_time,
    line_state,
    locate_pixels,
    quadratic_table,
    ray_dem,
    state_ray,
    trace_dem,
)
from carto.framework.geometry.linescan.solver import lagrange_weights
from carto.framework.geometry.linescan.terrain_intersection import (
    MODEL_ERROR_M,
    interpolated_quadratic,
    trace_model,
)


def _flat_dem(sensor, h_m: float, crs: str = "EPSG:4326") -> types.SimpleNamespace:
    """A constant-height geographic DEM over the sensor's footprint (with a margin)."""
    nl, ns = sensor.image_shape
    lon, lat = sensor.image_to_ground(
        np.array([0.0, 0.0, nl, nl]), np.array([0.0, ns, 0.0, ns]), np.full(4, h_m)
    )
    step = 1e-3
    x0, y1 = lon.min() - 0.05, lat.max() + 0.05
    width = int((lon.max() + 0.05 - x0) / step) + 1
    height = int((y1 - (lat.min() - 0.05)) / step) + 1
    heights = np.full((height, width), h_m)
    return types.SimpleNamespace(
        heights=heights, transform=Affine(step, 0.0, x0, 0.0, -step, y1), crs=crs
    )


def test_lagrange_weights_reproduce_a_cubic_and_refuse_the_table_ends():
    node0, spacing, n = 10.0, 0.5, 12
    times = node0 + spacing * np.arange(n)
    values = 0.3 * times**3 - times + 2.0
    for t in (11.2, 12.0, 13.74, 14.9):
        k, w0, w1, w2, w3 = lagrange_weights(t, node0, spacing, n)
        assert k >= 1
        got = w0 * values[k - 1] + w1 * values[k] + w2 * values[k + 1] + w3 * values[k + 2]
        assert got == pytest.approx(0.3 * t**3 - t + 2.0, rel=1e-12)
    assert lagrange_weights(node0 + 0.4 * spacing, node0, spacing, n)[0] == -1
    assert lagrange_weights(node0 + (n - 1.5) * spacing, node0, spacing, n)[0] == -1


def test_dem_grid_search_bounds_and_refusals(cartosat1_pair):
    dem = _flat_dem(cartosat1_pair["fore"], 250.0)
    grid = dem_grid(dem)
    assert isinstance(grid, DemGrid)
    assert (grid.h_top_m, grid.h_bottom_m) == (251.0, 249.0)
    assert grid.max_slope == pytest.approx(0.05)
    given = dem_grid(dem, (100.0, 400.0), 2.0)
    assert (given.h_top_m, given.h_bottom_m, given.max_slope) == (401.0, 99.0, 2.0)
    with pytest.raises(InputError, match="EPSG:4326"):
        dem_grid(_flat_dem(cartosat1_pair["fore"], 250.0, crs="EPSG:32643"))


def test_locate_pixels_on_a_flat_dem_matches_image_to_ground(cartosat1_pair):
    sensor = cartosat1_pair["fore"]
    dem = _flat_dem(sensor, 250.0)
    rng = np.random.default_rng(3)
    line = rng.uniform(0.0, sensor.n_lines, 500)
    sample = rng.uniform(0.0, sensor.image_shape[1], 500)
    lon, lat, h = locate_pixels(sensor, line, sample, dem)
    assert np.all(np.abs(h - 250.0) < 1e-4)
    lon_r, lat_r = sensor.image_to_ground(line, sample, h)
    np.testing.assert_allclose(lon, lon_r, atol=1e-9)
    np.testing.assert_allclose(lat, lat_r, atol=1e-9)


def test_ray_dem_is_trace_dem_with_loose_arguments(cartosat1_pair):
    sensor = cartosat1_pair["aft"]
    grid = dem_grid(_flat_dem(sensor, 120.0))
    p, u = sensor.ray(np.array([500.5]), np.array([700.5]))
    ray = (*p[0], *u[0])
    omega_c = np.asarray(sensor._table.omega_c, float)
    loose = ray_dem(*ray, grid.heights, *grid[1:5], *grid[5:8], omega_c)
    # loose arguments carry no local slope bounds: the same steps as a grid without them
    assert loose == trace_dem(ray, omega_c, grid._replace(slopes=np.empty((0, 0)), cell_m=0.0))
    assert loose[2] == pytest.approx(120.0, abs=1e-4)
    # the local bounds take other steps to the same point
    local = trace_dem(ray, omega_c, grid)
    assert local[2] == pytest.approx(120.0, abs=1e-4)
    np.testing.assert_allclose(local[:2], loose[:2], atol=1e-8)


def test_interpolated_ray_models_meet_the_terrain_where_the_exact_rays_do(cartosat1_pair):
    """The renderer traces each ray's quadratic model interpolated between the exact models
    of every QUADRATIC_STEP-th detector (:func:`trace_model`): within MODEL_ERROR_M of the
    exact ray's intersection (:func:`trace_dem`), on hilly terrain, for the plain and the
    staggered detectors."""
    sensor = cartosat1_pair["fore"]
    flat = _flat_dem(sensor, 400.0)
    n_rows, n_cols = flat.heights.shape
    yy, xx = np.mgrid[0:n_rows, 0:n_cols]
    rough = types.SimpleNamespace(
        heights=400.0 + 300.0 * np.sin(xx / 7.0) * np.cos(yy / 5.0),  # slopes up to about 0.6
        transform=flat.transform,
        crs=flat.crs,
    )
    grid = dem_grid(rough)
    cam = camera_states(sensor)
    state, ray = np.empty(STATE_SIZE), np.empty(RAY_SIZE)
    first, n_nodes = 100.25, 40
    table = np.empty((n_nodes, 11))
    samples = first + np.linspace(0.0, (n_nodes - 1) * QUADRATIC_STEP, 400, endpoint=False)
    worst = []
    for line, stagger in ((1500.75, 0.0), (9000.25, 3e-5)):
        assert line_state(interp_time(line, cam.line_nodes, cam.t_nodes), cam, state)
        quadratic_table(first, n_nodes, stagger, cam, grid, state, ray, table)
        for s in samples:
            state_ray(s, stagger, cam, state, ray)
            exact = np.array(trace_dem(tuple(ray[:6]), cam.omega_c, grid))
            q = interpolated_quadratic(table, n_nodes, first, s)
            model = np.array(trace_model(q, grid, np.inf))
            m_per_deg = np.array([111_320.0 * np.cos(np.radians(exact[1])), 110_570.0, 1.0])
            worst.append(np.abs(model - exact) * m_per_deg)
    worst = np.max(worst, axis=0)
    assert np.all(worst < MODEL_ERROR_M), worst
