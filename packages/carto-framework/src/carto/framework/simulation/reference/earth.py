"""The Earth of the reference geometry: time, GCRS <-> ITRS, geodesy and physical constants.

**Time.** Instants are ``dt_s`` SI seconds after an epoch given as a UTC string; astropy's
:class:`~astropy.time.Time` turns them into TT (precession-nutation) and UT1 (Earth rotation
angle, with UT1 - UTC from the IERS tables).

**Frames.** The inertial frame is the GCRS (geocentric, axes of the ICRS: what star trackers
refer attitude to); the Earth-fixed frame is the ITRS, realised by WGS84 (EPSG:4978). The
rotation between them is astropy's transformation (IAU 2006/2000A precession-nutation, Earth
rotation angle, polar motion; astropy-iers-data tables, downloads switched off), evaluated on
a grid of instants one second apart and interpolated by constant-rate rotation between them
(the Earth's orientation changes at a constant rate to better than 1e-13 rad over a second).

**Geodesy.** WGS84 geodetic coordinates through pyproj.
"""

from __future__ import annotations

import functools
import math

import attrs
import numpy as np
import pyproj
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.simulation.reference import rotations

FloatArray = NDArray[np.float64]

SPEED_OF_LIGHT_M_S = 299_792_458.0
GM_M3_S2 = 3.986004418e14
"""WGS84 gravitational parameter."""
J2 = 1.08262668e-3
EARTH_RADIUS_M = 6_378_137.0
EARTH_ROTATION_RAD_S = 7.292115146706979e-5
"""The Earth rotation angle's rate, radians per UT1 second (IAU 2000)."""
GRID_STEP_S = 1.0


def _iers_settings():
    from astropy.utils import iers

    return iers.conf.set_temp("auto_download", False)


def _time(epoch_utc: str, dt_s: ArrayLike):
    from astropy.time import Time, TimeDelta

    return Time(epoch_utc, scale="utc") + TimeDelta(np.asarray(dt_s, float), format="sec")


def gcrs_to_itrs_exact(epoch_utc: str, dt_s: ArrayLike) -> FloatArray:
    """``R (..., 3, 3)`` with ``x_itrs = R x_gcrs`` at each instant, straight from astropy's
    GCRS -> ITRS transformation of three basis vectors."""
    from astropy import units as u
    from astropy.coordinates import GCRS, ITRS, CartesianRepresentation

    dt = np.asarray(dt_s, float)
    flat = dt.reshape(-1)
    with _iers_settings():
        t = _time(epoch_utc, flat)[:, None]
        scale = 1.0e7
        basis = np.eye(3) * scale
        n = flat.size
        rep = CartesianRepresentation(*(np.broadcast_to(basis[i], (n, 3)) * u.m for i in range(3)))
        out = GCRS(rep, obstime=t).transform_to(ITRS(obstime=t)).cartesian
        cols = np.stack([out.x.to_value(u.m), out.y.to_value(u.m), out.z.to_value(u.m)], axis=1)
    return (cols / scale).reshape(*dt.shape, 3, 3)


@attrs.frozen(eq=False)
class EarthOrientation:
    """GCRS -> ITRS over a time span: astropy at instants ``GRID_STEP_S`` apart, constant-rate
    rotation (quaternion slerp) between them."""

    epoch_utc: str
    t0_s: float
    quaternions: FloatArray  # (K, 4) GCRS -> ITRS at t0 + k * GRID_STEP_S

    @classmethod
    def over(cls, epoch_utc: str, span_s: tuple[float, float]) -> EarthOrientation:
        lo = math.floor(span_s[0] / GRID_STEP_S) - 1
        hi = math.ceil(span_s[1] / GRID_STEP_S) + 1
        grid = np.arange(lo, hi + 1) * GRID_STEP_S
        q = rotations.from_matrix(gcrs_to_itrs_exact(epoch_utc, grid))
        return cls(epoch_utc, float(grid[0]), q)

    @property
    def span_s(self) -> tuple[float, float]:
        return self.t0_s, self.t0_s + (len(self.quaternions) - 1) * GRID_STEP_S

    def quaternion(self, dt_s: ArrayLike) -> FloatArray:
        """GCRS -> ITRS quaternions at ``dt_s (...)``."""
        t = np.asarray(dt_s, float)
        lo, hi = self.span_s
        if t.size and (np.nanmin(t) < lo or np.nanmax(t) > hi):
            raise InputError(
                f"reference Earth orientation: instants {np.nanmin(t):.3f}..{np.nanmax(t):.3f} s "
                f"outside the prepared span {lo:.1f}..{hi:.1f} s"
            )
        x = (t - self.t0_s) / GRID_STEP_S
        k = np.clip(np.floor(np.nan_to_num(x)).astype(int), 0, len(self.quaternions) - 2)
        return rotations.slerp(self.quaternions[k], self.quaternions[k + 1], x - k)

    def matrix(self, dt_s: ArrayLike) -> FloatArray:
        """``R_gcrs_to_itrs (..., 3, 3)``."""
        return rotations.to_matrix(self.quaternion(dt_s))

    def rotation_vector_gcrs(self, dt_s: ArrayLike) -> FloatArray:
        """The Earth's angular velocity in the GCRS, rad/s ``(..., 3)`` (the rotation axis
        from two neighbouring instants)."""
        t = np.asarray(dt_s, float)
        h = 0.5
        # an Earth-fixed point has GCRS coordinates g(t) = R(t)^T e, so g(t + h) = W g(t - h)
        # with W = R(t + h)^T R(t - h), a rotation by 2 h |omega| about omega
        r0 = self.matrix(t - h)
        r1 = self.matrix(t + h)
        w = np.swapaxes(r1, -1, -2) @ r0
        angle_axis = np.stack(
            [w[..., 2, 1] - w[..., 1, 2], w[..., 0, 2] - w[..., 2, 0], w[..., 1, 0] - w[..., 0, 1]],
            axis=-1,
        )
        return 0.5 * angle_axis / (2.0 * h)


@functools.cache
def _to_ecef() -> pyproj.Transformer:
    return pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@functools.cache
def _to_geodetic() -> pyproj.Transformer:
    return pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def geodetic_to_itrs(lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
    lon, lat, h = np.broadcast_arrays(
        np.asarray(lon_deg, float), np.asarray(lat_deg, float), np.asarray(h_m, float)
    )
    x, y, z = _to_ecef().transform(lon, lat, h)
    return np.stack([np.asarray(x), np.asarray(y), np.asarray(z)], axis=-1)


def itrs_to_geodetic(x_m: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    x = np.asarray(x_m, float)
    lon, lat, h = _to_geodetic().transform(x[..., 0], x[..., 1], x[..., 2])
    return np.asarray(lon), np.asarray(lat), np.asarray(h)


def up_direction(lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
    """The ellipsoid normal (geodetic up) in the ITRS."""
    lon = np.radians(np.asarray(lon_deg, float))
    lat = np.radians(np.asarray(lat_deg, float))
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
