"""The framework's own components, registered like any plugin through its entry point.

``carto-framework`` declares this module in its ``[project.entry-points.carto]``, so the
components it provides are listed and looked up exactly like a third party's.
"""

from __future__ import annotations

from collections.abc import Sequence

from carto.framework.adjust import Adjuster, RPCBiasAdjuster
from carto.framework.linescan import LineScannerModelType
from carto.framework.match import Matcher, NCCMatcher
from carto.framework.plugins import hookimpl
from carto.framework.rpc import RPCSensorType
from carto.framework.sensor import SensorType
from carto.framework.trajectory import (
    LagrangeTrajectoryModel,
    PolynomialTrajectoryModel,
    TrajectoryModel,
)


@hookimpl
def carto_sensor_types() -> Sequence[SensorType]:
    return [LineScannerModelType(), RPCSensorType()]


@hookimpl
def carto_trajectory_models() -> Sequence[TrajectoryModel]:
    return [PolynomialTrajectoryModel(), LagrangeTrajectoryModel()]


@hookimpl
def carto_adjusters() -> Sequence[Adjuster]:
    return [RPCBiasAdjuster()]


@hookimpl
def carto_matchers() -> Sequence[Matcher]:
    from carto.framework.tiepoints import OrthoTiePointMatcher

    return [NCCMatcher(), OrthoTiePointMatcher()]
