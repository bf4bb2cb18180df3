"""The trajectory-model component kind and the framework's two built-in models.

A :class:`TrajectoryModel` turns ephemeris and attitude samples into a continuous
:class:`~carto.framework.geometry.trajectory.Trajectory`. It is chosen by its registry name:
an ancillary file may name it (``"trajectory_model"``), ``carto adjust --trajectory NAME``
overrides that, and a fitted model file stores the name in each of its series, so a model
adjusted with a plugin's trajectory model is read back by that plugin.

A plugin's model implements two methods: :meth:`TrajectoryModel.fit_series` (fit the 6
ephemeris components or the 3 attitude angles over time) and
:meth:`TrajectoryModel.series_from_dict` (read a series back from a model file); everything
else (frames, correction parameters, fit report) is the framework's
:meth:`Trajectory.from_samples`.
"""

from __future__ import annotations

from typing import Any, ClassVar

from carto.framework.component import Component
from carto.framework.errors import InputError
from carto.framework.geometry.time_series import BuiltinSeries, TimeSeries
from carto.framework.geometry.trajectory import (
    AttitudeSamples,
    EphemerisSamples,
    FloatArray,
    Trajectory,
)


class TrajectoryModel(Component):
    """A way of turning ephemeris and attitude samples into a continuous trajectory."""

    def fit(
        self,
        epoch_j2000_s: float,
        ephemeris: EphemerisSamples,
        attitude: AttitudeSamples,
        **options: Any,
    ) -> Trajectory:
        """Build a :class:`Trajectory` from the samples.

        ``options`` are those of :meth:`Trajectory.from_samples` (correction orders and
        sigmas, ``prefix``); the default fits both series with :meth:`fit_series`.
        """
        return Trajectory.from_samples(
            epoch_j2000_s, ephemeris, attitude, interpolation=self, **options
        )

    def fit_series(
        self,
        t_s: FloatArray,
        values: FloatArray,
        *,
        role: str,
        t_mid_s: float,
        t_half_s: float,
    ) -> TimeSeries:
        """A continuous function through samples ``values`` ``(N, C)`` at times ``t_s``.

        Args:
            t_s: sample times, seconds since the trajectory's epoch (increasing).
            values: ``(N, 6)`` ECI position (m) and velocity (m/s) for ``role="orbit"``,
                ``(N, 3)`` attitude angles (rad, unwrapped) for ``role="attitude"``.
            t_mid_s, t_half_s: centre and half length of the samples' time span (for a
                normalised time ``(t - t_mid_s) / t_half_s``).

        Returns:
            a :class:`TimeSeries` whose ``kind`` is this model's ``name``.
        """
        raise NotImplementedError(f"trajectory model {self.name!r} must implement fit_series")

    def series_from_dict(self, d: dict[str, Any]) -> TimeSeries:
        """Read back a series this model wrote (``TimeSeries.to_dict``)."""
        raise NotImplementedError(f"trajectory model {self.name!r} must implement series_from_dict")


class _BuiltinModel(TrajectoryModel):
    """The framework's models: the series of :class:`BuiltinSeries`, with ``points`` (the
    polynomial order, or the Lagrange samples) by role."""

    points: ClassVar[dict[str, int]] = {}

    def fit(
        self,
        epoch_j2000_s: float,
        ephemeris: EphemerisSamples,
        attitude: AttitudeSamples,
        **options: Any,
    ) -> Trajectory:
        return Trajectory.from_samples(
            epoch_j2000_s, ephemeris, attitude, interpolation=self.name, **options
        )

    def fit_series(
        self,
        t_s: FloatArray,
        values: FloatArray,
        *,
        role: str,
        t_mid_s: float,
        t_half_s: float,
    ) -> TimeSeries:
        return BuiltinSeries.fit(t_s, values, self.name, self.points[role], t_mid_s, t_half_s)

    def series_from_dict(self, d: dict[str, Any]) -> TimeSeries:
        if d.get("kind") != self.name:
            raise InputError(f"trajectory model {self.name}: a series of kind {d.get('kind')!r}")
        return BuiltinSeries.from_dict(d)


class PolynomialTrajectoryModel(_BuiltinModel):
    """ISRO's practice: least-squares polynomial of order 1-3 in normalised time."""

    name = "polynomial"
    description = "Least-squares polynomial (order 1-3) per component of ephemeris and attitude"
    points: ClassVar[dict[str, int]] = {"orbit": 3, "attitude": 3}


class LagrangeTrajectoryModel(_BuiltinModel):
    """Lagrange interpolation through the samples nearest each time."""

    name = "lagrange"
    description = "Lagrange interpolation (8 samples for ephemeris, 4 for attitude)"
    points: ClassVar[dict[str, int]] = {"orbit": 8, "attitude": 4}
