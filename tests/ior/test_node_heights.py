"""Node heights from every matched ortho pixel: the per-group quantiles against NumPy, and the
heights of a flat tile seen by two straight rays (whose exact answer is written down here),
including a node whose pixels see two surfaces."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
from affine import Affine
from scipy import ndimage

import carto.ior.node_heights as node_heights_module
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.ior.node_heights import NodeHeights, block_quantiles, node_heights
from carto.ior.rays import RayField, intersect_offsets

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
        assert q.dtype == np.float64
        assert q.shape == (3, 5)
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


@pytest.mark.parametrize("k", [K, 1])
def test_the_compiled_points_equal_numpy_band_by_band(k, monkeypatch):
    """Relief, slopes, offsets of several pixels, invalid matches, rays turning across the
    tile, points beyond the height range and bands smaller than the tile: the compiled
    kernel against the same computation in numpy (scipy's bilinear interpolation, the ray
    field's gathers)."""
    import carto.ior.node_heights as module

    rng = np.random.default_rng(7)
    shape = (23, 19)
    grid = OrthoGrid(
        pyproj.CRS.from_epsg(32643), Affine(RES_M, 0, 500_000, 0, -RES_M, 2_000_000), shape
    )
    t = np.empty((2, 2, 3, 3))
    for i, (tx, ty) in enumerate((T_LEFT, T_RIGHT)):
        t[i, 0] = tx + rng.normal(0, 0.01, (3, 3))
        t[i, 1] = ty + rng.normal(0, 0.01, (3, 3))
    rays = RayField(grid, np.array([0, 11, 22]), np.array([0, 9, 18]), t)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    surface = 400.0 + 30.0 * np.sin(xx / 4.0) + 2.0 * yy + rng.normal(0, 1.0, shape)
    pixels = (shape[0] * k, shape[1] * k)
    d_row = rng.normal(0, 2.0, pixels)
    d_col = rng.normal(0, 3.0, pixels)
    valid = rng.random(pixels) > 0.2
    d_row[rng.random(pixels) < 0.01] = np.nan
    d_col[:k, -k:] = 500.0  # far beyond the height range
    score = rng.uniform(0.3, 1.0, pixels)
    monkeypatch.setattr(module, "BAND_PIXELS", 5 * shape[1] * k * k)  # bands of 5 node rows
    args = (d_row, d_col, valid, score, surface, grid, k, rays, (380.0, 460.0))
    got, want = module.node_heights(*args), _numpy_node_heights(*args)
    assert np.isfinite(want.height_m).sum() > 0.8 * want.height_m.size
    assert np.isnan(want.height_m).any()
    np.testing.assert_array_equal(got.count, want.count)
    for name in ("height_m", "spread_m", "score"):
        np.testing.assert_allclose(
            getattr(got, name), getattr(want, name), rtol=0, atol=1e-9, equal_nan=True
        )


def _numpy_node_heights(d_row_px, d_col_px, valid, score, surface_m, grid, k, rays, h_range):
    """node_heights as numpy arrays band by band: the independent implementation the
    compiled one is checked against (the module's code before session 59)."""
    n_r, n_c = grid.shape
    surface = np.asarray(surface_m, np.float64)
    g_row, g_col = np.gradient(surface) if min(surface.shape) > 1 else (surface * 0, surface * 0)
    px, py = grid.resolution
    slope_x, slope_y = g_col / px, -g_row / py
    height = np.full((n_r, n_c), np.nan)
    count = np.zeros((n_r, n_c), np.int32)
    spread = np.full((n_r, n_c), np.nan, np.float32)
    node_score = np.full((n_r, n_c), np.nan, np.float32)
    band = max(1, node_heights_module.BAND_PIXELS // max(n_c * k * k, 1))
    ok_all = valid & np.isfinite(d_row_px) & np.isfinite(d_col_px)
    for a in range(0, n_r, band):
        b = min(n_r, a + band)
        ok = ok_all[a * k : b * k]
        pr, pc = np.nonzero(ok)
        if pr.size == 0:
            continue
        pr = pr + a * k
        dr = np.asarray(d_row_px, np.float64)[pr, pc]
        dc = np.asarray(d_col_px, np.float64)[pr, pc]
        # the pixel as a fractional node index, and its match
        fr, fc = (pr + 0.5) / k - 0.5, (pc + 0.5) / k - 0.5
        mr, mc = (pr + dr + 0.5) / k - 0.5, (pc + dc + 0.5) / k - 0.5
        h_pix = ndimage.map_coordinates(surface, [fr, fc], order=1, mode="nearest")
        h_match = ndimage.map_coordinates(surface, [mr, mc], order=1, mode="nearest")
        x_m, y_m = grid.xy(mr, mc)
        # the rays' directions of the node a pixel lies in (they turn by micro-radians
        # across a node)
        nr, nc = pr // k, pc // k
        at_nodes = rays.on_nodes(slice(a, b), slice(0, n_c))
        directions = at_nodes[:, :, nr - a, nc]
        x_p, y_p, h_p = intersect_offsets(
            rays, fr, fc, h_pix, x_m, y_m, h_match, directions=directions
        )
        # to the centre of the node the pixel lies in, along the current surface
        x_n, y_n = grid.xy(nr, nc)
        h_n = h_p - slope_x[nr, nc] * (x_p - x_n) - slope_y[nr, nc] * (y_p - y_n)
        keep = (h_n >= h_range[0] - 500.0) & (h_n <= h_range[1] + 500.0)
        # the points back on their ortho pixels: a node's points are its k x k block
        points = np.full(((b - a) * k, n_c * k), np.nan)
        points[pr[keep] - a * k, pc[keep]] = h_n[keep]
        cnt, (q25, q50, q75) = block_quantiles(points, k, (0.25, 0.5, 0.75))
        scores = np.full(points.shape, np.nan)
        scores[pr[keep] - a * k, pc[keep]] = np.asarray(score, np.float64)[pr, pc][keep]
        height[a:b] = q50
        count[a:b] = cnt
        with np.errstate(invalid="ignore", divide="ignore"):
            spread[a:b] = np.where(cnt >= 3, (q75 - q25) * node_heights_module.IQR_TO_SIGMA, np.nan)
            total = np.nansum(scores.reshape(b - a, k, n_c, k), axis=(1, 3))
            node_score[a:b] = np.where(cnt > 0, total / np.maximum(cnt, 1), np.nan)
    return NodeHeights(height, count, spread, node_score)
