"""The ``carto`` entry point of carto-cartosat1.

Registered in the distribution's ``[project.entry-points.carto]``; the framework loads it with
pluggy. Components are added here as they are implemented and tested.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from carto.framework import hookimpl

if TYPE_CHECKING:  # the hooks import what they return: loading a plugin stays cheap
    from carto.framework.sdk.adjusters import Adjuster
    from carto.framework.sdk.presets import ScenePreset
    from carto.framework.sdk.sensors import SensorType


@hookimpl
def carto_scene_presets() -> Sequence[ScenePreset]:
    from carto.cartosat1.presets import Cartosat1PairPreset, Cartosat1StripPreset

    return [Cartosat1PairPreset(), Cartosat1StripPreset()]


@hookimpl
def carto_sensor_types() -> Sequence[SensorType]:
    from carto.cartosat1.sensor import Cartosat1SensorType

    return [Cartosat1SensorType()]


@hookimpl
def carto_adjusters() -> Sequence[Adjuster]:
    from carto.cartosat1.adjust import Cartosat1Adjuster

    return [Cartosat1Adjuster()]
