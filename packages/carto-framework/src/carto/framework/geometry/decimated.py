"""A sensor seen on its image reduced ``factor`` times (:class:`DecimatedSensor`): the model
of a :class:`~carto.framework.raster.image_source.DecimatedImage`, what the coarse stages of
a coarse-to-fine DEM generator orthorectify and match.

With pixel edges at whole coordinates (the first pixel's centre at 0.5), reduced pixel ``j``
spans the source's ``[j f, (j + 1) f)``: image coordinates divide by ``f``, exactly."""

from __future__ import annotations

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.geometry.sensor import Sensor
from carto.framework.raster.image_source import decimation_factor

__all__ = ["DecimatedSensor"]

FloatArray = NDArray[np.float64]


@attrs.frozen(eq=False)
class DecimatedSensor(Sensor):
    """``sensor`` on its image reduced ``factor`` times (see the module docstring)."""

    sensor: Sensor
    factor: int = attrs.field(validator=decimation_factor("sensor"))

    @property
    def name(self) -> str | None:
        return getattr(self.sensor, "name", None)

    @property
    def image_shape(self) -> tuple[int, int]:
        n_l, n_s = self.sensor.image_shape
        return (n_l // self.factor, n_s // self.factor)

    @property
    def ray_heights_m(self) -> tuple[float, float]:
        return self.sensor.ray_heights_m

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line, sample = self.sensor.ground_to_image(lon_deg, lat_deg, h_m)
        return np.asarray(line) / self.factor, np.asarray(sample) / self.factor

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        f = float(self.factor)
        return self.sensor.image_to_ground(np.asarray(line) * f, np.asarray(sample) * f, h_m)

    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        line, sample, _ = self.sensor.project(lon_deg, lat_deg, h_m)
        line, sample = np.asarray(line) / self.factor, np.asarray(sample) / self.factor
        n_l, n_s = self.image_shape
        inside = (line >= 0) & (line <= n_l) & (sample >= 0) & (sample <= n_s)
        return line, sample, inside
