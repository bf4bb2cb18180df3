"""Map projections chosen for a place: the UTM zone of a longitude and latitude."""

from __future__ import annotations

import math
from typing import Any


def utm_crs(lon_deg: float, lat_deg: float) -> Any:
    """The WGS84 UTM zone CRS (pyproj) containing the point."""
    import pyproj

    zone = math.floor((lon_deg + 180.0) / 6.0) % 60 + 1
    return pyproj.CRS.from_epsg((32600 if lat_deg >= 0 else 32700) + zone)
