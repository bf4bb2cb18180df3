"""The renderer's two ways of tracing a ray agree: a sub-line rendered on the interpolated
quadratic models (the usual path) and the same rays traced one by one on their exact rays
(the path of rays next to a node ray that misses) give the same texture sums."""

from __future__ import annotations

import numpy as np

from carto.framework.geometry.linescan.raycast import (
    RAY_SIZE,
    STATE_SIZE,
    camera_states,
    dem_grid,
    interp_time,
    line_state,
)
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.terrain_intersection import QUADRATIC_STEP
from carto.framework.geometry.linescan.terrain_tops import block_maxima
from carto.framework.raster.dem import DEM
from carto.framework.simulation import render
from carto.framework.simulation.texture import make_texture


def _scratch(n_cols: int, n_nodes: int, supersample: int, state: np.ndarray):
    return render._SublineScratch(
        state,
        np.empty(RAY_SIZE),
        np.empty((n_nodes, 11)),
        np.empty((n_nodes, 11)),
        np.empty(n_nodes),
        np.empty(n_nodes),
        np.zeros(n_cols),
        np.zeros(n_cols, np.int64),
        np.empty(n_cols * supersample),
        np.empty(n_cols * supersample, np.int64),
    )


def test_the_exact_rays_give_the_interpolated_models_sums(cartosat1_scene):
    sensor = LineScanner.load(cartosat1_scene / "truth" / "fore.model.json")
    dem = DEM.open(cartosat1_scene / "truth" / "dem.tif")
    tex = make_texture(dem, 1.25, seed=4)
    grid = dem_grid(dem)
    cam = camera_states(sensor)
    texture = render.GeoGrid(
        render._texture_values(tex.reflectance),
        tex.transform.c,
        tex.transform.a,
        tex.transform.f,
        tex.transform.e,
    )
    n_lines, n_cols = sensor.image_shape
    supersample = 2
    window = render._RenderWindow(
        0, n_lines, n_cols, sensor.first_sample, render._stagger_tan(sensor, True), supersample
    )
    n_nodes = int(np.ceil((n_cols - 0.5) / QUADRATIC_STEP)) + 2
    for line in (10.25, 200.75, 390.25):
        state = np.empty(STATE_SIZE)
        assert line_state(interp_time(line, cam.line_nodes, cam.t_nodes), cam, state)
        models = _scratch(n_cols, n_nodes, supersample, state)
        render._render_subline(window, cam, grid, texture, block_maxima(grid.heights), models)
        exact = _scratch(n_cols, n_nodes, supersample, state.copy())
        j = np.repeat(np.arange(n_cols), supersample)
        exact.exact_j[:] = j
        exact.exact_s[:] = (
            sensor.first_sample + j + (np.tile(np.arange(supersample), n_cols) + 0.5) / supersample
        )
        render._add_exact_rays(window, cam, grid, texture, exact, j.size)
        np.testing.assert_array_equal(exact.count, models.count)
        assert (models.count == supersample).mean() > 0.95  # the sub-line sees the DEM
        # the model's point is within a millimetre of the exact ray's: texture values alike
        np.testing.assert_allclose(exact.acc, models.acc, atol=2e-4)
