"""Where a ray meets a DEM: the local slope bounds of the safe steps hold on the bilinear
surface (distances by pyproj's geodesic), and the steps they allow still find the first
intersection a brute-force march finds (points converted by pyproj, heights interpolated by
scipy), on the exact ray and on its quadratic model alone."""

from __future__ import annotations

import types

import numpy as np
import pyproj
import pytest
from affine import Affine
from scipy.interpolate import RegularGridInterpolator

from carto.framework.geometry.linescan.terrain_intersection import (
    MODEL_ERROR_M,
    RayQuadratic,
    _cell_crossing,
    _cell_of,
    dem_grid,
    grid_bilinear,
    local_slopes,
    ray_quadratic,
    trace_dem,
    trace_model,
)

_STEP_DEG = 5e-5  # about 5 m
_X0, _Y1 = 77.9, 30.35


def _rough_dem(seed: int, n: int = 160) -> types.SimpleNamespace:
    """Mountain-like heights (a smooth relief, noise and thin north-south walls 60-150 m
    high, their cells in ``walls``) on a north-up geographic grid."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:n, 0:n] / n
    heights = 400.0 + 150.0 * np.sin(3 * xx) * np.cos(2 * yy) + rng.normal(0, 3.0, (n, n))
    walls = rng.integers(n // 3, 2 * n // 3, (40, 2))
    for r, c in walls:
        heights[r - 6 : r + 6, c] += rng.uniform(60, 150)
    transform = Affine(_STEP_DEG, 0.0, _X0, 0.0, -_STEP_DEG, _Y1)
    return types.SimpleNamespace(heights=heights, transform=transform, crs="EPSG:4326", walls=walls)


def test_local_slope_bounds_hold_for_steps_of_one_cell():
    dem = _rough_dem(0)
    grid = dem_grid(dem)
    slopes, cell_m = local_slopes(dem.heights, _STEP_DEG, -_STEP_DEG, (_Y1 - 0.01, _Y1))
    np.testing.assert_array_equal(slopes, grid.slopes)
    geod = pyproj.Geod(ellps="WGS84")
    rng = np.random.default_rng(1)
    n = dem.heights.shape[0]
    worst = 0.0
    for _ in range(3000):
        # a point of a cell, and one up to a cell side away in any direction
        i, j = rng.integers(1, n - 3, 2)
        lon = _X0 + (j + 0.5 + rng.random()) * _STEP_DEG
        lat = _Y1 - (i + 0.5 + rng.random()) * _STEP_DEG
        az, dist = rng.uniform(0, 360), rng.uniform(0.1, 1.0) * cell_m
        lon2, lat2, _ = geod.fwd(lon, lat, az, dist)
        z1 = grid_bilinear(dem.heights, _X0, _STEP_DEG, _Y1, -_STEP_DEG, lon, lat)
        z2 = grid_bilinear(dem.heights, _X0, _STEP_DEG, _Y1, -_STEP_DEG, lon2, lat2)
        assert abs(z2 - z1) <= slopes[i, j] * dist
        worst = max(worst, abs(z2 - z1) / dist / slopes[i, j])
    assert worst > 0.3  # the bounds are not loose by orders of magnitude
    # a void makes the cells around it unbounded
    holed = dem.heights.copy()
    holed[10, 10] = np.nan
    bounds, _ = local_slopes(holed, _STEP_DEG, -_STEP_DEG, (_Y1 - 0.01, _Y1))
    assert np.isinf(bounds[8:11, 8:11]).all()
    assert np.isfinite(bounds[20, 20])


def _first_hit(origin, u, dem) -> tuple[float, float, float]:
    """The first point of the ray below the terrain by a march of 2 cm steps (pyproj's
    geodetic conversion, scipy's bilinear heights), refined by bisection."""
    to_geo = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    n = dem.heights.shape[0]
    lats = _Y1 - (np.arange(n) + 0.5) * _STEP_DEG
    lons = _X0 + (np.arange(n) + 0.5) * _STEP_DEG
    terrain = RegularGridInterpolator((lats[::-1], lons), dem.heights[::-1], bounds_error=False)

    def gap(d):
        lon, lat, h = to_geo.transform(*(origin[:, None] + np.outer(u, d)))
        return h - terrain(np.column_stack([lat, lon])), lon, lat, h

    # from well above the highest terrain down past the lowest, 2 cm apart
    d = _distance_to_height(origin, u, 700.0) + np.arange(0.0, 1200.0, 0.02)
    g, *_ = gap(d)
    k = int(np.argmax(g <= 0.0))
    lo, hi = d[k - 1], d[k]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if gap(np.array([mid]))[0][0] > 0:
            lo = mid
        else:
            hi = mid
    _, lon, lat, h = gap(np.array([0.5 * (lo + hi)]))
    return float(lon[0]), float(lat[0]), float(h[0])


def _distance_to_height(origin, u, h_m) -> float:
    """Distance along the ray to the height ``h_m`` (pyproj; bisection)."""
    to_geo = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lo, hi = 0.0, 2_000_000.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if to_geo.transform(*(origin + u * mid))[2] > h_m:
            lo = mid
        else:
            hi = mid
    return lo


@pytest.mark.parametrize("seed", [0, 1])
def test_the_local_steps_find_the_first_intersection(seed):
    dem = _rough_dem(seed)
    grid = dem_grid(dem)
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    rng = np.random.default_rng(seed + 10)
    for r, c in dem.walls:
        # an oblique ray (up to 30 degrees off the vertical, across the walls) from 700 km
        # up to a ground point a few cells from a wall: it passes over the wall or hits it
        lon = _X0 + (c + 0.5 + rng.uniform(-5, 5)) * _STEP_DEG
        lat = _Y1 - (r + 0.5 + rng.uniform(-5, 5)) * _STEP_DEG
        target = np.array(to_ecef.transform(lon, lat, 300.0))
        up = np.array(to_ecef.transform(lon, lat, 1300.0)) - target
        up /= np.linalg.norm(up)
        side = np.cross(up, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        tilt = np.tan(np.radians(rng.uniform(-30, 30)))
        origin = target + 700_000.0 * (up + tilt * side) / np.hypot(1.0, tilt)
        u = (target - origin) / np.linalg.norm(target - origin)
        ray = (*origin, *u)
        lon_m, lat_m, h_m = _first_hit(origin, u, dem)
        q = ray_quadratic(ray, np.zeros(3), grid.h_top_m, grid.h_bottom_m)
        top_m = float(np.max(dem.heights))  # the safe steps from the highest terrain
        for got, tolerance_m in (
            (trace_dem(ray, np.zeros(3), grid), 2e-3),
            (trace_model(q, grid, np.inf), MODEL_ERROR_M),
            (trace_model(q, grid, top_m), MODEL_ERROR_M),
        ):
            assert got[2] == pytest.approx(h_m, abs=tolerance_m)
            # 1e-8 deg: about a millimetre
            assert got[0] == pytest.approx(lon_m, abs=1e-8)
            assert got[1] == pytest.approx(lat_m, abs=1e-8)


def test_the_cell_crossing_is_the_first_root_in_the_cell():
    """:func:`_cell_crossing` against a march of 1 mm steps along the straight ray over
    scipy's bilinear heights: where the ray meets the cell's surface, or where it leaves the
    cell without meeting it (edges found by the march too)."""
    dem = _rough_dem(2)
    grid = dem_grid(dem)
    n = dem.heights.shape[0]
    lats = _Y1 - (np.arange(n) + 0.5) * _STEP_DEG
    lons = _X0 + (np.arange(n) + 0.5) * _STEP_DEG
    terrain = RegularGridInterpolator((lats[::-1], lons), dem.heights[::-1])
    rng = np.random.default_rng(3)
    met = left = 0
    for _ in range(300):
        i, j = rng.integers(5, n - 6, 2)
        lon = _X0 + (j + 0.5 + rng.random()) * _STEP_DEG
        lat = _Y1 - (i + 0.5 + rng.random()) * _STEP_DEG
        # degrees per metre along the ray (a cell is ~5 m), descent per metre, start height
        heading = rng.uniform(0.0, 2.0 * np.pi)
        horizontal = rng.uniform(0.0, 0.6)
        a, b = (horizontal * _STEP_DEG / 5.0) * np.array([np.sin(heading), np.cos(heading)])
        c = np.sqrt(1.0 - horizontal**2)
        ground = float(terrain([lat, lon])[0])
        gap = rng.uniform(1e-3, 8.0)
        q = RayQuadratic(0.0, 1.0, lon, a, 0.0, lat, b, 0.0, ground + gap, -c, 0.0)
        meets, t = _cell_crossing(q, grid, 0.0, _cell_of(grid, lon, lat), c, gap)
        march = np.arange(0.0, 40.0, 1e-3)
        lo, la = lon + a * march, lat + b * march
        inside = (np.floor((lo - _X0) / _STEP_DEG - 0.5) == j) & (
            np.floor((_Y1 - la) / _STEP_DEG - 0.5) == i
        )
        exit_t = march[np.argmin(inside)] if not inside.all() else np.inf
        below = (ground + gap - c * march) <= terrain(np.column_stack([la, lo]))
        first = march[np.argmax(below & inside)] if (below & inside).any() else np.inf
        if first < np.inf:
            met += 1
            assert meets
            assert t == pytest.approx(first, abs=2e-3)
        else:
            left += 1
            assert not meets
            assert t == pytest.approx(exit_t, abs=2e-3)
    assert met > 50  # both cases are exercised
    assert left > 50
