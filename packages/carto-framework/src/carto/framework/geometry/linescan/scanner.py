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
    when the line changes by less than
    :data:`~carto.framework.geometry.linescan.solver.LINE_TOLERANCE` (1e-8 line); the sample is
    then ``s = tan_psi_y^-1(v_y / v_z)``. Points that do not converge in ``MAX_ITERATIONS``, or
    that are behind the camera, come back as NaN; points outside the image come back as NaN from
    :meth:`~LineScanner.ground_to_image` and with their (extrapolated) coordinates and a False
    mask from :meth:`~LineScanner.project`. The first guess, the camera-state table and the
    compiled solver are in :mod:`~carto.framework.geometry.linescan.solver`.

Image coordinates follow the project convention (first pixel centre at ``(0.5, 0.5)``); line
``l`` is imaged at ``t(l)`` given by a
:class:`~carto.framework.geometry.linescan.timing.LineTiming` (``t0 + (l - 0.5) * period`` for a
constant period, piecewise linear for asynchronous imaging).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.component import ComponentLookup
from carto.framework.errors import InputError
from carto.framework.files.documents import (
    check_document,
    read_json_document,
    write_json_atomic,
)
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.light_path import (
    SPEED_OF_LIGHT_M_S,
    LightPath,
    apparent_direction,
    emission_position,
    received_ground_point,
    source_direction,
)
from carto.framework.geometry.linescan.linearization import (
    linearization_point,
    parameter_jacobian,
)
from carto.framework.geometry.linescan.solver import (
    FirstGuess,
    LineTable,
    solve_lines,
    tabulated_lines,
)
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.sensor import (
    Linearization,
    Parameter,
    ParameterChanges,
    Sensor,
    SensorType,
    fields_as_json,
    refuse_options,
)
from carto.framework.geometry.trajectory import Trajectory, TrajectoryState

FloatArray = NDArray[np.float64]

MODEL_FORMAT = "carto-linescan-model"
MODEL_VERSION = 1
MAX_ITERATIONS = 25
HEIGHT_TOLERANCE_M = 1e-6
EDGE_TOLERANCE_PX = 1e-6
"""Points this close outside the image border still count as inside (rounding of round trips)."""
MAX_TABLE_NODES = 4e6
"""Most camera states the ground -> image table may hold (~400 MB): the image and its margins
(:data:`~carto.framework.geometry.linescan.solver.TABLE_MARGIN_LINES`) at two of the shortest
line periods per node. A 38 000-line Pleiades image needs 38 000; only a wrong line time or
period (a timing node far from the others) needs more."""


def table_nodes(n_lines: int, timing: LineTiming) -> float:
    """How many camera states :class:`LineTable` tabulates for an image of ``n_lines`` lines
    with ``timing`` (the same arithmetic as :meth:`LineTable.build`, without building it)."""
    first, last = tabulated_lines(n_lines)
    span = float(timing.time(last)) - float(timing.time(first))
    periods = np.diff(np.asarray(timing.dt_nodes_s)) / np.diff(np.asarray(timing.line_nodes))
    return span / (2.0 * float(periods.min())) + 8.0


@attrs.frozen(eq=False)
class LineScanner(Sensor):
    """Rigorous model of one pushbroom image: trajectory + camera + line timing.

    Attributes:
        name: image identifier (``"fore"``, ``"IMG_02"`` ...).
        n_lines: number of image lines.
        timing: :class:`~carto.framework.geometry.linescan.timing.LineTiming` of the lines.
        camera: :class:`~carto.framework.geometry.camera.Camera` of the whole detector line.
        trajectory: :class:`~carto.framework.geometry.trajectory.Trajectory` of the platform body.
        first_sample: detector index of the image's first column: an image that is a window
            of the detector line (a crop, as the simulator renders) has ``sample = detector
            sample - first_sample``; 0 for a full line.
        width: number of image columns (default: the detectors from ``first_sample`` on).
        first_line: line of the full acquisition that is this image's first line (for
            reference only: ``timing`` already gives the times of this image's lines).
        light_path: the light-time and aberration corrections the model applies
            (:mod:`~carto.framework.geometry.light_path`; both off by default).

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
    light_path: LightPath = attrs.field(factory=LightPath)
    _guess: FirstGuess = attrs.field(factory=FirstGuess, alias="guess", repr=False)
    _table: LineTable = attrs.field(factory=LineTable, init=False, repr=False)

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
        nodes = table_nodes(self.n_lines, self.timing)
        if not nodes <= MAX_TABLE_NODES:
            raise InputError(
                f"sensor {self.name}: the line timing (dt_nodes_s "
                f"{list(self.timing.dt_nodes_s)[:4]} at line_nodes "
                f"{list(self.timing.line_nodes)[:4]}) spans {nodes:.3g} shortest line periods "
                f"over the {self.n_lines} lines and their margins (at most {MAX_TABLE_NODES:.3g}):"
                " a wrong line time or period"
            )

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

    def with_changes(self, changes: ParameterChanges) -> LineScanner:
        known_t = {p.name for p in self.trajectory.parameters}
        known_c = {p.name for p in self.camera.parameters}
        unknown = changes.unknown(known_t | known_c)
        if unknown:
            raise InputError(f"sensor {self.name}: unknown parameter(s) {', '.join(unknown)}")
        return attrs.evolve(
            self,
            trajectory=changes.only(known_t).applied_to(self.trajectory),
            camera=changes.only(known_c).applied_to(self.camera),
        )

    def _collinearity(
        self,
        line: FloatArray,
        sample: FloatArray,
        x_ecef: FloatArray,
        pose: tuple[FloatArray, FloatArray] | None = None,
        light: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The collinearity condition at image point ``(line, sample)`` and ground ``x_ecef``:
        ``F (N, 2)``, zero when the point images there (camera-frame ``x/z`` and ``y/z`` of the
        ground direction minus the detector's ``tan psi``), and ``dF/dX (N, 2, 3)``, the
        camera-frame vector ``v (N, 3)`` and ``R_camera_to_ecef (N, 3, 3)``. ``pose``: the
        ``(P, R_camera_to_ecef)`` at ``line`` and ``light`` its :meth:`light_terms`, when
        already known."""
        p, r_c2e = self.camera_to_ecef(line) if pose is None else pose
        v = np.einsum("nji,nj->ni", r_c2e, self._apparent_vector(line, x_ecef, p, light))
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

    def _linearize(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> Linearization:
        """:meth:`Sensor.linearize` from one projection.

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
        line, sample, _ = self.project(lon, lat, h)
        ok = np.isfinite(line) & np.isfinite(sample)
        point = linearization_point(self, lon, lat, h, line, sample, ok)
        a_ground = -point.inv @ (point.df_dx @ np.swapaxes(frames.enu_basis(lon, lat), -1, -2))
        a_param = parameter_jacobian(self, point, names)
        bad = ~ok
        a_ground[bad] = np.nan
        a_param[bad] = np.nan
        return line, sample, a_ground, a_param

    def _parameter_partials(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> FloatArray:
        """Partials of ``(line, sample)`` w.r.t. parameters, ``(N, 2, P)`` (see
        :meth:`_linearize`)."""
        return self._linearize(lon, lat, h, names)[3]

    def ground_partials(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
        """Partials of ``(line, sample)`` w.r.t. local east, north, up displacements in
        metres, ``(N, 2, 3)`` (see :meth:`linearize`)."""
        return self.linearize(lon_deg, lat_deg, h_m, [])[2]

    def with_trajectory(self, trajectory: Trajectory) -> LineScanner:
        """The same image seen from another (e.g. adjusted, shared) trajectory."""
        return attrs.evolve(self, trajectory=trajectory)

    def with_camera(self, camera: Camera) -> LineScanner:
        """The same image through another camera model (e.g. the even array)."""
        return attrs.evolve(self, camera=camera, guess=FirstGuess())

    # ------------------------------------------------------------------ geometry
    def light_terms(
        self, t_s: ArrayLike, state: TrajectoryState | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """``(beta (..., 3), omega / c (3,))`` of the light path at times ``t_s``: the
        platform's inertial velocity over ``c`` and the Earth's angular velocity over ``c``
        (rad per metre), each zero where :attr:`light_path` switches its correction off;
        ``state``: the trajectory's state at ``t_s`` when known."""
        t = np.asarray(t_s, dtype=np.float64)
        if self.light_path.aberration:
            beta = self.trajectory.inertial_velocity_ecef(t, state) / SPEED_OF_LIGHT_M_S
        else:
            beta = np.zeros((*t.shape, 3))
        if self.light_path.light_time:
            omega_c = self.trajectory.earth_rotation_ecef / SPEED_OF_LIGHT_M_S
        else:
            omega_c = np.zeros(3)
        return beta, omega_c

    def _apparent_vector(
        self,
        line: FloatArray,
        x_ecef: FloatArray,
        p: FloatArray,
        light: tuple[FloatArray, FloatArray] | None = None,
    ) -> FloatArray:
        """``X - P`` turned into the direction the camera sees the point in (light time and
        aberration, when on), with the length of ``X - P``; ``light``: :meth:`light_terms`
        at ``line`` when known."""
        d = x_ecef - p
        if not (self.light_path.light_time or self.light_path.aberration):
            return d
        beta, omega_c = self.light_terms(self.timing.time(line)) if light is None else light
        d = emission_position(x_ecef, p, omega_c) - p
        dist = np.linalg.norm(d, axis=-1, keepdims=True)
        return apparent_direction(d / dist, beta) * dist

    def camera_to_ecef(self, line: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(P_ecef_m (..., 3), R_camera_to_ecef (..., 3, 3))`` at the time of ``line``."""
        p, r_b2e = self.trajectory.evaluate(self.timing.time(line))
        return p, r_b2e @ self.camera.camera_to_body()

    def ray(self, line: ArrayLike, sample: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Perspective centre ``(..., 3)`` and the unit direction the received light came
        from ``(..., 3)`` (the look direction corrected for aberration when on), ECEF."""
        line, sample = as_float_arrays(line, sample)
        p, r_c2e = self.camera_to_ecef(line)
        u = np.einsum(
            "...ij,...j->...i", r_c2e, self.camera.look_camera(sample + self.first_sample)
        )
        if self.light_path.aberration:
            u = source_direction(u, self.light_terms(self.timing.time(line))[0])
        return p, u

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line, sample, h = as_float_arrays(line, sample, h_m)
        p, u = self.ray(line, sample)
        lon, lat, h_out = intersect_ellipsoid_height(p, u, h)
        if self.light_path.light_time:
            x0 = frames.geodetic_to_ecef(lon, lat, h_out)
            _, omega_c = self.light_terms(np.zeros(0))
            lon, lat, _ = frames.ecef_to_geodetic(received_ground_point(x0, p, omega_c))
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
        cx, cy, stagger = cam.effective_coeffs()
        result_t, sample = solve_lines(
            np.ascontiguousarray(x),
            np.ascontiguousarray(self.timing.time(guess)),
            self._table.node0,
            self._table.spacing,
            self._table.position,
            self._table.rotation,
            self._table.beta,
            self._table.omega_c,
            cx,
            cy,
            stagger if cam.array == "even" else 0.0,
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
        return self._projection_in_image(lon_deg, lat_deg, h_m)

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
            "timing": fields_as_json(self.timing),
            "camera": self.camera.to_dict(),
            "trajectory": self.trajectory.to_dict(),
            "light_path": self.light_path.to_dict(),
        }

    @classmethod
    def from_dict(
        cls,
        d: Mapping[str, Any],
        source: str = "model",
        components: ComponentLookup | None = None,
    ) -> LineScanner:
        """Inverse of :meth:`to_dict`; ``source`` names the file in error messages;
        ``components`` (the registry) reads the series of a plugin's trajectory model."""
        check_document(d, MODEL_FORMAT, MODEL_VERSION, "model file", source)
        try:
            window = d.get("window", {})
            return cls(
                str(d["name"]),
                int(d["n_lines"]),
                LineTiming(d["timing"]["line_nodes"], d["timing"]["dt_nodes_s"]),
                Camera.from_dict(d["camera"]),
                Trajectory.from_dict(d["trajectory"], components),
                first_sample=int(window.get("first_sample", 0)),
                width=None if window.get("width") is None else int(window["width"]),
                first_line=int(window.get("first_line", 0)),
                light_path=LightPath.from_dict(d.get("light_path")),
            )
        except KeyError as exc:
            raise InputError(f"{source}: missing field {exc.args[0]!r}") from None
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def prepare_raw(self, raw: ArrayLike, dem: Any) -> NDArray[np.float32]:
        """The raw image with its staggered arrays merged onto this model's geometry
        (:func:`~carto.framework.geometry.linescan.stagger.merge_staggered`, stagger field every 8
        lines) when the camera is staggered and this model describes its odd array (raw
        Cartosat data); the image as it is otherwise."""
        if self.camera.stagger_tan and self.camera.array == "odd":
            from carto.framework.geometry.linescan.stagger import merge_staggered

            return merge_staggered(raw, self, dem, step=8).image
        return np.array(raw, dtype=np.float32)

    @property
    def raw_needs_preparation(self) -> bool:
        """True for the odd-array model of a staggered camera (raw Cartosat data)."""
        return bool(self.camera.stagger_tan) and self.camera.array == "odd"

    def prepare_rows(self, raw: Any, dem: Any, rows: slice) -> NDArray[np.float32]:
        """Lines ``rows`` of :meth:`prepare_raw`
        (:func:`~carto.framework.geometry.linescan.stagger.merge_staggered_rows`: the same values,
        reading only the raw lines the window needs)."""
        if self.raw_needs_preparation:
            from carto.framework.geometry.linescan.stagger import merge_staggered_rows

            return merge_staggered_rows(raw, self, dem, rows, step=8)
        return super().prepare_rows(raw, dem, rows)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the model file (JSON) atomically: temporary name, then rename."""
        return write_json_atomic(path, self.to_dict())

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], components: ComponentLookup | None = None
    ) -> LineScanner:
        """Read a model file written by :meth:`save` (``components``: see :meth:`from_dict`)."""
        doc = read_json_document(path, MODEL_FORMAT, MODEL_VERSION, "model file")
        return cls.from_dict(doc, source=str(Path(path)), components=components)


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

    def open(self, path: Path, **options: Any) -> LineScanner:
        """Read a model file; ``components`` (the registry) reads a plugin's trajectory
        series. A fitted model has no samples to refit: ``trajectory_model`` is refused."""
        refuse_options(f"{path} (a fitted model file)", options)
        return LineScanner.load(path, options.get("components"))

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """``<name>.model.json`` and an RPC fitted to it (``<name>_RPC.TXT``)."""
        return save_line_scanner(sensor, Path(out_dir), name, h_range_m)


def save_line_scanner(
    sensor: Sensor, out_dir: Path, name: str, h_range_m: tuple[float, float]
) -> dict[str, Any]:
    """Write an adjusted :class:`LineScanner` as ``<name>.model.json`` and an RPC fitted to it
    over ``h_range_m`` (``<name>_RPC.TXT``, GDAL's sidecar of ``<name>.tif``).

    An RPC is a smooth rational function: it is fitted to the model without its periodic
    attitude corrections (jitter, which it cannot follow and which can make the fit's
    denominator vanish), and the entry says how far the jitter moves the image
    (``periodic_attitude_left_out_max_px``): the model file is the rigorous product."""
    from carto.framework.geometry.rpc.fitting import fit_rpc
    from carto.framework.geometry.rpc.writers import write_rpc_txt

    if not isinstance(sensor, LineScanner):
        raise InputError(f"image {name}: not a line scanner ({type(sensor).__name__})")
    model = sensor.save(out_dir / f"{name}.model.json").name
    smooth = sensor
    entry: dict[str, Any] = {}
    if sensor.trajectory.attitude_periodic_hz:
        smooth = sensor.with_trajectory(sensor.trajectory.without_attitude_periodic())
        entry["periodic_attitude_left_out_max_px"] = _periodic_effect_px(sensor, smooth, h_range_m)
    rpc, report = fit_rpc(smooth, h_range=h_range_m)
    return {
        "model": model,
        "rpc": {
            "file": write_rpc_txt(rpc, out_dir / f"{name}_RPC.TXT").name,
            "fit_check_max_px": report.check_max_px,
            **entry,
        },
    }


def _periodic_effect_px(
    sensor: LineScanner, smooth: LineScanner, h_range_m: tuple[float, float]
) -> float:
    """Largest image displacement (px) between ``sensor`` and ``smooth`` over a grid of lines
    (every line up to 20 000) and 5 samples, at the middle of ``h_range_m``."""
    n_l, n_s = sensor.image_shape
    line, sample = np.meshgrid(
        np.linspace(0.5, n_l - 0.5, min(n_l, 20_000)), np.linspace(0.5, n_s - 0.5, 5)
    )
    h = np.full(line.size, 0.5 * (h_range_m[0] + h_range_m[1]))
    lon, lat = sensor.image_to_ground(line.ravel(), sample.ravel(), h)
    l2, s2, _ = smooth.project(lon, lat, h)
    d = np.hypot(l2 - line.ravel(), s2 - sample.ravel())
    return round(float(np.nanmax(d)), 3) if np.isfinite(d).any() else float("nan")


def shared_parameter_names(sensors: Sequence[Sensor]) -> list[str]:
    """Names of parameters that appear in more than one of ``sensors`` (tied parameters)."""
    seen: dict[str, int] = {}
    for sensor in sensors:
        for p in sensor.parameters:
            seen[p.name] = seen.get(p.name, 0) + 1
    return [n for n, c in seen.items() if c > 1]
