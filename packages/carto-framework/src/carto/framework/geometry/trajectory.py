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
  axes ``X_o, Y_o, -Z_o`` (radial is up).

Times: ``dt_s`` is seconds since the trajectory's ``epoch_j2000_s`` (an absolute time in seconds
since J2000, see :mod:`carto.framework.geometry.frames`). Working relative to an epoch keeps
float64 time precision at the nanosecond level (absolute J2000 seconds would only resolve 0.1 us, a
third of a Cartosat line). Normalised time is ``tau = (dt_s - t_mid_s) / t_half_s``, in [-1, 1]
over the samples.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import attrs
import numpy as np
from numpy.polynomial import polynomial as npoly
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Parameter, replace_parameters
from carto.framework.geometry.time_series import (
    BUILTIN_KINDS,
    BuiltinSeries,
    Interpolation,
    SeriesModel,
    TimeSeries,
)

if TYPE_CHECKING:
    from carto.framework.component import ComponentLookup

FloatArray = NDArray[np.float64]

EphemerisFrame = Literal["eci", "ecef"]
AttitudeFrame = Literal["orbit", "eci", "ecef"]

_ANGLE_NAMES = ("roll", "pitch", "yaw")
_POSITION_NAMES = ("along", "across", "radial")


ORBIT_RADIUS_RANGE_M = (6.45e6, 4.5e7)
"""Plausible distance of an Earth-orbiting satellite from the Earth's centre, metres: from
about 70 km above the equator (nothing orbits lower) to beyond the geostationary 42 164 km.
Positions in kilometres (~7e3) or centimetres (~7e8) fall outside."""
SPEED_LIMIT_M_S = 1.2e4
"""Largest plausible satellite speed (escape speed at a low orbit is 11.2 km/s)."""
ECI_SPEED_MIN_M_S = 2.5e3
"""Smallest plausible inertial speed (a geostationary satellite moves at 3.07 km/s)."""
VELOCITY_CONSISTENCY = 0.01
"""Largest relative difference between the mean tabulated velocity of two consecutive samples
and the chord of their positions over their time step (plus the chord's own curvature error,
``(omega dt)^2 / 4``): 1 % is 75 m/s in a low orbit, far above what real and simulated
products hold (< 1e-4) and below the Earth's rotation speed (an inertial velocity given as an
Earth-fixed one differs by up to 7 %) or any unit slip."""
QUATERNION_NORM_TOLERANCE = 1e-6
"""Largest ``| |q| - 1 |`` of an attitude sample; such samples are renormalised silently.
Simulated files hold 1e-16, float32 storage 6e-8, seven printed digits 1e-7; one damaged
component changes the norm by its error times its size, far more than this."""
ATTITUDE_RATE_LIMIT_RAD_S = 0.2
"""Largest plausible rotation rate between consecutive attitude samples (11 deg/s: agile
satellites slew at up to ~4 deg/s). A sample that is a unit quaternion but not the attitude
(components swapped, a sign flipped) jumps far more."""


def _as_array(value: Any, shape_tail: tuple[int, ...], what: str) -> FloatArray:
    if isinstance(value, (str, bytes, bool)) or (
        isinstance(value, (list, tuple)) and not _all_numbers(value)
    ):
        raise InputError(f"{what}: expected an array of numbers, got {_short(value)}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{what}: expected an array of numbers, got {_short(value)}") from None
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise InputError(
            f"{what}: expected shape (N, {', '.join(map(str, shape_tail))}), got {arr.shape}"
            if shape_tail
            else f"{what}: expected shape (N,), got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        i = int(np.argmax(~np.all(np.isfinite(arr.reshape(arr.shape[0], -1)), axis=1)))
        raise InputError(f"{what}: contains NaN or infinite values (sample {i})")
    return arr


def _all_numbers(value: Any) -> bool:
    """True for a (nested) list of int/float (JSON numbers; no bool, string or null)."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, (list, tuple)):
            stack.extend(v)
        elif isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
            return False
    return True


def _g(x: float) -> str:
    """``x`` to 3 significant digits, exponent without padding (``7.07e3``, ``6.5e6``)."""
    text = f"{x:.3g}"
    if "e" in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}e{int(exponent)}"
    return text


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_increasing(t: FloatArray, what: str) -> None:
    if t.shape[0] < 2:
        raise InputError(f"{what}: need >= 2 samples with strictly increasing times, got {t.size}")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(
            f"{what}: times must be strictly increasing: sample {i} (t = {t[i]:.9g} s) follows "
            f"t = {t[i - 1]:.9g} s"
        )


@attrs.frozen
class EphemerisSamples:
    """Position and velocity samples of the platform.

    Attributes:
        dt_s: sample times, seconds since the epoch, strictly increasing, shape ``(N,)``.
        position_m: positions, metres, shape ``(N, 3)``, in ``frame``.
        velocity_m_s: velocities, m/s, shape ``(N, 3)``, in ``frame`` (Earth-fixed velocities
            for ``"ecef"``, i.e. relative to the rotating Earth).
        frame: ``"eci"`` (the GMST-rotated inertial frame of
        :mod:`~carto.framework.geometry.frames`) or
            ``"ecef"``.
    """

    dt_s: FloatArray = attrs.field(converter=lambda v: _as_array(v, (), "ephemeris.dt_s"))
    position_m: FloatArray = attrs.field(
        converter=lambda v: _as_array(v, (3,), "ephemeris.position_m")
    )
    velocity_m_s: FloatArray = attrs.field(
        converter=lambda v: _as_array(v, (3,), "ephemeris.velocity_m_s")
    )
    frame: EphemerisFrame = "eci"

    def __attrs_post_init__(self) -> None:
        n = self.dt_s.shape[0]
        if self.position_m.shape[0] != n or self.velocity_m_s.shape[0] != n:
            raise InputError(
                f"ephemeris: dt_s, position_m and velocity_m_s differ in length "
                f"({n}, {self.position_m.shape[0]}, {self.velocity_m_s.shape[0]})"
            )
        _check_increasing(self.dt_s, "ephemeris.dt_s")
        if self.frame not in ("eci", "ecef"):
            raise InputError(f"ephemeris.frame: must be 'eci' or 'ecef', got {self.frame!r}")
        check_orbit_plausible(self.dt_s, self.position_m, self.velocity_m_s, self.frame)


def check_orbit_plausible(
    dt_s: FloatArray, position_m: FloatArray, velocity_m_s: FloatArray, frame: str
) -> None:
    """Refuse ephemeris samples that cannot be an Earth-orbiting satellite's in metres and m/s.

    Checks: the distance from the Earth's centre (:data:`ORBIT_RADIUS_RANGE_M`), the speed
    (:data:`SPEED_LIMIT_M_S`, and :data:`ECI_SPEED_MIN_M_S` in ``"eci"``), and the velocities
    against the positions (:data:`VELOCITY_CONSISTENCY`).

    Raises:
        InputError: one line naming the field, the sample and the value.
    """
    radius = np.linalg.norm(position_m, axis=1)
    lo, hi = ORBIT_RADIUS_RANGE_M
    bad = np.flatnonzero((radius < lo) | (radius > hi))
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"ephemeris.position_m: positions must be metres in ECEF/ECI: |r| = "
            f"{_g(radius[i])} at sample {i}, expected {_g(lo)}-{_g(hi)} for an Earth-orbiting "
            "satellite"
        )
    speed = np.linalg.norm(velocity_m_s, axis=1)
    low = ECI_SPEED_MIN_M_S if frame == "eci" else 0.0
    bad = np.flatnonzero((speed > SPEED_LIMIT_M_S) | (speed < low))
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"ephemeris.velocity_m_s: velocities must be m/s: |v| = {_g(speed[i])} at sample "
            f"{i}, expected {_g(low)}-{_g(SPEED_LIMIT_M_S)} for an Earth-orbiting satellite "
            f"({frame})"
        )
    step = np.diff(dt_s)
    chord = np.diff(position_m, axis=0) / step[:, None]
    mean_v = 0.5 * (velocity_m_s[1:] + velocity_m_s[:-1])
    mean_speed = np.linalg.norm(mean_v, axis=1)
    theta = np.linalg.norm(chord, axis=1) * step / radius[:-1]  # angle travelled
    allowed = mean_speed * (VELOCITY_CONSISTENCY + 0.25 * theta**2) + 1.0
    gap = np.linalg.norm(chord - mean_v, axis=1)
    bad = np.flatnonzero(~(gap <= allowed))
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"ephemeris.velocity_m_s: samples {i}-{i + 1} move at {np.linalg.norm(chord[i]):.6g} "
            f"m/s between their positions but their velocities say {mean_speed[i]:.6g} m/s "
            f"(differ by {gap[i]:.3g} m/s): a wrong position, velocity, time or unit"
            + (" (ecef velocities must be Earth-relative)" if frame == "ecef" else "")
        )


@attrs.frozen
class AttitudeSamples:
    """Attitude samples: the rotation from the body frame to ``frame``.

    Attributes:
        dt_s: sample times, seconds since the epoch, strictly increasing, ``(M,)``.
        quaternion_wxyz: unit quaternions, scalar first, ``(M, 4)``: body -> ``frame``.
        frame: ``"orbit"`` (roll/pitch/yaw w.r.t. the local orbital frame, Cartosat),
            ``"eci"`` or ``"ecef"``.
    """

    dt_s: FloatArray = attrs.field(converter=lambda v: _as_array(v, (), "attitude.dt_s"))
    quaternion_wxyz: FloatArray = attrs.field(
        converter=lambda v: _as_array(v, (4,), "attitude.quaternion_wxyz")
    )
    frame: AttitudeFrame = "orbit"

    def __attrs_post_init__(self) -> None:
        if self.quaternion_wxyz.shape[0] != self.dt_s.shape[0]:
            raise InputError(
                f"attitude: dt_s and quaternion_wxyz differ in length "
                f"({self.dt_s.shape[0]}, {self.quaternion_wxyz.shape[0]})"
            )
        _check_increasing(self.dt_s, "attitude.dt_s")
        if self.frame not in ("orbit", "eci", "ecef"):
            raise InputError(f"attitude.frame: must be orbit, eci or ecef, got {self.frame!r}")
        q = self.quaternion_wxyz
        norm = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(~(np.abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE))
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"attitude.quaternion_wxyz: sample {i} is not a unit quaternion: |q| = "
                f"{norm[i]:.9g} (allowed 1 +- {QUATERNION_NORM_TOLERANCE:g})"
            )
        q = q / norm[:, None]
        object.__setattr__(self, "quaternion_wxyz", q)
        # rotation angle between consecutive samples (q and -q are the same rotation)
        dot = np.clip(np.abs(np.sum(q[1:] * q[:-1], axis=1)), 0.0, 1.0)
        rate = 2.0 * np.arccos(dot) / np.diff(self.dt_s)
        bad = np.flatnonzero(rate > ATTITUDE_RATE_LIMIT_RAD_S)
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"attitude.quaternion_wxyz: the attitude turns at {np.degrees(rate[i]):.3g} "
                f"deg/s between samples {i} and {i + 1} (a satellite turns at most "
                f"{np.degrees(ATTITUDE_RATE_LIMIT_RAD_S):.3g} deg/s): a damaged sample"
            )

    @classmethod
    def from_quaternion_polynomials(
        cls,
        coeffs_wxyz: ArrayLike,
        dt_s: ArrayLike,
        *,
        dt_ref_s: float,
        scale_s: float,
        frame: AttitudeFrame = "ecef",
    ) -> AttitudeSamples:
        """Attitude delivered as one polynomial per quaternion component, sampled at ``dt_s``.

        Some products give the attitude not as samples but as polynomials of the four
        quaternion components in normalised time (Pleiades and SPOT 6/7 DIMAP, for instance):
        ``q_i(dt) = sum_k coeffs_wxyz[i][k] * tau**k`` with ``tau = (dt - dt_ref_s) / scale_s``.
        This evaluates them at ``dt_s`` and normalises each quaternion, so that a
        :class:`Trajectory` interpolates the samples (``interpolation="lagrange"``: 4-point
        Lagrange on rotation vectors). Sampled a few hundredths of a second apart, the
        interpolated attitude equals the polynomial one to far below 1e-9 rad for a satellite's
        smooth motion (tested). Sample the whole time range the sensor model evaluates (a line
        scanner also projects half an image beyond each end).

        Args:
            coeffs_wxyz: shape ``(4, K)``: the coefficients of ``w, x, y, z`` (scalar first), in
                increasing powers of ``tau`` (pad a shorter polynomial with zeros).
            dt_s: sample times, seconds since the trajectory epoch, strictly increasing.
            dt_ref_s: time of ``tau = 0``, seconds since the same epoch.
            scale_s: seconds per unit of ``tau`` (non-zero).
            frame: the frame the quaternions rotate the body to (``"ecef"``, ``"eci"`` or
                ``"orbit"``); the rotation is body -> ``frame``, as for the samples.

        Raises:
            InputError: malformed coefficients or times, a zero or non-finite scale, or a
                polynomial quaternion of (nearly) zero norm.
        """
        c = np.asarray(coeffs_wxyz, dtype=np.float64)
        if c.ndim != 2 or c.shape[0] != 4 or c.shape[1] < 1 or not np.all(np.isfinite(c)):
            raise InputError(
                "attitude polynomials: expected finite coefficients of shape (4, K), "
                f"got shape {c.shape}"
            )
        if not (np.isfinite(scale_s) and scale_s != 0.0 and np.isfinite(dt_ref_s)):
            raise InputError(
                f"attitude polynomials: invalid time reference {dt_ref_s!r} s / scale {scale_s!r} s"
            )
        t = _as_array(dt_s, (), "attitude.dt_s")
        tau = (t - float(dt_ref_s)) / float(scale_s)
        q = npoly.polyval(tau, c.T).T  # (N, 4)
        norm = np.linalg.norm(q, axis=1)
        if not np.all(norm > 1e-6):
            raise InputError("attitude polynomials: the quaternion vanishes at some sample time")
        return cls(t, q / norm[:, None], frame)


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
class Trajectory:
    """Position and attitude of a platform as continuous functions of time, with corrections.

    Build it with :meth:`from_samples`. Immutable: :meth:`with_parameters` returns a new one.

    Attributes:
        epoch_j2000_s: absolute time of ``dt_s = 0``, seconds since J2000 (UTC).
        attitude_frame: the frame the attitude samples refer to.
        attitude_correction_order, position_correction_order: polynomial order of the
            corrections (-1 = none), coefficients of normalised time ``tau``.
        parameters: the correction parameters (see module docstring), prefixed ``prefix``.
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
    _gmst0_rad: float = attrs.field(init=False)
    _gmst_rate: float = attrs.field(init=False)

    def __attrs_post_init__(self) -> None:
        object.__setattr__(self, "_gmst0_rad", float(frames.gmst_rad(self.epoch_j2000_s)))
        object.__setattr__(self, "_gmst_rate", float(frames.gmst_rate_rad_s(self.epoch_j2000_s)))

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

        # ephemeris in the inertial frame
        if ephemeris.frame == "ecef":
            gmst = (
                frames.gmst_rad(epoch_j2000_s)
                + frames.gmst_rate_rad_s(epoch_j2000_s) * ephemeris.dt_s
            )
            p_eci, v_eci = _ecef_to_eci_by_angle(gmst, ephemeris.position_m, ephemeris.velocity_m_s)
        else:
            p_eci, v_eci = ephemeris.position_m, ephemeris.velocity_m_s
        orbit_values = np.concatenate([p_eci, v_eci], axis=1)
        if isinstance(interpolation, str):
            points = order if interpolation == "polynomial" else lagrange_points
            orbit: TimeSeries = BuiltinSeries.fit(
                ephemeris.dt_s, orbit_values, interpolation, points, t_mid, t_half
            )
        else:
            orbit = interpolation.fit_series(
                ephemeris.dt_s, orbit_values, role="orbit", t_mid_s=t_mid, t_half_s=t_half
            )

        # attitude as three angles
        r_att = frames.quat_to_matrix(attitude.quaternion_wxyz)
        if attitude.frame == "orbit":
            r_ref = np.eye(3)
            angles = np.stack(frames.matrix_to_rpy(r_att), axis=-1)
        else:
            r_ref = r_att[attitude.dt_s.shape[0] // 2]
            angles = frames.matrix_to_rotvec(r_ref.T @ r_att)
        angles = np.unwrap(angles, axis=0)
        if isinstance(interpolation, str):
            att_points = min(order, 3) if interpolation == "polynomial" else min(lagrange_points, 4)
            ang: TimeSeries = BuiltinSeries.fit(
                attitude.dt_s, angles, interpolation, att_points, t_mid, t_half
            )
        else:
            ang = interpolation.fit_series(
                attitude.dt_s, angles, role="attitude", t_mid_s=t_mid, t_half_s=t_half
            )

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
    def with_parameters(
        self,
        values: dict[str, float] | None = None,
        free: dict[str, bool] | None = None,
        sigmas: dict[str, float] | None = None,
    ) -> Trajectory:
        """A new trajectory with some correction values / free flags / sigmas replaced."""
        params = replace_parameters(self.parameters, values, free, sigmas)
        return attrs.evolve(self, parameters=params)

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
    def gmst_rad(self, dt_s: ArrayLike) -> FloatArray:
        """Sidereal angle at ``dt_s`` (linear from the epoch: exact to 1e-14 rad over hours)."""
        return self._gmst0_rad + self._gmst_rate * np.asarray(dt_s, float)

    def state_eci(self, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Uncorrected inertial position (m) and velocity (m/s), each ``(..., 3)``."""
        values = self._orbit(np.asarray(dt_s, dtype=np.float64))
        return values[..., :3], values[..., 3:]

    def evaluate(self, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Corrected ``(P_ecef_m (..., 3), R_body_to_ecef (..., 3, 3))`` at ``dt_s``.

        The rotation chain is ``R_body_to_ecef = R_eci_to_ecef(t) @ R_orbit_to_eci(P, V) @
        R_correction(t) @ R_body_to_orbit(t)`` (for attitude given in eci/ecef,
        ``R_body_to_orbit = R_orbit_to_eci^T @ R_body_to_eci``), with the orbit frame of the
        corrected position ``P``.
        """
        p, r, _ = self._evaluate(dt_s, axes=False)
        return p, r

    def evaluate_with_axes(self, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`evaluate` plus the ECEF axes of the attitude corrections, ``(..., 3, 3)``
        (rows: roll, pitch, yaw): increasing the correction angle of axis ``a`` by ``d``
        (radians) rotates the body by ``d`` about ``axes[..., a, :]``, so
        ``dR_body_to_ecef / d angle_a = [axis_a]x @ R_body_to_ecef`` (analytic partials)."""
        return self._evaluate(dt_s, axes=True)

    def _evaluate(
        self, dt_s: ArrayLike, axes: bool
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        t = np.asarray(dt_s, dtype=np.float64)
        p_eci, v_eci = self.state_eci(t)
        tau = (t - self.t_mid_s) / self.t_half_s
        r_o2i = frames.orbit_to_eci_matrix(p_eci, v_eci)
        if self.position_correction_order >= 0:
            c = self._correction_coeffs("position", _POSITION_NAMES, self.position_correction_order)
            if c.any():
                d = npoly.polyval(tau, c)  # (3, ...): along, across, radial
                d_orbit = np.stack([d[0], d[1], -d[2]], axis=-1)  # radial up = -Z_o
                p_eci = p_eci + np.einsum("...ij,...j->...i", r_o2i, d_orbit)
                # the orbit frame follows the corrected position (it is defined by it)
                r_o2i = frames.orbit_to_eci_matrix(p_eci, v_eci)
        r_i2e = frames.rot_z(-self.gmst_rad(t))
        r_o2e = r_i2e @ r_o2i
        a = self._angles(t)
        if self.attitude_frame == "orbit":
            r_b2o = frames.rpy_to_matrix(a[..., 0], a[..., 1], a[..., 2])
        else:
            r_b2f = self._r_ref @ frames.small_rotation(a[..., 0], a[..., 1], a[..., 2])
            if self.attitude_frame == "eci":
                r_b2o = np.swapaxes(r_o2i, -1, -2) @ r_b2f
            else:
                r_b2o = np.swapaxes(r_o2e, -1, -2) @ r_b2f
        d = np.zeros((3, *t.shape))
        if self.attitude_correction_order >= 0:
            c = self._correction_coeffs("attitude", _ANGLE_NAMES, self.attitude_correction_order)
            if c.any():
                d = npoly.polyval(tau, c)
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
        gmst = self.gmst_rad(t)
        r_i2e = frames.rot_z(-gmst)
        p = np.einsum("...ij,...j->...i", r_i2e, p_eci)
        v = np.einsum("...ij,...j->...i", r_i2e, v_eci) - np.cross([0.0, 0.0, self._gmst_rate], p)
        return p, v

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
            )
        except KeyError as exc:
            raise InputError(f"trajectory: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"trajectory: invalid value: {exc}") from None


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


def _ecef_to_eci_by_angle(
    gmst_rad: FloatArray, p_ecef: FloatArray, v_ecef: FloatArray
) -> tuple[FloatArray, FloatArray]:
    r_e2i = frames.rot_z(gmst_rad)
    p = np.einsum("...ij,...j->...i", r_e2i, p_ecef)
    v_abs = v_ecef + np.cross([0.0, 0.0, frames.OMEGA_EARTH_RAD_S], p_ecef)
    return p, np.einsum("...ij,...j->...i", r_e2i, v_abs)


def _residuals(orbit_res: FloatArray, angle_res: FloatArray) -> tuple[tuple[float, ...], ...]:
    res = [orbit_res[:, i] for i in range(orbit_res.shape[1])] + [
        angle_res[:, i] for i in range(angle_res.shape[1])
    ]
    rms = tuple(float(np.sqrt(np.mean(r**2))) for r in res)
    mx = tuple(float(np.max(np.abs(r))) for r in res)
    return rms, mx
