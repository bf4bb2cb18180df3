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

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.products.scene import Scene

PLATFORM_PREFIX = "Cartosat-2"


def _scene_manifest(path: Path) -> Path | None:
    if path.is_dir():
        candidate = path / "scene.json"
    elif path.name == "scene.json":
        candidate = path
    elif path.suffix.lower() in (".tif", ".tiff"):
        candidate = path.parent / "scene.json"
    else:
        return None
    try:
        doc = json.loads(candidate.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or not str(doc.get("platform", "")).startswith(PLATFORM_PREFIX):
        return None
    if path.suffix.lower() in (".tif", ".tiff") and not any(
        i.get("raster") == path.name for i in doc.get("images", {}).values()
    ):
        return None
    return candidate


class Cartosat2SensorType(SensorType):
    """Cartosat-2 agile views (one trajectory segment per view) from ancillary data."""

    name = "cartosat2"
    description = "Cartosat-2 agile views: rigorous line scanners, one attitude segment each"
    priority = 10

    def identify(self, path: Path) -> bool:
        try:
            return _scene_manifest(Path(path)) is not None
        except OSError:
            return False

    def open_all(self, path: Path, **fit_options: Any) -> dict[str, Sensor]:
        manifest = _scene_manifest(Path(path))
        if manifest is None:
            raise InputError(f"{path}: not a Cartosat-2 scene")
        return dict(Scene.open(manifest).sensors(**fit_options))

    def open(self, path: Path) -> Sensor:
        path = Path(path)
        manifest = _scene_manifest(path)
        if manifest is None or path.is_dir() or path.name == "scene.json":
            raise InputError(f"{path}: open one image raster of a Cartosat-2 scene")
        sensors = Scene.open(manifest).sensors()
        for name, image in json.loads(manifest.read_text())["images"].items():
            if image["raster"] == path.name:
                return sensors[name]
        raise InputError(f"{path}: not an image of {manifest}")
