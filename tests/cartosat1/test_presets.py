"""The cartosat1-pair preset against figures computed from the design constants."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carto.cartosat1 import constants as c
from carto.framework.geometry import frames
from carto.framework.geometry.linescan.scanner import LineScanner


@pytest.fixture(scope="module")
def truth(cartosat1_scene) -> dict[str, LineScanner]:
    return {n: LineScanner.load(cartosat1_scene / f"truth/{n}.model.json") for n in ("fore", "aft")}


def _ground_step(sensor: LineScanner, d_line: float, d_sample: float, h: float) -> float:
    line, sample = np.array([200.0, 200.0 + d_line]), np.array([200.0, 200.0 + d_sample])
    lon, lat = sensor.image_to_ground(line, sample, h)
    xyz = frames.geodetic_to_ecef(lon, lat, h)
    return float(np.linalg.norm(xyz[1] - xyz[0]))


def test_ground_sampling_from_the_constants(truth):
    # across track: slant range x pitch / f (Aft ~2.2 m, Fore ~2.5 m at 26 deg)
    for name, tilt in (("aft", c.AFT_TILT_DEG), ("fore", c.FORE_TILT_DEG)):
        expected = (
            c.ORBIT_ALTITUDE_M
            / math.cos(math.radians(tilt))
            * (c.DETECTOR_PITCH_M / c.FOCAL_LENGTH_M)
        )
        assert _ground_step(truth[name], 0, 1, 250.0) == pytest.approx(expected, rel=0.04)
    assert 2.1 < _ground_step(truth["aft"], 0, 1, 250.0) < 2.35
    assert 2.4 < _ground_step(truth["fore"], 0, 1, 250.0) < 2.7
    # along track: the line spacing is the ground speed times 0.336 ms (~2.3 m)
    p, v = truth["aft"].trajectory.position_velocity_ecef(np.array([0.0]))
    r = np.linalg.norm(p)
    ground_speed = np.linalg.norm(v) * frames.WGS84_A_M / r
    for name in ("aft", "fore"):
        step = _ground_step(truth[name], 1, 0, 250.0)
        assert step == pytest.approx(ground_speed * c.LINE_PERIOD_S, rel=0.05)
        assert 2.2 < step < 2.45


def test_fore_aft_time_separation_and_base_to_height(truth):
    s = truth["aft"]
    lon, lat = s.image_to_ground(200.0, 200.0, 250.0)
    times, centres = {}, {}
    for name in ("fore", "aft"):
        line, _ = truth[name].ground_to_image(lon, lat, 250.0)
        times[name] = float(truth[name].timing.time(float(line)))
        centres[name] = truth[name].trajectory.evaluate(np.array([times[name]]))[0][0]
    assert times["aft"] - times["fore"] == pytest.approx(52.0, abs=3.0)
    base = np.linalg.norm(centres["aft"] - centres["fore"])
    ground = frames.geodetic_to_ecef(lon, lat, 250.0)
    up = frames.ellipsoid_normal(lon, lat)
    height = np.mean([np.dot(centres[n] - ground.ravel(), up.ravel()) for n in centres])
    assert base / height == pytest.approx(0.62, abs=0.03)


def test_orbit_altitude_speed_and_period_agree_with_kepler(truth):
    traj = truth["fore"].trajectory
    # within the truth's samples (they cover the acquisition, not the whole orbit)
    t = traj.t_mid_s + np.linspace(-0.9, 0.9, 9) * traj.t_half_s
    p, v = traj.state_eci(t)
    r = np.linalg.norm(p, axis=1)
    _, _, h = frames.ecef_to_geodetic(traj.position_velocity_ecef(t)[0])
    assert np.all(np.abs(h - c.ORBIT_ALTITUDE_M) < 25e3)  # circular over an oblate Earth
    speed = np.linalg.norm(v, axis=1)
    np.testing.assert_allclose(speed, np.sqrt(frames.GM_M3_S2 / r), rtol=2e-3)  # J2: < 0.2 %
    a = 1.0 / (2.0 / r - speed**2 / frames.GM_M3_S2)  # vis-viva
    period_min = 2 * np.pi * np.sqrt(a**3 / frames.GM_M3_S2) / 60
    np.testing.assert_allclose(period_min, 97.0, atol=0.4)  # Cartosat-1: 97 min
    # sun-synchronous inclination of the design brief, to the Earth's pole of the date (the
    # GCRS z axis is J2000's: precession moves it by 0.14 deg by 2026)
    h_vec = np.cross(p[4], v[4])
    pole = traj.eci_to_ecef_matrix(np.array([t[4]]))[0].T @ np.array([0.0, 0.0, 1.0])
    incl = math.degrees(math.acos(np.dot(h_vec, pole) / np.linalg.norm(h_vec)))
    assert incl == pytest.approx(c.ORBIT_INCLINATION_DEG, abs=0.05)
