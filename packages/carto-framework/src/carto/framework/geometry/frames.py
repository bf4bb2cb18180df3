"""Reference frames, time and rotations.

Conventions (tested in ``tests/framework/test_frames.py``, summarised in ``docs/conventions.md``):

Time
    ``t_s``: UTC seconds since the J2000 epoch 2000-01-01T12:00:00 UTC, leap seconds ignored
    (a product's times are differences within minutes, so this does not matter for geometry):
    ``t_s / 86400`` is the UTC quasi-Julian date less 2451545, as ERFA takes it. TT (for
    precession-nutation) and UT1 (for the Earth's rotation) follow from it through ERFA's
    leap-second table and the IERS UT1 - UTC.

Earth-fixed frame (ECEF)
    WGS84 geocentric Cartesian, metres (EPSG:4978). Geodetic coordinates are WGS84 longitude,
    latitude in degrees and height above the ellipsoid in metres (EPSG:4979), converted by pyproj.

Inertial frame (ECI)
    The GCRS (geocentric, ICRS axes: the frame star trackers and ephemerides refer to). The
    rotation to the ITRS (realised by WGS84 ECEF) is the IAU 2006/2000A chain of ERFA
    (:class:`EarthOrientation`): ``X_ecef = W R3(-ERA) C X_eci`` with ``C`` the GCRS -> CIRS
    precession-nutation (``c2i06a``), ``ERA`` the Earth rotation angle of UT1 and ``W`` the
    polar motion, UT1 - UTC and the pole from the IERS tables that astropy-iers-data installs
    (no downloads). About an epoch ``C`` and ``W`` are held constant and ``ERA`` linear: the
    precession then leaves 8e-12 rad per second of distance from the epoch (5e-10 rad a minute
    away, 0.3 mm on the ground from 700 km). Outside the tables (before 1973, or beyond the
    predictions about a year ahead) UT1 = UTC and the pole is the ITRS Z axis.

Orbit frame (local orbital, for roll/pitch/yaw)
    From the inertial position ``P`` and velocity ``V``: ``Z_o = -P/|P|`` (towards the Earth's
    centre), ``Y_o = -(P x V)/|P x V|`` (negative orbit normal), ``X_o = Y_o x Z_o`` (close to
    the velocity). ``R_orbit_to_eci`` has these axes as columns.

Roll, pitch, yaw
    ``R_body_to_orbit = Rz(yaw) @ Ry(pitch) @ Rx(roll)``: roll about X (along track), pitch
    about Y, yaw about Z (radians, right-handed, active rotations). With zero angles the body
    axes are the orbit axes.

Quaternions
    Scalar first ``(w, x, y, z)``, unit norm, Hamilton convention; ``quat_to_matrix(q)`` is the
    active rotation, so a quaternion "body to orbit" maps body-frame vectors to orbit-frame
    vectors like ``R_body_to_orbit``.
"""

from __future__ import annotations

import functools
import math

import attrs
import numpy as np
import pyproj
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

WGS84_A_M = 6378137.0
"""WGS84 semi-major axis, metres."""
WGS84_F = 1.0 / 298.257223563
"""WGS84 flattening."""
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
"""WGS84 semi-minor axis, metres."""
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""WGS84 first eccentricity squared."""
GM_M3_S2 = 3.986004418e14
"""Earth's gravitational parameter (WGS84), m^3/s^2."""
J2 = 1.08262668e-3
"""Earth's second zonal harmonic (EGM96, unnormalised)."""
OMEGA_EARTH_RAD_S = 7.2921151467e-5
"""Earth's rotation rate (WGS84), rad/s (inertial, sidereal)."""
SECONDS_PER_DAY = 86400.0


# ----------------------------------------------------------------------------- geodesy
@functools.cache
def _geodetic_to_ecef() -> pyproj.Transformer:
    return pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@functools.cache
def _ecef_to_geodetic() -> pyproj.Transformer:
    return pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def geodetic_to_ecef(lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
    """WGS84 geodetic (degrees, ellipsoidal metres) -> ECEF metres, shape ``(..., 3)``."""
    lon, lat, h = np.broadcast_arrays(
        np.asarray(lon_deg, float), np.asarray(lat_deg, float), np.asarray(h_m, float)
    )
    x, y, z = _geodetic_to_ecef().transform(lon, lat, h)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1).astype(np.float64)


def ecef_to_geodetic(xyz_m: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF metres ``(..., 3)`` -> WGS84 ``(lon_deg, lat_deg, h_m)``."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    lon, lat, h = _ecef_to_geodetic().transform(xyz[..., 0], xyz[..., 1], xyz[..., 2])
    return (
        np.asarray(lon, np.float64),
        np.asarray(lat, np.float64),
        np.asarray(h, np.float64),
    )


def ellipsoid_normal(lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
    """Unit upward normal of the WGS84 ellipsoid at geodetic ``(lon, lat)``, ECEF ``(..., 3)``."""
    lon = np.radians(np.asarray(lon_deg, float))
    lat = np.radians(np.asarray(lat_deg, float))
    return np.stack(
        np.broadcast_arrays(np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)),
        axis=-1,
    )


def enu_basis(lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
    """Rows: the ECEF unit vectors east, north, up at geodetic locations, shape ``(..., 3, 3)``
    (``(3, 3)`` for scalars); ``d_enu = enu_basis @ d_ecef``."""
    lon = np.radians(np.asarray(lon_deg, float))
    lat = np.radians(np.asarray(lat_deg, float))
    lon, lat = np.broadcast_arrays(lon, lat)
    east = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], -1)
    north = np.stack([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)], -1)
    return np.stack([east, north, ellipsoid_normal(lon_deg, lat_deg)], axis=-2)


# ----------------------------------------------------------------------------- time
J2000_JD = 2451545.0
_J2000_UTC = np.datetime64("2000-01-01T12:00:00", "ns")


def metres_per_radian(lat_deg: ArrayLike, h_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Metres per radian of longitude and of latitude at geodetic points: the radius of the
    parallel ``(N + h) cos(lat)`` and the meridian's ``M + h`` (WGS84 radii of curvature),
    which turn local east and north displacements into angles."""
    phi = np.radians(lat_deg)
    root = np.sqrt(1.0 - WGS84_E2 * np.sin(phi) ** 2)
    m_per_rad_lat = WGS84_A_M * (1.0 - WGS84_E2) / root**3 + h_m
    m_per_rad_lon = (WGS84_A_M / root + h_m) * np.cos(phi)
    return m_per_rad_lon, m_per_rad_lat


def utc_to_j2000_s(utc: str) -> float:
    """ISO-8601 UTC time (``"2026-03-01T05:12:33.250Z"``) -> seconds since J2000 (no leap s)."""
    text = str(utc).strip().removesuffix("Z").removesuffix("+00:00")
    try:
        stamp = np.datetime64(text, "ns")
    except ValueError as exc:
        from carto.framework.errors import InputError

        raise InputError(f"invalid UTC time {utc!r}: {exc}") from None
    return float((stamp - _J2000_UTC) / np.timedelta64(1, "ns")) * 1e-9


def j2000_s_to_utc(t_s: float) -> str:
    """Seconds since J2000 -> ISO-8601 UTC string with nanoseconds and a ``Z``."""
    stamp = _J2000_UTC + np.timedelta64(round(float(t_s) * 1e9), "ns")
    return str(stamp) + "Z"


def gmst_rad(t_s: ArrayLike) -> FloatArray:
    """Greenwich mean sidereal angle (IAU 1982, UT1 = UTC) at ``t_s`` seconds since J2000, rad.

    ``GMST = 67310.54841 s + (876600 h + 8640184.812866 s) T + 0.093104 s T^2 - 6.2e-6 s T^3``
    with ``T`` in Julian centuries of UT1 since J2000 (Vallado, eq. 3-47), reduced to [0, 2 pi).
    """
    t = np.asarray(t_s, dtype=np.float64)
    centuries = t / (SECONDS_PER_DAY * 36525.0)
    # split the big linear term to keep precision: 876600 h * T = t_s * (876600*3600)/(86400*36525)
    seconds = (
        67310.54841
        + t * (876600.0 * 3600.0) / (SECONDS_PER_DAY * 36525.0)
        + centuries * 8640184.812866
        + 0.093104 * centuries**2
        - 6.2e-6 * centuries**3
    )
    return np.mod(seconds, SECONDS_PER_DAY) * (2.0 * np.pi / SECONDS_PER_DAY)


def gmst_rate_rad_s(t_s: ArrayLike) -> FloatArray:
    """Time derivative of :func:`gmst_rad`, rad/s (about 7.2921158e-5)."""
    centuries = np.asarray(t_s, dtype=np.float64) / (SECONDS_PER_DAY * 36525.0)
    seconds_per_second = (
        876600.0 * 3600.0 + 8640184.812866 + 2 * 0.093104 * centuries - 3 * 6.2e-6 * centuries**2
    ) / (SECONDS_PER_DAY * 36525.0)
    return seconds_per_second * (2.0 * np.pi / SECONDS_PER_DAY)


def rot_z(angle_rad: ArrayLike) -> FloatArray:
    """Active rotation about Z by ``angle_rad``, shape ``(..., 3, 3)``."""
    a = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def rot_y(angle_rad: ArrayLike) -> FloatArray:
    """Active rotation about Y by ``angle_rad``, shape ``(..., 3, 3)``."""
    a = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack(
        [np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2
    )


def rot_x(angle_rad: ArrayLike) -> FloatArray:
    """Active rotation about X by ``angle_rad``, shape ``(..., 3, 3)``."""
    a = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack(
        [np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2
    )


ERA_RATE_RAD_S = 2.0 * math.pi * 1.00273781191135448 / SECONDS_PER_DAY
"""Rate of the Earth rotation angle, rad per UT1 second (IAU 2000)."""


def earth_orientation_parameters(t_s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(UT1 - UTC seconds, x_pole rad, y_pole rad)`` at ``t_s`` from the IERS tables
    (:mod:`carto.framework.geometry.iers`, as astropy's ``IERS_Auto``); zero outside them
    (see the module docstring)."""
    from carto.framework.geometry.iers import installed_table

    t = np.asarray(t_s, dtype=np.float64)
    dut1, xp, yp, inside = installed_table().interpolate(
        np.full(t.shape, J2000_JD), t / SECONDS_PER_DAY
    )
    arcsec = math.pi / (180.0 * 3600.0)
    return (
        np.where(inside, dut1, 0.0),
        np.where(inside, xp * arcsec, 0.0),
        np.where(inside, yp * arcsec, 0.0),
    )


def _time_scales(t_s: FloatArray) -> tuple[tuple[FloatArray, FloatArray], tuple, FloatArray]:
    """``((tt1, tt2), (ut11, ut12), (xp, yp))`` of UTC ``t_s`` (ERFA two-part dates)."""
    import erfa

    utc1 = np.full(t_s.shape, J2000_JD)
    utc2 = t_s / SECONDS_PER_DAY
    dut1, xp, yp = earth_orientation_parameters(t_s)
    tt = erfa.taitt(*erfa.utctai(utc1, utc2))
    ut1 = erfa.utcut1(utc1, utc2, dut1)
    return tt, ut1, np.stack([xp, yp])


@attrs.frozen(eq=False)
class EarthOrientation:
    """GCRS -> ITRS about an epoch: ``R(dt) = W @ rot_z(-(era0 + ERA_RATE dt)) @ C``.

    Attributes:
        c2i: GCRS -> CIRS (bias, precession, nutation; ERFA ``c2i06a``) at the epoch.
        era0_rad: the Earth rotation angle at the epoch.
        pom: TIRS -> ITRS polar motion (ERFA ``pom00``) at the epoch.
    """

    c2i: FloatArray
    era0_rad: float
    pom: FloatArray

    @classmethod
    def at(cls, epoch_j2000_s: float) -> EarthOrientation:
        """The orientation about ``epoch_j2000_s`` (cached: models on one epoch share it)."""
        return _orientation_at(float(epoch_j2000_s))

    def eci_to_ecef_matrix(self, dt_s: ArrayLike) -> FloatArray:
        """``R_eci_to_ecef`` at ``dt_s`` seconds after the epoch, ``(..., 3, 3)``."""
        era = self.era0_rad + ERA_RATE_RAD_S * np.asarray(dt_s, np.float64)
        return self.pom @ rot_z(-era) @ self.c2i

    @property
    def rotation_vector_ecef(self) -> FloatArray:
        """The Earth's angular velocity in the ITRS, rad/s (about the celestial pole)."""
        return ERA_RATE_RAD_S * self.pom[:, 2]

    def to_ecef(
        self, dt_s: ArrayLike, p_eci: ArrayLike, v_eci: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Inertial position and velocity -> Earth-fixed (velocity relative to the Earth)."""
        r = self.eci_to_ecef_matrix(dt_s)
        p = np.einsum("...ij,...j->...i", r, np.asarray(p_eci, float))
        v = np.einsum("...ij,...j->...i", r, np.asarray(v_eci, float))
        return p, v - np.cross(self.rotation_vector_ecef, p)

    def to_eci(
        self, dt_s: ArrayLike, p_ecef: ArrayLike, v_ecef: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Earth-fixed position and Earth-relative velocity -> inertial."""
        r_t = np.swapaxes(self.eci_to_ecef_matrix(dt_s), -1, -2)
        p_e = np.asarray(p_ecef, float)
        v_abs = np.asarray(v_ecef, float) + np.cross(self.rotation_vector_ecef, p_e)
        return np.einsum("...ij,...j->...i", r_t, p_e), np.einsum("...ij,...j->...i", r_t, v_abs)


@functools.lru_cache(maxsize=64)
def _orientation_at(epoch_j2000_s: float) -> EarthOrientation:
    import erfa

    (tt1, tt2), (ut11, ut12), (xp, yp) = _time_scales(np.asarray(epoch_j2000_s, np.float64))
    c2i = np.asarray(erfa.c2i06a(tt1, tt2), np.float64)
    era0 = float(erfa.era00(ut11, ut12))
    pom = np.asarray(erfa.pom00(xp, yp, erfa.sp00(tt1, tt2)), np.float64)
    return EarthOrientation(c2i, era0, pom)


def eci_to_ecef_matrix(t_s: ArrayLike) -> FloatArray:
    """``R_eci_to_ecef`` (GCRS -> ITRS, ERFA ``c2t06a``) at absolute ``t_s``, ``(..., 3, 3)``."""
    import erfa

    t = np.asarray(t_s, dtype=np.float64)
    (tt1, tt2), (ut11, ut12), (xp, yp) = _time_scales(t)
    return np.asarray(erfa.c2t06a(tt1, tt2, ut11, ut12, xp, yp), np.float64)


def eci_to_ecef(
    t_s: ArrayLike, position_eci_m: ArrayLike, velocity_eci_m_s: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray | None]:
    """Inertial position (and velocity) -> Earth-fixed, including the Earth-rotation term."""
    t = np.asarray(t_s, dtype=np.float64)
    r = eci_to_ecef_matrix(t)
    p = np.einsum("...ij,...j->...i", r, np.asarray(position_eci_m, float))
    if velocity_eci_m_s is None:
        return p, None
    omega = EarthOrientation.at(float(np.mean(t))).rotation_vector_ecef
    v = np.einsum("...ij,...j->...i", r, np.asarray(velocity_eci_m_s, float))
    return p, v - np.cross(omega, p)


def ecef_to_eci(
    t_s: ArrayLike, position_ecef_m: ArrayLike, velocity_ecef_m_s: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray | None]:
    """Earth-fixed position (and velocity) -> inertial, including the Earth-rotation term."""
    t = np.asarray(t_s, dtype=np.float64)
    r_t = np.swapaxes(eci_to_ecef_matrix(t), -1, -2)
    p_ecef = np.asarray(position_ecef_m, float)
    p = np.einsum("...ij,...j->...i", r_t, p_ecef)
    if velocity_ecef_m_s is None:
        return p, None
    omega = EarthOrientation.at(float(np.mean(t))).rotation_vector_ecef
    v_ecef = np.asarray(velocity_ecef_m_s, float) + np.cross(omega, p_ecef)
    return p, np.einsum("...ij,...j->...i", r_t, v_ecef)


def orbit_to_eci_matrix(position_eci_m: ArrayLike, velocity_eci_m_s: ArrayLike) -> FloatArray:
    """``R_orbit_to_eci`` from inertial position and velocity, ``(..., 3, 3)`` (columns X,Y,Z_o)."""
    p = np.asarray(position_eci_m, float)
    v = np.asarray(velocity_eci_m_s, float)
    z = -p / np.linalg.norm(p, axis=-1, keepdims=True)
    h = np.cross(p, v)
    y = -h / np.linalg.norm(h, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


# ----------------------------------------------------------------------------- attitude
def rpy_to_matrix(roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """``R_body_to_orbit = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, shape ``(..., 3, 3)``."""
    roll, pitch, yaw = np.broadcast_arrays(
        np.asarray(roll_rad, float), np.asarray(pitch_rad, float), np.asarray(yaw_rad, float)
    )
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def matrix_to_rpy(matrix: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of :func:`rpy_to_matrix`: ``(roll, pitch, yaw)`` radians, pitch in [-pi/2, pi/2]."""
    m = np.asarray(matrix, float)
    pitch = -np.arcsin(np.clip(m[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(m[..., 2, 1], m[..., 2, 2])
    yaw = np.arctan2(m[..., 1, 0], m[..., 0, 0])
    return roll, pitch, yaw


def quat_to_matrix(quat_wxyz: ArrayLike) -> FloatArray:
    """Unit quaternions ``(w, x, y, z)`` (normalised here) -> rotation matrices ``(..., 3, 3)``."""
    q = np.asarray(quat_wxyz, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(matrix: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(w, x, y, z)`` with ``w >= 0``."""
    m = np.asarray(matrix, float)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Shepperd's method: pick the largest of 4w^2, 4x^2, 4y^2, 4z^2 for stability
    cands = np.stack([trace, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], axis=-1)
    k = np.argmax(cands, axis=-1)
    r = lambda i, j: m[..., i, j]  # noqa: E731
    # case w largest
    s = np.sqrt(np.maximum(1.0 + trace, 1e-300)) * 2
    qw = np.stack(
        [0.25 * s, (r(2, 1) - r(1, 2)) / s, (r(0, 2) - r(2, 0)) / s, (r(1, 0) - r(0, 1)) / s], -1
    )
    s = np.sqrt(np.maximum(1.0 + r(0, 0) - r(1, 1) - r(2, 2), 1e-300)) * 2
    qx = np.stack(
        [(r(2, 1) - r(1, 2)) / s, 0.25 * s, (r(0, 1) + r(1, 0)) / s, (r(0, 2) + r(2, 0)) / s], -1
    )
    s = np.sqrt(np.maximum(1.0 + r(1, 1) - r(0, 0) - r(2, 2), 1e-300)) * 2
    qy = np.stack(
        [(r(0, 2) - r(2, 0)) / s, (r(0, 1) + r(1, 0)) / s, 0.25 * s, (r(1, 2) + r(2, 1)) / s], -1
    )
    s = np.sqrt(np.maximum(1.0 + r(2, 2) - r(0, 0) - r(1, 1), 1e-300)) * 2
    qz = np.stack(
        [(r(1, 0) - r(0, 1)) / s, (r(0, 2) + r(2, 0)) / s, (r(1, 2) + r(2, 1)) / s, 0.25 * s], -1
    )
    q = np.choose(k[..., None], [qw, qx, qy, qz])
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def small_rotation(rx_rad: ArrayLike, ry_rad: ArrayLike, rz_rad: ArrayLike) -> FloatArray:
    """Rotation by the rotation vector ``(rx, ry, rz)`` (Rodrigues), shape ``(..., 3, 3)``.

    Exact for any angle; used for corrections, which are small.
    """
    v = np.stack(np.broadcast_arrays(*(np.asarray(a, float) for a in (rx_rad, ry_rad, rz_rad))), -1)
    theta = np.linalg.norm(v, axis=-1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = v / safe[..., None]
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    kmat = np.stack(
        [
            np.stack([zero, -kz, ky], -1),
            np.stack([kz, zero, -kx], -1),
            np.stack([-ky, kx, zero], -1),
        ],
        -2,
    )
    s = np.where(theta > 1e-12, np.sin(theta), theta)[..., None, None]
    c1 = np.where(theta > 1e-12, 1 - np.cos(theta), 0.5 * theta**2)[..., None, None]
    eye = np.broadcast_to(np.eye(3), kmat.shape)
    return eye + s * kmat + c1 * (kmat @ kmat)


def matrix_to_rotvec(matrix: ArrayLike) -> FloatArray:
    """Rotation matrices -> rotation vectors ``(..., 3)`` (axis times angle, angle in [0, pi))."""
    q = matrix_to_quat(matrix)
    w = np.clip(q[..., 0], -1.0, 1.0)
    vec = q[..., 1:]
    sin_half = np.linalg.norm(vec, axis=-1)
    angle = 2.0 * np.arctan2(sin_half, w)
    scale = np.where(sin_half > 1e-15, angle / np.where(sin_half > 1e-15, sin_half, 1.0), 2.0)
    return vec * scale[..., None]
