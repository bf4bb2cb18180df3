"""Acquisition geometry: a satellite pass over a target, attitude laws and image placement.

The building blocks of the simulator and of geometric benchmarks: a sun-synchronous pass whose
ground track crosses a target at the epoch (propagated with two-body + J2 and sampled like
ancillary data, every 125 ms by default), attitude samples from a roll/pitch/yaw law, and the
line timing that puts a ground point at a chosen line of a camera's image.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import GeometryError, InputError
from carto.framework.geometry import frames, orbit
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory

FloatArray = NDArray[np.float64]
AttitudeLaw = Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]]
ANCILLARY_STEP_S = 0.125


def _sun_synchronous_elements(
    lon_deg: float, lat_deg: float, epoch_utc: str, altitude_m: float, descending: bool
) -> tuple[float, orbit.OrbitElements]:
    """``(epoch_j2000_s, elements)`` of the circular sun-synchronous orbit at ``altitude_m``
    whose ground track crosses ``(lon_deg, lat_deg)`` at ``epoch_utc``."""
    epoch = frames.utc_to_j2000_s(epoch_utc)
    a = frames.WGS84_A_M + altitude_m
    elements = orbit.circular_orbit_over(
        lon_deg,
        lat_deg,
        epoch,
        altitude_m,
        orbit.sun_synchronous_inclination(a),
        descending=descending,
    )
    return epoch, elements


def sun_synchronous_pass(
    target_lon_deg: float,
    target_lat_deg: float,
    epoch_utc: str,
    altitude_m: float,
    *,
    span_s: tuple[float, float] = (-60.0, 60.0),
    step_s: float = ANCILLARY_STEP_S,
    descending: bool = True,
) -> tuple[float, orbit.OrbitElements, EphemerisSamples]:
    """A circular sun-synchronous orbit over the target at ``epoch_utc``, sampled in ECI.

    Returns:
        ``(epoch_j2000_s, elements at the epoch, ephemeris samples every step_s over span_s)``.
    """
    if not span_s[0] < 0 < span_s[1]:
        raise InputError(f"pass span must contain 0 (the epoch), got {span_s}")
    epoch, el = _sun_synchronous_elements(
        target_lon_deg, target_lat_deg, epoch_utc, altitude_m, descending
    )
    p0, v0 = orbit.elements_to_state(el)
    n0 = int(np.floor(span_s[0] / step_s))
    n1 = int(np.ceil(span_s[1] / step_s))
    dt = step_s * np.arange(n0, n1 + 1)
    p, v = orbit.propagate(p0, v0, dt)
    return epoch, el, EphemerisSamples(dt, p, v, "eci")


def local_time_epoch(lon_deg: float, date: str, local_hours: float = 10.5) -> str:
    """UTC time (ISO string) at which the mean local solar time at ``lon_deg`` on ``date``
    (``YYYY-MM-DD``) is ``local_hours`` (10.5: a 10:30 sun-synchronous pass)."""
    utc_hours = (local_hours - lon_deg / 15.0) % 24.0
    t = frames.utc_to_j2000_s(f"{date}T00:00:00Z") + utc_hours * 3600.0
    return frames.j2000_s_to_utc(round(t, 3))


def sun_synchronous_overpass(
    lon_deg: float,
    lat_deg: float,
    date: str,
    altitude_m: float,
    *,
    local_hours: float = 10.5,
    descending: bool = True,
) -> tuple[str, float, orbit.OrbitElements]:
    """A sun-synchronous circular orbit over ``(lon, lat)`` at ``local_hours`` local solar time
    on ``date``: ``(epoch_utc, epoch_j2000_s, elements at the epoch)``."""
    epoch_utc = local_time_epoch(lon_deg, date, local_hours)
    epoch, elements = _sun_synchronous_elements(lon_deg, lat_deg, epoch_utc, altitude_m, descending)
    return epoch_utc, epoch, elements


def ground_directions(
    epoch_j2000_s: float, elements: orbit.OrbitElements, lon_deg: float, lat_deg: float
) -> tuple[NDArray, NDArray, NDArray]:
    """Unit ECEF directions at a ground point, for an orbit at its epoch: ``up`` (the
    ellipsoid normal), ``along`` (the satellite's motion projected on the horizontal plane:
    the ground track) and ``left`` (across it)."""
    p0, v0 = orbit.elements_to_state(elements)
    _, v_ecef = frames.eci_to_ecef(epoch_j2000_s, p0, v0)
    v_ecef = np.ravel(v_ecef)
    up = frames.ellipsoid_normal(lon_deg, lat_deg)
    along = v_ecef - np.dot(v_ecef, up) * up
    along /= np.linalg.norm(along)
    return up, along, np.cross(up, along)


def attitude_from_law(dt_s: ArrayLike, law: AttitudeLaw) -> AttitudeSamples:
    """Attitude samples (body -> orbit quaternions) from a ``(roll, pitch, yaw)(dt)`` law."""
    t = np.asarray(dt_s, dtype=np.float64)
    roll, pitch, yaw = (np.broadcast_to(np.asarray(a, float), t.shape) for a in law(t))
    q = frames.matrix_to_quat(frames.rpy_to_matrix(roll, pitch, yaw))
    return AttitudeSamples(t, q, "orbit")


def crossing_time(
    trajectory: Trajectory,
    camera: Camera,
    lon_deg: float,
    lat_deg: float,
    h_m: float,
    *,
    t_range_s: tuple[float, float] | None = None,
    step_s: float = 0.5,
) -> float:
    """The time (s since the epoch) at which a ground point crosses the camera's focal plane.

    Scans ``t_range_s`` (default: the trajectory's samples) for the sign change of the
    along-track look angle mismatch, then refines it by the secant method to 1e-12 s.

    Raises:
        GeometryError: the point is never in the focal plane within the range.
    """
    x = frames.geodetic_to_ecef(lon_deg, lat_deg, h_m)
    r_c2b = camera.camera_to_body()

    def mismatch(t: FloatArray) -> FloatArray:
        p, r_b2e = trajectory.evaluate(t)
        r_c2e = r_b2e @ r_c2b
        v = np.einsum("...ji,...j->...i", r_c2e, x - p)
        s = camera.sample_from_tan_psi_y(v[..., 1] / v[..., 2])
        tx, _ = camera.tan_psi(s)
        return np.where(v[..., 2] > 0, v[..., 0] / v[..., 2] - tx, np.nan)

    lo, hi = t_range_s or (
        trajectory.t_mid_s - trajectory.t_half_s,
        trajectory.t_mid_s + trajectory.t_half_s,
    )
    t = np.arange(lo, hi + step_s, step_s)
    f = mismatch(t)
    change = np.flatnonzero(np.isfinite(f[:-1]) & np.isfinite(f[1:]) & (f[:-1] * f[1:] <= 0))
    if change.size == 0:
        raise GeometryError(
            f"camera {camera.name} never sees ({lon_deg:.5f}, {lat_deg:.5f}) "
            f"between {lo:.1f} s and {hi:.1f} s"
        )
    i = change[0]
    t0, t1, f0, f1 = t[i], t[i + 1], f[i], f[i + 1]
    for _ in range(60):
        if f1 == f0:
            break
        t2 = t1 - f1 * (t1 - t0) / (f1 - f0)
        t0, f0 = t1, f1
        t1, f1 = t2, float(mismatch(np.array([t2]))[0])
        if abs(t1 - t0) < 1e-12:
            break
    return float(t1)


def centred_timing(
    trajectory: Trajectory,
    camera: Camera,
    lon_deg: float,
    lat_deg: float,
    h_m: float,
    *,
    n_lines: int,
    period_s: float,
    at_line: float | None = None,
) -> LineTiming:
    """Constant-period line timing that images the ground point at line ``at_line``
    (default: the middle of the image)."""
    t = crossing_time(trajectory, camera, lon_deg, lat_deg, h_m)
    line = n_lines / 2.0 if at_line is None else float(at_line)
    return LineTiming.constant(t - (line - 0.5) * period_s, period_s)
