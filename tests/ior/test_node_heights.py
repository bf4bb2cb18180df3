"""Node heights from every matched ortho pixel: the per-group quantiles against NumPy, and the
heights of a flat tile seen by two straight rays (whose exact answer is written down here),
including a node whose pixels see two surfaces."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
from affine import Affine

from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.ior.node_heights import block_quantiles, node_heights
from carto.ior.rays import RayField

K = 4
RES_M = 10.0
T_LEFT = (0.31, 0.02)  # horizontal displacement of each line of sight per metre of height
T_RIGHT = (-0.29, -0.01)


@pytest.mark.parametrize("k", [K, 1])  # 1: ortho-images at the posting, no sort
def test_block_quantiles_equal_numpy(k):
    rng = np.random.default_rng(0)
    values = rng.normal(size=(3 * k, 5 * k))
    values[rng.random(values.shape) < 0.4] = np.nan
    values[:k, :k] = np.nan  # a block without a value
    values[k : 2 * k, :k] = np.nan
    values[k, 0] = 1.5  # a block of one value
    values[-1, -1] = np.inf  # not a value
    count, (q25, q50, q90) = block_quantiles(values, k, (0.25, 0.5, 0.9))
    for q in (q25, q50, q90):
        assert q.dtype == np.float64 and q.shape == (3, 5)
    for i in range(3):
        for j in range(5):
            v = values[i * k : (i + 1) * k, j * k : (j + 1) * k]
            v = v[np.isfinite(v)]
            assert count[i, j] == v.size
            if v.size == 0:
                assert np.isnan(q50[i, j])
                continue
            want = np.quantile(v, [0.25, 0.5, 0.9])
            np.testing.assert_allclose([q25[i, j], q50[i, j], q90[i, j]], want, atol=1e-12)


def _setting(shape=(6, 7)):
    grid = OrthoGrid(
        pyproj.CRS.from_epsg(32643), Affine(RES_M, 0, 500_000, 0, -RES_M, 2_000_000), shape
    )
    rows = np.array([0, shape[0] - 1])
    cols = np.array([0, shape[1] - 1])
    t = np.zeros((2, 2, 2, 2))
    for i, (tx, ty) in enumerate((T_LEFT, T_RIGHT)):
        t[i, 0], t[i, 1] = tx, ty
    return grid, RayField(grid, rows, cols, t)


def _offsets(error_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ortho-pixel offsets (right minus left) of a flat surface too high by ``error_m`` (per
    ortho pixel): a detail moves by ``(t_R - t_L) e`` on the map (rays.py's geometry)."""
    dx = (T_RIGHT[0] - T_LEFT[0]) * error_m
    dy = (T_RIGHT[1] - T_LEFT[1]) * error_m
    res = RES_M / K
    return -dy / res, dx / res


def test_a_flat_surface_too_high_comes_back_to_the_truth():
    grid, rays = _setting()
    surface = np.full(grid.shape, 500.0)
    rng = np.random.default_rng(1)
    error = np.kron(rng.uniform(-8, 8, grid.shape), np.ones((K, K)))  # per node
    d_row, d_col = _offsets(error)
    valid = np.ones(d_row.shape, bool)
    valid[:K, :K] = False  # node (0, 0): no match
    score = np.full(d_row.shape, 0.8)
    out = node_heights(d_row, d_col, valid, score, surface, grid, K, rays, (400.0, 600.0))
    want = 500.0 - error[::K, ::K]
    ok = np.ones(grid.shape, bool)
    ok[0, 0] = False
    np.testing.assert_allclose(out.height_m[ok], want[ok], atol=1e-9)
    assert np.isnan(out.height_m[0, 0])
    assert out.count[0, 0] == 0
    assert (out.count[ok] == K * K).all()
    np.testing.assert_allclose(out.spread_m[ok], 0.0, atol=1e-9)
    np.testing.assert_allclose(out.score[ok], 0.8, atol=1e-6)


def test_a_node_whose_pixels_see_two_surfaces_takes_the_majority():
    """10 of the 16 pixels of a node match the ground 2 m below the surface, 6 a roof 12 m
    above it: the node's height is the ground's (a mean offset would give 5.5 m above), and
    its spread says the node is mixed."""
    grid, rays = _setting()
    surface = np.full(grid.shape, 300.0)
    error = np.full((grid.shape[0] * K, grid.shape[1] * K), 2.0)
    block = error[2 * K : 3 * K, 3 * K : 4 * K].ravel()
    block[:6] = -12.0
    error[2 * K : 3 * K, 3 * K : 4 * K] = block.reshape(K, K)
    d_row, d_col = _offsets(error)
    valid = np.ones(d_row.shape, bool)
    out = node_heights(
        d_row, d_col, valid, np.ones(d_row.shape), surface, grid, K, rays, (0.0, 1000.0)
    )
    assert out.height_m[2, 3] == pytest.approx(298.0, abs=1e-9)
    assert out.spread_m[2, 3] > 3.0
    assert out.height_m[1, 1] == pytest.approx(298.0, abs=1e-9)
    assert out.spread_m[1, 1] == pytest.approx(0.0, abs=1e-9)


def test_points_far_beyond_the_height_range_are_dropped():
    grid, rays = _setting()
    surface = np.full(grid.shape, 100.0)
    error = np.full((grid.shape[0] * K, grid.shape[1] * K), 1.0)
    error[:K, :K] = 900.0  # an intersection 800 m below the lowest height
    d_row, d_col = _offsets(error)
    out = node_heights(
        d_row,
        d_col,
        np.ones(d_row.shape, bool),
        np.ones(d_row.shape),
        surface,
        grid,
        K,
        rays,
        (90.0, 110.0),
    )
    assert out.count[0, 0] == 0
    assert np.isnan(out.height_m[0, 0])
    assert out.height_m[1, 1] == pytest.approx(99.0, abs=1e-9)
