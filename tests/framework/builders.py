"""Analytic geometry builders for tests: closed-form Keplerian circular orbits and
Cartosat-like cameras, independent of the simulator's propagator (so they serve as truth)."""

from __future__ import annotations

import numpy as np

from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory

EPOCH = frames.utc_to_j2000_s("2026-03-01T05:00:00Z")


def circular_orbit(
    dt_s: np.ndarray,
    altitude_m: float = 618e3,
    inclination_deg: float = 97.87,
    raan_deg: float = 30.0,
    arg_lat0_deg: float = 200.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Inertial position and velocity on a circular Keplerian orbit (closed form)."""
    r = frames.WGS84_A_M + altitude_m
    n = np.sqrt(frames.GM_M3_S2 / r**3)
    u = np.radians(arg_lat0_deg) + n * np.asarray(dt_s, float)
    p = np.stack([r * np.cos(u), r * np.sin(u), 0 * u], -1)
    v = np.stack([-r * n * np.sin(u), r * n * np.cos(u), 0 * u], -1)
    rot = frames.rot_z(np.radians(raan_deg)) @ frames.rot_x(np.radians(inclination_deg))
    return p @ rot.T, v @ rot.T


def make_trajectory(
    span_s: float = 40.0,
    rpy=lambda t: (1e-4 + 0 * t, 2e-4 + 1e-6 * t, 3e-4 + 0 * t),
    altitude_m: float = 618e3,
    step_s: float = 0.125,
    **kwargs,
) -> Trajectory:
    t = np.arange(-span_s, span_s + 1e-9, step_s)
    p, v = circular_orbit(t, altitude_m=altitude_m)
    roll, pitch, yaw = rpy(t)
    q = frames.matrix_to_quat(frames.rpy_to_matrix(roll, pitch, yaw))
    return Trajectory.from_samples(
        EPOCH, EphemerisSamples(t, p, v, "eci"), AttitudeSamples(t, q, "orbit"), **kwargs
    )


def cartosat1_camera(name: str, tilt_deg: float) -> Camera:
    return Camera.linear_array(
        name,
        12000,
        1.945,
        7e-6,
        stagger_m=35e-6,
        array="odd",
        mounting_rpy_rad=(0.0, np.radians(tilt_deg), 0.0),
    )
