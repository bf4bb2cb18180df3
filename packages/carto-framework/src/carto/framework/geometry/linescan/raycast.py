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
from typing import TYPE_CHECKING

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.light_path import SOURCE_DIRECTION_STEPS

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
    d0 = start_distance(px, py, pz, ux, uy, uz, h_top)
    d2 = start_distance(px, py, pz, ux, uy, uz, h_bottom)
    if not (np.isfinite(d0) and np.isfinite(d2)) or d2 <= d0:
        return np.nan, np.nan, np.nan
    d1 = 0.5 * (d0 + d2)
    lo0, la0, h0 = geodetic(*ray_point(px, py, pz, ux, uy, uz, omega_c, d0))
    lo1, la1, h1 = geodetic(*ray_point(px, py, pz, ux, uy, uz, omega_c, d1))
    lo2, la2, h2 = geodetic(*ray_point(px, py, pz, ux, uy, uz, omega_c, d2))
    span = d2 - d0
    # quadratic in tau = (d - d0) / span through tau = 0, 0.5, 1
    alo, blo = 4.0 * lo1 - 3.0 * lo0 - lo2, 2.0 * (lo0 + lo2) - 4.0 * lo1
    ala, bla = 4.0 * la1 - 3.0 * la0 - la2, 2.0 * (la0 + la2) - 4.0 * la1
    ah, bh = 4.0 * h1 - 3.0 * h0 - h2, 2.0 * (h0 + h2) - 4.0 * h1
    d = d0
    for _ in range(MAX_STEPS):
        tau = (d - d0) / span
        lon = lo0 + tau * (alo + tau * blo)
        lat = la0 + tau * (ala + tau * bla)
        h = h0 + tau * (ah + tau * bh)
        ground = grid_bilinear(dem, x0, dx, y0, dy, lon, lat)
        if not np.isfinite(ground):
            return np.nan, np.nan, np.nan
        gap = h - ground
        c = -(ah + 2.0 * tau * bh) / span  # height lost per metre along the ray
        if c <= 1e-6:
            return np.nan, np.nan, np.nan  # the ray does not descend
        if abs(gap) < 1e-3:
            break
        s = math.sqrt(max(1.0 - c * c, 0.0))
        d += gap / (c + s * max_slope)
    else:
        return np.nan, np.nan, np.nan
    # exact refinement: Newton steps with the closure rate of the quadratic model
    for _ in range(6):
        lon, lat, h = geodetic(*ray_point(px, py, pz, ux, uy, uz, omega_c, d))
        ground = grid_bilinear(dem, x0, dx, y0, dy, lon, lat)
        if not np.isfinite(ground):
            return np.nan, np.nan, np.nan
        gap = h - ground
        if abs(gap) < HEIGHT_TOLERANCE_M:
            return lon, lat, h
        eps = 0.05
        tau = (d + eps - d0) / span
        g_e = grid_bilinear(
            dem, x0, dx, y0, dy, lo0 + tau * (alo + tau * blo), la0 + tau * (ala + tau * bla)
        )
        h_e = h0 + tau * (ah + tau * bh)
        tau = (d - d0) / span
        g_0 = grid_bilinear(
            dem, x0, dx, y0, dy, lo0 + tau * (alo + tau * blo), la0 + tau * (ala + tau * bla)
        )
        h_0 = h0 + tau * (ah + tau * bh)
        rate = ((h_0 - g_0) - (h_e - g_e)) / eps
        if not np.isfinite(rate) or rate <= 1e-9:
            rate = c + math.sqrt(max(1.0 - c * c, 0.0)) * max_slope
        d += gap / rate
    return np.nan, np.nan, np.nan


@numba.njit(cache=True, nogil=True)
def interp_time(line: float, line_nodes: NDArray, t_nodes: NDArray) -> float:  # pragma: no cover
    n = line_nodes.shape[0]
    i = 0
    while i < n - 2 and line > line_nodes[i + 1]:
        i += 1
    slope = (t_nodes[i + 1] - t_nodes[i]) / (line_nodes[i + 1] - line_nodes[i])
    return t_nodes[i] + (line - line_nodes[i]) * slope


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
    nk = pos.shape[0]
    q = (t - node0) / spacing
    k = math.floor(q)
    if k < 1 or k > nk - 3:
        return False
    f = q - k
    w0 = -f * (f - 1.0) * (f - 2.0) / 6.0
    w1 = (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0
    w2 = -(f + 1.0) * f * (f - 2.0) / 2.0
    w3 = (f + 1.0) * f * (f - 1.0) / 6.0
    u = (det_sample - half) / half
    cx = 0.0
    for m in range(tan_x.shape[0] - 1, -1, -1):
        cx = cx * u + tan_x[m]
    cy = 0.0
    for m in range(tan_y.shape[0] - 1, -1, -1):
        cy = cy * u + tan_y[m]
    cx += stagger
    norm = math.sqrt(cx * cx + cy * cy + 1.0)
    v0, v1, v2 = cx / norm, cy / norm, 1.0 / norm
    for i in range(3):
        out[i] = w0 * pos[k - 1, i] + w1 * pos[k, i] + w2 * pos[k + 1, i] + w3 * pos[k + 2, i]
        # rot is ecef -> camera: the look vector in ECEF is rot^T v
        r0 = (
            w0 * rot[k - 1, 0, i]
            + w1 * rot[k, 0, i]
            + w2 * rot[k + 1, 0, i]
            + w3 * rot[k + 2, 0, i]
        )
        r1 = (
            w0 * rot[k - 1, 1, i]
            + w1 * rot[k, 1, i]
            + w2 * rot[k + 1, 1, i]
            + w3 * rot[k + 2, 1, i]
        )
        r2 = (
            w0 * rot[k - 1, 2, i]
            + w1 * rot[k, 2, i]
            + w2 * rot[k + 1, 2, i]
            + w3 * rot[k + 2, 2, i]
        )
        out[3 + i] = r0 * v0 + r1 * v1 + r2 * v2
    n = math.sqrt(out[3] ** 2 + out[4] ** 2 + out[5] ** 2)
    ub = 0.0
    b = np.empty(3)
    for i in range(3):
        out[3 + i] /= n
        b[i] = w0 * beta[k - 1, i] + w1 * beta[k, i] + w2 * beta[k + 1, i] + w3 * beta[k + 2, i]
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
    return True


@numba.njit(parallel=True, cache=True, nogil=True)
def _locate_kernel(
    lines: NDArray,
    det_samples: NDArray,
    staggers: NDArray,
    line_nodes: NDArray,
    t_nodes: NDArray,
    node0: float,
    spacing: float,
    pos: NDArray,
    rot: NDArray,
    beta: NDArray,
    omega_c: NDArray,
    tan_x: NDArray,
    tan_y: NDArray,
    half: float,
    dem: NDArray,
    x0: float,
    dx: float,
    y0: float,
    dy: float,
    h_top: float,
    h_bottom: float,
    max_slope: float,
) -> NDArray:  # pragma: no cover - compiled
    n = lines.shape[0]
    out = np.full((n, 3), np.nan)
    for i in numba.prange(n):
        ray = np.empty(6)
        t = interp_time(lines[i], line_nodes, t_nodes)
        if camera_ray(
            t, det_samples[i], staggers[i], node0, spacing, pos, rot, beta, tan_x, tan_y, half, ray
        ):
            lon, lat, h = ray_dem(
                ray[0],
                ray[1],
                ray[2],
                ray[3],
                ray[4],
                ray[5],
                dem,
                x0,
                dx,
                y0,
                dy,
                h_top,
                h_bottom,
                max_slope,
                omega_c,
            )
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


def locate_pixels(
    sensor: LineScanner, line: NDArray, sample: NDArray, dem: object
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Fast image -> ground on a geographic DEM for a line scanner: ``(lon, lat, h)``.

    Same result as :meth:`Sensor.locate_on_dem` (to 1e-4 m in height), computed in compiled
    code; NaN where the ray leaves the DEM.
    """
    grid, x0, dx, y0, dy = geographic_grid(dem.heights, dem.transform, dem.crs, "DEM")
    line = np.ascontiguousarray(np.ravel(line), float)
    sample = np.ascontiguousarray(np.ravel(sample), float)
    arr = sensor_arrays(sensor)
    lat_c = y0 + dy * grid.shape[0] / 2
    out = _locate_kernel(
        line,
        sample + sensor.first_sample,
        np.zeros_like(line),
        arr["line_nodes"],
        arr["t_nodes"],
        arr["node0"],
        arr["spacing"],
        arr["pos"],
        arr["rot"],
        arr["beta"],
        arr["omega_c"],
        arr["tan_x"],
        arr["tan_y"],
        arr["half"],
        grid,
        x0,
        dx,
        y0,
        dy,
        float(np.nanmax(grid)) + 1.0,
        float(np.nanmin(grid)) - 1.0,
        max_terrain_slope(grid, dx, dy, lat_c),
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
