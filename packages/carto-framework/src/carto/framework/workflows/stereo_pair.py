"""The stereo pair of a DEM run (:func:`carto.framework.workflows.dem.dem_product`): where it
comes from (:class:`StereoInputs`), its images and models opened (:func:`open_pair`), then
prepared, checked and its right image corrected to the left one (:func:`oriented_pair`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.adjustment.relative_orientation import RelativeOrientationSettings
from carto.framework.errors import InputError, UsageError
from carto.framework.files.staging import require_complete_output
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.raster.dem import DEM
from carto.framework.workflows.dem_datum import datum_gcps
from carto.framework.workflows.opening import (
    check_model_of_image,
    open_options,
    open_sensor,
    sensor_type_for,
)
from carto.framework.workflows.pair_checks import checked_pair
from carto.framework.workflows.reporting import progress

__all__ = ["OrientedPair", "StereoInputs", "StereoPair", "open_pair", "oriented_pair"]


def _model_beside(image: Path) -> Path:
    """The model file of an image: a sidecar ``.geom``/``_RPC.TXT``/``.RPB`` if there is
    one, else the image itself (RPC tags in a GeoTIFF)."""
    for candidate in (
        image.with_suffix(".geom"),
        image.with_name(image.stem + "_RPC.TXT"),
        image.with_suffix(".RPB"),
    ):
        if candidate.is_file():
            return candidate
    return image


def adjusted_model(models: Path | None, name: str, sensor: Sensor) -> Sensor:
    """The adjusted model of image ``name`` from a ``carto adjust`` output folder, if any."""
    if models is None:
        return sensor
    for candidate in (models / f"{name}.model.json", models / f"{name}_RPC.TXT"):
        if candidate.is_file():
            return open_sensor(candidate)
    raise InputError(f"{models}: no adjusted model for image {name!r} ({name}.model.json)")


@attrs.frozen
class StereoInputs:
    """Where the stereo pair of a DEM run comes from.

    Attributes:
        source: a scene folder (``carto simulate``); or None and ``left``/``right``.
        left, right: image files (rasters) when there is no scene.
        left_model, right_model: their model files (default: found beside each image).
        sensor_type: force a sensor type for the models (``rpc`` ...).
        models: a ``carto adjust`` output folder with adjusted models of the images.
        pair: for a scene, the two image names (default: its first two, the one closer to
            nadir as left).
    """

    source: str | os.PathLike[str] | None = None
    left: str | os.PathLike[str] | None = None
    right: str | os.PathLike[str] | None = None
    left_model: str | os.PathLike[str] | None = None
    right_model: str | os.PathLike[str] | None = None
    sensor_type: str | None = None
    models: str | os.PathLike[str] | None = None
    pair: Sequence[str] | None = None

    def __attrs_post_init__(self) -> None:
        loose = {
            "--left": self.left,
            "--right": self.right,
            "--left-model": self.left_model,
            "--right-model": self.right_model,
        }
        given = [name for name, value in loose.items() if value is not None]
        if self.source is not None and given:
            raise UsageError(
                f"a scene folder ({self.source}) and {', '.join(given)} exclude each other: "
                "give the scene (with --pair to choose its images) or two images"
            )
        if self.source is None and self.pair is not None:
            raise UsageError("--pair chooses two images of a scene folder: give the scene")


@attrs.frozen(eq=False)
class StereoPair:
    """The stereo pair of a DEM run (left first).

    Attributes:
        rasters: image name -> raster file.
        sensors: image name -> model (adjusted when a ``carto adjust`` folder was given).
        types: the sensor types that opened the images (they name the default generator).
        init_dem: the scene's initial DEM (``None`` for loose images).
    """

    rasters: dict[str, Path]
    sensors: dict[str, Sensor]
    types: tuple[SensorType, ...]
    init_dem: DEM | None


def open_pair(inputs: StereoInputs) -> StereoPair:
    """The stereo pair to process (see :class:`StereoInputs`). A sensor is fitted to the
    raster it comes with (:meth:`~carto.framework.geometry.sensor.Sensor.for_raster`: e.g. a
    crop's pixel offset applied to a full-scene RPC)."""

    source, pair, sensor_type = inputs.source, inputs.pair, inputs.sensor_type
    models_dir = (
        require_complete_output(inputs.models, "adjust") if inputs.models is not None else None
    )
    if source is not None:
        from carto.framework.products.scene import Scene
        from carto.framework.workflows.opening import check_models_of_scene, open_product

        if Path(source).is_file() and Path(source).name != "scene.json":
            raise UsageError(
                f"{source}: not a scene folder; carto dem takes a scene (carto simulate) or "
                "two images with --left/--right (their models beside them or with "
                "--left-model/--right-model, e.g. the _RPC.TXT a carto adjust wrote)"
            )
        scene = Scene.open(source)
        if models_dir is not None:
            check_models_of_scene(models_dir, scene.root)
        product = open_product(scene.root, sensor_type)
        sensors = product.sensors
        names = list(pair) if pair else list(sensors)[:2]
        if len(names) != 2 or any(n not in sensors for n in names):
            raise UsageError(
                f"{source}: --pair must name two of the images {', '.join(sensors)}, got "
                f"{' '.join(names)}"
            )
        if names[0] == names[1]:
            raise UsageError(f"--pair {names[0]} {names[1]}: a stereo pair needs two images")
        if len(sensors) < 2:
            raise InputError(f"{source}: a DEM needs two images, the scene has {len(sensors)}")
        if not pair:
            names.sort(key=lambda n: _off_nadir_deg(sensors[n]))
        chosen = {n: adjusted_model(models_dir, n, sensors[n]) for n in names}
        init = scene.manifest.get("init_dem")
        dem = DEM.open(scene.path(init)) if init else None
        types = tuple(product.types[n] for n in names)
        return StereoPair({n: scene.raster(n) for n in names}, chosen, types, dem)
    if inputs.left is None or inputs.right is None:
        raise InputError("dem: give a scene folder, or both --left and --right images")
    rasters: dict[str, Path] = {}
    sensors = {}
    types = []
    for key, image, model in (
        ("left", inputs.left, inputs.left_model),
        ("right", inputs.right, inputs.right_model),
    ):
        path = Path(image)
        if not path.is_file():
            raise InputError(f"{path}: no such image")
        model_path = Path(model) if model else _model_beside(path)
        chosen_type = sensor_type_for(model_path, sensor_type, "file")
        sensor = chosen_type.open(model_path, **open_options()).for_raster(path)
        check_model_of_image(path, model_path, sensor)
        sensors[key] = adjusted_model(models_dir, key, sensor)
        rasters[key] = path
        types.append(chosen_type)
    return StereoPair(rasters, sensors, tuple(types), None)


def _off_nadir_deg(sensor: Sensor) -> float:
    """Off-nadir angle of the line of sight at the image centre, degrees."""
    from carto.framework.geometry import frames

    n_l, n_s = sensor.image_shape
    lon, lat = sensor.image_to_ground(n_l / 2, n_s / 2, 0.0)
    lo2, la2 = sensor.image_to_ground(n_l / 2, n_s / 2, 1000.0)
    d = frames.geodetic_to_ecef(lo2, la2, 1000.0) - frames.geodetic_to_ecef(lon, lat, 0.0)
    up = frames.ellipsoid_normal(lon, lat)
    return float(np.degrees(np.arccos(np.clip(np.dot(np.ravel(d), up) / np.linalg.norm(d), -1, 1))))


@attrs.frozen(eq=False)
class OrientedPair:
    """The stereo pair ready for the generator.

    Attributes:
        names: the two image names, left first.
        rasters: image name -> raster file.
        sensors: image name -> model, the right one corrected to the left (relative
            orientation).
        images: the prepared images (read by windows, staggered arrays merged), left first.
        start: the starting DEM.
        checked: the pair check (:func:`~carto.framework.workflows.pair_checks.checked_pair`).
        warnings: what the pair check found poor.
        control: the datum GCPs of the ``carto adjust`` folder (None: none).
        orientation: what ``report.json`` says of the relative orientation.
    """

    names: list[str]
    rasters: dict[str, Path]
    sensors: dict[str, Sensor]
    images: list[Any]
    start: DEM
    checked: Any
    warnings: list[str]
    control: dict[str, Any] | None
    orientation: dict[str, Any]


def oriented_pair(
    pair: StereoPair,
    start: DEM,
    models: str | os.PathLike[str] | None,
    ro_settings: RelativeOrientationSettings,
    constant_dem: bool,
    allow_poor: bool,
    engine: Any,
    work: Path,
    quiet: bool,
) -> OrientedPair:
    """The pair's images prepared and checked, and its right image corrected to the left
    one (relative orientation, with the datum GCPs of the ``models`` folder)."""
    from carto.framework.adjustment.relative_orientation import relative_orientation

    sensors = pair.sensors
    names = list(sensors)
    from carto.framework.imaging.preparation import prepared_sources

    # read by windows, checked and prepared (staggered arrays merged) in the work folder
    prepared = prepared_sources(pair.rasters, pair.sensors, start, work / "prepared", engine)
    images = [prepared[n] for n in pair.sensors]
    checked, warnings = checked_pair(
        images, [sensors[n] for n in names], start, allow_poor=allow_poor
    )
    control = datum_gcps(models, names)
    oriented = relative_orientation(
        dict(zip(names, images, strict=True)),
        sensors,
        start,
        ro_settings,
        gcps=control,
        constant_dem=constant_dem,
        engine=engine,
        progress=lambda line: progress("dem", line, quiet),
    )
    sensors = {**sensors, names[0]: oriented.left or sensors[names[0]], names[1]: oriented.right}
    return OrientedPair(
        names, pair.rasters, sensors, images, start, checked, warnings, control, oriented.record
    )
