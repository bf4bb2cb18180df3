"""The trajectory-model component kind and the framework's two built-in models.

A :class:`TrajectoryModel` turns ephemeris and attitude samples into a continuous
:class:`~carto.framework.geometry.trajectory.Trajectory`. Ancillary files and model files name
the model by its registry name.
"""

from __future__ import annotations

import abc
from typing import Any

from carto.framework.component import Component
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory


class TrajectoryModel(Component):
    """A way of turning ephemeris and attitude samples into a continuous trajectory."""

    @abc.abstractmethod
    def fit(
        self,
        epoch_j2000_s: float,
        ephemeris: EphemerisSamples,
        attitude: AttitudeSamples,
        **options: Any,
    ) -> Trajectory:
        """Build a :class:`Trajectory` from the samples; ``options`` are model specific."""


class PolynomialTrajectoryModel(TrajectoryModel):
    """ISRO's practice: least-squares polynomial of order 1-3 in normalised time."""

    name = "polynomial"
    description = "Least-squares polynomial (order 1-3) per component of ephemeris and attitude"

    def fit(
        self,
        epoch_j2000_s: float,
        ephemeris: EphemerisSamples,
        attitude: AttitudeSamples,
        **options: Any,
    ) -> Trajectory:
        return Trajectory.from_samples(
            epoch_j2000_s, ephemeris, attitude, interpolation="polynomial", **options
        )


class LagrangeTrajectoryModel(TrajectoryModel):
    """Lagrange interpolation through the samples nearest each time."""

    name = "lagrange"
    description = "Lagrange interpolation (8 samples for ephemeris, 4 for attitude)"

    def fit(
        self,
        epoch_j2000_s: float,
        ephemeris: EphemerisSamples,
        attitude: AttitudeSamples,
        **options: Any,
    ) -> Trajectory:
        return Trajectory.from_samples(
            epoch_j2000_s, ephemeris, attitude, interpolation="lagrange", **options
        )
