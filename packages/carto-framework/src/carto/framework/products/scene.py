"""Scene folders: the products ``carto simulate`` writes (``docs/formats.md``), read as
images, ancillary files, control tables and truth.

:class:`Scene` opens a folder by its ``scene.json``; :func:`find_scene_manifest` tells a
sensor type cheaply whether a path is (or is an image of) a scene of its platform.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs

from carto.framework.errors import InputError
from carto.framework.files.documents import check_fields, read_json_document
from carto.framework.geometry.linescan.scanner import LineScanner

SCENE_FORMAT = "carto-scene"
SCENE_VERSION = 1
SCENE_FIELDS = (
    "format", "version", "preset", "platform", "seed", "platform_seed", "terrain", "size",
    "errors", "error_model", "epoch_utc", "target", "images", "gcps", "checkpoints", "init_dem",
    "truth", "vertical_reference", "pixel_convention", "counts", "epoch_j2000_s",
)  # fmt: skip
"""The fields of ``scene.json`` (``docs/formats.md``); any other is refused (a misspelt
``"init_dem"`` would start the DEM from a constant height without a word)."""
IMAGE_FIELDS = ("raster", "ancillary", "camera", "array", "truth_model")
SCENE_VERTICAL = "ellipsoid WGS84"
"""What a scene's heights are above (``vertical_reference``; any other value is refused: the
readers take every height as ellipsoidal)."""


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
        check_manifest(doc, manifest_path)
        return cls(manifest_path.parent, doc)

    @property
    def image_names(self) -> list[str]:
        return list(self.manifest["images"])

    def path(self, relative: str) -> Path:
        """A file of the scene, from its path relative to the folder."""
        return self.root / relative

    def raster(self, image: str) -> Path:
        """The raster file of ``image``."""
        images = self.manifest["images"]
        if image not in images:
            raise InputError(
                f"{self.root / 'scene.json'}: images: no image {image!r} "
                f"(the scene has {', '.join(images)})"
            )
        return self.path(images[image]["raster"])

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
        out = {}
        for n, i in self.manifest["images"].items():
            if "truth_model" not in i:
                raise InputError(
                    f"{self.root / 'scene.json'}: missing field 'images.{n}.truth_model' (the "
                    "scene has no truth; only simulated scenes have)"
                )
            out[n] = LineScanner.load(self.path(i["truth_model"]))
        return out

    def control(self, which: str = "checkpoints") -> dict[str, Any]:
        """The ``gcps`` or ``checkpoints`` table (long format), checked
        (:func:`carto.framework.files.control_table.read_control_table`: complete, finite and
        plausible coordinates and sigmas, one row per point and image, the scene's images
        only); errors name the file, row and column."""
        from carto.framework.files.control_table import read_control_table

        if which not in ("gcps", "checkpoints"):
            raise InputError(f"scene control tables are gcps and checkpoints, not {which!r}")
        path = self.path(self.manifest[which])
        table = read_control_table(path, which, images=self.image_names)
        counted = (self.manifest.get("counts") or {}).get(which)
        if not len(table["id"]) and isinstance(counted, int) and counted > 0:
            hint = " (--gcps 0 adjusts without GCPs)" if which == "gcps" else ""
            raise InputError(
                f"{path}: holds no point, where scene.json counts {counted}: a file cut short?"
                + hint
            )
        return table


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_manifest(doc: Mapping[str, Any], manifest_path: Path) -> None:
    """Check the fields of a scene manifest that opening the scene relies on.

    ``images`` must be a non-empty object of image entries, each an object with ``raster`` and
    ``ancillary`` (file names relative to the folder, of existing files) and optionally
    ``truth_model``, ``camera``, ``array`` (strings); ``gcps`` and ``checkpoints`` must name
    files (their tables are read by :meth:`Scene.control`); ``platform`` is a string.

    Raises:
        InputError: one line naming the manifest, the field and the value.
    """
    fields = _ManifestFields(manifest_path)
    check_fields(doc, SCENE_FIELDS, manifest_path)
    for key in ("images", "gcps", "checkpoints"):
        if key not in doc:
            raise InputError(f"{manifest_path}: missing field {key!r}")
    platform = doc.get("platform", "")
    if not isinstance(platform, str):
        raise fields.fail("platform", f"expected a string, got {_short(platform)}")
    images = doc["images"]
    if not isinstance(images, Mapping) or not images:
        raise fields.fail("images", f"expected an object of images by name, got {_short(images)}")
    for name, image in images.items():
        fields.check_image(f"images.{name}", image)
    for key in ("gcps", "checkpoints"):
        fields.file_name(doc[key], key)
    vertical = doc.get("vertical_reference", SCENE_VERTICAL)
    if vertical != SCENE_VERTICAL:
        raise fields.fail(
            "vertical_reference",
            f"{_short(vertical)}; a scene's heights (GCPs, checkpoints, DEMs) are above the "
            f"{SCENE_VERTICAL.split()[0]} ({SCENE_VERTICAL!r})",
        )


@attrs.frozen
class _ManifestFields:
    """The checks of one manifest's fields, whose errors name it."""

    path: Path

    def fail(self, field: str, problem: str) -> InputError:
        return InputError(f"{self.path}: {field}: {problem}")

    def file_name(self, value: Any, field: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(field, f"expected a file name (a string), got {_short(value)}")
        return value

    def check_image(self, where: str, image: Any) -> None:
        """One entry of ``images``: an object of existing ``raster`` and ``ancillary`` files
        and optional non-empty strings."""
        if not isinstance(image, Mapping):
            raise self.fail(
                where, f"expected an object (raster, ancillary ...), got {_short(image)}"
            )
        check_fields(image, IMAGE_FIELDS, self.path, f"{where}.")
        for key in ("raster", "ancillary"):
            if key not in image:
                raise InputError(f"{self.path}: missing field '{where}.{key}'")
            file = self.path.parent / self.file_name(image[key], f"{where}.{key}")
            if not file.is_file():
                raise self.fail(f"{where}.{key}", f"file {file} does not exist")
        for key in ("truth_model", "camera", "array"):
            if key in image and not (isinstance(image[key], str) and image[key].strip()):
                raise self.fail(
                    f"{where}.{key}", f"expected a non-empty string, got {_short(image[key])}"
                )


def scene_files(path: str | os.PathLike[str]) -> list[Path]:
    """Every file a scene folder's ``scene.json`` names (images, ancillary files, control
    tables, the starting DEM, the truth), read leniently (opening the scene checks them):
    an output folder may hold none of them, since it is replaced as a whole, and a manifest
    may name files outside its folder. Nothing for a path that is not a readable scene."""
    path = Path(path)
    manifest = path / "scene.json" if path.is_dir() else path
    try:
        doc = json.loads(manifest.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return []
    if not isinstance(doc, Mapping):
        return []
    names: list[Any] = [doc.get(k) for k in ("gcps", "checkpoints", "init_dem")]
    truth = doc.get("truth")
    if isinstance(truth, Mapping):
        names += list(truth.values())
    images = doc.get("images")
    if isinstance(images, Mapping):
        for image in images.values():
            if isinstance(image, Mapping):
                names += [image.get(k) for k in ("raster", "ancillary", "truth_model")]
    return [manifest.parent / n for n in names if isinstance(n, str) and n]


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
