"""Acquisition geometry: passes over a target and image placement."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.errors import GeometryError, InputError
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.trajectory import Trajectory
from carto.framework.simulation import acquisition


@pytest.fixture(scope="module")
def pass_over_india():
    epoch, el, eph = acquisition.sun_synchronous_pass(
        78.0, 20.0, "2026-03-01T05:00:00Z", 618e3, span_s=(-60, 60)
    )
    att = acquisition.attitude_from_law(eph.dt_s, lambda t: (0 * t, 0 * t, 0 * t))
    return Trajectory.from_samples(epoch, eph, att), el, eph


def test_pass_samples_every_125_ms_and_overflies_the_target(pass_over_india):
    traj, _, eph = pass_over_india
    np.testing.assert_allclose(np.diff(eph.dt_s), 0.125)
    p, _ = traj.position_velocity_ecef(np.array([0.0]))
    lon, lat, h = frames.ecef_to_geodetic(p)
    assert lon[0] == pytest.approx(78.0, abs=0.01)
    assert lat[0] == pytest.approx(20.0, abs=0.2)
    assert h[0] == pytest.approx(618e3, abs=25e3)  # circular orbit over an oblate Earth


@pytest.mark.parametrize("tilt_deg", [26.0, -5.0, 0.0])
def test_centred_timing_puts_the_target_on_the_middle_line(pass_over_india, tilt_deg):
    traj, _, _ = pass_over_india
    cam = Camera.linear_array(
        "c", 12000, 1.945, 7e-6, mounting_rpy_rad=(0.0, np.radians(tilt_deg), 0.0)
    )
    timing = acquisition.centred_timing(
        traj, cam, 78.05, 20.0, 300.0, n_lines=4000, period_s=0.336e-3
    )
    sensor = LineScanner("c", 4000, timing, cam, traj)
    line, sample = sensor.ground_to_image(78.05, 20.0, 300.0)
    assert line == pytest.approx(2000.0, abs=1e-6)
    assert 0 < sample < 12000


def test_forward_camera_sees_the_target_before_the_backward_one(pass_over_india):
    traj, _, _ = pass_over_india
    t = {}
    for name, tilt in (("fore", 26.0), ("aft", -5.0)):
        cam = Camera.linear_array(
            name, 12000, 1.945, 7e-6, mounting_rpy_rad=(0.0, np.radians(tilt), 0.0)
        )
        t[name] = acquisition.crossing_time(traj, cam, 78.0, 20.0, 0.0)
    assert t["aft"] - t["fore"] == pytest.approx(52.0, abs=3.0)  # design brief: ~52 s


def test_errors(pass_over_india):
    traj, _, _ = pass_over_india
    cam = Camera.linear_array("c", 100, 1.945, 7e-6)
    with pytest.raises(GeometryError, match="never sees"):
        acquisition.crossing_time(traj, cam, 0.0, 0.0, 0.0)
    with pytest.raises(InputError, match="must contain 0"):
        acquisition.sun_synchronous_pass(78.0, 20.0, "2026-03-01T05:00:00Z", 618e3, span_s=(1, 10))
