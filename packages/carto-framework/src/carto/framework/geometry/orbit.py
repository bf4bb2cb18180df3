"""Orbits: Keplerian elements, two-body + J2 propagation, sun-synchronous orbits.

All states are in the inertial frame of :mod:`carto.framework.geometry.frames` (ECI: ECEF rotated by
GMST), metres and m/s; times ``dt_s`` are seconds since an epoch. Propagation integrates
``a = -GM r / |r|^3 + a_J2(r)`` with scipy's DOP853 (relative tolerance 1e-12), which is what a
few minutes of a low orbit need to stay within millimetres of the reference solution.
"""

from __future__ import annotations

import math

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames

FloatArray = NDArray[np.float64]

TROPICAL_YEAR_S = 365.2421897 * 86400.0


@attrs.frozen
class OrbitElements:
    """Osculating Keplerian elements at the epoch (angles in radians, lengths in metres)."""

    semi_major_axis_m: float
    eccentricity: float
    inclination_rad: float
    raan_rad: float
    arg_perigee_rad: float
    mean_anomaly_rad: float

    def __attrs_post_init__(self) -> None:
        if not self.semi_major_axis_m > frames.WGS84_A_M:
            raise InputError(
                f"orbit: semi-major axis {self.semi_major_axis_m} m is inside the Earth"
            )
        if not 0.0 <= self.eccentricity < 1.0:
            raise InputError(f"orbit: eccentricity must be in [0, 1), got {self.eccentricity}")

    @property
    def period_s(self) -> float:
        """Keplerian period, seconds."""
        return 2.0 * math.pi * math.sqrt(self.semi_major_axis_m**3 / frames.GM_M3_S2)


def elements_to_state(el: OrbitElements) -> tuple[FloatArray, FloatArray]:
    """Inertial position (m) and velocity (m/s) from Keplerian elements."""
    e = el.eccentricity
    m = el.mean_anomaly_rad
    ecc_anomaly = m
    for _ in range(30):  # Newton on Kepler's equation
        ecc_anomaly -= (ecc_anomaly - e * math.sin(ecc_anomaly) - m) / (
            1 - e * math.cos(ecc_anomaly)
        )
    nu = 2 * math.atan2(
        math.sqrt(1 + e) * math.sin(ecc_anomaly / 2), math.sqrt(1 - e) * math.cos(ecc_anomaly / 2)
    )
    a = el.semi_major_axis_m
    p = a * (1 - e * e)
    r = p / (1 + e * math.cos(nu))
    mu = frames.GM_M3_S2
    r_pf = np.array([r * math.cos(nu), r * math.sin(nu), 0.0])
    v_pf = np.array(
        [-math.sqrt(mu / p) * math.sin(nu), math.sqrt(mu / p) * (e + math.cos(nu)), 0.0]
    )
    rot = (
        frames.rot_z(el.raan_rad)
        @ frames.rot_x(el.inclination_rad)
        @ frames.rot_z(el.arg_perigee_rad)
    )
    return rot @ r_pf, rot @ v_pf


def j2_acceleration(position_m: FloatArray) -> FloatArray:
    """Acceleration of the J2 zonal harmonic, m/s^2, for inertial positions ``(..., 3)``."""
    x, y, z = position_m[..., 0], position_m[..., 1], position_m[..., 2]
    r2 = x * x + y * y + z * z
    r = np.sqrt(r2)
    k = -1.5 * frames.J2 * frames.GM_M3_S2 * frames.WGS84_A_M**2 / r**5
    f = 5.0 * z * z / r2
    return np.stack([k * x * (1 - f), k * y * (1 - f), k * z * (3 - f)], axis=-1)


def propagate(
    position_m: ArrayLike, velocity_m_s: ArrayLike, dt_s: ArrayLike, *, j2: bool = True
) -> tuple[FloatArray, FloatArray]:
    """Propagate an inertial state given at ``dt_s = 0`` to the times ``dt_s`` (any order).

    Returns:
        positions ``(N, 3)`` (m) and velocities ``(N, 3)`` (m/s) at ``dt_s``.
    """
    from scipy.integrate import solve_ivp  # here: it imports scipy.stats (0.5 s of start-up)

    t = np.atleast_1d(np.asarray(dt_s, dtype=np.float64))
    y0 = np.concatenate([np.asarray(position_m, float), np.asarray(velocity_m_s, float)])

    def rhs(_t: float, y: FloatArray) -> FloatArray:
        r = y[:3]
        acc = -frames.GM_M3_S2 * r / np.linalg.norm(r) ** 3
        if j2:
            acc = acc + j2_acceleration(r)
        return np.concatenate([y[3:], acc])

    out = np.empty((t.size, 6))
    for sign in (-1.0, 1.0):
        mask = (t < 0) if sign < 0 else (t >= 0)
        if not np.any(mask):
            continue
        times = t[mask]
        order = np.argsort(sign * times)
        span = (0.0, float(times[order[-1]])) if times.size else (0.0, 0.0)
        if span[1] == 0.0:
            out[np.flatnonzero(mask)] = y0
            continue
        sol = solve_ivp(rhs, span, y0, method="DOP853", t_eval=times[order], rtol=1e-12, atol=1e-6)
        idx = np.flatnonzero(mask)[order]
        out[idx] = sol.y.T
    return out[:, :3], out[:, 3:]


def sun_synchronous_inclination(semi_major_axis_m: float, eccentricity: float = 0.0) -> float:
    """Inclination (rad) whose J2 nodal precession follows the mean Sun (one turn a year)."""
    a = semi_major_axis_m
    n = math.sqrt(frames.GM_M3_S2 / a**3)
    p = a * (1 - eccentricity**2)
    rate = 2 * math.pi / TROPICAL_YEAR_S
    cos_i = -rate / (1.5 * n * frames.J2 * (frames.WGS84_A_M / p) ** 2)
    if not -1.0 <= cos_i <= 1.0:
        raise InputError(f"orbit: no sun-synchronous inclination at a = {a:.0f} m")
    return math.acos(cos_i)


def nodal_precession_rad_s(el: OrbitElements) -> float:
    """Secular J2 drift of the right ascension of the ascending node, rad/s."""
    a = el.semi_major_axis_m
    n = math.sqrt(frames.GM_M3_S2 / a**3)
    p = a * (1 - el.eccentricity**2)
    return -1.5 * n * frames.J2 * (frames.WGS84_A_M / p) ** 2 * math.cos(el.inclination_rad)


def circular_orbit_over(
    lon_deg: float,
    lat_deg: float,
    epoch_j2000_s: float,
    altitude_m: float,
    inclination_rad: float,
    *,
    descending: bool = True,
) -> OrbitElements:
    """Circular orbit passing over geodetic ``(lon, lat)`` at the epoch.

    The satellite is at the epoch on the geocentric radius through the point (so the point is
    at nadir up to the small angle between the geocentric radius and the ellipsoid normal,
    <= 0.19 deg). The argument of latitude follows from the point's inertial declination and
    the pass direction; the right ascension of the node from its inertial right ascension.
    """
    # the point's inertial direction: declination and right ascension
    x_eci, _ = frames.ecef_to_eci(epoch_j2000_s, frames.geodetic_to_ecef(lon_deg, lat_deg, 0.0))
    lat = math.asin(float(x_eci[2]) / float(np.linalg.norm(x_eci)))
    inc = inclination_rad
    if abs(math.sin(lat)) > abs(math.sin(inc)) + 1e-12:
        raise InputError(
            f"orbit: latitude {lat_deg} deg is never overflown at inclination "
            f"{math.degrees(inc):.2f} deg"
        )
    u = math.asin(max(-1.0, min(1.0, math.sin(lat) / math.sin(inc))))
    if descending:
        u = math.pi - u
    # right ascension of the point: alpha = raan + atan2(cos i sin u, cos u)
    alpha = math.atan2(float(x_eci[1]), float(x_eci[0]))
    raan = alpha - math.atan2(math.cos(inc) * math.sin(u), math.cos(u))
    return OrbitElements(frames.WGS84_A_M + altitude_m, 0.0, inc, raan % (2 * math.pi), 0.0, u)
