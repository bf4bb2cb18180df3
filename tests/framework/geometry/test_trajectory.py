"""Trajectory fitting, interpolation, corrections and serialisation against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory

from ..builders import EPOCH, circular_orbit, make_trajectory


@pytest.mark.parametrize(("order", "tolerance_m"), [(1, 6000.0), (2, 200.0), (3, 1.0)])
def test_polynomial_fit_order_and_residuals(order, tolerance_m):
    traj = make_trajectory(span_s=40.0, order=order)
    t = np.linspace(-40, 40, 333)  # between the samples
    p_true, _ = circular_orbit(t)
    p_fit, _ = traj.state_eci(t)
    err = np.linalg.norm(p_fit - p_true, axis=1).max()
    assert err < tolerance_m
    report = traj.fit_report.as_dict()
    assert report["x_m"]["max_abs"] < tolerance_m
    if order > 1:  # the reported residuals describe the real error
        assert err < 3 * max(report[c]["max_abs"] for c in ("x_m", "y_m", "z_m"))


def test_lagrange_interpolation_is_exact_between_samples():
    traj = make_trajectory(span_s=40.0, interpolation="lagrange")
    t = np.linspace(-39, 39, 777)
    p_true, v_true = circular_orbit(t)
    p, v = traj.state_eci(t)
    assert np.abs(p - p_true).max() < 1e-4
    assert np.abs(v - v_true).max() < 1e-6


def test_ecef_ephemeris_gives_the_same_trajectory():
    t = np.arange(-20, 20.001, 0.125)
    p, v = circular_orbit(t)
    p_e, v_e = frames.eci_to_ecef(EPOCH + t, p, v)
    q = np.tile([1.0, 0, 0, 0], (t.size, 1))
    a = Trajectory.from_samples(EPOCH, EphemerisSamples(t, p, v), AttitudeSamples(t, q))
    b = Trajectory.from_samples(EPOCH, EphemerisSamples(t, p_e, v_e, "ecef"), AttitudeSamples(t, q))
    tt = np.linspace(-19, 19, 50)
    np.testing.assert_allclose(a.evaluate(tt)[0], b.evaluate(tt)[0], atol=1e-3)
    np.testing.assert_allclose(a.evaluate(tt)[1], b.evaluate(tt)[1], atol=1e-12)
    # Earth-fixed velocity from the trajectory equals the input ECEF velocity
    _, v_fit = b.position_velocity_ecef(t[10:-10])
    np.testing.assert_allclose(v_fit, v_e[10:-10], atol=1e-3)


def test_attitude_in_inertial_frame_matches_orbit_frame_attitude():
    t = np.arange(-10, 10.001, 0.125)
    p, v = circular_orbit(t)
    roll, pitch, yaw = 0.05 + 1e-4 * t, -0.3 + 0.01 * t, 0.01 + 0 * t
    r_b2o = frames.rpy_to_matrix(roll, pitch, yaw)
    r_b2i = frames.orbit_to_eci_matrix(p, v) @ r_b2o
    eph = EphemerisSamples(t, p, v)
    a = Trajectory.from_samples(EPOCH, eph, AttitudeSamples(t, frames.matrix_to_quat(r_b2o)))
    b = Trajectory.from_samples(EPOCH, eph, AttitudeSamples(t, frames.matrix_to_quat(r_b2i), "eci"))
    tt = np.linspace(-9, 9, 41)
    # compare pointing: angle between the body Z axes in ECEF
    za = a.evaluate(tt)[1][..., :, 2]
    zb = b.evaluate(tt)[1][..., :, 2]
    angle = np.arccos(np.clip(np.sum(za * zb, -1), -1, 1))
    assert angle.max() < 2e-7  # rad: both are cubic fits of the same smooth motion


def test_attitude_correction_rotates_in_the_orbit_frame():
    traj = make_trajectory(span_s=10.0, rpy=lambda t: (0 * t, 0 * t, 0 * t))
    delta = 1e-3
    corrected = traj.with_parameters({"trajectory.attitude.roll.c0": delta})
    t = np.array([0.0, 5.0])
    _, r0 = traj.evaluate(t)
    _, r1 = corrected.evaluate(t)
    # body Z (nadir) turns by delta about the orbit X axis (= body X here)
    z0, z1 = r0[..., :, 2], r1[..., :, 2]
    angle = np.arccos(np.clip(np.sum(z0 * z1, -1), -1, 1))
    np.testing.assert_allclose(angle, delta, rtol=1e-6)
    axis = np.cross(z0, z1)
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.sum(axis * r0[..., :, 0], -1)), 1.0, atol=1e-9)


def test_drift_term_uses_normalised_time_and_position_corrections():
    traj = make_trajectory(
        span_s=10.0, rpy=lambda t: (0 * t, 0 * t, 0 * t), position_correction_order=0
    )
    names = [p.name for p in traj.parameters]
    assert "trajectory.attitude.pitch.c1" in names
    assert "trajectory.position.radial.c0" in names
    moved = traj.with_parameters({"trajectory.position.radial.c0": 25.0})
    p0, _ = traj.evaluate(np.array([1.0]))
    p1, _ = moved.evaluate(np.array([1.0]))
    np.testing.assert_allclose(np.linalg.norm(p1) - np.linalg.norm(p0), 25.0, atol=1e-3)
    drift = traj.with_parameters({"trajectory.attitude.pitch.c1": 2e-4})
    _, ra = drift.evaluate(np.array([traj.t_mid_s, traj.t_mid_s + traj.t_half_s]))
    _, rb = traj.evaluate(np.array([traj.t_mid_s, traj.t_mid_s + traj.t_half_s]))
    ang = np.arccos(np.clip(np.sum(ra[:, :, 2] * rb[:, :, 2], -1), -1, 1))
    np.testing.assert_allclose(ang, [0.0, 2e-4], atol=1e-9)  # tau = 0 at mid, 1 at the end


@pytest.mark.parametrize("frame", ["orbit", "eci"])
def test_a_shared_state_gives_each_parameter_copy_its_own_evaluation(frame):
    """:meth:`Trajectory.state` computed once serves the copies that differ in their
    parameters (position and attitude corrections: the orbit frame follows the corrected
    position), and a state of another trajectory's series is not used."""
    t = np.arange(-10, 10.001, 0.125)
    p, v = circular_orbit(t)
    r_b2o = frames.rpy_to_matrix(0.05 + 1e-4 * t, -0.3 + 0.01 * t, 0.01 + 0 * t)
    r = r_b2o if frame == "orbit" else frames.orbit_to_eci_matrix(p, v) @ r_b2o
    attitude = AttitudeSamples(t, frames.matrix_to_quat(r), frame)
    traj = Trajectory.from_samples(
        EPOCH, EphemerisSamples(t, p, v), attitude, position_correction_order=1
    )
    tt = np.linspace(-9, 9, 37)
    state = traj.state(tt)
    moved = traj.with_parameters(
        {
            "trajectory.position.across.c1": 40.0,
            "trajectory.position.radial.c0": -25.0,
            "trajectory.attitude.yaw.c0": 3e-4,
        }
    )
    for copy in (traj, moved):
        own, shared = copy.evaluate_with_axes(tt), copy.evaluate_with_axes(tt, state)
        for a, b in zip(own, shared, strict=True):
            np.testing.assert_array_equal(b, a)
    np.testing.assert_array_equal(
        moved.inertial_velocity_ecef(tt, state), moved.inertial_velocity_ecef(tt)
    )
    assert np.abs(moved.evaluate(tt)[0] - traj.evaluate(tt)[0]).max() > 20.0
    other = Trajectory.from_samples(EPOCH + 60.0, EphemerisSamples(t, p, v), attitude)
    np.testing.assert_array_equal(other.evaluate(tt, state)[0], other.evaluate(tt)[0])


def test_serialisation_round_trip():
    traj = make_trajectory(span_s=10.0).with_parameters({"trajectory.attitude.yaw.c1": 1e-5})
    again = Trajectory.from_dict(traj.to_dict())
    t = np.linspace(-10, 10, 11)
    for x, y in zip(traj.evaluate(t), again.evaluate(t), strict=True):
        np.testing.assert_array_equal(x, y)
    assert again.parameters == traj.parameters


def test_bad_samples_raise_input_error():
    t = np.arange(5.0)
    with pytest.raises(InputError, match="strictly increasing"):
        EphemerisSamples(t[::-1], np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(InputError, match=r"expected shape \(N, 3\)"):
        EphemerisSamples(t, np.zeros((5, 2)), np.zeros((5, 3)))
    with pytest.raises(InputError, match="NaN"):
        AttitudeSamples(t, np.full((5, 4), np.nan))
    p, v = circular_orbit(t)
    with pytest.raises(InputError, match="order must be 1, 2 or 3"):
        Trajectory.from_samples(
            EPOCH,
            EphemerisSamples(t, p, v),
            AttitudeSamples(t, np.tile([1.0, 0, 0, 0], (5, 1))),
            order=5,
        )
    with pytest.raises(InputError, match="missing field 'orbit'"):
        Trajectory.from_dict({"epoch_j2000_s": 0.0, "attitude_frame": "orbit"})


# ----------------------------------------------------------------------------- plausibility
def _samples(span_s: float = 10.0, step_s: float = 0.125):
    t = np.arange(-span_s, span_s + 1e-9, step_s)
    p, v = circular_orbit(t)
    q = frames.matrix_to_quat(frames.rpy_to_matrix(0.01 + 0 * t, -0.2 + 1e-3 * t, 0 * t))
    return t, p, v, q


def test_quaternions_within_the_tolerance_are_renormalised_silently():
    t, p, v, q = _samples()
    wobble = 1.0 + 1e-9 * np.sin(np.arange(t.size))
    att = AttitudeSamples(t, q * wobble[:, None])
    np.testing.assert_allclose(np.linalg.norm(att.quaternion_wxyz, axis=1), 1.0, atol=1e-15)
    a = Trajectory.from_samples(EPOCH, EphemerisSamples(t, p, v), AttitudeSamples(t, q))
    b = Trajectory.from_samples(EPOCH, EphemerisSamples(t, p, v), att)
    tt = np.linspace(-9, 9, 7)
    np.testing.assert_allclose(a.evaluate(tt)[1], b.evaluate(tt)[1], atol=1e-12)


@pytest.mark.parametrize(("factor", "shown"), [(0.0, "0"), (3.0, "3"), (1.0 + 2e-6, "1.000002")])
def test_a_non_unit_quaternion_is_refused_with_sample_and_norm(factor, shown):
    t, _, _, q = _samples()
    q[12] *= factor
    with pytest.raises(InputError) as err:
        AttitudeSamples(t, q)
    assert str(err.value) == (
        f"attitude.quaternion_wxyz: sample 12 is not a unit quaternion: |q| = {shown} "
        "(allowed 1 +- 1e-06)"
    )


def test_a_unit_quaternion_that_is_not_the_attitude_is_refused():
    t, _, _, q = _samples()
    q[30] = q[30][[1, 0, 3, 2]]  # components swapped: still unit
    with pytest.raises(InputError, match=r"turns at .* deg/s between samples 29 and 30"):
        AttitudeSamples(t, q)


def test_positions_in_kilometres_and_wrong_velocities_are_refused():
    t, p, v, _ = _samples()
    with pytest.raises(
        InputError, match=r"\|r\| = 7(\.\d+)?e3 at sample 0, expected 6\.45e6-4\.5e7"
    ):
        EphemerisSamples(t, p / 1e3, v)
    with pytest.raises(InputError, match=r"velocities must be m/s: \|v\| = 7\.\d+ at sample 0"):
        EphemerisSamples(t, p, v / 1e3, "eci")
    p_e, v_e = frames.eci_to_ecef(EPOCH + t, p, v)
    EphemerisSamples(t, p_e, v_e, "ecef")
    with pytest.raises(InputError, match=r"ephemeris.velocity_m_s: samples 0-1 move at 7\d{3}"):
        EphemerisSamples(t, p_e, v_e / 1e3, "ecef")
    # an inertial velocity given as an Earth-fixed one is off by omega x r
    inertial_on_ecef_axes = v_e + np.cross([0.0, 0.0, frames.OMEGA_EARTH_RAD_S], p_e)
    with pytest.raises(InputError, match=r"ecef velocities must be Earth-relative"):
        EphemerisSamples(t, p_e, inertial_on_ecef_axes, "ecef")
    v_e[40] *= 1.05  # one damaged sample
    with pytest.raises(InputError, match=r"samples 39-40 move at"):
        EphemerisSamples(t, p_e, v_e, "ecef")


def test_sparse_ephemeris_samples_pass_the_velocity_check():
    """30 s apart (Pleiades): the chord of the arc differs from the mean velocity by ~1e-4."""
    t = np.arange(-120.0, 121.0, 30.0)
    p, v = circular_orbit(t)
    EphemerisSamples(t, p, v)


def test_times_name_the_first_sample_out_of_order():
    t, p, v, q = _samples()
    t[5] = t[3]
    with pytest.raises(InputError, match=r"ephemeris.dt_s: times must be strictly increasing: "):
        EphemerisSamples(t, p, v)
    with pytest.raises(
        InputError, match=r"attitude.dt_s: .* sample 5 \(t = -9.625 s\) follows t = -9.5 s"
    ):
        AttitudeSamples(t, q)
