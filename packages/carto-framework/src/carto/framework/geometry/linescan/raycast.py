"""Compiled ray casting of line-scanner pixels onto a geographic DEM: the fast location the
stagger merge uses (:mod:`carto.framework.geometry.linescan.stagger`), and the kernels the
simulator's renderer (:mod:`carto.framework.simulation.render`) builds on.

Each pixel's line of sight comes from the model's exact camera-state table (see
:mod:`carto.framework.geometry.linescan.solver`), interpolated once per image line
(:func:`line_state`) and turned into each detector's ray (:func:`state_ray`); the ray meets the
terrain by the safe stepping of
:mod:`carto.framework.geometry.linescan.terrain_intersection`. The result equals the generic
search of :func:`carto.framework.geometry.surface.dem_surface_locate` to 1e-4 m in height.

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

from carto.framework.geometry.light_path import SOURCE_DIRECTION_STEPS
from carto.framework.geometry.linescan.solver import (
    interp_node,
    interp_rotation,
    lagrange_weights,
)
from carto.framework.geometry.linescan.terrain_intersection import (
    HEIGHT_TOLERANCE_M,
    MAX_STEPS,
    QUADRATIC_STEP,
    DemGrid,
    GeoGrid,
    dem_grid,
    geo_grid,
    geographic_grid,
    grid_bilinear,
    max_terrain_slope,
    ray_dem,
    ray_quadratic,
    trace_dem,
)

if TYPE_CHECKING:  # the model whose table the kernels read
    from carto.framework.geometry.linescan.scanner import LineScanner

__all__ = [
    "HEIGHT_TOLERANCE_M",
    "MAX_STEPS",
    "QUADRATIC_STEP",
    "RAY_SIZE",
    "STATE_SIZE",
    "CameraStates",
    "DemGrid",
    "GeoGrid",
    "camera_states",
    "dem_grid",
    "geo_grid",
    "geographic_grid",
    "grid_bilinear",
    "interp_time",
    "is_lonlat_grid",
    "line_state",
    "locate_pixels",
    "max_terrain_slope",
    "quadratic_table",
    "ray_dem",
    "sensor_arrays",
    "state_ray",
    "trace_dem",
    "trace_pixel",
]

FloatArray = NDArray[np.float64]


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
def _source_direction(out: NDArray, state: NDArray) -> None:  # pragma: no cover - compiled
    """Turn the unit look vector ``out[3:6]`` into the unit direction the received light came
    from, for the velocity over c ``b = state[12:15]`` (:func:`line_state`): ``u - beta +
    (u . beta) u`` refined as :func:`~carto.framework.geometry.light_path.source_direction`
    does. ``out[6:12]`` is scratch space (no allocation per ray)."""
    ub = 0.0
    for i in range(3):
        ub += out[3 + i] * state[12 + i]
    for i in range(3):
        out[6 + i] = out[3 + i]  # u
    n = 0.0
    for i in range(3):
        out[3 + i] = out[3 + i] - state[12 + i] + ub * out[3 + i]
        n += out[3 + i] ** 2
    n = math.sqrt(n)
    for i in range(3):
        out[3 + i] /= n
    # refined to the exact inverse of the aberration (light_path.source_direction)
    b0, b1, b2 = state[12], state[13], state[14]
    for _ in range(SOURCE_DIRECTION_STEPS):
        nb = out[3] * b0 + out[4] * b1 + out[5] * b2
        na = 0.0
        for i in range(3):
            out[9 + i] = out[3 + i] + state[12 + i] - nb * out[3 + i]  # a
            na += out[9 + i] ** 2
        na = math.sqrt(na)
        n = 0.0
        for i in range(3):
            out[3 + i] += out[6 + i] - out[9 + i] / na
            n += out[3 + i] ** 2
        n = math.sqrt(n)
        for i in range(3):
            out[3 + i] /= n


STATE_SIZE = 15
"""Length of a :func:`line_state` (position, rotation, velocity over c)."""
RAY_SIZE = 12
"""Length of the scratch array of :func:`state_ray` (the ray in ``[0:6]``)."""


@numba.njit(cache=True, nogil=True, inline="always")
def line_state(t: float, cam: CameraStates, state: NDArray) -> bool:  # pragma: no cover
    """Fill ``state`` (:data:`STATE_SIZE`) with the camera state at time ``t``, shared by
    every detector of the line: the perspective centre (``[0:3]``, ECEF m), the ECEF ->
    camera rotation (``[3:12]``, row-major) and the velocity over c (``[12:15]``), each
    interpolated from the table; False where the table has no state."""
    k, w0, w1, w2, w3 = lagrange_weights(t, cam.node0, cam.spacing, cam.pos.shape[0])
    if k < 0:
        return False
    for i in range(3):
        state[i] = interp_node(cam.pos, k, w0, w1, w2, w3, i)
        for r in range(3):
            state[3 + 3 * r + i] = interp_rotation(cam.rot, k, w0, w1, w2, w3, r, i)
        state[12 + i] = interp_node(cam.beta, k, w0, w1, w2, w3, i)
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def state_ray(
    det_sample: float, stagger: float, cam: CameraStates, state: NDArray, out: NDArray
) -> None:  # pragma: no cover - compiled
    """Fill ``out[0:3]`` with the perspective centre and ``out[3:6]`` with the unit direction
    the received light came from for a (fractional) detector sample of the line whose
    :func:`line_state` is ``state`` (the look vector corrected for aberration); ``out`` is
    :data:`RAY_SIZE` long, its tail scratch space."""
    v0, v1, v2 = _look_vector(det_sample, stagger, cam.tan_x, cam.tan_y, cam.half)
    for i in range(3):
        out[i] = state[i]
        # rot is ecef -> camera: the look vector in ECEF is rot^T v
        out[3 + i] = state[3 + i] * v0 + state[6 + i] * v1 + state[9 + i] * v2
    n = math.sqrt(out[3] ** 2 + out[4] ** 2 + out[5] ** 2)
    for i in range(3):
        out[3 + i] /= n
    _source_direction(out, state)


@numba.njit(cache=True, nogil=True, inline="always")
def trace_pixel(
    t: float,
    det_sample: float,
    stagger: float,
    cam: CameraStates,
    dem: DemGrid,
    state: NDArray,
    ray: NDArray,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """Ground point ``(lon_deg, lat_deg, h_m)`` a (fractional) detector sample sees at time
    ``t``: :func:`line_state`, :func:`state_ray` then :func:`trace_dem`; NaN where the table
    has no state or the ray leaves the DEM. ``state`` and ``ray`` are scratch space
    (:data:`STATE_SIZE`, :data:`RAY_SIZE`)."""
    if not line_state(t, cam, state):
        return np.nan, np.nan, np.nan
    state_ray(det_sample, stagger, cam, state, ray)
    return trace_dem((ray[0], ray[1], ray[2], ray[3], ray[4], ray[5]), cam.omega_c, dem)


@numba.njit(cache=True, nogil=True)
def quadratic_table(
    first: float,
    n_nodes: int,
    stagger: float,
    cam: CameraStates,
    dem: DemGrid,
    state: NDArray,
    ray: NDArray,
    table: NDArray,
) -> None:  # pragma: no cover - compiled
    """Fill ``table[:n_nodes]`` (``(>= n_nodes, 11)``) with the exact quadratic models of
    the rays of the detector samples ``first + m QUADRATIC_STEP`` of the line whose
    :func:`line_state` is ``state``, with the along-track ``stagger``."""
    for m in range(n_nodes):
        state_ray(first + m * QUADRATIC_STEP, stagger, cam, state, ray)
        exact = (ray[0], ray[1], ray[2], ray[3], ray[4], ray[5])
        q = ray_quadratic(exact, cam.omega_c, dem.h_top_m, dem.h_bottom_m)
        for c in range(11):
            table[m, c] = q[c]


@numba.njit(parallel=True, cache=True, nogil=True)
def _locate_kernel(
    lines: NDArray, det_samples: NDArray, staggers: NDArray, cam: CameraStates, dem: DemGrid
) -> NDArray:  # pragma: no cover - compiled
    n = lines.shape[0]
    out = np.full((n, 3), np.nan)
    for i in numba.prange(n):
        state = np.empty(STATE_SIZE)
        ray = np.empty(RAY_SIZE)
        t = interp_time(lines[i], cam.line_nodes, cam.t_nodes)
        lon, lat, h = trace_pixel(t, det_samples[i], staggers[i], cam, dem, state, ray)
        out[i, 0] = lon
        out[i, 1] = lat
        out[i, 2] = h
    return out


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
