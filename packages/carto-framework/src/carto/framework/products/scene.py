"""Scene folders: the products ``carto simulate`` writes (``docs/formats.md``), read as
images, ancillary files, control tables and truth.

:class:`Scene` opens a folder by its ``scene.json``; :func:`find_scene_manifest` tells a
sensor type cheaply whether a path is (or is an image of) a scene of its platform.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import attrs

from carto.framework.errors import InputError
from carto.framework.files.documents import read_json_document
from carto.framework.geometry.linescan import LineScanner

SCENE_FORMAT = "carto-scene"
SCENE_VERSION = 1


@attrs.frozen(eq=False)
class Scene:
    """A scene folder written by ``carto simulate`` (see ``docs/formats.md``).

    Attributes:
        root: the folder.
        manifest: the parsed ``scene.json``.
    """

    root: Path
    manifest: dict[str, Any]

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> Scene:
        """Open a scene folder (or its ``scene.json``); errors name the file and field."""
        path = Path(path)
        manifest_path = path / "scene.json" if path.is_dir() else path
        doc = read_json_document(manifest_path, SCENE_FORMAT, SCENE_VERSION, "scene manifest")
        for key in ("images", "gcps", "checkpoints"):
            if key not in doc:
                raise InputError(f"{manifest_path}: missing field {key!r}")
        return cls(manifest_path.parent, doc)

    @property
    def image_names(self) -> list[str]:
        return list(self.manifest["images"])

    def path(self, relative: str) -> Path:
        """A file of the scene, from its path relative to the folder."""
        return self.root / relative

    def raster(self, image: str) -> Path:
        return self.path(self.manifest["images"][image]["raster"])

    def sensors(self, **fit_options: Any) -> dict[str, LineScanner]:
        """The images' line-scanner models from their ancillary files, as delivered (images
        that share an ancillary file share one fitted trajectory)."""
        from carto.framework.products.ancillary import read_ancillary

        out: dict[str, LineScanner] = {}
        by_file: dict[str, list[str]] = {}
        for name, image in self.manifest["images"].items():
            by_file.setdefault(image["ancillary"], []).append(name)
        for file, names in by_file.items():
            sensors = read_ancillary(self.path(file)).sensors(**fit_options)
            for name in names:
                if name not in sensors:
                    raise InputError(f"{self.path(file)}: has no image {name!r}")
                out[name] = sensors[name]
        return {n: out[n] for n in self.image_names}

    def truth_sensors(self) -> dict[str, LineScanner]:
        """The true models the images were rendered with (``truth/``)."""
        return {
            n: LineScanner.load(self.path(i["truth_model"]))
            for n, i in self.manifest["images"].items()
        }

    def control(self, which: str = "checkpoints") -> dict[str, Any]:
        """The ``gcps`` or ``checkpoints`` table (long format)."""
        from carto.framework.files.point_table import read_point_table

        return read_point_table(
            self.path(self.manifest[which]),
            numeric=("lon_deg", "lat_deg", "h_m", "line", "sample"),
            text=("id", "image"),
        )


def find_scene_manifest(path: str | os.PathLike[str], platform_prefix: str) -> Path | None:
    """The ``scene.json`` of a scene of a platform (``"Cartosat-1"`` ...) that ``path`` is
    (the folder or its manifest), or is an image raster of; ``None`` otherwise.

    Cheap and silent (sensor types call it from ``identify``): it reads the first 64 KiB of
    the manifest and never raises for foreign or unreadable files.
    """
    path = Path(path)
    if path.is_dir():
        candidate = path / "scene.json"
    elif path.name == "scene.json":
        candidate = path
    elif path.suffix.lower() in (".tif", ".tiff"):
        candidate = path.parent / "scene.json"
    else:
        return None
    try:
        with candidate.open("rb") as fh:
            head = fh.read(65536)
        doc = json.loads(head) if head.strip().endswith(b"}") else None
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or not str(doc.get("platform", "")).startswith(platform_prefix):
        return None
    images = doc.get("images", {})
    if path.suffix.lower() in (".tif", ".tiff") and not (
        isinstance(images, dict)
        and any(isinstance(i, dict) and i.get("raster") == path.name for i in images.values())
    ):
        return None
    return candidate
