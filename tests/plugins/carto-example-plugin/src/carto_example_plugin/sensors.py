"""Sensor type ``example-affine``: ``*.affine.json`` files (see the package docstring)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from carto.framework import InputError, hookimpl
from carto.framework.sdk.common import as_float_arrays
from carto.framework.sdk.sensors import Sensor, SensorType, refuse_options

FORMAT = "carto-example-affine"


class AffineSensor(Sensor):
    """Ground (lon, lat) <-> image (line, sample) by an affine geotransform; height ignored."""

    def __init__(self, shape: tuple[int, int], geotransform: list[float]) -> None:
        self._shape = (int(shape[0]), int(shape[1]))
        g = np.asarray(geotransform, dtype=float)
        self._forward = np.array([[g[2], g[1]], [g[5], g[4]]])  # d(lon,lat)/d(line,sample)
        self._origin = np.array([g[0], g[3]])

    @property
    def image_shape(self) -> tuple[int, int]:
        return self._shape

    def image_to_ground(self, line, sample, h_m):
        line, sample, _ = as_float_arrays(line, sample, h_m)
        lon = self._origin[0] + self._forward[0, 0] * line + self._forward[0, 1] * sample
        lat = self._origin[1] + self._forward[1, 0] * line + self._forward[1, 1] * sample
        return lon, lat

    def ground_to_image(self, lon_deg, lat_deg, h_m):
        lon, lat, _ = as_float_arrays(lon_deg, lat_deg, h_m)
        inverse = np.linalg.inv(self._forward)
        dlon, dlat = lon - self._origin[0], lat - self._origin[1]
        return inverse[0, 0] * dlon + inverse[0, 1] * dlat, inverse[1, 0] * dlon + inverse[
            1, 1
        ] * dlat


class AffineSensorType(SensorType):
    name = "example-affine"
    description = "Toy affine sensor read from *.affine.json (third-party plugin example)"

    def identify(self, path: Path) -> bool:
        return Path(path).name.endswith(".affine.json")

    def open(self, path: Path, **options) -> Sensor:
        refuse_options(f"{path} (example-affine)", options)
        path = Path(path)
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read affine model: {exc}") from None
        if doc.get("format") != FORMAT:
            raise InputError(f"{path}: field 'format' is {doc.get('format')!r}, not {FORMAT!r}")
        return AffineSensor(doc["shape"], doc["geotransform"])


@hookimpl
def carto_sensor_types():
    return [AffineSensorType()]
