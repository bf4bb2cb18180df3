"""Trajectories: position, velocity and attitude of a platform as functions of time.

A :class:`Trajectory` is built from ephemeris samples (time, position, velocity) and attitude
samples (time, quaternion) as a product delivers them (every 125 ms for Cartosat), either by a
least-squares polynomial of order 1, 2 or 3 in normalised time per component (ISRO's practice,
with the fit residuals reported) or by Lagrange interpolation. Corrections estimated by an
adjustment are polynomials added on top:

* attitude corrections ``(d_roll, d_pitch, d_yaw)(tau)`` in radians, applied as a rotation in the
  **orbit frame**: ``R_body_to_orbit' = rpy_to_matrix(d_roll, d_pitch, d_yaw) @ R_body_to_orbit``
  (so a roll correction always moves the line of sight across track, a pitch correction along
  track, whatever the pointing);
* position corrections ``(d_along, d_across, d_radial)(tau)`` in metres along the orbit frame
  axes ``X_o, Y_o, -Z_o`` (radial is up);
* periodic attitude corrections (the platform's jitter an adjustment estimated, fixed values:
  :meth:`Trajectory.with_attitude_periodic`), ``sum_f s sin(2 pi f (dt_s - t_mid_s)) + c
  cos(...)`` per axis, added to the polynomial attitude corrections.

Times: ``dt_s`` is seconds since the trajectory's ``epoch_j2000_s`` (an absolute time in seconds
since J2000, see :mod:`carto.framework.geometry.frames`). Working relative to an epoch keeps
float64 time precision at the nanosecond level (absolute J2000 seconds would only resolve 0.1 us, a
third of a Cartosat line). Normalised time is ``tau = (dt_s - t_mid_s) / t_half_s``, in [-1, 1]
over the samples.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.polynomial import polynomial as npoly
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Adjustable, Parameter
from carto.framework.geometry.time_series import (
    BUILTIN_KINDS,
    BuiltinSeries,
    Interpolation,
    SeriesModel,
    TimeSeries,
)
from carto.framework.geometry.trajectory_samples import (
    AttitudeFrame,
    AttitudeSamples,
    EphemerisSamples,
)

if TYPE_CHECKING:
    from carto.framework.component import ComponentLookup

__all__ = ["AttitudeSamples", "EphemerisSamples", "FitReport", "Trajectory"]

FloatArray = NDArray[np.float64]


_ANGLE_NAMES = ("roll", "pitch", "yaw")
_POSITION_NAMES = ("along", "across", "radial")


@attrs.frozen
class FitReport:
    """Residuals of a trajectory fit at its samples, per component.

    Attributes:
        components: component names (``"x_m" ... "vz_m_s", "roll_rad" ...``).
        rms: RMS residual per component, in its units.
        max_abs: largest absolute residual per component.
    """

    components: tuple[str, ...]
    rms: tuple[float, ...]
    max_abs: tuple[float, ...]

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {
            c: {"rms": r, "max_abs": m}
            for c, r, m in zip(self.components, self.rms, self.max_abs, strict=True)
        }


# ------------------------------------------------------------------------ interpolators


# ------------------------------------------------------------------------ the trajectory
@attrs.frozen(eq=False)
class TrajectoryState:
    """A trajectory at times ``t_s`` before its correction parameters (:meth:`Trajectory.
    state`): what the trajectories that differ from it only in their parameters (its
    :meth:`~Trajectory.with_parameters` copies) share there. An adjustment's partials
    evaluate one trajectory many times with one parameter changed; with the state the Earth
    orientation, the orbit and the attitude samples are interpolated once.

    Attributes:
        t_s: the times, seconds since the trajectory's epoch.
        p_eci, v_eci: uncorrected inertial position (m) and velocity (m/s), ``(..., 3)``.
        r_orbit_to_eci: the orbit frame of the uncorrected position, ``(..., 3, 3)``.
        r_eci_to_ecef: GCRS -> ITRS, ``(..., 3, 3)``.
        r_attitude: the uncorrected attitude, ``R_body_to_orbit`` for an orbit-frame
            trajectory, ``R_body_to_frame`` (its eci or ecef frame) otherwise.
        source: the trajectory's orbit and attitude series (whose state this is).
    """

    t_s: FloatArray
    p_eci: FloatArray
    v_eci: FloatArray
    r_orbit_to_eci: FloatArray
    r_eci_to_ecef: FloatArray
    r_attitude: FloatArray
    source: tuple[Any, ...]


@attrs.frozen(eq=False)
class Trajectory(Adjustable):
    """Position and attitude of a platform as continuous functions of time, with corrections.

    Build it with :meth:`from_samples`. Immutable: :meth:`with_parameters` returns a new one.

    Attributes:
        epoch_j2000_s: absolute time of ``dt_s = 0``, seconds since J2000 (UTC).
        attitude_frame: the frame the attitude samples refer to.
        attitude_correction_order, position_correction_order: polynomial order of the
            corrections (-1 = none), coefficients of normalised time ``tau``.
        parameters: the correction parameters (see module docstring), prefixed ``prefix``.
        attitude_periodic_hz: frequencies of the periodic attitude corrections (Hz).
        attitude_periodic_rad: their coefficients, axis-major (roll, pitch, yaw), for each
            axis ``sin, cos`` per frequency (radians; ``3 x 2F`` values).
    """

    epoch_j2000_s: float
    attitude_frame: AttitudeFrame
    _orbit: TimeSeries  # 6 components: P_eci (m), V_eci (m/s)
    _angles: TimeSeries  # 3 components: roll, pitch, yaw (orbit frame) or rotvec w.r.t. _r_ref
    _r_ref: FloatArray  # (3, 3) reference rotation for rotvec attitude
    t_mid_s: float
    t_half_s: float
    parameters: tuple[Parameter, ...]
    prefix: str
    attitude_correction_order: int
    position_correction_order: int
    fit_report: FitReport | None = None
    attitude_periodic_hz: tuple[float, ...] = ()
    attitude_periodic_rad: tuple[float, ...] = ()
    _earth: frames.EarthOrientation = attrs.field(init=False)

    def __attrs_post_init__(self) -> None:
        object.__setattr__(self, "_earth", frames.EarthOrientation.at(self.epoch_j2000_s))
        freqs, coeffs = self.attitude_periodic_hz, self.attitude_periodic_rad
        if len(coeffs) != 6 * len(freqs):
            raise InputError(
                f"trajectory: attitude_periodic has {len(freqs)} frequencies but "
                f"{len(coeffs)} coefficients (3 axes x sin, cos per frequency: {6 * len(freqs)})"
            )
        if not all(np.isfinite(f) and f > 0 for f in freqs) or not np.all(np.isfinite(coeffs)):
            raise InputError(
                f"trajectory: attitude_periodic frequencies must be > 0 Hz and its coefficients "
                f"finite, got {list(freqs)}"
            )

    @property
    def model(self) -> str:
        """Registry name of the trajectory model that made the orbit series
        (``"polynomial"``, ``"lagrange"`` or a plugin's)."""
        return self._orbit.kind

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_samples(
        cls,
        epoch_j2000_s: float,
        ephemeris: EphemerisSamples,
        attitude: AttitudeSamples,
        *,
        interpolation: Interpolation | SeriesModel = "polynomial",
        order: int = 3,
        lagrange_points: int = 8,
        attitude_correction_order: int = 1,
        position_correction_order: int = 0,
        prefix: str = "trajectory.",
        attitude_sigma_rad: tuple[float, ...] = (1e-3, 1e-4, 1e-5, 1e-5),
        position_sigma_m: tuple[float, ...] = (30.0, 5.0),
    ) -> Trajectory:
        """Fit or interpolate the samples.

        Args:
            epoch_j2000_s: absolute time of ``dt_s = 0`` (seconds since J2000).
            interpolation: ``"polynomial"`` (least squares, ``order`` 1-3, per component),
                ``"lagrange"`` (``lagrange_points`` samples around each time), or a trajectory
                model (a plugin's) whose ``fit_series`` fits the orbit and the attitude angles.
            attitude_correction_order, position_correction_order: orders of the correction
                polynomials, -1 for none (Cartosat-1: attitude bias + drift = 1).
            attitude_sigma_rad, position_sigma_m: a-priori sigmas of the correction
                coefficients by power of ``tau`` (default: ~0.06 deg bias, 30 m position).
        """
        if not -1 <= attitude_correction_order <= 3 or not -1 <= position_correction_order <= 3:
            raise InputError("correction orders must be between -1 (none) and 3")
        t_all = np.concatenate([ephemeris.dt_s, attitude.dt_s])
        t_mid = 0.5 * (t_all.min() + t_all.max())
        t_half = max(0.5 * (t_all.max() - t_all.min()), 1e-3)
        span = _TimeSpan(float(t_mid), float(t_half))

        orbit_values = _inertial_orbit(epoch_j2000_s, ephemeris)
        points = order if interpolation == "polynomial" else lagrange_points
        orbit = _fit_series(interpolation, ephemeris.dt_s, orbit_values, "orbit", points, span)

        angles, r_ref = _attitude_angles(attitude)
        att_points = min(order, 3) if interpolation == "polynomial" else min(lagrange_points, 4)
        ang = _fit_series(interpolation, attitude.dt_s, angles, "attitude", att_points, span)

        report = FitReport(
            ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "a1_rad", "a2_rad", "a3_rad"),
            *_residuals(
                np.concatenate([orbit(ephemeris.dt_s) - orbit_values], axis=1),
                ang(attitude.dt_s) - angles,
            ),
        )
        params = _correction_parameters(
            prefix,
            attitude_correction_order,
            position_correction_order,
            attitude_sigma_rad,
            position_sigma_m,
        )
        return cls(
            float(epoch_j2000_s),
            attitude.frame,
            orbit,
            ang,
            r_ref,
            float(t_mid),
            float(t_half),
            tuple(params),
            prefix,
            attitude_correction_order,
            position_correction_order,
            report,
        )

    # ---------------------------------------------------------------- parameters
    def with_correction_orders(
        self, attitude: int | None = None, position: int | None = None
    ) -> Trajectory:
        """The trajectory with correction polynomials of other orders (-1: none).

        Coefficients that exist in both keep their value, sigma and free flag; new ones start
        at zero with the default a-priori sigmas."""
        att = self.attitude_correction_order if attitude is None else int(attitude)
        pos = self.position_correction_order if position is None else int(position)
        if not -1 <= att <= 3 or not -1 <= pos <= 3:
            raise InputError("correction orders must be between -1 (none) and 3")
        old = {p.name: p for p in self.parameters}
        params = tuple(old.get(p.name, p) for p in _correction_parameters(self.prefix, att, pos))
        return attrs.evolve(
            self, parameters=params, attitude_correction_order=att, position_correction_order=pos
        )

    def with_attitude_periodic(
        self, frequencies_hz: tuple[float, ...], coefficients_rad: ArrayLike
    ) -> Trajectory:
        """The trajectory with periodic attitude corrections added to those it has:
        ``coefficients_rad`` ``(3, 2F)`` (roll, pitch, yaw; ``sin, cos`` per frequency of
        ``frequencies_hz``, time from ``t_mid_s``)."""
        c = np.asarray(coefficients_rad, dtype=np.float64).reshape(3, 2 * len(frequencies_hz))
        old = np.asarray(self.attitude_periodic_rad, dtype=np.float64).reshape(3, -1)
        return attrs.evolve(
            self,
            attitude_periodic_hz=(*self.attitude_periodic_hz, *map(float, frequencies_hz)),
            attitude_periodic_rad=tuple(np.concatenate([old, c], axis=1).ravel().tolist()),
        )

    def without_attitude_periodic(self) -> Trajectory:
        """The trajectory without its periodic attitude corrections (the smooth motion)."""
        return attrs.evolve(self, attitude_periodic_hz=(), attitude_periodic_rad=())

    def attitude_periodic_angles(self, dt_s: ArrayLike) -> FloatArray:
        """The periodic attitude corrections (roll, pitch, yaw; radians) at ``dt_s``,
        ``(3, ...)``."""
        t = np.asarray(dt_s, dtype=np.float64) - self.t_mid_s
        out = np.zeros((3, *t.shape))
        c = np.asarray(self.attitude_periodic_rad, dtype=np.float64).reshape(3, -1)
        for k, f in enumerate(self.attitude_periodic_hz):
            w = 2.0 * np.pi * f * t
            sin_w, cos_w = np.sin(w), np.cos(w)
            for a in range(3):
                out[a] += c[a, 2 * k] * sin_w + c[a, 2 * k + 1] * cos_w
        return out

    def with_prefix(self, prefix: str) -> Trajectory:
        """The same trajectory whose parameter names start with ``prefix`` instead (so that
        sensors sharing it can be given independent corrections)."""
        n = len(self.prefix)
        params = tuple(attrs.evolve(p, name=prefix + p.name[n:]) for p in self.parameters)
        return attrs.evolve(self, parameters=params, prefix=prefix)

    def _correction_coeffs(self, group: str, names: tuple[str, ...], order: int) -> FloatArray:
        values = {p.name: p.value for p in self.parameters}
        out = np.zeros((order + 1, 3))
        for k in range(order + 1):
            for i, name in enumerate(names):
                out[k, i] = values[f"{self.prefix}{group}.{name}.c{k}"]
        return out

    # ---------------------------------------------------------------- evaluation
    def eci_to_ecef_matrix(self, dt_s: ArrayLike) -> FloatArray:
        """``R_eci_to_ecef`` (GCRS -> ITRS, :class:`~carto.framework.geometry.frames.
        EarthOrientation`) at ``dt_s``, ``(..., 3, 3)``."""
        return self._earth.eci_to_ecef_matrix(dt_s)

    def inertial_velocity_ecef(
        self, dt_s: ArrayLike, state: TrajectoryState | None = None
    ) -> FloatArray:
        """The platform's inertial velocity in the Earth-fixed axes of ``dt_s``, m/s
        ``(..., 3)`` (what aberration depends on, :mod:`~carto.framework.geometry.light_path`);
        ``state``: this trajectory's :meth:`state` at ``dt_s``, when known."""
        if state is not None and self._is_source_of(state):
            return np.einsum("...ij,...j->...i", state.r_eci_to_ecef, state.v_eci)
        t = np.asarray(dt_s, dtype=np.float64)
        _, v_eci = self.state_eci(t)
        return np.einsum("...ij,...j->...i", self._earth.eci_to_ecef_matrix(t), v_eci)

    @property
    def earth_rotation_ecef(self) -> FloatArray:
        """The Earth's angular velocity in the Earth-fixed frame, rad/s ``(3,)``."""
        return self._earth.rotation_vector_ecef

    def state_eci(self, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Uncorrected inertial position (m) and velocity (m/s), each ``(..., 3)``."""
        values = self._orbit(np.asarray(dt_s, dtype=np.float64))
        return values[..., :3], values[..., 3:]

    def state(self, dt_s: ArrayLike) -> TrajectoryState:
        """The trajectory at ``dt_s`` before its correction parameters (:class:`TrajectoryState`),
        for :meth:`evaluate` of it and of its :meth:`with_parameters` copies."""
        t = np.asarray(dt_s, dtype=np.float64)
        p_eci, v_eci = self.state_eci(t)
        a = self._angles(t)
        if self.attitude_frame == "orbit":
            r_att = frames.rpy_to_matrix(a[..., 0], a[..., 1], a[..., 2])
        else:
            r_att = self._r_ref @ frames.small_rotation(a[..., 0], a[..., 1], a[..., 2])
        return TrajectoryState(
            t,
            p_eci,
            v_eci,
            frames.orbit_to_eci_matrix(p_eci, v_eci),
            self._earth.eci_to_ecef_matrix(t),
            r_att,
            self._state_source,
        )

    @property
    def _state_source(self) -> tuple[Any, ...]:
        return (self._orbit, self._angles, self._r_ref, self._earth, self.attitude_frame)

    def _is_source_of(self, state: TrajectoryState) -> bool:
        """Whether ``state`` is of this trajectory's series (its own or a parameter copy's)."""
        return all(a is b for a, b in zip(state.source, self._state_source, strict=True))

    def evaluate(
        self, dt_s: ArrayLike, state: TrajectoryState | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Corrected ``(P_ecef_m (..., 3), R_body_to_ecef (..., 3, 3))`` at ``dt_s``.

        The rotation chain is ``R_body_to_ecef = R_eci_to_ecef(t) @ R_orbit_to_eci(P, V) @
        R_correction(t) @ R_body_to_orbit(t)`` (for attitude given in eci/ecef,
        ``R_body_to_orbit = R_orbit_to_eci^T @ R_body_to_eci``), with the orbit frame of the
        corrected position ``P``. ``state``: :meth:`state` at ``dt_s`` of this trajectory or
        of one that differs from it only in its parameters (computed when not given).
        """
        p, r, _ = self._evaluate(dt_s, False, state)
        return p, r

    def evaluate_with_axes(
        self, dt_s: ArrayLike, state: TrajectoryState | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`evaluate` plus the ECEF axes of the attitude corrections, ``(..., 3, 3)``
        (rows: roll, pitch, yaw): increasing the correction angle of axis ``a`` by ``d``
        (radians) rotates the body by ``d`` about ``axes[..., a, :]``, so
        ``dR_body_to_ecef / d angle_a = [axis_a]x @ R_body_to_ecef`` (analytic partials)."""
        return self._evaluate(dt_s, True, state)

    def _evaluate(
        self, dt_s: ArrayLike, axes: bool, state: TrajectoryState | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        if state is None or not self._is_source_of(state):
            state = self.state(dt_s)
        t = state.t_s
        p_eci, r_o2i = state.p_eci, state.r_orbit_to_eci
        tau = (t - self.t_mid_s) / self.t_half_s
        if self.position_correction_order >= 0:
            c = self._correction_coeffs("position", _POSITION_NAMES, self.position_correction_order)
            if c.any():
                d = npoly.polyval(tau, c)  # (3, ...): along, across, radial
                d_orbit = np.stack([d[0], d[1], -d[2]], axis=-1)  # radial up = -Z_o
                p_eci = p_eci + np.einsum("...ij,...j->...i", r_o2i, d_orbit)
                # the orbit frame follows the corrected position (it is defined by it)
                r_o2i = frames.orbit_to_eci_matrix(p_eci, state.v_eci)
        r_i2e = state.r_eci_to_ecef
        r_o2e = r_i2e @ r_o2i
        if self.attitude_frame == "orbit":
            r_b2o = state.r_attitude
        elif self.attitude_frame == "eci":
            r_b2o = np.swapaxes(r_o2i, -1, -2) @ state.r_attitude
        else:
            r_b2o = np.swapaxes(r_o2e, -1, -2) @ state.r_attitude
        d = np.zeros((3, *t.shape))
        corrected = False
        if self.attitude_correction_order >= 0:
            c = self._correction_coeffs("attitude", _ANGLE_NAMES, self.attitude_correction_order)
            if c.any():
                d = npoly.polyval(tau, c)
                corrected = True
        if self.attitude_periodic_hz:
            d = d + self.attitude_periodic_angles(t)
            corrected = True
        if corrected:
            r_b2o = frames.rpy_to_matrix(d[0], d[1], d[2]) @ r_b2o
        p_ecef = np.einsum("...ij,...j->...i", r_i2e, p_eci)
        if not axes:
            return p_ecef, r_o2e @ r_b2o, None
        # R_correction = Rz(yaw) Ry(pitch) Rx(roll): d/d roll = [Rz Ry e_x]x R, d/d pitch =
        # [Rz e_y]x R, d/d yaw = [e_z]x R (orbit frame), then into ECEF
        cp, sp, cy, sy = np.cos(d[1]), np.sin(d[1]), np.cos(d[2]), np.sin(d[2])
        zero, one = np.zeros_like(cp), np.ones_like(cp)
        orbit_axes = np.stack(
            [
                np.stack([cy * cp, sy * cp, -sp], -1),
                np.stack([-sy, cy, zero], -1),
                np.stack([zero, zero, one], -1),
            ],
            axis=-2,
        )
        return p_ecef, r_o2e @ r_b2o, orbit_axes @ np.swapaxes(r_o2e, -1, -2)

    def position_velocity_ecef(self, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Uncorrected Earth-fixed position (m) and velocity (m/s, relative to the Earth)."""
        t = np.asarray(dt_s, dtype=np.float64)
        p_eci, v_eci = self.state_eci(t)
        return self._earth.to_ecef(t, p_eci, v_eci)

    # ---------------------------------------------------------------- serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready state (exact: fitted coefficients or samples are stored as they are)."""

        return {
            "epoch_j2000_s": self.epoch_j2000_s,
            "epoch_utc": frames.j2000_s_to_utc(self.epoch_j2000_s),
            "attitude_frame": self.attitude_frame,
            "orbit": self._orbit.to_dict(),
            "angles": self._angles.to_dict(),
            "r_ref": self._r_ref.tolist(),
            "t_mid_s": self.t_mid_s,
            "t_half_s": self.t_half_s,
            "prefix": self.prefix,
            "attitude_correction_order": self.attitude_correction_order,
            "position_correction_order": self.position_correction_order,
            "parameters": [attrs.asdict(p) for p in self.parameters],
            **(
                {
                    "attitude_periodic": {
                        "frequencies_hz": list(self.attitude_periodic_hz),
                        "coefficients_rad": list(self.attitude_periodic_rad),
                    }
                }
                if self.attitude_periodic_hz
                else {}
            ),
            "fit_report": None
            if self.fit_report is None
            else {
                "components": list(self.fit_report.components),
                "rms": list(self.fit_report.rms),
                "max_abs": list(self.fit_report.max_abs),
            },
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], components: ComponentLookup | None = None) -> Trajectory:
        """Inverse of :meth:`to_dict`; raises :class:`InputError` naming a missing field.

        Series of a trajectory model that is not built in are read by that model, looked up
        by its name in ``components`` (the registry, which the opening workflow passes)."""
        try:

            def series(s: dict[str, Any]) -> TimeSeries:
                kind = s["kind"]
                if kind in BUILTIN_KINDS:
                    return BuiltinSeries.from_dict(s)
                if components is None:
                    raise InputError(
                        f"trajectory model {kind!r} is not built in; open the model through "
                        "the registry (carto commands do) so that its plugin reads it"
                    )
                return components.get("trajectory", kind).series_from_dict(s)

            fr = d.get("fit_report")
            periodic = d.get("attitude_periodic") or {}
            return cls(
                float(d["epoch_j2000_s"]),
                d["attitude_frame"],
                series(d["orbit"]),
                series(d["angles"]),
                np.asarray(d["r_ref"], float),
                float(d["t_mid_s"]),
                float(d["t_half_s"]),
                tuple(Parameter(**p) for p in d["parameters"]),
                str(d["prefix"]),
                int(d["attitude_correction_order"]),
                int(d["position_correction_order"]),
                None
                if fr is None
                else FitReport(tuple(fr["components"]), tuple(fr["rms"]), tuple(fr["max_abs"])),
                tuple(float(f) for f in periodic.get("frequencies_hz", ())),
                tuple(float(c) for c in periodic.get("coefficients_rad", ())),
            )
        except KeyError as exc:
            raise InputError(f"trajectory: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"trajectory: invalid value: {exc}") from None


@attrs.frozen
class _TimeSpan:
    """The normalisation of time over the samples: ``tau = (dt_s - t_mid_s) / t_half_s``."""

    t_mid_s: float
    t_half_s: float


def _inertial_orbit(epoch_j2000_s: float, ephemeris: EphemerisSamples) -> FloatArray:
    """The ephemeris samples in the inertial frame: ``(N, 6)`` position (m), velocity (m/s)."""
    if ephemeris.frame == "ecef":
        p_eci, v_eci = frames.EarthOrientation.at(epoch_j2000_s).to_eci(
            ephemeris.dt_s, ephemeris.position_m, ephemeris.velocity_m_s
        )
    else:
        p_eci, v_eci = ephemeris.position_m, ephemeris.velocity_m_s
    return np.concatenate([p_eci, v_eci], axis=1)


def _attitude_angles(attitude: AttitudeSamples) -> tuple[FloatArray, FloatArray]:
    """The attitude as three unwrapped angles per sample and their reference rotation:
    roll, pitch, yaw for an orbit-frame attitude (reference: identity), else the rotation
    vector with respect to the middle sample's rotation."""
    r_att = frames.quat_to_matrix(attitude.quaternion_wxyz)
    if attitude.frame == "orbit":
        r_ref = np.eye(3)
        angles = np.stack(frames.matrix_to_rpy(r_att), axis=-1)
    else:
        r_ref = r_att[attitude.dt_s.shape[0] // 2]
        angles = frames.matrix_to_rotvec(r_ref.T @ r_att)
    return np.unwrap(angles, axis=0), r_ref


def _fit_series(
    interpolation: Interpolation | SeriesModel,
    dt_s: FloatArray,
    values: FloatArray,
    role: str,
    points: int,
    span: _TimeSpan,
) -> TimeSeries:
    """One component group (``role``: ``"orbit"`` or ``"attitude"``) fitted or interpolated:
    a built-in series of ``points`` (polynomial order or Lagrange samples), or the trajectory
    model's own ``fit_series``."""
    if isinstance(interpolation, str):
        return BuiltinSeries.fit(dt_s, values, interpolation, points, span.t_mid_s, span.t_half_s)
    return interpolation.fit_series(
        dt_s, values, role=role, t_mid_s=span.t_mid_s, t_half_s=span.t_half_s
    )


def _correction_parameters(
    prefix: str,
    attitude_order: int,
    position_order: int,
    attitude_sigma_rad: tuple[float, ...] = (1e-3, 1e-4, 1e-5, 1e-5),
    position_sigma_m: tuple[float, ...] = (30.0, 5.0),
) -> tuple[Parameter, ...]:
    """The correction parameters of the given orders, zero, with a-priori sigmas by power."""
    params: list[Parameter] = []
    for k in range(attitude_order + 1):
        sigma = attitude_sigma_rad[min(k, len(attitude_sigma_rad) - 1)]
        for name in _ANGLE_NAMES:
            params.append(
                Parameter(
                    f"{prefix}attitude.{name}.c{k}",
                    0.0,
                    sigma,
                    "rad",
                    description=f"{name} correction, coefficient of tau^{k} (orbit frame)",
                )
            )
    for k in range(position_order + 1):
        sigma = position_sigma_m[min(k, len(position_sigma_m) - 1)]
        for name in _POSITION_NAMES:
            what = "radial" if name == "radial" else f"{name}-track"
            params.append(
                Parameter(
                    f"{prefix}position.{name}.c{k}",
                    0.0,
                    sigma,
                    "m",
                    description=f"{what} position correction, coefficient of tau^{k}",
                )
            )
    return tuple(params)


def _residuals(orbit_res: FloatArray, angle_res: FloatArray) -> tuple[tuple[float, ...], ...]:
    res = [orbit_res[:, i] for i in range(orbit_res.shape[1])] + [
        angle_res[:, i] for i in range(angle_res.shape[1])
    ]
    rms = tuple(float(np.sqrt(np.mean(r**2))) for r in res)
    mx = tuple(float(np.max(np.abs(r))) for r in res)
    return rms, mx
