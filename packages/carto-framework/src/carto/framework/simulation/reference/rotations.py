"""Quaternions of the reference geometry: scalar first ``(w, x, y, z)``, Hamilton product,
active rotations (``q`` "A to B" maps A-frame vectors to B-frame vectors, ``v_B = q v_A q*``).
Arrays of quaternions have shape ``(..., 4)``."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def multiply(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p q`` (the rotation ``q`` first, then ``p``)."""
    p = np.asarray(p, float)
    q = np.asarray(q, float)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: ArrayLike) -> FloatArray:
    q = np.asarray(q, float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def about_axis(axis: ArrayLike, angle_rad: ArrayLike) -> FloatArray:
    """The rotation by ``angle_rad`` (right-handed) about the unit ``axis``."""
    axis = np.asarray(axis, float)
    half = 0.5 * np.asarray(angle_rad, float)
    s = np.sin(half)[..., None]
    return np.concatenate([np.cos(half)[..., None], s * axis], axis=-1)


def from_rpy(roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike) -> FloatArray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` as a quaternion: roll first, about X, then pitch about
    Y, then yaw about Z (fixed axes)."""
    qx = about_axis([1.0, 0.0, 0.0], roll_rad)
    qy = about_axis([0.0, 1.0, 0.0], pitch_rad)
    qz = about_axis([0.0, 0.0, 1.0], yaw_rad)
    return multiply(qz, multiply(qy, qx))


def rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """``q v q*`` for vectors ``v (..., 3)``."""
    q = np.asarray(q, float)
    v = np.asarray(v, float)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def to_matrix(q: ArrayLike) -> FloatArray:
    """The ``(..., 3, 3)`` matrix of ``rotate(q, .)``."""
    eye = np.eye(3)
    q = np.asarray(q, float)
    cols = [rotate(q, np.broadcast_to(eye[i], (*q.shape[:-1], 3))) for i in range(3)]
    return np.stack(cols, axis=-1)


def from_matrix(m: ArrayLike) -> FloatArray:
    """The unit quaternion (``w >= 0``) of rotation matrices ``(..., 3, 3)`` (Shepperd's
    method: the largest of ``w, x, y, z`` is computed from the trace, the others from it)."""
    m = np.asarray(m, float)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for i in range(4):
        sel = k == i
        if not sel.any():
            continue
        a = m[sel]
        if i == 0:
            r = np.sqrt(1.0 + tr[sel])
            s = 0.5 / r
            q[sel] = np.stack(
                [
                    0.5 * r,
                    (a[:, 2, 1] - a[:, 1, 2]) * s,
                    (a[:, 0, 2] - a[:, 2, 0]) * s,
                    (a[:, 1, 0] - a[:, 0, 1]) * s,
                ],
                axis=1,
            )
        else:
            j, k2 = (i % 3) + 1, ((i + 1) % 3) + 1  # the cyclic successors of axis i
            ii, jj, ll = i - 1, j - 1, k2 - 1
            r = np.sqrt(1.0 + a[:, ii, ii] - a[:, jj, jj] - a[:, ll, ll])
            s = 0.5 / r
            out = np.empty((a.shape[0], 4))
            out[:, 0] = (a[:, ll, jj] - a[:, jj, ll]) * s
            out[:, i] = 0.5 * r
            out[:, j] = (a[:, jj, ii] + a[:, ii, jj]) * s
            out[:, k2] = (a[:, ll, ii] + a[:, ii, ll]) * s
            q[sel] = out
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(*shape, 4)


def slerp(q0: ArrayLike, q1: ArrayLike, fraction: ArrayLike) -> FloatArray:
    """Spherical linear interpolation from ``q0`` (fraction 0) to ``q1`` (fraction 1): the
    rotation at a constant rate about one axis between them."""
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    f = np.asarray(fraction, float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-12
    sin_t = np.where(small, 1.0, np.sin(theta))
    a = np.where(small, 1.0 - f, np.sin((1.0 - f) * theta) / sin_t)
    b = np.where(small, f, np.sin(f * theta) / sin_t)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
