"""DEM generator ``ior``: iterative ortho-image refinement (:mod:`carto.ior.refine`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import attrs
import numpy as np

from carto.framework.dem_generation.base import DEMGenerator
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.raster.dem import DEM
from carto.ior.refine import IORResult, IORSettings, refine_dem

_SETTINGS = {f.name for f in attrs.fields(IORSettings)}


class IORGenerator(DEMGenerator):
    """DEM and ortho-images of a stereo pair by iterative ortho-image refinement."""

    name = "ior"
    description = "DEM + ortho-images by iterative ortho-image refinement (Radhadevi et al. 2010)"

    def generate(
        self, images: Sequence[Any], sensors: Sequence[Sensor], **options: Any
    ) -> IORResult:
        """``images``: the left and right raw images (2-D arrays, staggered arrays merged);
        ``sensors``: their models. Options: ``init_dem`` (a :class:`DEM`, required),
        ``progress`` (callable taking a line), ``scheduler`` (see :func:`refine_dem`) and the
        fields of :class:`IORSettings` (``posting_m``, ``ortho_res_m``, ``crs``,
        ``max_iterations`` ...)."""
        if len(images) != 2 or len(sensors) != 2:
            raise InputError(
                f"ior: needs exactly two images and two sensors, got {len(images)} and "
                f"{len(sensors)}"
            )
        init_dem = options.pop("init_dem", None)
        if not isinstance(init_dem, DEM):
            raise InputError("ior: option init_dem (a DEM or a constant height) is required")
        progress = options.pop("progress", None)
        scheduler = options.pop("scheduler", None)
        unknown = sorted(set(options) - _SETTINGS)
        if unknown:
            known = ", ".join(sorted(_SETTINGS))
            raise InputError(f"ior: unknown option(s) {', '.join(unknown)} (known: {known})")
        settings = IORSettings(**{k: v for k, v in options.items() if v is not None})
        left, right = (np.asarray(i) for i in images)
        return refine_dem(
            left, right, sensors[0], sensors[1], init_dem, settings, progress, scheduler
        )
