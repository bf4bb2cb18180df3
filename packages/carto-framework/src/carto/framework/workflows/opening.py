"""Opening products as sensors through the registry of sensor types.

:func:`open_sensor` and :func:`open_sensors` ask every registered sensor type whether it
recognises a file (``identify``); the one with the highest priority opens it. They pass the
registry down (option ``components``), so a model file that names a plugin's component (its
trajectory model) is read by that plugin, and an optional ``trajectory_model`` (a registered
trajectory model's name, ``carto adjust --trajectory``) for products whose trajectories are
fitted to ancillary data. :func:`open_product` also returns the sensor type, which saves the
adjusted models and names the default adjuster and DEM generator.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import attrs

from carto.framework.errors import InputError, UsageError
from carto.framework.geometry.sensor import Sensor, SensorType


@attrs.frozen(eq=False)
class OpenedProduct:
    """The images of a product as sensors, with the sensor type that opened each.

    Attributes:
        sensors: image name -> sensor.
        types: image name -> the sensor type that opened it.
    """

    sensors: dict[str, Sensor]
    types: dict[str, SensorType]


def sensor_type_for(path: Path, sensor_type: str | None, what: str = "file") -> SensorType:
    """The named sensor type, or the one that identifies ``path`` (highest priority)."""
    from carto.framework.plugins.registry import get_registry

    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    registry = get_registry()
    if sensor_type is not None:
        return registry.get("sensor", sensor_type)
    types = [info.component for info in registry.components("sensor")]
    candidates = [t for t in types if _safe_identify(t, path)]
    if not candidates:
        names = ", ".join(t.name for t in types) or "none"
        if path.is_dir() and what == "file":
            raise InputError(
                f"{path}: is a folder, not a model file (known sensor types: {names}); "
                "name the model file itself"
            )
        reason = _why_unrecognised(path)
        because = f": {reason}" if reason else ""
        kind = "folder" if path.is_dir() else what
        raise InputError(
            f"{path}: no sensor type recognises this {kind}{because} (known: {names}); "
            "name one with --sensor TYPE"
        )
    best = max(t.priority for t in candidates)
    top = [t for t in candidates if t.priority == best]
    if len(top) > 1:
        raise InputError(
            f"{path}: several sensor types recognise this {what} "
            f"({', '.join(t.name for t in top)}); choose one with --sensor"
        )
    return top[0]


def check_installed(*named: tuple[str, str, str | None]) -> None:
    """Each ``(kind, flag, name)`` names an installed component of ``kind`` (or is None):
    a usage error naming the flag and what is installed otherwise, before any work."""
    from carto.framework.plugins.registry import get_registry

    registry = get_registry()
    for kind, flag, name in named:
        if name is not None and name not in registry.names(kind):
            raise UsageError(
                f"{flag} {name!r}: not installed (installed: {', '.join(registry.names(kind))}; "
                f"carto plugins --kind {kind})"
            )


def open_options(trajectory_model: str | None = None) -> dict[str, Any]:
    """The options every opening passes to a sensor type: the registry as ``components``,
    and the registered trajectory model named ``trajectory_model`` (if any)."""
    from carto.framework.plugins.registry import get_registry

    registry = get_registry()
    options: dict[str, Any] = {"components": registry}
    if trajectory_model is not None:
        options["trajectory_model"] = registry.get("trajectory", trajectory_model)
    return options


def open_sensor(
    path: str | Path, sensor_type: str | None = None, *, trajectory_model: str | None = None
) -> Sensor:
    """Open ``path`` with the named sensor type, or with the one that identifies it.

    Raises:
        InputError: the file does not exist, no registered type recognises it, or several do
            with the same priority.
        UnknownComponentError: ``sensor_type`` or ``trajectory_model`` is not registered.
    """
    path = Path(path)
    chosen = sensor_type_for(path, sensor_type, "file")
    return chosen.open(path, **open_options(trajectory_model))


def open_product(
    path: str | Path, sensor_type: str | None = None, *, trajectory_model: str | None = None
) -> OpenedProduct:
    """Open every image of a product (scene folder, stereo product, single image) by name,
    through the sensor type's ``open_all``; see :func:`open_sensor`."""
    path = Path(path)
    chosen = sensor_type_for(path, sensor_type, "product")
    sensors = chosen.open_all(path, **open_options(trajectory_model))
    return OpenedProduct(dict(sensors), {name: chosen for name in sensors})


def open_sensors(
    path: str | Path, sensor_type: str | None = None, *, trajectory_model: str | None = None
) -> dict[str, Sensor]:
    """The sensors of :func:`open_product`."""
    return open_product(path, sensor_type, trajectory_model=trajectory_model).sensors


def _why_unrecognised(path: Path) -> str | None:
    """What is wrong with a file no sensor type identifies, when we can tell: empty,
    unreadable, a raster GDAL cannot open (GDAL's reason) or without RPC metadata, a damaged
    RPC file (the reader's reason); None otherwise."""
    if not path.is_file():
        return None
    try:
        if path.stat().st_size == 0:
            return "the file is empty"
        with path.open("rb") as fh:
            fh.read(1)
    except OSError as err:
        return f"cannot read it: {err.strerror or err}"
    from carto.framework.geometry.rpc.sensor import why_not_rpc

    return why_not_rpc(path)


def _safe_identify(sensor_type: SensorType, path: Path) -> bool:
    try:
        return bool(sensor_type.identify(path))
    except Exception:  # noqa: BLE001 - a faulty identify must not hide the other types
        return False


def check_models_of_scene(models: Path, scene_root: Path) -> None:
    """Refuse a ``carto adjust`` output whose models were adjusted on another scene than
    ``scene_root``: its ``report.json`` names the scene it adjusted, and when that scene
    still exists its manifest must be this one's (a copy of the scene elsewhere passes). An
    outside probe gave a scene the models of another simulated scene, and of a Cartosat-2
    triplet: DEMs 11 m off or half matched, with exit 0 (issue 31)."""
    import json

    try:
        source = json.loads((models / "report.json").read_text()).get("source")
    except (OSError, ValueError, AttributeError):
        return  # an adjust output without a readable report: its marker was checked
    if not isinstance(source, str) or not Path(source).is_absolute():
        return  # an older report's path, relative to a folder we do not know
    adjusted = Path(source)
    manifest = adjusted / "scene.json" if adjusted.is_dir() else adjusted
    if manifest.name != "scene.json" or not manifest.is_file():
        return  # a configuration, or a scene no longer there: nothing to compare
    here = scene_root / "scene.json"
    if manifest.resolve() == here.resolve():
        return
    if manifest.read_bytes() != here.read_bytes():
        raise InputError(
            f"--models {models}: adjusted on the scene {adjusted}, not on {scene_root} (its "
            "manifest differs): give the carto adjust output of these images"
        )


MAX_VIEW_ANGLE_DEG = 2.0
"""The most a model given for an image may turn the line of sight at the image's centre away
from the model the image carries itself (RPC tags): an adjustment turns it by arc-seconds, a
model fitted to another crop of the same image by at most the instrument's field of view
(1-2.5 degrees at the edges); the other image of a stereo pair (base-to-height ratio at
least 0.05, ``pair_checks.MIN_BASE_TO_HEIGHT``) by 2.9 degrees or more."""


def check_model_of_image(image: Path, model: Path, sensor: Sensor) -> None:
    """Refuse a model (``sensor``, read from ``model``) that is not of ``image``, when the
    image carries a model of its own (RPC tags): their lines of sight at the image's centre
    differ by more than :data:`MAX_VIEW_ANGLE_DEG`. An outside probe gave each image of the
    Reunion pair the other's RPCs: a DEM of the relief upside down (NMAD 113 m) with exit 0
    (issue 31), since the two views still overlap and correlate."""
    if model.resolve() == image.resolve():
        return
    try:
        own = sensor_type_for(image, None, "image").open(image, **open_options())
    except InputError:
        return  # the image carries no model: nothing to compare with
    angle = _view_angle_deg(own.for_raster(image), sensor)
    if angle > MAX_VIEW_ANGLE_DEG:
        raise InputError(
            f"{model}: not a model of {image}: its line of sight at the image's centre is "
            f"{angle:.1f} degrees from the image's own model (> {MAX_VIEW_ANGLE_DEG:g}): the "
            "model of another image (the two images' models swapped?)"
        )


def _view_angle_deg(a: Sensor, b: Sensor) -> float:
    """Angle between two models' lines of sight at ``a``'s image centre, degrees."""
    import numpy as np

    from carto.framework.geometry.intersection import sensor_rays

    n_l, n_s = a.image_shape
    rays = [np.ravel(sensor_rays(s, n_l / 2, n_s / 2, 0.0, 1000.0)[1]) for s in (a, b)]
    return float(np.degrees(np.arccos(np.clip(np.dot(rays[0], rays[1]), -1.0, 1.0))))
