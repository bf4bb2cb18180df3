"""Sensors: the geometric model of one image, and sensor types that open products as sensors.

Conventions (see ``docs/conventions.md``):

* Image coordinates are continuous ``(line, sample)`` in pixels, with the **centre of the first
  pixel at (0.5, 0.5)** and its outer corner at (0, 0): the convention of GDAL's RPC transformer
  and of rasterio. ``line`` grows down the image (along track, with time), ``sample`` across.
* Ground coordinates are geodetic WGS84 longitude and latitude in degrees and height in metres
  above the WGS84 **ellipsoid**.
* Every method works on arrays of any shape that broadcast together, and returns arrays of the
  broadcast shape. Points that cannot be computed (outside the model's domain) come back as NaN.
"""

from __future__ import annotations

import abc
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.component import Component

FloatArray = NDArray[np.float64]


class Sensor(abc.ABC):
    """The geometric model of one image: ground <-> image.

    Implementations: the rigorous line scanner and the RPC model in the framework, and any sensor
    a plugin adds.
    """

    @property
    @abc.abstractmethod
    def image_shape(self) -> tuple[int, int]:
        """Image size as ``(n_lines, n_samples)``."""

    @abc.abstractmethod
    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Project ground points into the image.

        Args:
            lon_deg, lat_deg: WGS84 geodetic longitude and latitude, degrees.
            h_m: height above the WGS84 ellipsoid, metres.

        Returns:
            ``(line, sample)`` in pixels (first pixel centre at 0.5, 0.5); NaN where the point
            has no image in the model's domain.
        """

    @abc.abstractmethod
    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Locate image points on the surface at ellipsoidal height ``h_m``.

        Returns:
            ``(lon_deg, lat_deg)``; NaN where the location cannot be computed.
        """


class SensorType(Component):
    """A kind of product that can be opened as a :class:`Sensor` (like a GDAL driver).

    ``identify`` must be cheap and must not raise for foreign files: ``carto project MODEL``
    asks every registered sensor type in turn which of them can open ``MODEL``.
    """

    @abc.abstractmethod
    def identify(self, path: Path) -> bool:
        """Return True if ``path`` looks like a product this sensor type opens."""

    @abc.abstractmethod
    def open(self, path: Path) -> Sensor:
        """Open ``path`` as a sensor; raise :class:`carto.framework.errors.InputError` naming
        the file and field when it is not a valid product of this type."""


def as_float_arrays(*values: ArrayLike) -> tuple[FloatArray, ...]:
    """Broadcast the arguments together as float64 arrays (the sensors' input convention)."""
    arrays = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in values))
    return tuple(np.array(a, dtype=np.float64) for a in arrays)
