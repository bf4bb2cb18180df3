"""Detector look directions of the reference geometry, from the camera's constants as the
product states them (``docs/formats.md``, ``docs/conventions.md``):

* camera frame: ``Z`` the boresight, ``X`` along track (the flight direction), ``Y`` to the
  right of it;
* detector ``k`` (0-based) of an ``n``-detector line sits at ``y = -(k + 1/2 - n/2) pitch +
  across_offset`` (detector indices grow to the left), continuous sample ``s = k + 1/2`` at its
  centre; the odd array (even 0-based ``k``) at ``x = along_offset``, the even array
  ``stagger`` further in the flight direction; the whole line then turned by ``rotation`` in
  the focal plane (about the optical axis, from ``X`` towards ``Y``);
* the look direction is ``(x / f, y / f, 1)``; camera -> payload is the mounting
  ``Rz(yaw) Ry(pitch) Rx(roll)``, payload -> body the alignment.
"""

from __future__ import annotations

import math

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.simulation.reference import rotations

FloatArray = NDArray[np.float64]


@attrs.frozen
class CameraGeometry:
    """The true geometry of one linear-array camera (lengths in metres, angles in degrees)."""

    n_detectors: int
    focal_length_m: float
    pitch_m: float
    stagger_m: float = 0.0
    along_offset_m: float = 0.0
    mounting_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    alignment_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    across_offset_m: float = 0.0
    rotation_rad: float = 0.0

    def camera_to_body(self) -> FloatArray:
        """Quaternion camera -> body: alignment after mounting."""
        m = rotations.from_rpy(*(math.radians(a) for a in self.mounting_rpy_deg))
        a = rotations.from_rpy(*(math.radians(a) for a in self.alignment_rpy_deg))
        return rotations.multiply(a, m)

    def focal_plane(
        self, sample: ArrayLike, even: ArrayLike = False
    ) -> tuple[FloatArray, FloatArray]:
        """Focal-plane position ``(x, y)`` (metres) of continuous detector-line samples."""
        s = np.asarray(sample, float)
        x0 = self.along_offset_m + np.where(np.asarray(even, bool), self.stagger_m, 0.0)
        y0 = -(s - 0.5 * self.n_detectors) * self.pitch_m + self.across_offset_m
        c, si = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return x0 * c - y0 * si, x0 * si + y0 * c

    def look(self, sample: ArrayLike, even: ArrayLike = False) -> FloatArray:
        """Unit look directions in the camera frame ``(..., 3)`` of continuous detector-line
        samples (``even``: the even array's)."""
        x, y = self.focal_plane(sample, even)
        x, y = np.broadcast_arrays(x, y)
        v = np.stack([x / self.focal_length_m, y / self.focal_length_m, np.ones_like(x)], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def line_condition(self, tan_x: ArrayLike, tan_y: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """For an apparent direction ``(tan_x, tan_y, 1)``: its along-track distance from the
        odd array in the focal plane (metres; zero when the array sees it) and the continuous
        sample of the detector it falls on."""
        x = np.asarray(tan_x, float) * self.focal_length_m
        y = np.asarray(tan_y, float) * self.focal_length_m
        c, si = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        x0 = x * c + y * si  # back to the unrotated line
        y0 = -x * si + y * c
        sample = 0.5 * self.n_detectors - (y0 - self.across_offset_m) / self.pitch_m
        return x0 - self.along_offset_m, sample
