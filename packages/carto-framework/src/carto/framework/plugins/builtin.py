"""The framework's own components, registered like any plugin through its entry point.

``carto-framework`` declares this module in its ``[project.entry-points.carto]``, so the
components it provides are listed and looked up exactly like a third party's.
"""

from __future__ import annotations

from collections.abc import Sequence

from carto.framework.adjustment.base import Adjuster
from carto.framework.adjustment.rpc_bias import RPCBiasAdjuster
from carto.framework.geometry.linescan.scanner import LineScannerModelType
from carto.framework.geometry.rpc.sensor import RPCSensorType
from carto.framework.geometry.sensor import SensorType
from carto.framework.geometry.trajectory_models import (
    LagrangeTrajectoryModel,
    PolynomialTrajectoryModel,
    TrajectoryModel,
)
from carto.framework.matching.base import Matcher
from carto.framework.matching.ncc_matcher import NCCMatcher
from carto.framework.plugins.hooks import hookimpl
from carto.framework.products.scene_sensor_type import SceneSensorType
from carto.framework.simulation.generic_pair import GenericPairPreset
from carto.framework.simulation.preset import ScenePreset


@hookimpl
def carto_sensor_types() -> Sequence[SensorType]:
    return [LineScannerModelType(), RPCSensorType(), SceneSensorType()]


@hookimpl
def carto_trajectory_models() -> Sequence[TrajectoryModel]:
    return [PolynomialTrajectoryModel(), LagrangeTrajectoryModel()]


@hookimpl
def carto_adjusters() -> Sequence[Adjuster]:
    return [RPCBiasAdjuster()]


@hookimpl
def carto_matchers() -> Sequence[Matcher]:
    from carto.framework.matching.sgm_matcher import SGMMatcher
    from carto.framework.matching.tiepoints import OrthoTiePointMatcher

    return [NCCMatcher(), OrthoTiePointMatcher(), SGMMatcher()]


@hookimpl
def carto_scene_presets() -> Sequence[ScenePreset]:
    return [GenericPairPreset()]
