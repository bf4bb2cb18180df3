"""Frames, time and rotations against closed forms and published values."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry import frames


def test_gmst_matches_vallado_example():
    # Vallado, Fundamentals of Astrodynamics, example 3-5: 1992-08-20 12:14:00 UT1
    t = frames.utc_to_j2000_s("1992-08-20T12:14:00")
    assert np.degrees(frames.gmst_rad(t)) == pytest.approx(152.578787886, abs=1e-6)


def test_gmst_rate_is_the_sidereal_rate():
    t = frames.utc_to_j2000_s("2026-03-01T05:00:00Z")
    numeric = (frames.gmst_rad(t + 10.0) - frames.gmst_rad(t - 10.0)) / 20.0
    assert frames.gmst_rate_rad_s(t) == pytest.approx(numeric, rel=1e-9)
    assert frames.gmst_rate_rad_s(t) == pytest.approx(frames.OMEGA_EARTH_RAD_S, rel=1e-6)


def test_utc_round_trip_and_errors():
    # float64 seconds since J2000 resolve ~0.1 us in 2026 (why models keep an epoch)
    t = frames.utc_to_j2000_s("2026-03-01T05:12:33.123456789Z")
    assert frames.j2000_s_to_utc(t).startswith("2026-03-01T05:12:33.123456")
    assert frames.utc_to_j2000_s("2000-01-01T12:00:00Z") == 0.0
    with pytest.raises(InputError, match="invalid UTC time"):
        frames.utc_to_j2000_s("yesterday")


def test_geodetic_to_ecef_closed_form():
    lon, lat, h = np.array([2.23, -120.0]), np.array([30.5, -45.0]), np.array([150.0, 4000.0])
    phi, lam = np.radians(lat), np.radians(lon)
    n = frames.WGS84_A_M / np.sqrt(1 - frames.WGS84_E2 * np.sin(phi) ** 2)
    expected = np.stack(
        [
            (n + h) * np.cos(phi) * np.cos(lam),
            (n + h) * np.cos(phi) * np.sin(lam),
            (n * (1 - frames.WGS84_E2) + h) * np.sin(phi),
        ],
        -1,
    )
    xyz = frames.geodetic_to_ecef(lon, lat, h)
    np.testing.assert_allclose(xyz, expected, atol=1e-6)
    back = frames.ecef_to_geodetic(xyz)
    np.testing.assert_allclose(back[0], lon, atol=1e-12)
    np.testing.assert_allclose(back[1], lat, atol=1e-12)
    np.testing.assert_allclose(back[2], h, atol=1e-6)


def test_earth_fixed_point_has_inertial_velocity_omega_cross_r():
    t = 1e8
    p_ecef = frames.geodetic_to_ecef(10.0, 40.0, 0.0)
    p_eci, v_eci = frames.ecef_to_eci(t, p_ecef, np.zeros(3))
    omega = frames.EarthOrientation.at(t).rotation_vector_ecef  # about the celestial pole
    assert np.linalg.norm(omega) == pytest.approx(frames.OMEGA_EARTH_RAD_S, rel=1e-9)
    np.testing.assert_allclose(
        np.linalg.norm(v_eci), np.linalg.norm(np.cross(omega, p_ecef)), rtol=1e-12
    )
    p2, v2 = frames.eci_to_ecef(t, p_eci, v_eci)
    np.testing.assert_allclose(p2, p_ecef, atol=1e-6)
    np.testing.assert_allclose(v2, 0.0, atol=1e-9)


def test_orbit_frame_axes():
    p = np.array([7e6, 0.0, 0.0])
    v = np.array([0.0, 7.5e3, 0.0])  # prograde equatorial
    r = frames.orbit_to_eci_matrix(p, v)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(r[:, 2], [-1, 0, 0], atol=1e-15)  # Z to the Earth's centre
    np.testing.assert_allclose(r[:, 0], [0, 1, 0], atol=1e-15)  # X along the velocity
    np.testing.assert_allclose(r[:, 1], [0, 0, -1], atol=1e-15)  # Y = -orbit normal
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_rpy_sequence_and_quaternions():
    roll, pitch, yaw = 0.1, -0.2, 0.3
    expected = frames.rot_z(yaw) @ frames.rot_y(pitch) @ frames.rot_x(roll)
    m = frames.rpy_to_matrix(roll, pitch, yaw)
    np.testing.assert_allclose(m, expected, atol=1e-15)
    np.testing.assert_allclose(frames.matrix_to_rpy(m), (roll, pitch, yaw), atol=1e-14)
    # quaternion of a rotation by theta about Z is (cos theta/2, 0, 0, sin theta/2)
    theta = 0.7
    q = np.array([np.cos(theta / 2), 0, 0, np.sin(theta / 2)])
    np.testing.assert_allclose(frames.quat_to_matrix(q), frames.rot_z(theta), atol=1e-15)
    rng = np.random.default_rng(1)
    qs = rng.normal(size=(1000, 4))
    qs /= np.linalg.norm(qs, axis=1, keepdims=True)
    qs[qs[:, 0] < 0] *= -1
    np.testing.assert_allclose(frames.matrix_to_quat(frames.quat_to_matrix(qs)), qs, atol=1e-12)


def test_rotation_vectors():
    rng = np.random.default_rng(2)
    v = rng.normal(size=(500, 3)) * 0.5
    m = frames.small_rotation(v[:, 0], v[:, 1], v[:, 2])
    np.testing.assert_allclose(frames.matrix_to_rotvec(m), v, atol=1e-12)
    # a rotation vector along Z is rot_z
    np.testing.assert_allclose(frames.small_rotation(0, 0, 0.3), frames.rot_z(0.3), atol=1e-15)
    np.testing.assert_allclose(frames.small_rotation(0, 0, 0), np.eye(3), atol=0)


def test_inertial_to_earth_fixed_is_astropys_gcrs_to_itrs():
    """The GCRS -> ITRS rotation against astropy's coordinate transformation (IAU 2006/2000A,
    UT1 and polar motion from the IERS tables), and the linear-ERA form a trajectory uses
    against the full chain over two minutes."""
    from astropy import units as u
    from astropy.coordinates import GCRS, ITRS, CartesianRepresentation
    from astropy.time import Time
    from astropy.utils import iers

    epoch = "2026-03-01T05:18:12Z"
    t0 = frames.utc_to_j2000_s(epoch)
    dt = np.array([-60.0, -1.5, 0.0, 37.25, 60.0])
    v = np.array([1.2e6, -6.1e6, 2.9e6])
    with iers.conf.set_temp("auto_download", False):
        t = Time("2026-03-01T05:18:12", scale="utc") + dt * u.s
        gcrs = GCRS(CartesianRepresentation(*(np.broadcast_to(v, (5, 3)).T * u.m)), obstime=t)
        itrs = gcrs.transform_to(ITRS(obstime=t)).cartesian.xyz.to_value(u.m).T
    full = np.einsum("nij,j->ni", frames.eci_to_ecef_matrix(t0 + dt), v)
    linear = np.einsum("nij,j->ni", frames.EarthOrientation.at(t0).eci_to_ecef_matrix(dt), v)
    assert np.abs(full - itrs).max() < 1e-4  # metres at 7000 km: 1.4e-11 rad (float J2000 s)
    assert np.abs(linear - itrs).max() < 2e-3  # precession over 60 s: 5e-10 rad
    # not the sidereal-angle-only frame: precession since J2000 alone is ~0.36 deg
    gmst_only = np.einsum("nij,j->ni", frames.rot_z(-frames.gmst_rad(t0 + dt)), v)
    assert np.abs(gmst_only - itrs).max() > 1e4


def test_metres_per_radian_match_the_ellipsoid():
    """A small step east and north on the ellipsoid, divided by its angle."""
    lat, h = np.array([0.0, 19.5, -60.0]), np.array([0.0, 500.0, 2000.0])
    m_lon, m_lat = frames.metres_per_radian(lat, h)
    d = 1e-6  # degrees
    east = frames.geodetic_to_ecef(10.0 + d, lat, h) - frames.geodetic_to_ecef(10.0, lat, h)
    north = frames.geodetic_to_ecef(10.0, lat + d, h) - frames.geodetic_to_ecef(10.0, lat, h)
    np.testing.assert_allclose(m_lon, np.linalg.norm(east, axis=-1) / np.radians(d), rtol=1e-6)
    np.testing.assert_allclose(m_lat, np.linalg.norm(north, axis=-1) / np.radians(d), rtol=1e-6)
