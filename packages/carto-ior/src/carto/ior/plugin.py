"""The ``carto`` entry point of carto-ior.

Registered in the distribution's ``[project.entry-points.carto]``; the framework loads it with
pluggy.
"""

from __future__ import annotations

from collections.abc import Sequence

from carto.framework import hookimpl
from carto.framework.sdk.dem import DEMGenerator
from carto.ior.generator import IORGenerator


@hookimpl
def carto_dem_generators() -> Sequence[DEMGenerator]:
    return [IORGenerator()]
