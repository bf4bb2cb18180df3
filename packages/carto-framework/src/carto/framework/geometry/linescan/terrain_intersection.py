"""Where a ray meets a DEM (:func:`trace_dem`): the compiled intersection the ray caster
(:mod:`carto.framework.geometry.linescan.raycast`) and the simulator's renderer build on.

Rays are intersected with the terrain by *safe stepping*: at a height ``dh`` above the
terrain, a ray that descends ``c`` metres per metre and moves ``s`` metres horizontally cannot
meet terrain of slope at most ``S`` before it has travelled ``dh / (c + s S)``; stepping by
that much never jumps over a ridge. ``S`` is the largest slope of the DEM's bilinear surface
in the 3 x 3 cells around the ray where the step stays within one cell (:func:`local_slopes`),
else that of the whole DEM. Along the ray the bilinear surface of the cell under it is a
quadratic, so where the ray meets it there is solved exactly (:func:`_cell_crossing`); a ray
that crosses the cell without meeting it steps at least to the cell's edge. Between the
search heights the ray's geodetic coordinates are quadratics in the distance along it
(:func:`ray_quadratic`), which makes the steps cheap; the last steps use the exact geodetic
conversion and stop within ``1e-4`` m of the terrain height.

Grids are regular geographic grids (EPSG:4326, north up, pixel-is-area);
:func:`dem_grid` raises :class:`InputError` for anything else.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames

FloatArray = NDArray[np.float64]

_A = frames.WGS84_A_M
_B = frames.WGS84_B_M
_E2 = frames.WGS84_E2
_EP2 = (_A * _A - _B * _B) / (_B * _B)
HEIGHT_TOLERANCE_M = 1e-4
MODEL_ERROR_M = 1e-3
"""Bound on the distance between :func:`trace_model`'s point and the exact ray's
(:func:`trace_dem`), checked by the tests on whole image bands (measured: under 2e-4 m)."""
_SAFE_STOP_M = 1e-3  # where the safe steps hand over to the exact refinement
_LINEAR_STEP_M = 0.05  # longest final Newton step checked on the tangent (see _exact_refinement)
MAX_STEPS = 4000


@numba.njit(cache=True, nogil=True)
def geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:  # pragma: no cover
    """ECEF -> (lon_deg, lat_deg, h_m) by Bowring's formula with one refinement of the
    parametric latitude (error < 1e-8 m for heights within +-10 km of the ellipsoid)."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    beta = math.atan2(_A * z, _B * p)
    lat = math.atan2(z + _EP2 * _B * math.sin(beta) ** 3, p - _E2 * _A * math.cos(beta) ** 3)
    beta = math.atan2((1.0 - 1.0 / 298.257223563) * math.sin(lat), math.cos(lat))
    lat = math.atan2(z + _EP2 * _B * math.sin(beta) ** 3, p - _E2 * _A * math.cos(beta) ** 3)
    sin_lat = math.sin(lat)
    n = _A / math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
    h = p * math.cos(lat) + z * sin_lat - _A * _A / n
    return math.degrees(lon), math.degrees(lat), h


@numba.njit(cache=True, nogil=True, inline="always")
def grid_bilinear(
    grid: NDArray, x0: float, dx: float, y0: float, dy: float, x: float, y: float
) -> float:  # pragma: no cover - compiled
    """Bilinear value of a north-up grid at (x, y); pixel centres at x0 + (j + 0.5) dx."""
    fx = (x - x0) / dx - 0.5
    fy = (y - y0) / dy - 0.5
    j = math.floor(fx)
    i = math.floor(fy)
    if i < 0 or j < 0 or i + 1 >= grid.shape[0] or j + 1 >= grid.shape[1]:
        return np.nan
    tx = fx - j
    ty = fy - i
    return (1.0 - ty) * ((1.0 - tx) * grid[i, j] + tx * grid[i, j + 1]) + ty * (
        (1.0 - tx) * grid[i + 1, j] + tx * grid[i + 1, j + 1]
    )


@numba.njit(cache=True, nogil=True)
def start_distance(
    px: float, py: float, pz: float, ux: float, uy: float, uz: float, h: float
) -> float:  # pragma: no cover - compiled
    """Distance along the ray to the ellipsoid of semi-axes (a+h, a+h, b+h)."""
    a = _A + h
    b = _B + h
    sx, sy, sz = px / a, py / a, pz / b
    vx, vy, vz = ux / a, uy / a, uz / b
    qa = vx * vx + vy * vy + vz * vz
    qb = 2.0 * (sx * vx + sy * vy + sz * vz)
    qc = sx * sx + sy * sy + sz * sz - 1.0
    disc = qb * qb - 4.0 * qa * qc
    if disc < 0.0:
        return np.nan
    return max((-qb - math.sqrt(disc)) / (2.0 * qa), 0.0)


@numba.njit(cache=True, nogil=True)
def ray_point(
    px: float,
    py: float,
    pz: float,
    ux: float,
    uy: float,
    uz: float,
    omega_c: NDArray,
    d: float,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """The Earth-fixed point whose light travelled ``d`` metres along the ray: ``X0 = P + d u``
    turned forward by the light time, ``X0 + (omega/c x X0) d`` (``omega_c`` zero: no light
    time)."""
    x = px + d * ux
    y = py + d * uy
    z = pz + d * uz
    return (
        x + (omega_c[1] * z - omega_c[2] * y) * d,
        y + (omega_c[2] * x - omega_c[0] * z) * d,
        z + (omega_c[0] * y - omega_c[1] * x) * d,
    )


class GeoGrid(NamedTuple):
    """A north-up EPSG:4326 grid as the kernels read it: ``values[i, j]`` has its pixel centre
    at ``(x0_deg + (j + 0.5) dx_deg, y0_deg + (i + 0.5) dy_deg)`` (``dy_deg`` < 0)."""

    values: NDArray
    x0_deg: float
    dx_deg: float
    y0_deg: float
    dy_deg: float


class DemGrid(NamedTuple):
    """A DEM of ellipsoidal heights (a :class:`GeoGrid` of ``heights``) and the bounds of the
    ray search over it: rays start at ``h_top_m``, end at ``h_bottom_m`` and step safely for
    slopes up to ``max_slope`` (rise/run), or ``slopes[i, j]`` (:func:`local_slopes`) for a
    step that moves at most ``cell_m`` metres across from the cell ``(i, j)`` of the bilinear
    surface (``slopes`` of shape ``(0, 0)``: none). Flat, not holding a :class:`GeoGrid`:
    numba's parallel loops take tuples of arrays, not nested ones."""

    heights: NDArray
    x0_deg: float
    dx_deg: float
    y0_deg: float
    dy_deg: float
    h_top_m: float
    h_bottom_m: float
    max_slope: float
    slopes: NDArray
    cell_m: float


class RayQuadratic(NamedTuple):
    """A ray's geodetic coordinates as quadratics in ``tau = (d - d0_m) / span_m`` between
    the search heights (``d``: metres along the ray): ``lon_deg = lon0 + tau (lon1 + tau
    lon2)``, the same for ``lat_deg`` and ``h_m``. ``d0_m`` is NaN for a ray that misses."""

    d0_m: float
    span_m: float
    lon0: float
    lon1: float
    lon2: float
    lat0: float
    lat1: float
    lat2: float
    h0: float
    h1: float
    h2: float


@numba.njit(cache=True, nogil=True, inline="always")
def _terrain_height(dem: DemGrid, lon_deg: float, lat_deg: float) -> float:  # pragma: no cover
    """:func:`grid_bilinear` of the DEM's heights (m)."""
    return grid_bilinear(
        dem.heights, dem.x0_deg, dem.dx_deg, dem.y0_deg, dem.dy_deg, lon_deg, lat_deg
    )


@numba.njit(cache=True, nogil=True, inline="always")
def _geodetic_along(
    ray: tuple[float, float, float, float, float, float], omega_c: NDArray, d: float
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """(lon_deg, lat_deg, h_m) of :func:`ray_point` at ``d`` metres along ``ray`` (origin,
    unit direction)."""
    return geodetic(*ray_point(ray[0], ray[1], ray[2], ray[3], ray[4], ray[5], omega_c, d))


@numba.njit(cache=True, nogil=True, inline="always")
def ray_quadratic(
    ray: tuple[float, float, float, float, float, float],
    omega_c: NDArray,
    h_top: float,
    h_bottom: float,
) -> RayQuadratic:  # pragma: no cover - compiled
    """The quadratic model of the ray between the heights ``h_top`` and ``h_bottom``, fitted
    on three exact points (error below a centimetre over kilometres); ``d0_m`` NaN when the
    ray misses either height or does not descend through them."""
    d0 = start_distance(ray[0], ray[1], ray[2], ray[3], ray[4], ray[5], h_top)
    d2 = start_distance(ray[0], ray[1], ray[2], ray[3], ray[4], ray[5], h_bottom)
    if not (np.isfinite(d0) and np.isfinite(d2)) or d2 <= d0:
        nan = np.nan
        return RayQuadratic(nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan)
    d1 = 0.5 * (d0 + d2)
    lo0, la0, h0 = _geodetic_along(ray, omega_c, d0)
    lo1, la1, h1 = _geodetic_along(ray, omega_c, d1)
    lo2, la2, h2 = _geodetic_along(ray, omega_c, d2)
    # quadratic in tau = (d - d0) / span through tau = 0, 0.5, 1
    return RayQuadratic(
        d0,
        d2 - d0,
        lo0,
        4.0 * lo1 - 3.0 * lo0 - lo2,
        2.0 * (lo0 + lo2) - 4.0 * lo1,
        la0,
        4.0 * la1 - 3.0 * la0 - la2,
        2.0 * (la0 + la2) - 4.0 * la1,
        h0,
        4.0 * h1 - 3.0 * h0 - h2,
        2.0 * (h0 + h2) - 4.0 * h1,
    )


@numba.njit(cache=True, nogil=True, inline="always")
def _quadratic_at(
    q: RayQuadratic, d: float
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """``(tau, lon_deg, lat_deg, h_m)`` of the quadratic model ``d`` metres along the ray."""
    tau = (d - q.d0_m) / q.span_m
    lon = q.lon0 + tau * (q.lon1 + tau * q.lon2)
    lat = q.lat0 + tau * (q.lat1 + tau * q.lat2)
    h = q.h0 + tau * (q.h1 + tau * q.h2)
    return tau, lon, lat, h


@numba.njit(cache=True, nogil=True, inline="always")
def _safe_steps(
    q: RayQuadratic, dem: DemGrid, tolerance_m: float, d_start: float
) -> tuple[float, float]:  # pragma: no cover - compiled
    """Safe steps along the quadratic model from ``d_start`` metres along the ray (at or
    above the terrain) until the ray is within ``tolerance_m`` of the terrain, or meets it
    in the cell it is over (:func:`_cell_crossing`): ``(d, c)``,
    the distance along the ray (m) and the height it loses per metre there; ``d`` NaN when
    the ray leaves the DEM, does not descend or takes :data:`MAX_STEPS` steps."""
    d = d_start
    for _ in range(MAX_STEPS):
        tau, lon, lat, h = _quadratic_at(q, d)
        cell = _cell_of(dem, lon, lat)
        ground, slope = _height_and_slope(dem, cell)
        if not np.isfinite(ground):
            return np.nan, np.nan
        gap = h - ground
        c = -(q.h1 + 2.0 * tau * q.h2) / q.span_m  # height lost per metre along the ray
        if c <= 1e-6:
            return np.nan, np.nan  # the ray does not descend
        if abs(gap) < tolerance_m:
            return d, c
        s = math.sqrt(max(1.0 - c * c, 0.0))
        step = gap / (c + s * dem.max_slope)
        if gap > 0.0 and np.isfinite(slope):  # the cells around, for a step that stays there
            local = gap / (c + s * slope)
            if s * local <= dem.cell_m:
                step = local
            meets, t = _cell_crossing(q, dem, tau, cell, c, gap)
            step = t if meets else max(step, t)
        d += step
    return np.nan, np.nan


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_crossing(
    q: RayQuadratic,
    dem: DemGrid,
    tau: float,
    cell: tuple[int, int, float, float],
    c: float,
    gap: float,
) -> tuple[bool, float]:  # pragma: no cover - compiled
    """Where the ray, ``gap`` metres above the terrain at a point of the DEM's bilinear
    ``cell`` (:func:`_cell_of`; ``tau`` on its model) and descending ``c`` metres per metre,
    meets the cell's surface: ``(True, distance along the ray to that point)``, or ``(False,
    distance to where it leaves the cell)`` when it does not meet it there (m). Along a
    straight line the bilinear surface is a quadratic in the distance; the ray is taken as
    its tangent line (over a cell it departs from its model by micrometres)."""
    i, j, tx, ty = cell
    grid = dem.heights
    g00, g01 = grid[i, j], grid[i, j + 1]
    g10, g11 = grid[i + 1, j], grid[i + 1, j + 1]
    b = g01 - g00
    e = g10 - g00
    f = g11 - g01 - g10 + g00
    p = (q.lon1 + 2.0 * tau * q.lon2) / (q.span_m * dem.dx_deg)  # cell fractions per metre
    r = (q.lat1 + 2.0 * tau * q.lat2) / (q.span_m * dem.dy_deg)
    exit_t = np.inf
    if p > 0.0:
        exit_t = (1.0 - tx) / p
    elif p < 0.0:
        exit_t = -tx / p
    if r > 0.0:
        exit_t = min(exit_t, (1.0 - ty) / r)
    elif r < 0.0:
        exit_t = min(exit_t, -ty / r)
    # gap(t) = gap - lin t - quad t^2
    lin = c + b * p + e * r + f * (tx * r + ty * p)
    quad = f * p * r
    disc = lin * lin + 4.0 * quad * gap
    if disc >= 0.0:
        root = np.inf
        half = -0.5 * (lin + math.copysign(math.sqrt(disc), lin))
        if half != 0.0:
            t2 = -gap / half
            if t2 >= 0.0:
                root = t2
        if quad != 0.0:
            t1 = half / quad
            if 0.0 <= t1 < root:
                root = t1
        if root <= exit_t:
            return True, root
    return False, exit_t


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_of(
    dem: DemGrid, lon_deg: float, lat_deg: float
) -> tuple[int, int, float, float]:  # pragma: no cover - compiled
    """``(i, j, tx, ty)``: the bilinear cell under ``(lon_deg, lat_deg)`` (between the
    node centres ``(i, j)`` and ``(i + 1, j + 1)``, the cell :func:`grid_bilinear` reads;
    possibly outside the grid) and the point's fractions across it."""
    fx = (lon_deg - dem.x0_deg) / dem.dx_deg - 0.5
    fy = (lat_deg - dem.y0_deg) / dem.dy_deg - 0.5
    j = math.floor(fx)
    i = math.floor(fy)
    return i, j, fx - j, fy - i


@numba.njit(cache=True, nogil=True, inline="always")
def _height_and_slope(
    dem: DemGrid, cell: tuple[int, int, float, float]
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`grid_bilinear` of the DEM's heights (m, NaN outside) at a point of ``cell``
    (:func:`_cell_of`) and ``dem.slopes`` of that cell (infinite where there is none)."""
    i, j, tx, ty = cell
    grid = dem.heights
    if i < 0 or j < 0 or i + 1 >= grid.shape[0] or j + 1 >= grid.shape[1]:
        return np.nan, np.inf
    h = (1.0 - ty) * ((1.0 - tx) * grid[i, j] + tx * grid[i, j + 1]) + ty * (
        (1.0 - tx) * grid[i + 1, j] + tx * grid[i + 1, j + 1]
    )
    if i >= dem.slopes.shape[0] or j >= dem.slopes.shape[1]:
        return h, np.inf
    return h, dem.slopes[i, j]


@numba.njit(cache=True, nogil=True, inline="always")
def _closure_rate(
    q: RayQuadratic, dem: DemGrid, d: float, c: float
) -> float:  # pragma: no cover - compiled
    """Rate (m/m) at which the ray closes on the terrain at ``d`` by the quadratic model (a
    5 cm difference); the safe-step rate for the descent ``c`` where that is not positive."""
    eps = 0.05
    _, lon_e, lat_e, h_e = _quadratic_at(q, d + eps)
    g_e = _terrain_height(dem, lon_e, lat_e)
    _, lon_0, lat_0, h_0 = _quadratic_at(q, d)
    g_0 = _terrain_height(dem, lon_0, lat_0)
    rate = ((h_0 - g_0) - (h_e - g_e)) / eps
    if not np.isfinite(rate) or rate <= 1e-9:
        rate = c + math.sqrt(max(1.0 - c * c, 0.0)) * dem.max_slope
    return rate


@numba.njit(cache=True, nogil=True, inline="always")
def _exact_refinement(
    ray: tuple[float, float, float, float, float, float],
    omega_c: NDArray,
    q: RayQuadratic,
    dem: DemGrid,
    d: float,
    c: float,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """(lon_deg, lat_deg, h_m) within :data:`HEIGHT_TOLERANCE_M` of the terrain, from ``d``
    metres along the ray: Newton steps on the exact geodetic conversion with the closure
    rate of the quadratic model; NaN when the ray leaves the DEM or does not converge.

    A step shorter than :data:`_LINEAR_STEP_M` is checked at the point moved along the
    model's tangent (off by under 1e-12 m over that distance) rather than by converting the
    exact ray again: the one conversion a ray usually needs."""
    for _ in range(6):
        lon, lat, h = _geodetic_along(ray, omega_c, d)
        ground = _terrain_height(dem, lon, lat)
        if not np.isfinite(ground):
            return np.nan, np.nan, np.nan
        gap = h - ground
        if abs(gap) < HEIGHT_TOLERANCE_M:
            return lon, lat, h
        step = gap / _closure_rate(q, dem, d, c)
        if abs(step) < _LINEAR_STEP_M:
            tau = (d - q.d0_m) / q.span_m
            f = step / q.span_m
            lon += f * (q.lon1 + 2.0 * tau * q.lon2)
            lat += f * (q.lat1 + 2.0 * tau * q.lat2)
            h += f * (q.h1 + 2.0 * tau * q.h2)
            ground = _terrain_height(dem, lon, lat)
            if np.isfinite(ground) and abs(h - ground) < HEIGHT_TOLERANCE_M:
                return lon, lat, h
        d += step
    return np.nan, np.nan, np.nan


@numba.njit(cache=True, nogil=True, inline="always")
def trace_dem(
    ray: tuple[float, float, float, float, float, float], omega_c: NDArray, dem: DemGrid
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """:func:`ray_dem` of a ray ``(px, py, pz, ux, uy, uz)`` and a :class:`DemGrid`."""
    q = ray_quadratic(ray, omega_c, dem.h_top_m, dem.h_bottom_m)
    if np.isnan(q.d0_m):
        return np.nan, np.nan, np.nan
    d, c = _safe_steps(q, dem, _SAFE_STOP_M, q.d0_m)
    if np.isnan(d):
        return np.nan, np.nan, np.nan
    return _exact_refinement(ray, omega_c, q, dem, d, c)


@numba.njit(cache=True, nogil=True, inline="always")
def trace_quadratic(
    ray: tuple[float, float, float, float, float, float],
    omega_c: NDArray,
    q: RayQuadratic,
    dem: DemGrid,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """:func:`trace_dem` with the ray's quadratic model ``q`` given (exact or
    :func:`interpolated_quadratic`): the model only guides the safe steps, the point is found
    on the exact ray (:func:`_exact_refinement`)."""
    if np.isnan(q.d0_m):
        return np.nan, np.nan, np.nan
    d, c = _safe_steps(q, dem, _SAFE_STOP_M, q.d0_m)
    if np.isnan(d):
        return np.nan, np.nan, np.nan
    return _exact_refinement(ray, omega_c, q, dem, d, c)


@numba.njit(cache=True, nogil=True, inline="always")
def trace_model(
    q: RayQuadratic, dem: DemGrid, top_m: float
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """Where a ray's quadratic model ``q`` meets the DEM, ``(lon_deg, lat_deg, h_m)``
    within :data:`HEIGHT_TOLERANCE_M` of the terrain by safe steps alone (NaN as
    :func:`trace_dem`): the model's point, not the exact ray's. For an exact model
    (:func:`ray_quadratic`) or one interpolated over :data:`QUADRATIC_STEP` samples
    (:func:`interpolated_quadratic`) it lies within :data:`MODEL_ERROR_M` of
    :func:`trace_dem`'s, at a third of the cost: the simulator's renderer, which samples a
    texture there, takes it.

    ``top_m`` bounds the terrain under the model's path between the search heights (``inf``:
    unknown): the steps start where the ray descends to it (:func:`_start_below`)."""
    if np.isnan(q.d0_m):
        return np.nan, np.nan, np.nan
    d, _ = _safe_steps(q, dem, HEIGHT_TOLERANCE_M, _start_below(q, top_m))
    if np.isnan(d):
        return np.nan, np.nan, np.nan
    _, lon, lat, h = _quadratic_at(q, d)
    return lon, lat, h


@numba.njit(cache=True, nogil=True, inline="always")
def _start_below(q: RayQuadratic, top_m: float) -> float:  # pragma: no cover - compiled
    """Distance along the ray (m) where its model has descended to 1 cm above ``top_m``, the
    highest the terrain gets under its path: no terrain above, so safe steps may start there.
    The search's top ``q.d0_m`` where ``top_m`` is not below it (or unknown)."""
    target = top_m + 0.01
    if not target < q.h0:
        return q.d0_m
    tau = (target - q.h0) / q.h1  # h1 < 0 for a descending ray; then Newton on the quadratic
    for _ in range(2):
        tau -= (q.h0 + tau * (q.h1 + tau * q.h2) - target) / (q.h1 + 2.0 * tau * q.h2)
    if not 0.0 < tau < 1.0 or q.h0 + tau * (q.h1 + tau * q.h2) < top_m:
        return q.d0_m
    return q.d0_m + tau * q.span_m


QUADRATIC_STEP = 32.0
"""Detector samples between the rays whose quadratic models
:func:`~carto.framework.geometry.linescan.raycast.quadratic_table` fits exactly; the rays
between take :func:`interpolated_quadratic` (linear in the sample: the models are smooth in
the look angle, so the interpolated one meets the terrain within :data:`MODEL_ERROR_M` of the
exact ray, and :func:`trace_quadratic`'s exact refinement removes even that)."""


@numba.njit(cache=True, nogil=True, inline="always")
def interpolated_quadratic(
    table: NDArray, n_nodes: int, first: float, sample: float
) -> RayQuadratic:  # pragma: no cover - compiled
    """The quadratic model of the ray of a detector sample, linear between the nodes of
    :func:`quadratic_table` (NaN beyond them or next to a ray that misses)."""
    f = (sample - first) / QUADRATIC_STEP
    m = min(max(math.floor(f), 0), n_nodes - 2)
    frac = f - m
    lo, hi = table[m], table[m + 1]
    rest = 1.0 - frac
    return RayQuadratic(
        rest * lo[0] + frac * hi[0],
        rest * lo[1] + frac * hi[1],
        rest * lo[2] + frac * hi[2],
        rest * lo[3] + frac * hi[3],
        rest * lo[4] + frac * hi[4],
        rest * lo[5] + frac * hi[5],
        rest * lo[6] + frac * hi[6],
        rest * lo[7] + frac * hi[7],
        rest * lo[8] + frac * hi[8],
        rest * lo[9] + frac * hi[9],
        rest * lo[10] + frac * hi[10],
    )


@numba.njit(cache=True, nogil=True)
def ray_dem(
    px: float,
    py: float,
    pz: float,
    ux: float,
    uy: float,
    uz: float,
    dem: NDArray,
    x0: float,
    dx: float,
    y0: float,
    dy: float,
    h_top: float,
    h_bottom: float,
    max_slope: float,
    omega_c: NDArray,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """First intersection of a ray with the DEM surface, seen from the ray's origin (points
    along it turned by the light time, :func:`ray_point`).

    Between the heights ``h_top`` and ``h_bottom`` the ray's geodetic coordinates are
    quadratic functions of the distance along it (fitted on three exact points; error below a
    centimetre over kilometres), which makes the safe steps cheap; the last steps use the exact
    geodetic conversion.
    """
    grid = DemGrid(dem, x0, dx, y0, dy, h_top, h_bottom, max_slope, np.empty((0, 0)), 0.0)
    return trace_dem((px, py, pz, ux, uy, uz), omega_c, grid)


def geographic_grid(
    grid: NDArray, transform: object, crs: object, what: str
) -> tuple[NDArray, float, float, float, float]:
    """(grid, x0, dx, y0, dy) of a north-up EPSG:4326 grid, or InputError."""
    import pyproj

    if crs is None or not pyproj.CRS.from_user_input(crs).equals(
        pyproj.CRS("EPSG:4326"), ignore_axis_order=True
    ):
        raise InputError(f"{what} must be on a geographic EPSG:4326 grid, got {crs}")
    a, b, c, d, e, f = (
        transform.a,
        transform.b,
        transform.c,
        transform.d,
        transform.e,
        transform.f,
    )
    if b != 0 or d != 0 or e >= 0:
        raise InputError(f"{what} must be a north-up grid without rotation")
    return read_only(grid), c, a, f, e


def read_only(values: NDArray) -> NDArray[np.float64]:
    """``values`` as the kernels take a grid: C-contiguous float64, flagged read-only (a view,
    copied only to convert). numba compiles a kernel once per argument type, and read-only is
    part of the type: a writable grid from one caller and a read-only one (a
    :class:`~carto.framework.raster.dem.DEM`'s heights) from another compiled it twice."""
    view = np.ascontiguousarray(values, dtype=np.float64).view()
    view.flags.writeable = False
    return view


def max_terrain_slope(heights: NDArray, dx_deg: float, dy_deg: float, lat_deg: float) -> float:
    """Largest terrain slope (rise/run) of a geographic grid, with a safety margin."""
    m_lat = math.radians(1.0) * frames.WGS84_A_M
    m_lon = m_lat * math.cos(math.radians(lat_deg))
    gy, gx = np.gradient(
        np.nan_to_num(heights, nan=np.nanmean(heights)), abs(dy_deg) * m_lat, abs(dx_deg) * m_lon
    )
    return float(np.hypot(gx, gy).max() * 1.5 + 0.05)


def local_slopes(
    heights: NDArray, dx_deg: float, dy_deg: float, lat_deg: tuple[float, float]
) -> tuple[FloatArray, float]:
    """The slope bound (rise/run) of the safe steps around each cell of a geographic grid's
    bilinear surface, and the side of a cell (m, the least over the latitudes ``lat_deg``).

    Within the cell between the centres ``(i, j)`` and ``(i + 1, j + 1)`` the bilinear
    surface's gradient is at most the largest difference along each axis over the cell's
    edges, per metre; the bound of cell ``(i, j)`` is the largest of its 3 x 3 neighbourhood
    (so it holds for a step of up to one cell side from anywhere in it), with the margin of
    :func:`max_terrain_slope` (x 1.5 + 0.05). Metres per degree are taken on a sphere of the
    ellipsoid's least radius of curvature, and at the latitude farthest from the equator:
    cells are never smaller, slopes never steeper, than assumed. Infinite next to a void."""
    from scipy import ndimage

    radius = frames.WGS84_A_M * (1.0 - frames.WGS84_E2)
    m_lat = math.radians(abs(dy_deg)) * radius
    far = max(abs(lat_deg[0]), abs(lat_deg[1]))
    m_lon = math.radians(abs(dx_deg)) * radius * math.cos(math.radians(min(far, 89.0)))
    z = np.asarray(heights, np.float64)
    out = np.full(z.shape, np.inf)
    if min(z.shape) < 2:
        return out, min(m_lat, m_lon)
    along_x = np.abs(np.diff(z, axis=1)) / m_lon
    along_y = np.abs(np.diff(z, axis=0)) / m_lat
    patch = np.hypot(
        np.maximum(along_x[:-1], along_x[1:]), np.maximum(along_y[:, :-1], along_y[:, 1:])
    )
    patch[~np.isfinite(patch)] = np.inf
    out[:-1, :-1] = ndimage.maximum_filter(patch, size=3, mode="nearest") * 1.5 + 0.05
    return out, min(m_lat, m_lon)


def geo_grid(values: NDArray, transform: object, crs: object, what: str) -> GeoGrid:
    """:func:`geographic_grid` as the kernels take it (or InputError)."""
    grid, x0, dx, y0, dy = geographic_grid(values, transform, crs, what)
    return GeoGrid(grid, float(x0), float(dx), float(y0), float(dy))


def dem_grid(
    dem: object, h_range: tuple[float, float] | None = None, max_slope: float | None = None
) -> DemGrid:
    """The DEM (``heights``, ``transform``, ``crs``; a north-up EPSG:4326 grid, or
    InputError) as the kernels search it: between the heights ``h_range`` (default the DEM's
    own lowest and highest) widened by 1 m, stepping safely for slopes up to ``max_slope``
    (default :func:`max_terrain_slope` of the DEM), or those of :func:`local_slopes` for
    short steps."""
    grid = geo_grid(dem.heights, dem.transform, dem.crs, "DEM")
    if h_range is None:
        h_range = (float(np.nanmin(grid.values)), float(np.nanmax(grid.values)))
    if max_slope is None:
        lat_c = grid.y0_deg + grid.dy_deg * grid.values.shape[0] / 2
        max_slope = max_terrain_slope(grid.values, grid.dx_deg, grid.dy_deg, lat_c)
    lat_edges = (grid.y0_deg, grid.y0_deg + grid.dy_deg * grid.values.shape[0])
    slopes, cell_m = local_slopes(grid.values, grid.dx_deg, grid.dy_deg, lat_edges)
    return DemGrid(
        *grid,
        float(h_range[1]) + 1.0,
        float(h_range[0]) - 1.0,
        float(max_slope),
        slopes,
        float(cell_m),
    )
