"""Ephemeris and attitude samples as a product delivers them, checked when they are built:
numbers in metres, seconds and unit quaternions, strictly increasing times, an Earth orbit
whose velocities agree with its positions, attitudes without jumps. A
:class:`~carto.framework.geometry.trajectory.Trajectory` is fitted to them."""

from __future__ import annotations

from typing import Any, Literal

import attrs
import numpy as np
from numpy.polynomial import polynomial as npoly
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError

FloatArray = NDArray[np.float64]

EphemerisFrame = Literal["eci", "ecef"]
AttitudeFrame = Literal["orbit", "eci", "ecef"]


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
