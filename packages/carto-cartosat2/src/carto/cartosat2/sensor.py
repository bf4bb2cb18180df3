"""Sensor type ``cartosat2``: agile Cartosat-2 acquisitions as rigorous line scanners.

Each view of a triplet or paint-brush set has its own ancillary file (its own attitude segment:
the platform steers between views), so every image becomes a line scanner on its own fitted
trajectory, with asynchronous line timing as the product gives it. Open the scene folder (all
views, :meth:`Cartosat2SensorType.open_all`) or one raster of it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from carto.framework.sdk.common import InputError
from carto.framework.sdk.presets import Scene, find_scene_manifest
from carto.framework.sdk.sensors import Sensor, SensorType, save_line_scanner

PLATFORM_PREFIX = "Cartosat-2"


def _scene_manifest(path: Path) -> Path | None:
    return find_scene_manifest(path, PLATFORM_PREFIX)


class Cartosat2SensorType(SensorType):
    """Cartosat-2 agile views (one trajectory segment per view) from ancillary data."""

    name = "cartosat2"
    description = "Cartosat-2 agile views: rigorous line scanners, one attitude segment each"
    priority = 10
    default_adjuster = "cartosat2-bba"
    default_dem_generator = "ior"

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """A view's line scanner as a model file and a fitted RPC."""
        return save_line_scanner(sensor, Path(out_dir), name, h_range_m)

    def identify(self, path: Path) -> bool:
        try:
            return _scene_manifest(Path(path)) is not None
        except OSError:
            return False

    def open_all(self, path: Path, **options: Any) -> dict[str, Sensor]:
        """Every view of a scene; ``options``: ``trajectory_model``, ``components`` (see
        :meth:`SensorType.open_all`) and the fit options of
        :meth:`carto.framework.products.ancillary.Ancillary.trajectory`."""
        manifest = _scene_manifest(Path(path))
        if manifest is None:
            raise InputError(f"{path}: not a Cartosat-2 scene")
        return dict(Scene.open(manifest).sensors(**options))

    def open(self, path: Path, **options: Any) -> Sensor:
        path = Path(path)
        manifest = _scene_manifest(path)
        if manifest is None or path.is_dir() or path.name == "scene.json":
            raise InputError(f"{path}: open one image raster of a Cartosat-2 scene")
        sensors = Scene.open(manifest).sensors(**options)
        for name, image in json.loads(manifest.read_text())["images"].items():
            if image["raster"] == path.name:
                return sensors[name]
        raise InputError(f"{path}: not an image of {manifest}")
