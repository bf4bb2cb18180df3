"""Functions of time fitted to samples: what a trajectory is made of.

A :class:`TimeSeries` gives vector values (the 6 ECI position and velocity components of an
orbit, or 3 attitude angles) at any time of a trajectory; its ``kind`` names the trajectory
model that fitted it. The framework's own kinds are :class:`BuiltinSeries`: a least-squares
polynomial in normalised time, or Lagrange interpolation through the samples nearest each time.
A plugin's trajectory model brings its own series (:class:`SeriesModel`).
"""

from __future__ import annotations

import abc
from typing import Any, Literal, Protocol

import attrs
import numpy as np
from numpy.polynomial import polynomial as npoly
from numpy.typing import NDArray

from carto.framework.errors import InputError

FloatArray = NDArray[np.float64]


Interpolation = Literal["polynomial", "lagrange"]


class TimeSeries(abc.ABC):
    """A vector-valued function of time fitted to samples: what a trajectory model makes of
    the ephemeris (6 components: position and velocity, ECI) and of the attitude (3 angles).

    ``kind`` is the registry name of the trajectory model that made it; a model file stores
    :meth:`to_dict`, which the model's ``series_from_dict`` reads back. Times are seconds
    since the trajectory's epoch.
    """

    kind: str

    @abc.abstractmethod
    def __call__(self, t: FloatArray) -> FloatArray:
        """Values at times ``t`` (any shape): shape ``(*t.shape, C)``."""

    def derivative(self, t: FloatArray) -> FloatArray:
        """d value / d t (per second); central differences of 1 ms by default."""
        h = 1e-3
        return (self(t + h) - self(t - h)) / (2 * h)

    @abc.abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready state, with ``"kind"`` (the model's registry name)."""


class SeriesModel(Protocol):
    """What :meth:`Trajectory.from_samples` needs of a trajectory model that is not built in
    (:class:`carto.framework.geometry.trajectory_models.TrajectoryModel` provides it)."""

    name: str

    def fit_series(
        self, t_s: FloatArray, values: FloatArray, *, role: str, t_mid_s: float, t_half_s: float
    ) -> TimeSeries: ...

    def series_from_dict(self, d: dict[str, Any]) -> TimeSeries: ...


BUILTIN_KINDS = ("polynomial", "lagrange")
"""The series kinds the framework reads without the registry."""


@attrs.frozen(eq=False)
class BuiltinSeries(TimeSeries):
    """Vector-valued function of time: polynomial in normalised time, or Lagrange."""

    kind: Interpolation
    t_mid_s: float
    t_half_s: float
    coeffs: FloatArray | None = None  # (order+1, C): value = sum_k coeffs[k] * tau**k
    samples_t: FloatArray | None = None  # (N,)
    samples_v: FloatArray | None = None  # (N, C)
    lagrange_points: int = 8

    @classmethod
    def fit(
        cls,
        t: FloatArray,
        values: FloatArray,
        kind: Interpolation,
        order: int,
        t_mid: float,
        t_half: float,
    ) -> BuiltinSeries:
        if kind == "polynomial":
            if order not in (1, 2, 3):
                raise InputError(f"polynomial order must be 1, 2 or 3, got {order}")
            tau = (t - t_mid) / t_half
            coeffs = npoly.polyfit(tau, values, order)
            return cls("polynomial", t_mid, t_half, coeffs=np.atleast_2d(coeffs))
        if kind == "lagrange":
            points = min(order, t.shape[0])
            return cls(
                "lagrange", t_mid, t_half, samples_t=t, samples_v=values, lagrange_points=points
            )
        raise InputError(f"interpolation must be 'polynomial' or 'lagrange', got {kind!r}")

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": self.kind, "t_mid_s": self.t_mid_s, "t_half_s": self.t_half_s}
        if self.kind == "polynomial":
            d["coeffs"] = self.coeffs.tolist()
        else:
            d["samples_t"] = self.samples_t.tolist()
            d["samples_v"] = self.samples_v.tolist()
            d["lagrange_points"] = self.lagrange_points
        return d

    @classmethod
    def from_dict(cls, s: dict[str, Any]) -> BuiltinSeries:
        if s["kind"] == "polynomial":
            return cls(
                "polynomial",
                float(s["t_mid_s"]),
                float(s["t_half_s"]),
                coeffs=np.asarray(s["coeffs"], float),
            )
        return cls(
            "lagrange",
            float(s["t_mid_s"]),
            float(s["t_half_s"]),
            samples_t=np.asarray(s["samples_t"], float),
            samples_v=np.asarray(s["samples_v"], float),
            lagrange_points=int(s["lagrange_points"]),
        )

    def __call__(self, t: FloatArray) -> FloatArray:
        if self.kind == "polynomial":
            tau = (t - self.t_mid_s) / self.t_half_s
            out = np.zeros((*tau.shape, self.coeffs.shape[1]))
            for k in range(self.coeffs.shape[0] - 1, -1, -1):  # Horner
                out = out * tau[..., None] + self.coeffs[k]
            return out
        return _lagrange(self.samples_t, self.samples_v, t, self.lagrange_points)

    def derivative(self, t: FloatArray) -> FloatArray:
        """d value / d t (per second)."""
        if self.kind == "polynomial":
            tau = (t - self.t_mid_s) / self.t_half_s
            order = self.coeffs.shape[0] - 1
            out = np.zeros((*tau.shape, self.coeffs.shape[1]))
            for k in range(order, 0, -1):
                out = out * tau[..., None] + k * self.coeffs[k]
            return out / self.t_half_s
        h = 1e-3
        return (self(t + h) - self(t - h)) / (2 * h)


def _lagrange(ts: FloatArray, vs: FloatArray, t: FloatArray, points: int) -> FloatArray:
    """Lagrange interpolation with ``points`` samples centred on each ``t`` (vectorised)."""
    n = ts.shape[0]
    points = min(points, n)
    idx = np.searchsorted(ts, t) - points // 2
    idx = np.clip(idx, 0, n - points)
    window = idx[..., None] + np.arange(points)  # (..., P)
    tw = ts[window]
    out = np.zeros((*t.shape, vs.shape[1]))
    for j in range(points):
        w = np.ones(t.shape)
        for m in range(points):
            if m != j:
                w = w * (t - tw[..., m]) / (tw[..., j] - tw[..., m])
        out += w[..., None] * vs[window[..., j]]
    return out
