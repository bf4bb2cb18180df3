"""Compiled ray casting of line-scanner pixels onto a geographic DEM: the fast location the
stagger merge uses (:mod:`carto.framework.geometry.linescan.stagger`), and the kernels the
simulator's renderer (:mod:`carto.framework.simulation.render`) builds on.

Each pixel's line of sight comes from the model's exact camera-state table (see
:mod:`carto.framework.geometry.linescan.solver`) and is intersected with the terrain by *safe
stepping*: at a height ``dh`` above the terrain, a ray that descends ``c`` metres per metre and
moves ``s`` metres horizontally cannot meet terrain of slope at most ``S`` before it has
travelled ``dh / (c + s S)``; stepping by that much never jumps over a ridge and converges like
Newton's method on gentle terrain. Iterations stop within ``1e-4`` m of the terrain height.
The result equals the generic search of
:func:`carto.framework.geometry.surface.dem_surface_locate` to 1e-4 m in height.

Grids are regular geographic grids (EPSG:4326, north up, pixel-is-area);
:func:`locate_pixels` raises :class:`InputError` for anything else (:func:`is_lonlat_grid`
tells beforehand).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.light_path import SOURCE_DIRECTION_STEPS
from carto.framework.geometry.linescan.solver import (
    interp_node,
    interp_rotation,
    lagrange_weights,
)

if TYPE_CHECKING:  # the model whose table the kernels read
    from carto.framework.geometry.linescan.scanner import LineScanner

FloatArray = NDArray[np.float64]

_A = frames.WGS84_A_M
_B = frames.WGS84_B_M
_E2 = frames.WGS84_E2
_EP2 = (_A * _A - _B * _B) / (_B * _B)
HEIGHT_TOLERANCE_M = 1e-4
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


@numba.njit(cache=True, nogil=True)
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
    slopes up to ``max_slope`` (rise/run). Flat, not holding a :class:`GeoGrid`: numba's
    parallel loops take tuples of arrays, not nested ones."""

    heights: NDArray
    x0_deg: float
    dx_deg: float
    y0_deg: float
    dy_deg: float
    h_top_m: float
    h_bottom_m: float
    max_slope: float


class CameraStates(NamedTuple):
    """What the kernels need to turn (line, detector sample) into a line of sight (the keys
    of :func:`sensor_arrays`): the line timing nodes (``line_nodes`` -> ``t_nodes``, s), the
    exact camera-state table at times ``node0 + k spacing`` (s; ECEF positions ``pos`` in m,
    ECEF -> camera rotations ``rot``, velocities over c ``beta``, and the Earth's angular
    velocity over c ``omega_c`` in rad/m) and the camera's look-angle polynomials ``tan_x``,
    ``tan_y`` in the sample normalised by ``half`` (half the detector count)."""

    line_nodes: NDArray
    t_nodes: NDArray
    node0: float
    spacing: float
    pos: NDArray
    rot: NDArray
    beta: NDArray
    omega_c: NDArray
    tan_x: NDArray
    tan_y: NDArray
    half: float


class _RayQuadratic(NamedTuple):
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
def _ray_quadratic(
    ray: tuple[float, float, float, float, float, float],
    omega_c: NDArray,
    h_top: float,
    h_bottom: float,
) -> _RayQuadratic:  # pragma: no cover - compiled
    """The quadratic model of the ray between the heights ``h_top`` and ``h_bottom``, fitted
    on three exact points (error below a centimetre over kilometres); ``d0_m`` NaN when the
    ray misses either height or does not descend through them."""
    d0 = start_distance(ray[0], ray[1], ray[2], ray[3], ray[4], ray[5], h_top)
    d2 = start_distance(ray[0], ray[1], ray[2], ray[3], ray[4], ray[5], h_bottom)
    if not (np.isfinite(d0) and np.isfinite(d2)) or d2 <= d0:
        nan = np.nan
        return _RayQuadratic(nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan)
    d1 = 0.5 * (d0 + d2)
    lo0, la0, h0 = _geodetic_along(ray, omega_c, d0)
    lo1, la1, h1 = _geodetic_along(ray, omega_c, d1)
    lo2, la2, h2 = _geodetic_along(ray, omega_c, d2)
    # quadratic in tau = (d - d0) / span through tau = 0, 0.5, 1
    return _RayQuadratic(
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
    q: _RayQuadratic, d: float
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """``(tau, lon_deg, lat_deg, h_m)`` of the quadratic model ``d`` metres along the ray."""
    tau = (d - q.d0_m) / q.span_m
    lon = q.lon0 + tau * (q.lon1 + tau * q.lon2)
    lat = q.lat0 + tau * (q.lat1 + tau * q.lat2)
    h = q.h0 + tau * (q.h1 + tau * q.h2)
    return tau, lon, lat, h


@numba.njit(cache=True, nogil=True, inline="always")
def _safe_steps(q: _RayQuadratic, dem: DemGrid) -> tuple[float, float]:  # pragma: no cover
    """Safe steps along the quadratic model from the top height until the ray is within 1e-3
    m of the terrain: ``(d, c)``, the distance along the ray (m) and the height it loses per
    metre there; ``d`` NaN when the ray leaves the DEM, does not descend or takes
    :data:`MAX_STEPS` steps."""
    d = q.d0_m
    for _ in range(MAX_STEPS):
        tau, lon, lat, h = _quadratic_at(q, d)
        ground = _terrain_height(dem, lon, lat)
        if not np.isfinite(ground):
            return np.nan, np.nan
        gap = h - ground
        c = -(q.h1 + 2.0 * tau * q.h2) / q.span_m  # height lost per metre along the ray
        if c <= 1e-6:
            return np.nan, np.nan  # the ray does not descend
        if abs(gap) < 1e-3:
            return d, c
        s = math.sqrt(max(1.0 - c * c, 0.0))
        d += gap / (c + s * dem.max_slope)
    return np.nan, np.nan


@numba.njit(cache=True, nogil=True, inline="always")
def _closure_rate(
    q: _RayQuadratic, dem: DemGrid, d: float, c: float
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
    q: _RayQuadratic,
    dem: DemGrid,
    d: float,
    c: float,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """(lon_deg, lat_deg, h_m) within :data:`HEIGHT_TOLERANCE_M` of the terrain, from ``d``
    metres along the ray: Newton steps on the exact geodetic conversion with the closure
    rate of the quadratic model; NaN when the ray leaves the DEM or does not converge."""
    for _ in range(6):
        lon, lat, h = _geodetic_along(ray, omega_c, d)
        ground = _terrain_height(dem, lon, lat)
        if not np.isfinite(ground):
            return np.nan, np.nan, np.nan
        gap = h - ground
        if abs(gap) < HEIGHT_TOLERANCE_M:
            return lon, lat, h
        d += gap / _closure_rate(q, dem, d, c)
    return np.nan, np.nan, np.nan


@numba.njit(cache=True, nogil=True, inline="always")
def trace_dem(
    ray: tuple[float, float, float, float, float, float], omega_c: NDArray, dem: DemGrid
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """:func:`ray_dem` of a ray ``(px, py, pz, ux, uy, uz)`` and a :class:`DemGrid`."""
    q = _ray_quadratic(ray, omega_c, dem.h_top_m, dem.h_bottom_m)
    if np.isnan(q.d0_m):
        return np.nan, np.nan, np.nan
    d, c = _safe_steps(q, dem)
    if np.isnan(d):
        return np.nan, np.nan, np.nan
    return _exact_refinement(ray, omega_c, q, dem, d, c)


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
    grid = DemGrid(dem, x0, dx, y0, dy, h_top, h_bottom, max_slope)
    return trace_dem((px, py, pz, ux, uy, uz), omega_c, grid)


@numba.njit(cache=True, nogil=True)
def interp_time(line: float, line_nodes: NDArray, t_nodes: NDArray) -> float:  # pragma: no cover
    n = line_nodes.shape[0]
    i = 0
    while i < n - 2 and line > line_nodes[i + 1]:
        i += 1
    slope = (t_nodes[i + 1] - t_nodes[i]) / (line_nodes[i + 1] - line_nodes[i])
    return t_nodes[i] + (line - line_nodes[i]) * slope


@numba.njit(cache=True, nogil=True, inline="always")
def _look_vector(
    det_sample: float, stagger: float, tan_x: NDArray, tan_y: NDArray, half: float
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """Unit look vector in the camera frame of a (fractional) detector sample, its
    along-track tangent offset by ``stagger``."""
    u = (det_sample - half) / half
    cx = 0.0
    for m in range(tan_x.shape[0] - 1, -1, -1):
        cx = cx * u + tan_x[m]
    cy = 0.0
    for m in range(tan_y.shape[0] - 1, -1, -1):
        cy = cy * u + tan_y[m]
    cx += stagger
    norm = math.sqrt(cx * cx + cy * cy + 1.0)
    return cx / norm, cy / norm, 1.0 / norm


@numba.njit(cache=True, nogil=True, inline="always")
def _source_direction(out: NDArray, b: NDArray) -> None:  # pragma: no cover - compiled
    """Turn the unit look vector ``out[3:6]`` into the unit direction the received light came
    from, for the velocity over c ``b``: ``u - beta + (u . beta) u`` refined as
    :func:`~carto.framework.geometry.light_path.source_direction` does."""
    ub = 0.0
    for i in range(3):
        ub += out[3 + i] * b[i]
    u = out[3:6].copy()
    n = 0.0
    for i in range(3):
        out[3 + i] = out[3 + i] - b[i] + ub * out[3 + i]
        n += out[3 + i] ** 2
    n = math.sqrt(n)
    for i in range(3):
        out[3 + i] /= n
    # refined to the exact inverse of the aberration (light_path.source_direction)
    a = np.empty(3)
    for _ in range(SOURCE_DIRECTION_STEPS):
        nb = out[3] * b[0] + out[4] * b[1] + out[5] * b[2]
        na = 0.0
        for i in range(3):
            a[i] = out[3 + i] + b[i] - nb * out[3 + i]
            na += a[i] ** 2
        na = math.sqrt(na)
        n = 0.0
        for i in range(3):
            out[3 + i] += u[i] - a[i] / na
            n += out[3 + i] ** 2
        n = math.sqrt(n)
        for i in range(3):
            out[3 + i] /= n


@numba.njit(cache=True, nogil=True)
def camera_ray(
    t: float,
    det_sample: float,
    stagger: float,
    node0: float,
    spacing: float,
    pos: NDArray,
    rot: NDArray,
    beta: NDArray,
    tan_x: NDArray,
    tan_y: NDArray,
    half: float,
    out: NDArray,
) -> bool:  # pragma: no cover - compiled
    """Fill out[0:3] with the perspective centre and out[3:6] with the unit direction the
    received light came from (the look vector corrected for aberration by ``beta``, the
    table's velocity over c: ``u - beta + (u . beta) u`` refined as
    :func:`~carto.framework.geometry.light_path.source_direction` does)."""
    k, w0, w1, w2, w3 = lagrange_weights(t, node0, spacing, pos.shape[0])
    if k < 0:
        return False
    v0, v1, v2 = _look_vector(det_sample, stagger, tan_x, tan_y, half)
    for i in range(3):
        out[i] = interp_node(pos, k, w0, w1, w2, w3, i)
        # rot is ecef -> camera: the look vector in ECEF is rot^T v
        r0 = interp_rotation(rot, k, w0, w1, w2, w3, 0, i)
        r1 = interp_rotation(rot, k, w0, w1, w2, w3, 1, i)
        r2 = interp_rotation(rot, k, w0, w1, w2, w3, 2, i)
        out[3 + i] = r0 * v0 + r1 * v1 + r2 * v2
    n = math.sqrt(out[3] ** 2 + out[4] ** 2 + out[5] ** 2)
    b = np.empty(3)
    for i in range(3):
        out[3 + i] /= n
        b[i] = interp_node(beta, k, w0, w1, w2, w3, i)
    _source_direction(out, b)
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def trace_pixel(
    t: float,
    det_sample: float,
    stagger: float,
    cam: CameraStates,
    dem: DemGrid,
    ray: NDArray,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """Ground point ``(lon_deg, lat_deg, h_m)`` a (fractional) detector sample sees at time
    ``t``: :func:`camera_ray` then :func:`trace_dem`; NaN where the table has no state or the
    ray leaves the DEM. ``ray`` is scratch space, ``(6,)``."""
    if not camera_ray(
        t,
        det_sample,
        stagger,
        cam.node0,
        cam.spacing,
        cam.pos,
        cam.rot,
        cam.beta,
        cam.tan_x,
        cam.tan_y,
        cam.half,
        ray,
    ):
        return np.nan, np.nan, np.nan
    return trace_dem((ray[0], ray[1], ray[2], ray[3], ray[4], ray[5]), cam.omega_c, dem)


@numba.njit(parallel=True, cache=True, nogil=True)
def _locate_kernel(
    lines: NDArray, det_samples: NDArray, staggers: NDArray, cam: CameraStates, dem: DemGrid
) -> NDArray:  # pragma: no cover - compiled
    n = lines.shape[0]
    out = np.full((n, 3), np.nan)
    for i in numba.prange(n):
        ray = np.empty(6)
        t = interp_time(lines[i], cam.line_nodes, cam.t_nodes)
        lon, lat, h = trace_pixel(t, det_samples[i], staggers[i], cam, dem, ray)
        out[i, 0] = lon
        out[i, 1] = lat
        out[i, 2] = h
    return out


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
    return np.ascontiguousarray(grid, dtype=np.float64), c, a, f, e


def max_terrain_slope(heights: NDArray, dx_deg: float, dy_deg: float, lat_deg: float) -> float:
    """Largest terrain slope (rise/run) of a geographic grid, with a safety margin."""
    m_lat = math.radians(1.0) * frames.WGS84_A_M
    m_lon = m_lat * math.cos(math.radians(lat_deg))
    gy, gx = np.gradient(
        np.nan_to_num(heights, nan=np.nanmean(heights)), abs(dy_deg) * m_lat, abs(dx_deg) * m_lon
    )
    return float(np.hypot(gx, gy).max() * 1.5 + 0.05)


def sensor_arrays(sensor: LineScanner) -> dict[str, object]:
    table = sensor._table
    if table.position is None:
        table.build(sensor)
    cam = sensor.camera
    cx, cy, stagger = cam.effective_coeffs()
    return {
        "line_nodes": np.asarray(sensor.timing.line_nodes, float),
        "t_nodes": np.asarray(sensor.timing.dt_nodes_s, float),
        "node0": table.node0,
        "spacing": table.spacing,
        "pos": table.position,
        "rot": table.rotation,
        "beta": table.beta,
        "omega_c": table.omega_c,
        "tan_x": cx + np.array([stagger if cam.array == "even" else 0.0] + [0.0] * (len(cx) - 1)),
        "tan_y": cy,
        "half": cam.n_samples / 2.0,
    }


def camera_states(sensor: LineScanner) -> CameraStates:
    """:func:`sensor_arrays` as the kernels take them."""
    return CameraStates(**sensor_arrays(sensor))


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
    (default :func:`max_terrain_slope` of the DEM)."""
    grid = geo_grid(dem.heights, dem.transform, dem.crs, "DEM")
    if h_range is None:
        h_range = (float(np.nanmin(grid.values)), float(np.nanmax(grid.values)))
    if max_slope is None:
        lat_c = grid.y0_deg + grid.dy_deg * grid.values.shape[0] / 2
        max_slope = max_terrain_slope(grid.values, grid.dx_deg, grid.dy_deg, lat_c)
    return DemGrid(*grid, float(h_range[1]) + 1.0, float(h_range[0]) - 1.0, float(max_slope))


def locate_pixels(
    sensor: LineScanner, line: NDArray, sample: NDArray, dem: object
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Fast image -> ground on a geographic DEM for a line scanner: ``(lon, lat, h)``.

    Same result as :meth:`Sensor.locate_on_dem` (to 1e-4 m in height), computed in compiled
    code; NaN where the ray leaves the DEM.
    """
    grid = dem_grid(dem)
    line = np.ascontiguousarray(np.ravel(line), float)
    sample = np.ascontiguousarray(np.ravel(sample), float)
    out = _locate_kernel(
        line, sample + sensor.first_sample, np.zeros_like(line), camera_states(sensor), grid
    )
    return out[:, 0], out[:, 1], out[:, 2]


def is_lonlat_grid(dem: object) -> bool:
    """True for a north-up geographic EPSG:4326 grid (what the compiled location takes)."""
    import pyproj

    crs, t = getattr(dem, "crs", None), getattr(dem, "transform", None)
    if crs is None or t is None:
        return False
    return bool(
        pyproj.CRS.from_user_input(crs).equals(pyproj.CRS("EPSG:4326"), ignore_axis_order=True)
        and t.b == 0.0
        and t.d == 0.0
        and t.e < 0.0
    )
