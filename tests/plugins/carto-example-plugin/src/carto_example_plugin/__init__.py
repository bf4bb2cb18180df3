"""A third-party Carto plugin: an affine toy sensor type, two matchers and a trajectory model.

Sensor type ``example-affine`` opens ``*.affine.json`` files::

    {"format": "carto-example-affine", "version": 1,
     "shape": [n_lines, n_samples],
     "geotransform": [lon0, dlon_dsample, dlon_dline, lat0, dlat_dsample, dlat_dline]}

(GDAL geotransform order: ``lon = lon0 + sample * dlon_dsample + line * dlon_dline``, same for
lat; heights are ignored, as for an ortho-image). Matcher ``example-shift`` estimates one
translation between two images by phase correlation and returns it at the points asked for.

Matcher ``example-biased`` is the framework's ``ncc`` matcher (looked up in the registry, as a
plugin would) with every match moved by ``BIAS_PX`` pixels along lines, sparse and dense: a
test uses it to show that ``carto adjust --matcher`` and ``carto dem --matcher`` really use the
matcher they are given.

Trajectory model ``example-spline`` interpolates the ephemeris and attitude samples with cubic
splines (scipy), and reads its own series back from model files.
"""

from __future__ import annotations

import json
from pathlib import Path

import attrs
import numpy as np

from carto.framework import InputError, get_registry, hookimpl
from carto.framework.sdk.common import as_float_arrays
from carto.framework.sdk.matchers import Matcher, Matches, OffsetField
from carto.framework.sdk.sensors import Sensor, SensorType, TimeSeries, refuse_options
from carto.framework.sdk.trajectories import TrajectoryModel

BIAS_PX = 0.75
"""The shift ``example-biased`` adds to every match, pixels along lines."""

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


def _phase_shift(a: np.ndarray, b: np.ndarray) -> tuple[list[float], float]:
    """The translation of ``a`` to ``b`` by phase correlation, and the peak's height."""
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
    return shift, float(surface[peak])


class ShiftMatcher(Matcher):
    name = "example-shift"
    description = "One global translation by phase correlation, reported at the given points"

    def match(self, left, right) -> Matches:
        a = np.asarray(left, dtype=float)
        lines, samples = np.meshgrid(
            np.linspace(0.5, a.shape[0] - 0.5, 5),
            np.linspace(0.5, a.shape[1] - 0.5, 5),
            indexing="ij",
        )
        return self.match_points(left, right, np.stack([lines.ravel(), samples.ravel()], 1))

    def match_points(self, left, right, points, *, guess_offsets=None, settings=None) -> Matches:
        a = np.asarray(left, dtype=float)
        b = np.asarray(right, dtype=float)
        shift, peak = _phase_shift(np.nan_to_num(a), np.nan_to_num(b))
        pts = np.asarray(points, float).reshape(-1, 2)
        # left(x) = right(x - shift): the point x in left is at x - shift in right
        score = np.full(pts.shape[0], peak)
        return Matches(pts[:, 0], pts[:, 1], pts[:, 0] - shift[0], pts[:, 1] - shift[1], score)


class BiasedMatcher(Matcher):
    name = "example-biased"
    description = f"the ncc matcher with every match moved {BIAS_PX} px along lines (tests)"

    @staticmethod
    def _ncc() -> Matcher:
        return get_registry().get("matcher", "ncc")

    def match_points(self, left, right, points, *, guess_offsets=None, settings=None) -> Matches:
        found = self._ncc().match_points(
            left, right, points, guess_offsets=guess_offsets, settings=settings
        )
        return attrs.evolve(found, right_line=found.right_line + BIAS_PX)

    def match_dense(self, left, right, *, settings=None) -> OffsetField:
        field = self._ncc().match_dense(left, right, settings=settings)
        return attrs.evolve(field, d_row=field.d_row + np.float32(BIAS_PX))


@attrs.frozen(eq=False)
class SplineSeries(TimeSeries):
    """Cubic-spline interpolation of samples (``kind`` ``example-spline``)."""

    t_s: np.ndarray
    values: np.ndarray
    kind: str = "example-spline"
    _spline: object = attrs.field(init=False, repr=False)

    def __attrs_post_init__(self) -> None:
        from scipy.interpolate import CubicSpline

        object.__setattr__(self, "_spline", CubicSpline(self.t_s, self.values, axis=0))

    def __call__(self, t):
        return self._spline(np.asarray(t, float))

    def derivative(self, t):
        return self._spline(np.asarray(t, float), 1)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "t_s": self.t_s.tolist(), "values": self.values.tolist()}


class SplineTrajectoryModel(TrajectoryModel):
    name = "example-spline"
    description = "cubic-spline interpolation of ephemeris and attitude samples (tests)"

    def fit_series(self, t_s, values, *, role, t_mid_s, t_half_s) -> TimeSeries:
        return SplineSeries(np.asarray(t_s, float), np.asarray(values, float))

    def series_from_dict(self, d) -> TimeSeries:
        if d.get("kind") != self.name:
            raise InputError(f"example-spline: a series of kind {d.get('kind')!r}")
        return SplineSeries(np.asarray(d["t_s"], float), np.asarray(d["values"], float))


@hookimpl
def carto_sensor_types():
    return [AffineSensorType()]


@hookimpl
def carto_matchers():
    return [ShiftMatcher(), BiasedMatcher()]


@hookimpl
def carto_trajectory_models():
    return [SplineTrajectoryModel()]
