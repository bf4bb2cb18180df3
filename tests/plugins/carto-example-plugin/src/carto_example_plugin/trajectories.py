"""Trajectory model ``example-spline``: cubic splines through the samples (scipy), read back
from model files; the plugin guide's section 12 shows it whole."""

from __future__ import annotations

import attrs
import numpy as np

from carto.framework import InputError, hookimpl
from carto.framework.sdk.sensors import TimeSeries
from carto.framework.sdk.trajectories import TrajectoryModel


@attrs.frozen(eq=False)
class SplineSeries(TimeSeries):
    """Cubic-spline interpolation of samples (``kind`` ``example-spline``)."""

    t_s: np.ndarray
    values: np.ndarray
    kind: str = "example-spline"  # the model's registry name
    _spline: object = attrs.field(init=False, repr=False)

    def __attrs_post_init__(self) -> None:
        from scipy.interpolate import CubicSpline

        object.__setattr__(self, "_spline", CubicSpline(self.t_s, self.values, axis=0))

    def __call__(self, t):  # values at times t: shape (*t.shape, C)
        return self._spline(np.asarray(t, float))

    def derivative(self, t):  # optional: default central differences of 1 ms
        return self._spline(np.asarray(t, float), 1)

    def to_dict(self) -> dict:  # JSON-ready, with "kind"
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
def carto_trajectory_models():
    return [SplineTrajectoryModel()]
