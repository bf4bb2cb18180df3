"""carto.pleiades: the Pleiades DIMAP v1.4 physical sensor model as a Carto line scanner.

An example third-party plugin: a separate distribution that uses only the public API of
``carto.framework`` and registers the sensor type ``pleiades-dimap`` through the ``carto``
entry-point group (``docs/writing-a-plugin.md`` walks through it).

    from carto.pleiades import open_dimap

    sensor = open_dimap("PHRDIMAP_P1BP--2018122638935449CP.XML")
    line, sample = sensor.ground_to_image(lon_deg, lat_deg, h_m)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from carto.pleiades.dimap import DimapSensorModel, is_dimap_v14_sensor, read_dimap
    from carto.pleiades.sensor import PleiadesDimapType, line_scanner_from_dimap, open_dimap

_HOMES = {
    "DimapSensorModel": "carto.pleiades.dimap",
    "is_dimap_v14_sensor": "carto.pleiades.dimap",
    "read_dimap": "carto.pleiades.dimap",
    "PleiadesDimapType": "carto.pleiades.sensor",
    "line_scanner_from_dimap": "carto.pleiades.sensor",
    "open_dimap": "carto.pleiades.sensor",
}

__all__ = [
    "DimapSensorModel",
    "PleiadesDimapType",
    "is_dimap_v14_sensor",
    "line_scanner_from_dimap",
    "open_dimap",
    "read_dimap",
]


def __getattr__(name: str) -> Any:
    """The public names, imported on first use (loading the plugin's entry point, the
    package's ``plugin`` module, stays cheap)."""
    if name in _HOMES:
        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'carto.pleiades' has no attribute {name!r}")
