"""The ``carto`` entry point of carto-pleiades.

``pyproject.toml`` declares this module in the ``carto`` entry-point group::

    [project.entry-points.carto]
    pleiades = "carto.pleiades.plugin"

and the framework calls the hooks below through pluggy. Only public names of
``carto.framework`` are used, as any third-party plugin would.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from carto.framework import hookimpl

if TYPE_CHECKING:  # the hooks import what they return: loading a plugin stays cheap
    from carto.framework.sdk.sensors import SensorType


@hookimpl
def carto_sensor_types() -> Sequence[SensorType]:
    from carto.pleiades.sensor import PleiadesDimapType

    return [PleiadesDimapType()]
