"""Attitude laws of the reference geometry: the body's orientation, as body -> GCRS
quaternions, at any instant.

* :class:`YawSteering` (Cartosat-1's stable imaging): the local orbital frame (``Z`` to the
  Earth's centre, ``Y`` against the orbit normal, ``X`` completing it), turned about ``Z`` so
  that the body ``X`` axis follows the ground track (the Earth-relative velocity), then the
  fixed roll and pitch: ``R_body_to_orbit = Rz(yaw) Ry(pitch) Rx(roll)``.
* :class:`Pointing` (Cartosat-2 step-and-stare): body ``Z`` at an aim point that moves on the
  ground at a constant velocity, body ``X`` along the scan direction.
* :class:`Jittered`: a law plus attitude jitter, sinusoids about the body axes.
"""

from __future__ import annotations

import math

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.simulation.reference import earth, rotations
from carto.framework.simulation.reference.orbit import ReferenceOrbit

FloatArray = NDArray[np.float64]


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def orbital_frame(p: FloatArray, v: FloatArray) -> FloatArray:
    """``(..., 3, 3)``: the local orbital frame's axes (columns) in the frame of ``p``, ``v``."""
    z = _unit(-p)
    y = _unit(-np.cross(p, v))
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


@attrs.frozen
class YawSteering:
    roll_deg: float = 0.0
    pitch_deg: float = 0.0

    def body_to_gcrs(
        self, dt_s: ArrayLike, orbit: ReferenceOrbit, orientation: earth.EarthOrientation
    ) -> FloatArray:
        t = np.asarray(dt_s, float)
        p, v = orbit.state(t)
        omega = orientation.rotation_vector_gcrs(t)
        v_ground = v - np.cross(omega, p)
        frame = orbital_frame(p, v)
        v_o = np.einsum("...ji,...j->...i", frame, v_ground)
        yaw = np.arctan2(v_o[..., 1], v_o[..., 0])
        q_b2o = rotations.from_rpy(
            np.full_like(yaw, math.radians(self.roll_deg)),
            np.full_like(yaw, math.radians(self.pitch_deg)),
            yaw,
        )
        return rotations.multiply(rotations.from_matrix(frame), q_b2o)


@attrs.frozen
class Pointing:
    """Body ``Z`` at ``aim_itrs_m + (dt_s - t_c_s) * aim_velocity_itrs_m_s`` (Earth-fixed),
    body ``X`` along ``scan_direction_itrs`` made perpendicular to ``Z``."""

    aim_itrs_m: tuple[float, float, float]
    aim_velocity_itrs_m_s: tuple[float, float, float]
    t_c_s: float
    scan_direction_itrs: tuple[float, float, float]

    def body_to_gcrs(
        self, dt_s: ArrayLike, orbit: ReferenceOrbit, orientation: earth.EarthOrientation
    ) -> FloatArray:
        t = np.asarray(dt_s, float)
        p, _ = orbit.state(t)
        r = orientation.matrix(t)  # GCRS -> ITRS
        aim = np.asarray(self.aim_itrs_m) + (t - self.t_c_s)[..., None] * np.asarray(
            self.aim_velocity_itrs_m_s
        )
        aim_gcrs = np.einsum("...ji,...j->...i", r, aim)
        z = _unit(aim_gcrs - p)
        scan = np.einsum("...ji,...j->...i", r, np.broadcast_to(self.scan_direction_itrs, z.shape))
        x = _unit(scan - np.sum(scan * z, axis=-1, keepdims=True) * z)
        y = np.cross(z, x)
        return rotations.from_matrix(np.stack([x, y, z], axis=-1))


@attrs.frozen
class Jittered:
    """``base`` turned in the body frame by sums of sinusoids per axis (roll, pitch, yaw):
    ``angle_a(t) = sum_k amplitude_rad[a][k] sin(2 pi frequency_hz[k] t + phase_rad[a][k])``."""

    base: YawSteering | Pointing
    amplitude_rad: tuple[tuple[float, ...], ...]
    frequency_hz: tuple[float, ...]
    phase_rad: tuple[tuple[float, ...], ...]

    def angles(self, dt_s: ArrayLike) -> FloatArray:
        """``(3, ...)`` roll, pitch, yaw of the perturbation at ``dt_s``."""
        t = np.asarray(dt_s, float)
        amp = np.asarray(self.amplitude_rad, float)
        ph = np.asarray(self.phase_rad, float)
        out = np.zeros((3, *t.shape))
        for k, f in enumerate(self.frequency_hz):
            arg = 2.0 * np.pi * f * t
            for a in range(3):
                out[a] += amp[a, k] * np.sin(arg + ph[a, k])
        return out

    def body_to_gcrs(
        self, dt_s: ArrayLike, orbit: ReferenceOrbit, orientation: earth.EarthOrientation
    ) -> FloatArray:
        j = self.angles(dt_s)
        q = self.base.body_to_gcrs(dt_s, orbit, orientation)
        return rotations.multiply(q, rotations.from_rpy(j[0], j[1], j[2]))


AttitudeLaw = YawSteering | Pointing | Jittered
