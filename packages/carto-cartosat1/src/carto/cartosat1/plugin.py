"""The ``carto`` entry point of carto-cartosat1.

Registered in the distribution's ``[project.entry-points.carto]``; the framework loads it with
pluggy. Components are added here as they are implemented and tested; each hook imports what
it returns only when called, so loading the plugin stays cheap.
"""

from __future__ import annotations

from carto.framework.sdk.hooks import component_hook

carto_scene_presets = component_hook(
    "carto.cartosat1.presets", "Cartosat1PairPreset", "Cartosat1StripPreset"
)
carto_sensor_types = component_hook("carto.cartosat1.sensor", "Cartosat1SensorType")
carto_adjusters = component_hook("carto.cartosat1.adjust", "Cartosat1Adjuster")
