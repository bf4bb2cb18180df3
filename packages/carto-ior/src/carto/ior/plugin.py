"""The ``carto`` entry point of carto-ior.

Registered in the distribution's ``[project.entry-points.carto]``; the framework loads it with
pluggy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from carto.framework import hookimpl

if TYPE_CHECKING:  # the hooks import what they return: loading a plugin stays cheap
    from carto.framework.sdk.dem import DEMGenerator


@hookimpl
def carto_dem_generators() -> Sequence[DEMGenerator]:
    from carto.ior.generator import IORGenerator

    return [IORGenerator()]
