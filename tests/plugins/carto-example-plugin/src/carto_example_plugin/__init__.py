"""A third-party Carto plugin: an affine toy sensor type and a global-shift matcher.

Sensor type ``example-affine`` opens ``*.affine.json`` files::

    {"format": "carto-example-affine", "version": 1,
     "shape": [n_lines, n_samples],
     "geotransform": [lon0, dlon_dsample, dlon_dline, lat0, dlat_dsample, dlat_dline]}

(GDAL geotransform order: ``lon = lon0 + sample * dlon_dsample + line * dlon_dline``, same for
lat; heights are ignored, as for an ortho-image). Matcher ``example-shift`` estimates one
translation between two images by phase correlation and returns it on a grid of points.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from carto.framework import InputError, hookimpl
from carto.framework.arrays import as_float_arrays
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.matching.base import Matcher, Matches

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

    def open(self, path: Path) -> Sensor:
        path = Path(path)
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read affine model: {exc}") from None
        if doc.get("format") != FORMAT:
            raise InputError(f"{path}: field 'format' is {doc.get('format')!r}, not {FORMAT!r}")
        return AffineSensor(doc["shape"], doc["geotransform"])


class ShiftMatcher(Matcher):
    name = "example-shift"
    description = "One global translation by phase correlation, reported on a grid of points"

    def match(self, left, right) -> Matches:
        a = np.asarray(left, dtype=float)
        b = np.asarray(right, dtype=float)
        cross = np.fft.fft2(a - a.mean()) * np.conj(np.fft.fft2(b - b.mean()))
        surface = np.real(np.fft.ifft2(cross / np.maximum(np.abs(cross), 1e-12)))
        peak = np.unravel_index(np.argmax(surface), surface.shape)
        shift = []
        for axis, p in enumerate(peak):
            n = surface.shape[axis]
            idx = [peak[0], peak[1]]
            idx[axis] = (p - 1) % n
            lo = surface[tuple(idx)]
            idx[axis] = (p + 1) % n
            hi = surface[tuple(idx)]
            denom = lo - 2 * surface[peak] + hi
            sub = 0.5 * (lo - hi) / denom if denom != 0 else 0.0
            s = p + sub
            shift.append(s - n if s > n / 2 else s)
        # left(x) = right(x - shift): the point x in left is at x - shift in right
        lines, samples = np.meshgrid(
            np.linspace(0.5, a.shape[0] - 0.5, 5),
            np.linspace(0.5, a.shape[1] - 0.5, 5),
            indexing="ij",
        )
        lines, samples = lines.ravel(), samples.ravel()
        score = np.full(lines.shape, float(surface[peak]))
        return Matches(lines, samples, lines - shift[0], samples - shift[1], score)


@hookimpl
def carto_sensor_types():
    return [AffineSensorType()]


@hookimpl
def carto_matchers():
    return [ShiftMatcher()]
