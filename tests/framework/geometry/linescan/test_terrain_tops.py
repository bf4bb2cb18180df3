"""The highest terrain under bundles of rays: block maxima against a plain loop over the cells,
segment tops against the terrain sampled densely along every ray between two nodes, and the
safe steps started there against steps from the search's top (walls that hide the ground
included)."""

from __future__ import annotations

import types

import numpy as np

from carto.framework.geometry.linescan.raycast import (
    QUADRATIC_STEP,
    RAY_SIZE,
    STATE_SIZE,
    camera_states,
    dem_grid,
    interp_time,
    line_state,
    quadratic_table,
)
from carto.framework.geometry.linescan.terrain_intersection import (
    grid_bilinear,
    interpolated_quadratic,
    trace_model,
)
from carto.framework.geometry.linescan.terrain_tops import (
    BLOCK_CELLS,
    block_maxima,
    segment_top,
    segment_tops,
)

from .test_raycast import _flat_dem


def test_block_maxima_hold_every_node_their_cells_read():
    rng = np.random.default_rng(4)
    heights = rng.normal(300.0, 50.0, (37, 53))
    heights[20, 11] = np.nan
    block = 8
    got = block_maxima(heights, block)
    assert got.shape == (5, 7)  # the 36 x 52 cells in blocks of 8, rounded up
    want = np.full(got.shape, -np.inf)
    for i in range(heights.shape[0] - 1):
        for j in range(heights.shape[1] - 1):
            nodes = heights[i : i + 2, j : j + 2]
            top = np.inf if np.isnan(nodes).any() else nodes.max()
            want[i // block, j // block] = max(want[i // block, j // block], top)
    np.testing.assert_array_equal(got[:, :-1][:-1], want[:-1, :-1])
    # the last row and column of blocks also see the nodes of the grid's last row / column
    assert np.all(got[-1] >= want[-1])
    assert np.all(got[:, -1] >= want[:, -1])
    assert np.isinf(got[20 // block, 11 // block])
    assert np.isinf(got[19 // block, 10 // block])


def _walled_dem(sensor, seed: int) -> types.SimpleNamespace:
    """Hilly heights under the sensor's footprint with thin walls 100-400 m high."""
    flat = _flat_dem(sensor, 400.0)
    rows, cols = flat.heights.shape
    yy, xx = np.mgrid[0:rows, 0:cols]
    heights = 400.0 + 200.0 * np.sin(xx / 9.0) * np.cos(yy / 6.0)
    rng = np.random.default_rng(seed)
    for r, c in rng.integers(5, min(rows, cols) - 5, (300, 2)):
        heights[r - 2 : r + 3, c] += rng.uniform(100.0, 400.0)
    return types.SimpleNamespace(heights=heights, transform=flat.transform, crs=flat.crs)


def test_segment_tops_bound_the_terrain_under_the_rays_and_keep_the_first_hit(cartosat1_pair):
    sensor = cartosat1_pair["fore"]
    grid = dem_grid(_walled_dem(sensor, 2))
    blocks = block_maxima(grid.heights)
    cam = camera_states(sensor)
    state, ray = np.empty(STATE_SIZE), np.empty(RAY_SIZE)
    first, n_nodes = 30.25, 60
    table, tops = np.empty((n_nodes, 11)), np.empty(n_nodes)
    tau = np.linspace(0.0, 1.0, 801)
    faster = 0
    for line, stagger in ((2000.5, 0.0), (7000.25, 3e-5)):
        assert line_state(interp_time(line, cam.line_nodes, cam.t_nodes), cam, state)
        quadratic_table(first, n_nodes, stagger, cam, grid, state, ray, table)
        segment_tops(table, n_nodes, grid, blocks, BLOCK_CELLS, tops)
        for m in range(n_nodes - 1):
            assert tops[m] == segment_top(table[m], table[m + 1], grid, blocks, BLOCK_CELLS)
            assert np.isfinite(tops[m])
            for s in first + (m + np.linspace(0.0, 1.0, 9)) * QUADRATIC_STEP:
                q = interpolated_quadratic(table, n_nodes, first, s)
                lon = q.lon0 + tau * (q.lon1 + tau * q.lon2)
                lat = q.lat0 + tau * (q.lat1 + tau * q.lat2)
                under = [
                    grid_bilinear(grid.heights, *grid[1:5], x, y)
                    for x, y in zip(lon, lat, strict=True)
                ]
                assert np.nanmax(under) <= tops[m]
                from_top = trace_model(q, grid, np.inf)
                from_block = trace_model(q, grid, tops[m])
                # the same intersection (a wall missed would move it by metres)
                np.testing.assert_allclose(from_block[2], from_top[2], atol=2e-4)
                np.testing.assert_allclose(from_block[:2], from_top[:2], atol=1e-8)
                faster += tops[m] < grid.h_top_m - 50.0
    assert faster > 100  # the tops are well below the search's top for most rays
