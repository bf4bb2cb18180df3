"""The rigorous line-scanner (pushbroom) sensor model.

Collinearity: the perspective centre ``P(t)``, the image point and the ground point ``X`` lie on
one line, ``u_cam ~ R_camera_to_ecef(t)^T (X - P(t))`` with ``R_camera_to_ecef(t) =
R_body_to_ecef(t) @ R_camera_to_body`` (see :mod:`~carto.framework.geometry.trajectory` and
:mod:`~carto.framework.geometry.camera` for the chain and the frames).

Image -> ground (:meth:`LineScanner.image_to_ground`)
    The time of the line, the ray from ``P(t)`` along the detector's look direction, and its
    intersection with the surface at ellipsoidal height ``h``: first with the ellipsoid of
    semi-axes ``(a+h, a+h, b+h)``, then Newton steps along the ray on the geodetic height until
    it is within 1e-6 m of ``h``.
Ground -> image (:meth:`LineScanner.ground_to_image`)
    Find the line whose focal plane contains the point: the secant method on the line
    coordinate, solving ``v_x / v_z = tan psi_x(s)`` for the camera-frame vector
    ``v = R_camera_to_ecef(t)^T (X - P(t))``, from a first guess given by a cubic polynomial
    in (lon, lat, h) fitted to the model over the image and heights -500..9000 m. Iterations stop
    when the line changes by less than ``LINE_TOLERANCE`` (1e-8 line); the sample is then
    ``s = tan_psi_y^-1(v_y / v_z)``. Points that do not converge in ``MAX_ITERATIONS``, or that
    are behind the camera, come back as NaN; points outside the image come back as NaN from
    :meth:`~LineScanner.ground_to_image` and with their (extrapolated) coordinates and a False
    mask from :meth:`~LineScanner.project`.

Image coordinates follow the project convention (first pixel centre at ``(0.5, 0.5)``); line
``l`` is imaged at ``t(l)`` given by a :class:`LineTiming` (``t0 + (l - 0.5) * period`` for a
constant period, piecewise linear for asynchronous imaging).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.files.documents import (
    check_document,
    read_json_document,
    write_json_atomic,
)
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.sensor import Parameter, Sensor, SensorType
from carto.framework.geometry.trajectory import Trajectory

FloatArray = NDArray[np.float64]

MODEL_FORMAT = "carto-linescan-model"
MODEL_VERSION = 1
LINE_TOLERANCE = 1e-8
MAX_ITERATIONS = 25
HEIGHT_TOLERANCE_M = 1e-6
TABLE_MARGIN_LINES = 3000
"""Ground -> image works this many lines (or half an image) beyond the image's ends: room for
the orientation errors an adjustment starts from; farther points come back NaN."""
EDGE_TOLERANCE_PX = 1e-6
"""Points this close outside the image border still count as inside (rounding of round trips)."""


def _tuple_of_floats(value: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in np.atleast_1d(np.asarray(value, dtype=np.float64)))


@attrs.frozen
class LineTiming:
    """Time of each image line: piecewise linear through nodes, extrapolated linearly.

    Attributes:
        line_nodes: line coordinates (project convention), strictly increasing, >= 2.
        dt_nodes_s: imaging times of those lines, seconds since the trajectory's epoch,
            strictly increasing.
    """

    line_nodes: tuple[float, ...] = attrs.field(converter=_tuple_of_floats)
    dt_nodes_s: tuple[float, ...] = attrs.field(converter=_tuple_of_floats)

    def __attrs_post_init__(self) -> None:
        lines, times = np.asarray(self.line_nodes), np.asarray(self.dt_nodes_s)
        if lines.size < 2 or lines.size != times.size:
            raise InputError("line timing: need >= 2 (line, time) nodes of equal count")
        if np.any(np.diff(lines) <= 0) or np.any(np.diff(times) <= 0):
            raise InputError("line timing: lines and times must increase strictly")

    @classmethod
    def constant(cls, dt_first_line_s: float, period_s: float) -> LineTiming:
        """``t(l) = dt_first_line_s + (l - 0.5) * period_s`` (the first line's centre is 0.5)."""
        if not period_s > 0:
            raise InputError(f"line timing: period must be > 0 s, got {period_s}")
        return cls((0.5, 1.5), (dt_first_line_s, dt_first_line_s + period_s))

    @staticmethod
    def _piecewise(x: FloatArray, xs: FloatArray, ys: FloatArray) -> FloatArray:
        i = np.clip(np.searchsorted(xs, x) - 1, 0, xs.size - 2)
        slope = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i])
        return ys[i] + (x - xs[i]) * slope

    def time(self, line: ArrayLike) -> FloatArray:
        """Imaging time (s since epoch) of continuous line coordinates."""
        return self._piecewise(
            np.asarray(line, float), np.asarray(self.line_nodes), np.asarray(self.dt_nodes_s)
        )

    def line(self, dt_s: ArrayLike) -> FloatArray:
        """Continuous line coordinate imaged at ``dt_s``."""
        return self._piecewise(
            np.asarray(dt_s, float), np.asarray(self.dt_nodes_s), np.asarray(self.line_nodes)
        )

    def period(self, line: ArrayLike) -> FloatArray:
        """Local line period (s per line) at ``line``."""
        line = np.asarray(line, float)
        return self.time(line + 0.5) - self.time(line - 0.5)


class _FirstGuess:
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
        return _eval_guess(lon, lat, h, self.offset, self.scale, self.coeffs)


def _eval_guess_py(
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    offset: FloatArray,
    scale: FloatArray,
    c: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled; same terms as _FirstGuess._terms
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


class _LineTable:
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
        self.tolerance_s: float = 1e-12

    def build(self, sensor: LineScanner) -> None:
        n = max(int(sensor.n_lines), 1)
        timing = sensor.timing
        margin = max(0.5 * n, TABLE_MARGIN_LINES)
        t_lo = float(timing.time(-margin))
        t_hi = float(timing.time(n + margin))
        periods = np.diff(np.asarray(timing.dt_nodes_s)) / np.diff(np.asarray(timing.line_nodes))
        self.spacing = float(2.0 * periods.min())
        self.tolerance_s = LINE_TOLERANCE * float(periods.min())
        k = int(np.ceil((t_hi - t_lo) / self.spacing)) + 8
        self.node0 = t_lo - 4 * self.spacing
        times = self.node0 + self.spacing * np.arange(k)
        p, r_b2e = sensor.trajectory.evaluate(times)
        r_c2e = r_b2e @ sensor.camera.camera_to_body()
        self.position = np.ascontiguousarray(p)
        self.rotation = np.ascontiguousarray(np.swapaxes(r_c2e, -1, -2))


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


@numba.njit(cache=True, nogil=True)
def _focal_offset(
    x: FloatArray,
    t_s: float,
    node0: float,
    spacing: float,
    pos: FloatArray,
    rot: FloatArray,
    tan_x: FloatArray,
    tan_y: FloatArray,
    stagger: float,
    half: float,
    v: FloatArray,
) -> float:  # pragma: no cover - compiled
    """Interpolate the camera state at time ``t_s``; fill ``v`` (camera frame); return f."""
    nk = pos.shape[0]
    q = (t_s - node0) / spacing
    k = int(np.floor(q))
    if k < 1 or k > nk - 3:
        return np.nan
    t = q - k
    # 4-point Lagrange weights for nodes k-1, k, k+1, k+2 at local coordinate t in [0, 1)
    w0 = -t * (t - 1.0) * (t - 2.0) / 6.0
    w1 = (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0
    w2 = -(t + 1.0) * t * (t - 2.0) / 2.0
    w3 = (t + 1.0) * t * (t - 1.0) / 6.0
    d0 = x[0] - (w0 * pos[k - 1, 0] + w1 * pos[k, 0] + w2 * pos[k + 1, 0] + w3 * pos[k + 2, 0])
    d1 = x[1] - (w0 * pos[k - 1, 1] + w1 * pos[k, 1] + w2 * pos[k + 1, 1] + w3 * pos[k + 2, 1])
    d2 = x[2] - (w0 * pos[k - 1, 2] + w1 * pos[k, 2] + w2 * pos[k + 1, 2] + w3 * pos[k + 2, 2])
    for i in range(3):
        r0 = (
            w0 * rot[k - 1, i, 0]
            + w1 * rot[k, i, 0]
            + w2 * rot[k + 1, i, 0]
            + w3 * rot[k + 2, i, 0]
        )
        r1 = (
            w0 * rot[k - 1, i, 1]
            + w1 * rot[k, i, 1]
            + w2 * rot[k + 1, i, 1]
            + w3 * rot[k + 2, i, 1]
        )
        r2 = (
            w0 * rot[k - 1, i, 2]
            + w1 * rot[k, i, 2]
            + w2 * rot[k + 1, i, 2]
            + w3 * rot[k + 2, i, 2]
        )
        v[i] = r0 * d0 + r1 * d1 + r2 * d2
    if v[2] <= 0.0:
        return np.nan
    if tan_x.shape[0] == 1:
        target = tan_x[0] + stagger
    else:
        s = _sample_from_tan_y(tan_y, v[1] / v[2], half)
        target = _polyval(tan_x, (s - half) / half) + stagger
    return v[0] / v[2] - target


@numba.njit(cache=True, nogil=True)
def _camera_vectors(
    x: FloatArray,
    t_s: FloatArray,
    node0: float,
    spacing: float,
    pos: FloatArray,
    rot: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    """Camera-frame vectors ``R_ecef_to_camera (X - P)`` at times ``t_s`` from the table,
    ``(N, 3)``; NaN outside the table."""
    out = np.full((x.shape[0], 3), np.nan)
    one = np.zeros(1)
    for i in range(x.shape[0]):
        _focal_offset(x[i], t_s[i], node0, spacing, pos, rot, one, one, 0.0, 1.0, out[i])
    return out


def _solve_lines_py(
    x: FloatArray,
    guess: FloatArray,
    node0: float,
    spacing: float,
    pos: FloatArray,
    rot: FloatArray,
    tan_x: FloatArray,
    tan_y: FloatArray,
    stagger: float,
    half: float,
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
        f0 = _focal_offset(xi, l0, node0, spacing, pos, rot, tan_x, tan_y, stagger, half, v)
        if not np.isfinite(f0):
            continue
        l1 = l0 + 0.5 * spacing
        converged = False
        for _ in range(max_iter):
            f1 = _focal_offset(xi, l1, node0, spacing, pos, rot, tan_x, tan_y, stagger, half, v)
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
            f1 = _focal_offset(xi, l1, node0, spacing, pos, rot, tan_x, tan_y, stagger, half, v)
            if np.isfinite(f1):
                out_line[i] = l1
                out_sample[i] = _sample_from_tan_y(tan_y, v[1] / v[2], half)
    return out_line, out_sample


PARALLEL_MIN_POINTS = 20_000
"""Below this many points the compiled kernels run on one thread (no thread start-up cost)."""
_eval_guess_parallel = numba.njit(parallel=True, cache=True, nogil=True)(_eval_guess_py)
_eval_guess_serial = numba.njit(cache=True, nogil=True)(_eval_guess_py)
_solve_lines_parallel = numba.njit(parallel=True, cache=True, nogil=True)(_solve_lines_py)
_solve_lines_serial = numba.njit(cache=True, nogil=True)(_solve_lines_py)


def _eval_guess(
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    offset: FloatArray,
    scale: FloatArray,
    c: FloatArray,
) -> FloatArray:
    fn = _eval_guess_parallel if lon.shape[0] >= PARALLEL_MIN_POINTS else _eval_guess_serial
    return fn(lon, lat, h, offset, scale, c)


def _solve_lines(x: FloatArray, *args: Any) -> tuple[FloatArray, FloatArray]:
    fn = _solve_lines_parallel if x.shape[0] >= PARALLEL_MIN_POINTS else _solve_lines_serial
    return fn(x, *args)


@attrs.frozen(eq=False)
class LineScanner(Sensor):
    """Rigorous model of one pushbroom image: trajectory + camera + line timing.

    Attributes:
        name: image identifier (``"fore"``, ``"IMG_02"`` ...).
        n_lines: number of image lines.
        timing: :class:`LineTiming` of the lines.
        camera: :class:`~carto.framework.geometry.camera.Camera` of the whole detector line.
        trajectory: :class:`~carto.framework.geometry.trajectory.Trajectory` of the platform body.
        first_sample: detector index of the image's first column: an image that is a window
            of the detector line (a crop, as the simulator renders) has ``sample = detector
            sample - first_sample``; 0 for a full line.
        width: number of image columns (default: the detectors from ``first_sample`` on).
        first_line: line of the full acquisition that is this image's first line (for
            reference only: ``timing`` already gives the times of this image's lines).

    Adjustable parameters are the trajectory's corrections followed by the camera's alignment
    corrections, with their own names (two sensors sharing a trajectory share the names of its
    parameters, which is how a tied-camera adjustment knows they are one set).
    """

    name: str
    n_lines: int
    timing: LineTiming
    camera: Camera
    trajectory: Trajectory
    first_sample: int = 0
    width: int | None = None
    first_line: int = 0
    _guess: _FirstGuess = attrs.field(factory=_FirstGuess, alias="guess", repr=False)
    _table: _LineTable = attrs.field(factory=_LineTable, init=False, repr=False)

    # ------------------------------------------------------------------ Sensor interface
    def __attrs_post_init__(self) -> None:
        if self.n_lines < 1:
            raise InputError(f"sensor {self.name}: n_lines must be >= 1, got {self.n_lines}")
        if not 0 <= self.first_sample < self.camera.n_samples:
            raise InputError(
                f"sensor {self.name}: first_sample {self.first_sample} is outside "
                f"the {self.camera.n_samples} detectors"
            )
        if self.width is not None and self.width < 1:
            raise InputError(f"sensor {self.name}: width must be >= 1, got {self.width}")

    @property
    def image_shape(self) -> tuple[int, int]:
        return (int(self.n_lines), self.n_samples)

    @property
    def n_samples(self) -> int:
        """Image width in columns."""
        if self.width is not None:
            return int(self.width)
        return int(self.camera.n_samples - self.first_sample)

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        return self.trajectory.parameters + self.camera.parameters

    def with_parameters(
        self,
        values: Mapping[str, float] | None = None,
        free: Mapping[str, bool] | None = None,
        sigmas: Mapping[str, float] | None = None,
    ) -> LineScanner:
        known_t = {p.name for p in self.trajectory.parameters}
        known_c = {p.name for p in self.camera.parameters}
        for mapping in (values, free, sigmas):
            unknown = sorted(set(mapping or {}) - known_t - known_c)
            if unknown:
                raise InputError(f"sensor {self.name}: unknown parameter(s) {', '.join(unknown)}")

        def part(mapping: Mapping[str, Any] | None, keys: set[str]) -> dict[str, Any] | None:
            return None if mapping is None else {k: v for k, v in mapping.items() if k in keys}

        trajectory = self.trajectory.with_parameters(
            part(values, known_t), part(free, known_t), part(sigmas, known_t)
        )
        camera = self.camera.with_parameters(
            part(values, known_c), part(free, known_c), part(sigmas, known_c)
        )
        return attrs.evolve(self, trajectory=trajectory, camera=camera)

    def _collinearity(
        self,
        line: FloatArray,
        sample: FloatArray,
        x_ecef: FloatArray,
        pose: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The collinearity condition at image point ``(line, sample)`` and ground ``x_ecef``:
        ``F (N, 2)``, zero when the point images there (camera-frame ``x/z`` and ``y/z`` of the
        ground direction minus the detector's ``tan psi``), and ``dF/dX (N, 2, 3)``, the
        camera-frame vector ``v (N, 3)`` and ``R_camera_to_ecef (N, 3, 3)``. ``pose``: the
        ``(P, R_camera_to_ecef)`` at ``line`` when already known."""
        p, r_c2e = self.camera_to_ecef(line) if pose is None else pose
        v = np.einsum("nji,nj->ni", r_c2e, x_ecef - p)
        tx, ty = self.camera.tan_psi(sample + self.first_sample)
        f = np.stack([v[:, 0] / v[:, 2] - tx, v[:, 1] / v[:, 2] - ty], -1)
        # v = R^T (X - P): dv/dX = R^T, rows of R^T are the columns of R
        v2 = v[:, 2:3]
        df_dx = np.stack(
            [
                (r_c2e[:, :, 0] * v2 - v[:, 0:1] * r_c2e[:, :, 2]) / v2**2,
                (r_c2e[:, :, 1] * v2 - v[:, 1:2] * r_c2e[:, :, 2]) / v2**2,
            ],
            axis=1,
        )
        return f, df_dx, v, r_c2e

    def linearize(
        self,
        lon_deg: ArrayLike,
        lat_deg: ArrayLike,
        h_m: ArrayLike,
        names: Sequence[str] | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(line, sample, ground partials (N, 2, 3), parameter partials (N, 2, P))`` from
        one projection (see :meth:`Sensor.linearize`).

        The image point is defined implicitly by the collinearity condition
        ``F(line, sample; X, p) = 0`` (:meth:`_collinearity`), so by the implicit function
        theorem ``d(line, sample) = -(dF/d(line, sample))^-1 (dF/dX dX + dF/dp dp)``.
        ``dF/dX`` is analytic, and so is ``dF/dp`` for the attitude corrections (a
        correction angle rotates the body about an axis the trajectory gives:
        :meth:`Trajectory.evaluate_with_axes`); ``dF/d(line, sample)`` and ``dF/dp`` of other
        parameters (position, camera) are central differences of F at the fixed image
        point, which evaluate the trajectory and camera but solve no projection. A correction
        polynomial's coefficient ``c_k`` acts like ``c_0`` times ``tau^k`` at the imaging
        time. Ground partials are w.r.t. local east, north, up displacements in metres.
        """
        lon, lat, h = (a.ravel() for a in as_float_arrays(lon_deg, lat_deg, h_m))
        if names is None:
            names = [p.name for p in self.parameters if p.free]
        names = list(names)
        line, sample, _ = self.project(lon, lat, h)
        ok = np.isfinite(line) & np.isfinite(sample)
        li = np.where(ok, line, 0.5 * self.n_lines)
        sa = np.where(ok, sample, 0.5 * self.n_samples)
        x = frames.geodetic_to_ecef(lon, lat, h)
        t = self.timing.time(li)
        p_e, r_b2e, axes = self.trajectory.evaluate_with_axes(t)
        _, df_dx, v, _ = self._collinearity(li, sa, x, (p_e, r_b2e @ self.camera.camera_to_body()))
        # dF/d(line, sample): (N, 2, 2); F is smooth along the line: a forward difference,
        # with the camera state interpolated in the projection's table
        jac = np.empty((lon.size, 2, 2))
        step = 0.5
        table = self._table
        v_step = _camera_vectors(
            np.ascontiguousarray(x),
            np.ascontiguousarray(self.timing.time(li + step)),
            table.node0,
            table.spacing,
            table.position,
            table.rotation,
        )
        jac[:, 0, 0] = (v_step[:, 0] / v_step[:, 2] - v[:, 0] / v[:, 2]) / step
        jac[:, 1, 0] = (v_step[:, 1] / v_step[:, 2] - v[:, 1] / v[:, 2]) / step
        tx_p, ty_p = self.camera.tan_psi(sa + self.first_sample + step)
        tx_m, ty_m = self.camera.tan_psi(sa + self.first_sample - step)
        jac[:, 0, 1] = -(tx_p - tx_m) / (2 * step)
        jac[:, 1, 1] = -(ty_p - ty_m) / (2 * step)
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        inv = (
            np.stack(
                [
                    np.stack([jac[:, 1, 1], -jac[:, 0, 1]], -1),
                    np.stack([-jac[:, 1, 0], jac[:, 0, 0]], -1),
                ],
                axis=1,
            )
            / det[:, None, None]
        )
        a_ground = -inv @ (df_dx @ np.swapaxes(frames.enu_basis(lon, lat), -1, -2))
        # dF/dp at the fixed image point
        a_param = np.empty((lon.size, 2, len(names)))
        if names:
            params = {p.name: p for p in self.parameters}
            prefix = self.trajectory.prefix
            base: dict[str, tuple[str, int]] = {}
            for name in names:
                rest = name[len(prefix) :] if name.startswith(prefix) else ""
                group, _, power = rest.rpartition(".c")
                if rest and power.isdigit() and group.split(".")[0] in ("attitude", "position"):
                    base[name] = (group, int(power))
            tau = (t - self.trajectory.t_mid_s) / self.trajectory.t_half_s
            differenced: dict[str, FloatArray] = {}
            for k, name in enumerate(names):
                group, power = base.get(name, (name, 0))
                if group not in differenced:
                    kind, _, axis = group.partition(".")
                    if name in base and kind == "attitude":
                        # dR/d angle = [w]x R: dv = -R^T (w x (X - P)), dF = dF/dX (X - P) x w
                        w = axes[:, ("roll", "pitch", "yaw").index(axis)]
                        df = np.einsum("nij,nj->ni", df_dx, np.cross(x - p_e, w))
                    else:
                        target = f"{prefix}{group}.c0" if name in base else name
                        p = params[target]
                        d = 1e-3 * p.sigma if math.isfinite(p.sigma) else 1e-6
                        plus = self.with_parameters({target: p.value + d})
                        minus = self.with_parameters({target: p.value - d})
                        df = (
                            plus._collinearity(li, sa, x)[0] - minus._collinearity(li, sa, x)[0]
                        ) / (2 * d)
                    differenced[group] = -np.einsum("nij,nj->ni", inv, df)
                a_param[:, :, k] = differenced[group] * (tau**power)[:, None]
        bad = ~ok
        a_ground[bad] = np.nan
        a_param[bad] = np.nan
        return line, sample, a_ground, a_param

    def parameter_partials(
        self,
        lon_deg: ArrayLike,
        lat_deg: ArrayLike,
        h_m: ArrayLike,
        names: Sequence[str] | None = None,
    ) -> FloatArray:
        """Partials of ``(line, sample)`` w.r.t. parameters, ``(N, 2, P)`` (see
        :meth:`linearize`)."""
        return self.linearize(lon_deg, lat_deg, h_m, names)[3]

    def ground_partials(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
        """Partials of ``(line, sample)`` w.r.t. local east, north, up displacements in
        metres, ``(N, 2, 3)`` (see :meth:`linearize`)."""
        return self.linearize(lon_deg, lat_deg, h_m, [])[2]

    def with_trajectory(self, trajectory: Trajectory) -> LineScanner:
        """The same image seen from another (e.g. adjusted, shared) trajectory."""
        return attrs.evolve(self, trajectory=trajectory)

    def with_camera(self, camera: Camera) -> LineScanner:
        """The same image through another camera model (e.g. the even array)."""
        return attrs.evolve(self, camera=camera, guess=_FirstGuess())

    # ------------------------------------------------------------------ geometry
    def camera_to_ecef(self, line: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(P_ecef_m (..., 3), R_camera_to_ecef (..., 3, 3))`` at the time of ``line``."""
        p, r_b2e = self.trajectory.evaluate(self.timing.time(line))
        return p, r_b2e @ self.camera.camera_to_body()

    def ray(self, line: ArrayLike, sample: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Perspective centre ``(..., 3)`` and unit look direction ``(..., 3)``, ECEF."""
        line, sample = as_float_arrays(line, sample)
        p, r_c2e = self.camera_to_ecef(line)
        u = np.einsum(
            "...ij,...j->...i", r_c2e, self.camera.look_camera(sample + self.first_sample)
        )
        return p, u

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line, sample, h = as_float_arrays(line, sample, h_m)
        p, u = self.ray(line, sample)
        lon, lat, _ = intersect_ellipsoid_height(p, u, h)
        return lon, lat

    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """Ground -> image without clipping: ``(line, sample, inside)``.

        ``inside`` is True where the point falls within the image (``0 <= line <= n_lines``,
        ``0 <= sample <= n_samples``); coordinates outside are extrapolated along the model.
        NaN where the iteration fails (point behind the camera, no convergence).
        """
        lon, lat, h = as_float_arrays(lon_deg, lat_deg, h_m)
        shape = lon.shape
        lon, lat, h = lon.ravel(), lat.ravel(), h.ravel()
        x = frames.geodetic_to_ecef(lon, lat, h)
        if self._guess.coeffs is None:
            self._guess.fit(self)
        guess = self._guess(lon, lat, h)
        guess = np.where(np.isfinite(guess), guess, 0.5 * self.n_lines)
        if self._table.position is None:
            self._table.build(self)
        cam = self.camera
        result_t, sample = _solve_lines(
            np.ascontiguousarray(x),
            np.ascontiguousarray(self.timing.time(guess)),
            self._table.node0,
            self._table.spacing,
            self._table.position,
            self._table.rotation,
            np.asarray(cam.tan_psi_x_coeffs, float),
            np.asarray(cam.tan_psi_y_coeffs, float),
            cam.stagger_tan if cam.array == "even" else 0.0,
            cam.n_samples / 2.0,
            self._table.tolerance_s,
            MAX_ITERATIONS,
        )
        result_line = self.timing.line(result_t)
        sample = sample - self.first_sample
        ok = np.isfinite(result_line) & np.isfinite(sample)
        e = EDGE_TOLERANCE_PX
        inside = (
            ok
            & (result_line >= -e)
            & (result_line <= self.n_lines + e)
            & (sample >= -e)
            & (sample <= self.n_samples + e)
        )
        return result_line.reshape(shape), sample.reshape(shape), inside.reshape(shape)

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line, sample, inside = self.project(lon_deg, lat_deg, h_m)
        return np.where(inside, line, np.nan), np.where(inside, sample, np.nan)

    # ------------------------------------------------------------------ model file
    def to_dict(self) -> dict[str, Any]:
        """The full state as JSON-ready data (``format`` and ``version`` first)."""
        return {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "name": self.name,
            "n_lines": self.n_lines,
            "window": {
                "first_line": self.first_line,
                "first_sample": self.first_sample,
                "width": self.n_samples,
            },
            "timing": {
                "line_nodes": list(self.timing.line_nodes),
                "dt_nodes_s": list(self.timing.dt_nodes_s),
            },
            "camera": self.camera.to_dict(),
            "trajectory": self.trajectory.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "model") -> LineScanner:
        """Inverse of :meth:`to_dict`; ``source`` names the file in error messages."""
        check_document(d, MODEL_FORMAT, MODEL_VERSION, "model file", source)
        try:
            window = d.get("window", {})
            return cls(
                str(d["name"]),
                int(d["n_lines"]),
                LineTiming(d["timing"]["line_nodes"], d["timing"]["dt_nodes_s"]),
                Camera.from_dict(d["camera"]),
                Trajectory.from_dict(d["trajectory"]),
                first_sample=int(window.get("first_sample", 0)),
                width=None if window.get("width") is None else int(window["width"]),
                first_line=int(window.get("first_line", 0)),
            )
        except KeyError as exc:
            raise InputError(f"{source}: missing field {exc.args[0]!r}") from None
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the model file (JSON) atomically: temporary name, then rename."""
        return write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> LineScanner:
        """Read a model file written by :meth:`save`."""
        doc = read_json_document(path, MODEL_FORMAT, MODEL_VERSION, "model file")
        return cls.from_dict(doc, source=str(Path(path)))


def intersect_ellipsoid_height(
    position_m: FloatArray, direction: FloatArray, h_m: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """First intersection of rays with the surface at ellipsoidal height ``h_m``.

    Args:
        position_m: ray origins, ECEF ``(..., 3)``; must be above the surface.
        direction: ray directions, ECEF ``(..., 3)`` (need not be unit).
        h_m: target height above the WGS84 ellipsoid, broadcastable to ``(...)``.

    Returns:
        ``(lon_deg, lat_deg, h_m)`` of the intersection; NaN where the ray misses.
    """
    p = np.asarray(position_m, float)
    u = np.asarray(direction, float)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    h = np.broadcast_to(np.asarray(h_m, float), p.shape[:-1])
    a = frames.WGS84_A_M + h
    b = frames.WGS84_B_M + h
    scale = np.stack([1.0 / a, 1.0 / a, 1.0 / b], axis=-1)
    ps, us = p * scale, u * scale
    qa = np.sum(us * us, axis=-1)
    qb = 2.0 * np.sum(ps * us, axis=-1)
    qc = np.sum(ps * ps, axis=-1) - 1.0
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(invalid="ignore"):
        d = (-qb - np.sqrt(disc)) / (2.0 * qa)
    d = np.where((disc >= 0) & (d > 0), d, np.nan)
    for _ in range(6):
        x = p + d[..., None] * u
        lon, lat, hx = frames.ecef_to_geodetic(x)
        up = frames.ellipsoid_normal(lon, lat)
        cos = np.sum(u * up, axis=-1)
        err = hx - h
        d = d + err / np.where(cos != 0, -cos, np.nan)  # height falls by -cos per metre
        if np.nanmax(np.abs(err), initial=0.0) < HEIGHT_TOLERANCE_M * 1e-3:
            break
    x = p + d[..., None] * u
    return frames.ecef_to_geodetic(x)


class LineScannerModelType(SensorType):
    """Opens Carto line-scanner model files (``*.model.json``, format ``carto-linescan-model``)."""

    name = "linescan"
    description = "Carto rigorous line-scanner model file (JSON, versioned)"

    def identify(self, path: Path) -> bool:
        path = Path(path)
        if path.suffix.lower() != ".json" or not path.is_file():
            return False
        try:
            with path.open("rb") as fh:
                head = fh.read(4096)
        except OSError:
            return False
        return MODEL_FORMAT.encode() in head

    def open(self, path: Path) -> LineScanner:
        return LineScanner.load(path)


def shared_parameter_names(sensors: Sequence[Sensor]) -> list[str]:
    """Names of parameters that appear in more than one of ``sensors`` (tied parameters)."""
    seen: dict[str, int] = {}
    for sensor in sensors:
        for p in sensor.parameters:
            seen[p.name] = seen.get(p.name, 0) + 1
    return [n for n, c in seen.items() if c > 1]
