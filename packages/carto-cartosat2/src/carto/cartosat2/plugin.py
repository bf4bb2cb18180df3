"""The ``carto`` entry point of carto-cartosat2.

Registered in the distribution's ``[project.entry-points.carto]``; the framework loads it with
pluggy. Components are added here as they are implemented and tested; each hook imports what
it returns only when called, so loading the plugin stays cheap.
"""

from __future__ import annotations

from carto.framework.sdk.hooks import component_hook

carto_scene_presets = component_hook(
    "carto.cartosat2.presets", "TripletPreset", "PaintbrushPreset", "StereoPaintbrushPreset"
)
carto_sensor_types = component_hook("carto.cartosat2.sensor", "Cartosat2SensorType")
carto_adjusters = component_hook("carto.cartosat2.adjust", "Cartosat2BlockAdjuster")
