"""The ground -> image machinery of :class:`~carto.framework.geometry.linescan.scanner.LineScanner`.

:meth:`~carto.framework.geometry.linescan.scanner.LineScanner.project` starts every point at
the line that :class:`FirstGuess` gives (a cubic polynomial (lon, lat, h) -> line fitted to
the model), then solves the focal-plane condition by the secant method on the imaging time
(:func:`solve_lines`), with the camera state interpolated in a :class:`LineTable` of exact
positions and rotations at regularly spaced times. The kernels are compiled with numba and run
in parallel over the points from :data:`PARALLEL_MIN_POINTS` points on; :func:`camera_vectors`
gives camera-frame vectors from the same table (for the partials of
:meth:`~carto.framework.geometry.linescan.scanner.LineScanner.linearize`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError

if TYPE_CHECKING:  # the sensor the guess and the table are built for
    from carto.framework.geometry.linescan.scanner import LineScanner

FloatArray = NDArray[np.float64]

LINE_TOLERANCE = 1e-8
"""Ground -> image stops when the line changes by less than this, lines."""
TABLE_MARGIN_LINES = 3000
"""Ground -> image works this many lines (or half an image) beyond the image's ends: room for
the orientation errors an adjustment starts from; farther points come back NaN."""


def tabulated_lines(n_lines: int) -> tuple[float, float]:
    """The first and last line of an image of ``n_lines`` lines that ground -> image covers:
    the image and half an image (at least :data:`TABLE_MARGIN_LINES`) on each side. A
    sensor built from samples (attitude, ephemeris) must sample at least these lines."""
    n = max(int(n_lines), 1)
    margin = max(0.5 * n, TABLE_MARGIN_LINES)
    return -margin, n + margin


class FirstGuess:
    """Cubic polynomial (lon, lat, h) -> line fitted to the model; shared by sensors that differ
    only by small corrections (it is only a starting point)."""

    def __init__(self) -> None:
        self.coeffs: FloatArray | None = None
        self.offset: FloatArray | None = None
        self.scale: FloatArray | None = None

    @staticmethod
    def _terms(x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
        one = np.ones_like(x)
        return np.stack(
            [
                one,
                x,
                y,
                z,
                x * y,
                x * z,
                y * z,
                x * x,
                y * y,
                z * z,
                x * y * z,
                x**3,
                x * y * y,
                x * z * z,
                x * x * y,
                y**3,
                y * z * z,
                x * x * z,
                y * y * z,
                z**3,
            ],
            axis=-1,
        )

    def fit(self, sensor: LineScanner) -> None:
        lines = np.linspace(0.0, sensor.n_lines, 9)
        samples = np.linspace(0.0, sensor.n_samples, 9)
        heights = np.array([-500.0, 1500.0, 4500.0, 9000.0])
        ll, ss, hh = np.meshgrid(lines, samples, heights, indexing="ij")
        lon, lat = sensor.image_to_ground(ll.ravel(), ss.ravel(), hh.ravel())
        xyz = np.stack([lon, lat, hh.ravel()], axis=-1)
        ok = np.all(np.isfinite(xyz), axis=1)
        if ok.sum() < 40:
            raise InputError(f"sensor {sensor.name}: the image does not intersect the Earth")
        xyz = xyz[ok]
        self.offset = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
        self.scale = np.maximum(0.5 * (xyz.max(axis=0) - xyz.min(axis=0)), 1e-9)
        n = (xyz - self.offset) / self.scale
        a = self._terms(n[:, 0], n[:, 1], n[:, 2])
        self.coeffs = np.linalg.lstsq(a, ll.ravel()[ok], rcond=None)[0]

    def __call__(self, lon: FloatArray, lat: FloatArray, h: FloatArray) -> FloatArray:
        fn = _for_size(lon.shape[0], _eval_guess_parallel, _eval_guess_serial)
        return fn(lon, lat, h, self.offset, self.scale, self.coeffs)


def _eval_guess_py(
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    offset: FloatArray,
    scale: FloatArray,
    c: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled; same terms as FirstGuess._terms
    out = np.empty(lon.shape[0])
    for i in numba.prange(lon.shape[0]):
        x = (lon[i] - offset[0]) / scale[0]
        y = (lat[i] - offset[1]) / scale[1]
        z = (h[i] - offset[2]) / scale[2]
        out[i] = (
            c[0]
            + c[1] * x
            + c[2] * y
            + c[3] * z
            + c[4] * x * y
            + c[5] * x * z
            + c[6] * y * z
            + c[7] * x * x
            + c[8] * y * y
            + c[9] * z * z
            + c[10] * x * y * z
            + c[11] * x**3
            + c[12] * x * y * y
            + c[13] * x * z * z
            + c[14] * x * x * y
            + c[15] * y**3
            + c[16] * y * z * z
            + c[17] * x * x * z
            + c[18] * y * y * z
            + c[19] * z**3
        )
    return out


class LineTable:
    """Exact camera state at regularly spaced times: ``P_ecef`` and ``R_ecef_to_camera``.

    Between nodes the state is interpolated by 4-point Lagrange polynomials (cubic) in time, in
    which the motion of a satellite is smooth (the line timing may have kinks, so the table is
    not indexed by line). Nodes are at most two line periods apart and span half an image
    before the first line to half an image after the last; the interpolation error is far
    below 1e-6 px (tested against the exact chain).
    """

    def __init__(self) -> None:
        self.node0: float = 0.0
        self.spacing: float = 1.0
        self.position: FloatArray | None = None  # (K, 3)
        self.rotation: FloatArray | None = None  # (K, 3, 3) ecef -> camera
        self.beta: FloatArray | None = None  # (K, 3) inertial velocity / c, ECEF axes
        self.omega_c: FloatArray = np.zeros(3)  # Earth's angular velocity / c, rad/m
        self.tolerance_s: float = 1e-12

    def build(self, sensor: LineScanner) -> None:
        timing = sensor.timing
        first, last = tabulated_lines(sensor.n_lines)
        t_lo = float(timing.time(first))
        t_hi = float(timing.time(last))
        periods = np.diff(np.asarray(timing.dt_nodes_s)) / np.diff(np.asarray(timing.line_nodes))
        self.spacing = float(2.0 * periods.min())
        self.tolerance_s = LINE_TOLERANCE * float(periods.min())
        k = int(np.ceil((t_hi - t_lo) / self.spacing)) + 8
        self.node0 = t_lo - 4 * self.spacing
        times = self.node0 + self.spacing * np.arange(k)
        p, r_b2e = sensor.trajectory.evaluate(times)
        r_c2e = r_b2e @ sensor.camera.camera_to_body()
        beta, omega_c = sensor.light_terms(times)
        self.position = np.ascontiguousarray(p)
        self.rotation = np.ascontiguousarray(np.swapaxes(r_c2e, -1, -2))
        self.beta = np.ascontiguousarray(beta)
        self.omega_c = np.ascontiguousarray(omega_c, dtype=np.float64)


@numba.njit(cache=True, nogil=True)
def _polyval(coeffs: FloatArray, u: float) -> float:  # pragma: no cover - compiled
    out = 0.0
    for k in range(coeffs.shape[0] - 1, -1, -1):
        out = out * u + coeffs[k]
    return out


@numba.njit(cache=True, nogil=True)
def _sample_from_tan_y(coeffs: FloatArray, t: float, half: float) -> float:  # pragma: no cover
    u = (t - coeffs[0]) / coeffs[1]
    if coeffs.shape[0] > 2:
        for _ in range(6):
            val = 0.0
            der = 0.0
            for k in range(coeffs.shape[0] - 1, -1, -1):
                der = der * u + val
                val = val * u + coeffs[k]
            u = u - (val - t) / der
    return u * half + half


class TableStates(NamedTuple):
    """A :class:`LineTable` as the kernels read it: camera states at times ``node0 +
    k spacing`` (s): ECEF positions ``pos`` (m, ``(K, 3)``), ECEF -> camera rotations ``rot``
    (``(K, 3, 3)``), velocities over c ``beta`` (``(K, 3)``) and the Earth's angular velocity
    over c ``omega_c`` (rad/m)."""

    node0: float
    spacing: float
    pos: FloatArray
    rot: FloatArray
    beta: FloatArray
    omega_c: FloatArray


class FocalPlane(NamedTuple):
    """The detector line as ground -> image reads it: ``tan psi_x`` and ``tan psi_y``
    polynomials (``tan_x``, ``tan_y``) of the sample normalised by ``half`` (half the detector
    count), ``tan psi_x`` offset by ``stagger``."""

    tan_x: FloatArray
    tan_y: FloatArray
    stagger: float
    half: float


@numba.njit(cache=True, nogil=True, inline="always")
def lagrange_weights(
    t: float, node0: float, spacing: float, n_nodes: int
) -> tuple[int, float, float, float, float]:  # pragma: no cover - compiled
    """``(k, w0, w1, w2, w3)``: the 4-point Lagrange weights of the table nodes ``k - 1``,
    ``k``, ``k + 1``, ``k + 2`` at time ``t`` (nodes at ``node0 + k spacing``, local
    coordinate in [0, 1)); ``k`` is -1 where the table has no four nodes around ``t``."""
    q = (t - node0) / spacing
    k = math.floor(q)
    if k < 1 or k > n_nodes - 3:
        return -1, 0.0, 0.0, 0.0, 0.0
    f = q - k
    w0 = -f * (f - 1.0) * (f - 2.0) / 6.0
    w1 = (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0
    w2 = -(f + 1.0) * f * (f - 2.0) / 2.0
    w3 = (f + 1.0) * f * (f - 1.0) / 6.0
    return k, w0, w1, w2, w3


@numba.njit(cache=True, nogil=True, inline="always")
def interp_node(
    table: FloatArray, k: int, w0: float, w1: float, w2: float, w3: float, i: int
) -> float:  # pragma: no cover - compiled
    """Component ``i`` of a ``(K, 3)`` table row interpolated with :func:`lagrange_weights`."""
    return w0 * table[k - 1, i] + w1 * table[k, i] + w2 * table[k + 1, i] + w3 * table[k + 2, i]


@numba.njit(cache=True, nogil=True, inline="always")
def interp_rotation(
    rot: FloatArray, k: int, w0: float, w1: float, w2: float, w3: float, r: int, i: int
) -> float:  # pragma: no cover - compiled
    """Element ``(r, i)`` of the ``(K, 3, 3)`` rotations interpolated like
    :func:`interp_node`."""
    return w0 * rot[k - 1, r, i] + w1 * rot[k, r, i] + w2 * rot[k + 1, r, i] + w3 * rot[k + 2, r, i]


@numba.njit(cache=True, nogil=True, inline="always")
def _focal_offset(
    x: FloatArray, t_s: float, table: TableStates, focal: FocalPlane, v: FloatArray
) -> float:  # pragma: no cover - compiled
    """Interpolate the camera state at time ``t_s``; fill ``v`` (camera frame: the direction
    the camera sees ``x`` in, after light time and aberration, scaled by the distance);
    return f."""
    # 4-point Lagrange weights for nodes k-1, k, k+1, k+2 at local coordinate t in [0, 1)
    k, w0, w1, w2, w3 = lagrange_weights(t_s, table.node0, table.spacing, table.pos.shape[0])
    if k < 0:
        return np.nan
    pos, beta, omega_c = table.pos, table.beta, table.omega_c
    d0 = x[0] - interp_node(pos, k, w0, w1, w2, w3, 0)
    d1 = x[1] - interp_node(pos, k, w0, w1, w2, w3, 1)
    d2 = x[2] - interp_node(pos, k, w0, w1, w2, w3, 2)
    # light time: the point where it was when the light left, X - (omega/c x X) |X - P|
    dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    d0 -= (omega_c[1] * x[2] - omega_c[2] * x[1]) * dist
    d1 -= (omega_c[2] * x[0] - omega_c[0] * x[2]) * dist
    d2 -= (omega_c[0] * x[1] - omega_c[1] * x[0]) * dist
    # aberration: seen at n + beta - (n . beta) n (n = d / |d|), kept at length |d|
    b0 = interp_node(beta, k, w0, w1, w2, w3, 0)
    b1 = interp_node(beta, k, w0, w1, w2, w3, 1)
    b2 = interp_node(beta, k, w0, w1, w2, w3, 2)
    dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    nb = (d0 * b0 + d1 * b1 + d2 * b2) / dist
    d0, d1, d2 = d0 + dist * b0 - nb * d0, d1 + dist * b1 - nb * d1, d2 + dist * b2 - nb * d2
    for i in range(3):
        r0 = interp_rotation(table.rot, k, w0, w1, w2, w3, i, 0)
        r1 = interp_rotation(table.rot, k, w0, w1, w2, w3, i, 1)
        r2 = interp_rotation(table.rot, k, w0, w1, w2, w3, i, 2)
        v[i] = r0 * d0 + r1 * d1 + r2 * d2
    if v[2] <= 0.0:
        return np.nan
    if focal.tan_x.shape[0] == 1:
        target = focal.tan_x[0] + focal.stagger
    else:
        s = _sample_from_tan_y(focal.tan_y, v[1] / v[2], focal.half)
        target = _polyval(focal.tan_x, (s - focal.half) / focal.half) + focal.stagger
    return v[0] / v[2] - target


@numba.njit(cache=True, nogil=True)
def camera_vectors(
    x: FloatArray,
    t_s: FloatArray,
    node0: float,
    spacing: float,
    pos: FloatArray,
    rot: FloatArray,
    beta: FloatArray,
    omega_c: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    """Camera-frame vectors ``R_ecef_to_camera (X - P)`` (light time and aberration applied
    as the table says) at times ``t_s`` from the table, ``(N, 3)``; NaN outside the table."""
    out = np.full((x.shape[0], 3), np.nan)
    one = np.zeros(1)
    table = TableStates(node0, spacing, pos, rot, beta, omega_c)
    focal = FocalPlane(one, one, 0.0, 1.0)
    for i in range(x.shape[0]):
        _focal_offset(x[i], t_s[i], table, focal, out[i])
    return out


def _solve_lines_py(
    x: FloatArray,
    guess: FloatArray,
    table: TableStates,
    focal: FocalPlane,
    tol: float,
    max_iter: int,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Secant iteration on the imaging time for every point (parallel over points).

    ``guess`` and the result are times (s since epoch); ``tol`` in seconds."""
    n = x.shape[0]
    out_line = np.full(n, np.nan)
    out_sample = np.full(n, np.nan)
    for i in numba.prange(n):
        v = np.empty(3)
        xi = x[i]
        l0 = guess[i]
        f0 = _focal_offset(xi, l0, table, focal, v)
        if not np.isfinite(f0):
            continue
        l1 = l0 + 0.5 * table.spacing
        converged = False
        for _ in range(max_iter):
            f1 = _focal_offset(xi, l1, table, focal, v)
            if not np.isfinite(f1):
                break
            if f1 == f0:  # stagnation at the rounding floor of f (~1e-15)
                converged = f1 == 0.0 or abs(l1 - l0) < 1e3 * tol
                break
            l2 = l1 - f1 * (l1 - l0) / (f1 - f0)
            l0, f0 = l1, f1
            l1 = l2
            if abs(l1 - l0) < tol:
                converged = True
                break
        if converged:
            f1 = _focal_offset(xi, l1, table, focal, v)
            if np.isfinite(f1):
                out_line[i] = l1
                out_sample[i] = _sample_from_tan_y(focal.tan_y, v[1] / v[2], focal.half)
    return out_line, out_sample


PARALLEL_MIN_POINTS = 20_000
"""Below this many points the compiled kernels run on one thread (no thread start-up cost)."""
_eval_guess_parallel = numba.njit(parallel=True, cache=True, nogil=True)(_eval_guess_py)
_eval_guess_serial = numba.njit(cache=True, nogil=True)(_eval_guess_py)
_solve_lines_parallel = numba.njit(parallel=True, cache=True, nogil=True)(_solve_lines_py)
_solve_lines_serial = numba.njit(cache=True, nogil=True)(_solve_lines_py)


def _for_size(n_points: int, parallel: Any, serial: Any) -> Any:
    """The parallel kernel from :data:`PARALLEL_MIN_POINTS` points on, else the serial one."""
    return parallel if n_points >= PARALLEL_MIN_POINTS else serial


def solve_lines(x: FloatArray, *args: Any) -> tuple[FloatArray, FloatArray]:
    """Imaging times and detector samples of the ECEF points ``x`` (NaN where the secant
    iteration fails); ``args``: the first-guess times, the table (``node0, spacing, pos, rot,
    beta, omega_c``), the focal plane (``tan_x, tan_y, stagger, half``), the tolerance (s)
    and the iterations at most."""
    guess, table, focal, (tol, max_iter) = args[0], args[1:7], args[7:11], args[11:]
    fn = _for_size(x.shape[0], _solve_lines_parallel, _solve_lines_serial)
    return fn(x, guess, TableStates(*table), FocalPlane(*focal), tol, max_iter)
