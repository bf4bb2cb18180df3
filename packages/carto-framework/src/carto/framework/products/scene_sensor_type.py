"""Sensor type ``carto-scene``: the images of any scene folder as rigorous line scanners.

Scene folders (``carto simulate``, ``docs/formats.md``) give every image an ancillary file;
this type fits the trajectories and builds the line scanners, whatever the platform. Platform
plugins register more specific types (higher ``priority``) for their own scenes, which name
their adjusters and DEM generators; this one names none.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import save_line_scanner
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.products.scene import Scene, find_scene_manifest


class SceneSensorType(SensorType):
    """Any Carto scene folder, or one image raster of it, as line scanners."""

    name = "carto-scene"
    description = "Carto scene folder (any platform): line scanners from its ancillary files"
    priority = 1  # below the platform plugins' own scene types

    def identify(self, path: Path) -> bool:
        try:
            return find_scene_manifest(Path(path), "") is not None
        except OSError:
            return False

    def open_all(self, path: Path, **options: Any) -> dict[str, Sensor]:
        """Every image of the scene (``options``: ``trajectory_model``, ``components`` and
        the fit options of :meth:`carto.framework.products.ancillary.Ancillary.trajectory`)."""
        manifest = find_scene_manifest(Path(path), "")
        if manifest is None:
            raise InputError(f"{path}: not a Carto scene folder")
        return dict(Scene.open(manifest).sensors(**options))

    def open(self, path: Path, **options: Any) -> Sensor:
        path = Path(path)
        manifest = find_scene_manifest(path, "")
        if manifest is None or path.is_dir() or path.name == "scene.json":
            raise InputError(f"{path}: open one image raster of a scene")
        scene = Scene.open(manifest)
        for name in scene.image_names:
            if scene.raster(name).name == path.name:
                return scene.sensors(**options)[name]
        raise InputError(f"{path}: not an image of {manifest}")

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """The adjusted line scanner as a model file and a fitted RPC."""
        return save_line_scanner(sensor, Path(out_dir), name, h_range_m)
