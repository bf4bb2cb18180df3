"""The DEM-generator component kind: what ``carto dem`` asks of a DEM generator."""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any

from carto.framework.component import Component
from carto.framework.geometry.sensor import Sensor


class DEMGenerator(Component):
    """Derives a digital elevation model from overlapping images with known orientation."""

    @abc.abstractmethod
    def generate(self, images: Sequence[Any], sensors: Sequence[Sensor], **options: Any) -> Any:
        """Generate a DEM (and ortho-images and quality layers) from ``images`` seen through
        ``sensors``; ``options`` carry the initial DEM, posting and output CRS."""
