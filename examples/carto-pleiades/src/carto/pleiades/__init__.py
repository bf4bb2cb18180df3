"""carto.pleiades: the Pleiades DIMAP v1.4 physical sensor model as a Carto line scanner.

An example third-party plugin: a separate distribution that uses only the public API of
``carto.framework`` and registers the sensor type ``pleiades-dimap`` through the ``carto``
entry-point group (``docs/writing-a-plugin.md`` walks through it).

    from carto.pleiades import open_dimap

    sensor = open_dimap("PHRDIMAP_P1BP--2018122638935449CP.XML")
    line, sample = sensor.ground_to_image(lon_deg, lat_deg, h_m)
"""

from __future__ import annotations

from carto.pleiades.dimap import DimapSensorModel, is_dimap_v14_sensor, read_dimap
from carto.pleiades.sensor import PleiadesDimapType, line_scanner_from_dimap, open_dimap

__all__ = [
    "DimapSensorModel",
    "PleiadesDimapType",
    "is_dimap_v14_sensor",
    "line_scanner_from_dimap",
    "open_dimap",
    "read_dimap",
]
