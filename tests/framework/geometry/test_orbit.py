"""Orbits against Kepler and J2 theory."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry import frames, orbit

EPOCH = frames.utc_to_j2000_s("2026-03-01T05:00:00Z")


def test_sun_synchronous_inclination_of_the_presets():
    # DESIGN: Cartosat-1 618 km, i = 97.87 deg; Cartosat-2 630 km, i = 97.91 deg
    i1 = math.degrees(orbit.sun_synchronous_inclination(frames.WGS84_A_M + 618e3))
    i2 = math.degrees(orbit.sun_synchronous_inclination(frames.WGS84_A_M + 630e3))
    assert i1 == pytest.approx(97.87, abs=0.02)
    assert i2 == pytest.approx(97.91, abs=0.02)


def test_two_body_propagation_is_keplerian():
    el = orbit.OrbitElements(frames.WGS84_A_M + 618e3, 0.001, 1.7, 0.3, 0.5, 1.0)
    p0, v0 = orbit.elements_to_state(el)
    # vis-viva: v^2 = GM (2/r - 1/a)
    r = np.linalg.norm(p0)
    assert np.linalg.norm(v0) ** 2 == pytest.approx(
        frames.GM_M3_S2 * (2 / r - 1 / el.semi_major_axis_m), rel=1e-12
    )
    # one Keplerian period later the state is back
    p1, _ = orbit.propagate(p0, v0, [el.period_s], j2=False)
    assert np.linalg.norm(p1[0] - p0) < 1e-3
    # mean anomaly advance matches elements_to_state at another time
    dt = 300.0
    n = 2 * math.pi / el.period_s
    el_t = orbit.OrbitElements(
        el.semi_major_axis_m,
        el.eccentricity,
        el.inclination_rad,
        el.raan_rad,
        el.arg_perigee_rad,
        el.mean_anomaly_rad + n * dt,
    )
    p_expected, _ = orbit.elements_to_state(el_t)
    p_prop, _ = orbit.propagate(p0, v0, [dt], j2=False)
    assert np.linalg.norm(p_prop[0] - p_expected) < 1e-3


def test_j2_nodal_precession_matches_theory():
    a = frames.WGS84_A_M + 618e3
    el = orbit.OrbitElements(a, 0.0, orbit.sun_synchronous_inclination(a), 1.0, 0.0, 0.0)
    p0, v0 = orbit.elements_to_state(el)
    t = np.array([10 * el.period_s])
    p, v = orbit.propagate(p0, v0, t)

    def raan(p, v):
        h = np.cross(p, v)
        return math.atan2(h[0], -h[1])

    drift = (raan(p[0], v[0]) - raan(p0, v0)) / t[0]
    expected = orbit.nodal_precession_rad_s(el)  # ~ +0.9856 deg/day
    assert expected == pytest.approx(2 * math.pi / orbit.TROPICAL_YEAR_S, rel=1e-9)
    assert drift == pytest.approx(expected, rel=0.05)  # short-period terms spoil a few %


def test_circular_orbit_over_a_target_and_its_speed():
    inc = orbit.sun_synchronous_inclination(frames.WGS84_A_M + 618e3)
    el = orbit.circular_orbit_over(78.0, 20.0, EPOCH, 618e3, inc, descending=True)
    p, v = orbit.elements_to_state(el)
    pe, ve = frames.eci_to_ecef(EPOCH, p, v)
    lon, lat, _ = frames.ecef_to_geodetic(pe)
    assert lon == pytest.approx(78.0, abs=1e-9)
    assert lat == pytest.approx(20.0, abs=0.2)  # geocentric radius vs ellipsoid normal
    assert ve[2] < 0  # descending: moving south
    assert np.linalg.norm(v) == pytest.approx(math.sqrt(frames.GM_M3_S2 / el.semi_major_axis_m))
    assert el.period_s / 60 == pytest.approx(97.0, abs=0.3)  # Cartosat-1: 97 min
    with pytest.raises(InputError, match="never overflown"):
        orbit.circular_orbit_over(0.0, 89.0, EPOCH, 618e3, math.radians(60.0))
