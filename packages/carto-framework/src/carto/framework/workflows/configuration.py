"""The JSON configuration of ``carto adjust`` (:func:`read_configuration`): images with their
models and rasters, GCPs, a DEM or a flat height, a matcher and a trajectory model, each field
checked where it enters, with errors naming the file and the field; and
:func:`configuration_files`, what a configuration names (an output folder may hold none)."""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import attrs
from numpy.typing import NDArray

from carto.framework.adjustment.control_checks import check_control
from carto.framework.errors import InputError, UnknownComponentError
from carto.framework.files.control_table import read_control_table
from carto.framework.files.documents import check_fields, read_json
from carto.framework.files.paths import resolved
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.plugins.registry import get_registry
from carto.framework.workflows.opening import check_model_of_image, open_options, sensor_type_for

Table = dict[str, NDArray]


@attrs.frozen(eq=False)
class Configuration:
    """A JSON configuration of ``carto adjust`` (see :func:`read_configuration`)."""

    sensors: dict[str, Sensor]
    types: dict[str, SensorType]
    rasters: dict[str, Path]
    gcps: Table | None
    dem: Any
    platform: str
    matcher: str | None
    trajectory_model: str | None
    flat_height_m: float | None = None


CONFIGURATION_KEYS = (
    "images", "gcps", "dem", "geoid", "height_m", "platform", "matcher", "trajectory_model",
)  # fmt: skip
"""The fields of an adjustment configuration (:func:`read_configuration`)."""
IMAGE_KEYS = ("model", "raster", "sensor")
"""The fields of one image in it."""


def _check_distinct(path: Path, images: Mapping[str, Any], base: Path) -> None:
    """Refuse two images of a configuration that name one model or one raster: the same
    view twice has no stereo (an outside probe got '300 of 300 points have no
    intersection', naming neither the file nor the cause)."""
    for key in ("model", "raster"):
        seen: dict[Path, str] = {}
        for name, spec in images.items():
            value = spec.get(key) if isinstance(spec, dict) else None
            if not isinstance(value, str) or not value:
                continue  # checked with the image
            file = resolved(base / value, f"images.{name}.{key}")
            if file in seen:
                raise InputError(
                    f"{path}: images.{seen[file]}.{key} and images.{name}.{key} name the same "
                    f"file {file}: each image needs its own"
                )
            seen[file] = name


def _check_component(path: Path, field: str, name: str) -> None:
    """Refuse a configuration ``field`` naming a component nobody registered, naming both."""
    kind = "matcher" if field == "matcher" else "trajectory"
    try:
        get_registry().info(kind, name)
    except UnknownComponentError as exc:
        raise InputError(f"{path}: field {field!r}: {exc}") from None


@contextlib.contextmanager
def _field(path: Path, field: str) -> Iterator[None]:
    """Errors of reading what configuration ``path``'s ``field`` names, naming both."""
    try:
        yield
    except InputError as exc:
        if str(path) in str(exc):
            raise
        raise InputError(f"{path}: field {field!r}: {exc}") from None


def configuration_files(path: Path) -> list[Path]:
    """The files a configuration names (models, rasters, GCPs, DEM, geoid), read leniently
    (:func:`read_configuration` checks them): the output folder may hold none of them, since
    it is replaced as a whole. Nothing for a scene folder or an unreadable file."""
    if not path.is_file():
        return []
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return []
    if not isinstance(doc, dict):
        return []
    names = [doc.get(key) for key in ("gcps", "dem", "geoid")]
    images = doc.get("images")
    if isinstance(images, dict):
        for spec in images.values():
            if isinstance(spec, dict):
                names += [spec.get("model"), spec.get("raster")]
    return [path.parent / n for n in names if isinstance(n, str) and n]


def read_configuration(
    path: Path, sensor_type: str | None = None, trajectory: str | None = None
) -> Configuration:
    """A JSON configuration: ``{"images": {name: {"model": file, "raster": file,
    "sensor": type}}, "gcps": csv, "dem": file, "geoid": gtx, "platform": text,
    "matcher": name, "trajectory_model": name}``, or ``"height_m": number`` (ellipsoidal)
    for a flat DEM instead of ``"dem"``; paths relative to the file. ``sensor_type`` and
    ``trajectory`` (the command line's) override the file's."""
    doc = read_json(path, "configuration")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: a configuration is a JSON object, got {type(doc).__name__}")
    check_fields(doc, CONFIGURATION_KEYS, path, "")
    base = path.parent
    images = doc.get("images")
    if not isinstance(images, dict) or len(images) < 1:
        raise InputError(f"{path}: field 'images' must map image names to models")
    names = {key: _component_name(path, doc, key) for key in ("matcher", "trajectory_model")}
    trajectory = trajectory or names["trajectory_model"]
    _check_distinct(path, images, base)
    sensors: dict[str, Sensor] = {}
    types: dict[str, SensorType] = {}
    rasters: dict[str, Path] = {}
    for name, spec in images.items():
        types[name], sensors[name], raster = _open_image(path, name, spec, sensor_type, trajectory)
        if raster is not None:
            rasters[name] = raster
    dem, flat_height_m = _configured_dem(path, doc)
    return Configuration(
        sensors,
        types,
        rasters,
        _configured_gcps(path, doc, sensors),
        dem,
        str(doc.get("platform", "")),
        names["matcher"],
        names["trajectory_model"],
        flat_height_m,
    )


def _component_name(path: Path, doc: Mapping[str, Any], key: str) -> str | None:
    """A configuration's ``matcher`` or ``trajectory_model``: a registered component's name,
    or None."""
    value = doc.get(key)
    if value is not None and not isinstance(value, str):
        raise InputError(f"{path}: field {key!r} must be a component name, got {value!r}")
    if value is not None:
        _check_component(path, key, value)
    return value


def _open_image(
    path: Path, name: str, spec: Any, sensor_type: str | None, trajectory: str | None
) -> tuple[SensorType, Sensor, Path | None]:
    """One image of a configuration: its sensor type, its model (for its raster, which it
    must be the model of) and its raster (None when not given)."""
    base = path.parent
    if not isinstance(spec, dict):
        raise InputError(
            f"{path}: images.{name} must be an object with 'model' and 'raster', got {spec!r}"
        )
    check_fields(spec, IMAGE_KEYS, path, f"images.{name}.")
    for key in ("model", "raster", "sensor"):
        value = spec.get(key)
        if (key == "model" or value is not None) and (not isinstance(value, str) or not value):
            raise InputError(f"{path}: images.{name}.{key} must be a file name, got {value!r}")
    model = base / spec["model"]
    if not model.exists():
        raise InputError(f"{path}: images.{name}.model: no such file {model}")
    with _field(path, f"images.{name}.model"):
        chosen = sensor_type_for(model, sensor_type or spec.get("sensor"), "file")
        sensor = chosen.open(model, **open_options(trajectory))
    if spec.get("raster") is None:
        return chosen, sensor, None
    raster = base / spec["raster"]
    if not raster.is_file():
        raise InputError(f"{path}: images.{name}.raster: no such file {raster}")
    with _field(path, f"images.{name}.raster"):
        sensor = sensor.for_raster(raster)
        check_model_of_image(raster, model, sensor)
    return chosen, sensor, raster


def _configured_gcps(
    path: Path, doc: Mapping[str, Any], sensors: Mapping[str, Sensor]
) -> Table | None:
    """The configuration's GCP table, checked against its images (None: no ``gcps``)."""
    if doc.get("gcps") is None:
        return None
    if not isinstance(doc["gcps"], str) or not doc["gcps"]:
        raise InputError(f"{path}: field 'gcps' must be a CSV file name, got {doc['gcps']!r}")
    file = path.parent / doc["gcps"]
    with _field(path, "gcps"):
        gcps = read_control_table(file, "gcps", images=list(sensors))
        if not len(gcps["id"]):
            raise InputError(
                f"{file}: holds no GCP (a header only); to adjust without GCPs, leave the field out"
            )
        check_control(gcps, sensors, "gcps")
    return gcps


def _configured_dem(path: Path, doc: Mapping[str, Any]) -> tuple[Any, float | None]:
    """The configuration's DEM (``dem``, with ``geoid`` for geoid heights) or flat height
    (``height_m``, returned too), else ``(None, None)``."""
    from carto.framework.raster.dem import DEM, Geoid
    from carto.framework.raster.dem_measures import check_terrain_posting

    base = path.parent
    for key in ("dem", "geoid"):
        value = doc.get(key)
        if value is not None and (not isinstance(value, str) or not value):
            raise InputError(f"{path}: field {key!r} must be a file name, got {value!r}")
    if doc.get("dem"):
        with _field(path, "geoid"):
            geoid = Geoid.open(base / doc["geoid"]) if doc.get("geoid") else None
        with _field(path, "dem"):
            dem = DEM.open(base / doc["dem"], geoid=geoid, require_ellipsoidal=True)
        check_terrain_posting(dem, f"{path}: dem {base / doc['dem']}")
        return dem, None
    h = doc.get("height_m")
    if h is None:
        return None, None
    if isinstance(h, bool) or not isinstance(h, int | float) or not math.isfinite(h):
        raise InputError(f"{path}: field 'height_m' must be a number, got {h!r}")
    return DEM.constant(float(h)), float(h)
