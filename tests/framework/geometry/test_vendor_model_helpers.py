"""Building blocks for vendor physical models: look-direction polynomials in the raw detector
index (:meth:`Camera.from_detector_polynomials`) and attitude quaternion polynomials
(:meth:`AttitudeSamples.from_quaternion_polynomials`), against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import polynomial as npoly

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory

from ..builders import EPOCH, circular_orbit


# ----------------------------------------------------------------------------- detector polynomials
@pytest.mark.parametrize("first_detector", [0.0, 1.0, 1234.0])
def test_detector_polynomials_are_converted_exactly(first_detector):
    n = 40000
    tx = [8e-5, 1e-10, -3e-15]  # along track, slightly curved array
    ty = [0.01422, -7.11e-7, 2e-14, 1e-19]  # across track, with distortion
    cam = Camera.from_detector_polynomials("pan", n, tx, ty, first_detector=first_detector)
    s = np.array([0.0, 0.5, 1.0, 1234.25, 20000.0, 39999.5, 40000.0])
    k = first_detector + s - 0.5  # the raw detector index
    got_x, got_y = cam.tan_psi(s)
    np.testing.assert_allclose(got_x, npoly.polyval(k, tx), rtol=0, atol=1e-16)
    np.testing.assert_allclose(got_y, npoly.polyval(k, ty), rtol=0, atol=1e-16)
    # the inverse used by ground -> image recovers the sample
    np.testing.assert_allclose(cam.sample_from_tan_psi_y(got_y), s, rtol=0, atol=1e-7)
    assert Camera.from_dict(cam.to_dict()).tan_psi(s)[1] == pytest.approx(got_y, abs=0)


def test_detector_polynomials_reproduce_a_linear_array():
    n, f, pitch = 12000, 1.945, 7e-6
    ref = Camera.linear_array("pan", n, f, pitch, along_offset_m=1e-3)
    # detector k (from 0 at the first column's centre) sits at s = k + 0.5
    ty = [-(0.5 - n / 2) * pitch / f, -pitch / f]
    cam = Camera.from_detector_polynomials("pan", n, [1e-3 / f], ty)
    s = np.linspace(0, n, 101)
    for a, b in zip(cam.tan_psi(s), ref.tan_psi(s), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)
    assert cam.has_linear_along_track


@pytest.mark.parametrize(
    ("tx", "ty", "message"),
    [
        ([], [0.0, 1e-6], "tan_psi_x coefficients"),
        ([0.0], [np.nan, 1e-6], "tan_psi_y coefficients"),
        ([0.0], [0.01], "tan_psi_y must vary"),
    ],
)
def test_detector_polynomial_errors(tx, ty, message):
    with pytest.raises(InputError, match=message):
        Camera.from_detector_polynomials("pan", 100, tx, ty)


# ----------------------------------------------------------------------------- attitude polynomials
# a slewing attitude (Pleiades-like coefficients: about 0.3 deg/s, small curvature)
QUAT_COEFFS = np.array(
    [
        [0.0802008688, 0.0010465831, -2.04282e-05, 3.13065e-06],
        [-0.9138563379, 0.0003729083, 2.607086e-06, 7.77004e-08],
        [0.0452862749, 0.0024018187, 1.250936e-05, 7.402486e-07],
        [0.3954536240, 0.0003744548, -3.086565e-07, -5.686492e-07],
    ]
)


def exact_rotation(dt_s, dt_ref_s=0.3, scale_s=1.625):
    tau = (np.asarray(dt_s) - dt_ref_s) / scale_s
    return frames.quat_to_matrix(npoly.polyval(tau, QUAT_COEFFS.T).T)


def test_quaternion_polynomials_are_sampled_normalised():
    t = np.linspace(-3, 3, 13)
    att = AttitudeSamples.from_quaternion_polynomials(
        QUAT_COEFFS, t, dt_ref_s=0.3, scale_s=1.625, frame="ecef"
    )
    assert att.frame == "ecef"
    np.testing.assert_allclose(np.linalg.norm(att.quaternion_wxyz, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(frames.quat_to_matrix(att.quaternion_wxyz), exact_rotation(t))
    at_ref = AttitudeSamples.from_quaternion_polynomials(
        QUAT_COEFFS, [0.3, 0.4], dt_ref_s=0.3, scale_s=1.625
    ).quaternion_wxyz[0]
    np.testing.assert_allclose(at_ref, QUAT_COEFFS[:, 0] / np.linalg.norm(QUAT_COEFFS[:, 0]))


def test_trajectory_from_quaternion_polynomials_matches_the_polynomials():
    """4-point Lagrange between samples 10 ms apart reproduces the exact polynomial attitude."""
    t_eph = np.arange(-120.0, 120.01, 30.0)
    p, v = circular_orbit(t_eph)
    p_e, v_e = frames.eci_to_ecef(EPOCH + t_eph, p, v)
    t_att = np.arange(-4.0, 4.0001, 0.01)
    att = AttitudeSamples.from_quaternion_polynomials(
        QUAT_COEFFS, t_att, dt_ref_s=0.3, scale_s=1.625, frame="ecef"
    )
    traj = Trajectory.from_samples(
        EPOCH,
        EphemerisSamples(t_eph, p_e, v_e, "ecef"),
        att,
        interpolation="lagrange",
        lagrange_points=8,
    )
    t = np.linspace(-3.9, 3.9, 997)  # between the samples
    _, r = traj.evaluate(t)
    err = frames.matrix_to_rotvec(np.swapaxes(exact_rotation(t), -1, -2) @ r)
    assert np.abs(err).max() < 1e-13  # rad; one Pleiades pixel is 7e-7 rad
    # the Earth-fixed ephemeris comes back at its samples
    np.testing.assert_allclose(traj.evaluate(t_eph)[0], p_e, rtol=0, atol=1e-6)


def test_line_scanner_from_vendor_polynomials_round_trips():
    """A line scanner assembled only from the two helpers projects and locates consistently."""
    t_eph = np.arange(-120.0, 120.01, 30.0)
    p, v = circular_orbit(t_eph, altitude_m=694e3)
    p_e, v_e = frames.eci_to_ecef(EPOCH + t_eph, p, v)
    # nadir-looking body: orbit frame expressed in ECEF at each attitude sample
    t_att = np.arange(-3.0, 3.0001, 0.01)
    pa, va = circular_orbit(t_att, altitude_m=694e3)
    r_o2e = frames.eci_to_ecef_matrix(EPOCH + t_att) @ frames.orbit_to_eci_matrix(pa, va)
    q = frames.matrix_to_quat(r_o2e)
    coeffs = np.stack([npoly.polyfit(t_att, q[:, i], 3) for i in range(4)])
    att = AttitudeSamples.from_quaternion_polynomials(
        coeffs, t_att, dt_ref_s=0.0, scale_s=1.0, frame="ecef"
    )
    traj = Trajectory.from_samples(
        EPOCH, EphemerisSamples(t_eph, p_e, v_e, "ecef"), att, interpolation="lagrange"
    )
    cam = Camera.from_detector_polynomials("pan", 4000, [0.0], [0.0014, -7e-7])
    sensor = LineScanner("s", 4000, LineTiming.constant(-0.15, 7.35e-5), cam, traj)
    line = np.array([0.5, 1000.0, 3999.5])
    sample = np.array([3999.5, 10.0, 2000.0])
    lon, lat = sensor.image_to_ground(line, sample, 300.0)
    back_line, back_sample = sensor.ground_to_image(lon, lat, 300.0)
    np.testing.assert_allclose(back_line, line, atol=1e-6)
    np.testing.assert_allclose(back_sample, sample, atol=1e-6)


@pytest.mark.parametrize(
    ("coeffs", "scale", "message"),
    [
        (np.zeros((3, 4)), 1.0, r"shape \(4, K\)"),
        (QUAT_COEFFS, 0.0, "invalid time reference"),
        (np.zeros((4, 2)), 1.0, "vanishes"),
    ],
)
def test_quaternion_polynomial_errors(coeffs, scale, message):
    with pytest.raises(InputError, match=message):
        AttitudeSamples.from_quaternion_polynomials(coeffs, [0.0, 1.0], dt_ref_s=0.0, scale_s=scale)
