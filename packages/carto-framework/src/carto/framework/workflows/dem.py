"""The DEM workflow behind ``carto dem``: a stereo pair (two images with models, or a scene
folder with its adjusted models) -> a DEM generator (chosen by name, or the default the images'
sensor types name) with a matcher (default ``sgm``) -> ``dem.tif``,
``ortho_left.tif``, ``ortho_right.tif``, ``quality.tif``, ``report.json`` and a hillshade
(and, against a reference DEM, the accuracy and a difference map).

Every file is written to a temporary name and renamed when complete.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.adjustment.relative_orientation import RelativeOrientationSettings
from carto.framework.errors import InputError, UsageError
from carto.framework.files.documents import write_json_atomic
from carto.framework.files.staging import require_complete_output, staged_folder
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.plugins.registry import get_registry
from carto.framework.products.scene import scene_files
from carto.framework.products.stac import ITEM_FILE, dem_item
from carto.framework.raster.dem import DEM, Geoid
from carto.framework.raster.dem_file import states_vertical
from carto.framework.raster.vertical_reference import vertical_tag
from carto.framework.workflows.dem_checks import (
    departs_from_start,
    mismatched,
    off_the_gcps,
    poor_dem,
)
from carto.framework.workflows.dem_datum import (
    auto_coregisters,
    coregistered,
    datum_gcps,
    resolve_coregister,
)
from carto.framework.workflows.dem_options import check_names, check_options
from carto.framework.workflows.geographic_output import geographic_output
from carto.framework.workflows.opening import (
    check_model_of_image,
    open_options,
    open_sensor,
    sensor_type_for,
)
from carto.framework.workflows.pair_checks import checked_pair
from carto.framework.workflows.reporting import progress, resolved_settings, write_report
from carto.framework.workflows.resumable import fingerprint, open_work, settle_work
from carto.framework.workflows.run_record import record_run, utc_now

__all__ = [
    "StereoInputs",
    "StereoPair",
    "choose_dem_generator",
    "dem_product",
    "open_pair",
]


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


def _adjusted(models: Path | None, name: str, sensor: Sensor) -> Sensor:
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
        chosen = {n: _adjusted(models_dir, n, sensors[n]) for n in names}
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
        sensors[key] = _adjusted(models_dir, key, sensor)
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


def _radiometry(path: str | os.PathLike[str]) -> Any:
    """The dtype of an input image's first band: the ortho-image is written in it (an
    integer image: rounded, nodata 0)."""
    import warnings

    import rasterio

    with warnings.catch_warnings():  # a raw image has no georeferencing: nothing to say
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path) as ds:
            return np.dtype(ds.dtypes[0])


def initial_dem(
    init_dem: str | os.PathLike[str] | None,
    geoid: str | os.PathLike[str] | None,
    init_height_m: float | None,
    scene_dem: DEM | None,
) -> DEM:
    """The starting DEM: a file (with a geoid for orthometric heights such as SRTM), a
    constant ellipsoidal height, or the scene's initial DEM."""
    if init_dem is not None and init_height_m is not None:
        raise UsageError("dem: give --init-dem or --init-height, not both")
    if init_dem is not None:
        start = DEM.open(
            init_dem, geoid=Geoid.open(geoid) if geoid else None, require_ellipsoidal=True
        )
        from carto.framework.raster.dem_measures import check_terrain_posting

        check_terrain_posting(start, f"initial DEM {init_dem}")
        return start
    if init_height_m is not None:
        if not (np.isfinite(init_height_m) and -1000.0 <= init_height_m <= 10000.0):
            raise UsageError(
                f"--init-height {init_height_m:g}: expected an ellipsoidal height in metres "
                "between -1000 and 10000"
            )
        return DEM.constant(float(init_height_m))
    if scene_dem is not None:
        return scene_dem
    raise InputError("dem: give an initial DEM (--init-dem FILE [--geoid GTX]) or --init-height M")


def choose_dem_generator(requested: str | None, types: Sequence[SensorType]) -> str:
    """The DEM generator of a run: the one named, else the first default of the images'
    sensor types that is installed, else the only one installed, else the one of the
    highest :attr:`~carto.framework.dem_generation.base.DEMGenerator.priority` if no other
    has it (a test plugin's generator beside ``ior`` left RPC pairs without a default)."""
    registry = get_registry()
    installed = registry.names("dem-generator")
    if requested is not None:
        registry.get("dem-generator", requested)  # a clear error when it is not installed
        return requested
    for sensor_type in types:
        default = sensor_type.default_dem_generator
        if default is not None and default in installed:
            return default
    if len(installed) == 1:
        return installed[0]
    priority = {n: registry.get("dem-generator", n).priority for n in installed}
    top = max(priority.values(), default=0)
    best = [n for n, p in priority.items() if p == top]
    if top > 0 and len(best) == 1:
        return best[0]
    raise InputError(
        "dem: no default DEM generator for these images "
        f"(installed: {', '.join(installed) or 'none'}); name one with --generator"
    )


def dem_product(
    out_dir: str | os.PathLike[str],
    inputs: StereoInputs,
    *,
    init_dem: str | os.PathLike[str] | None = None,
    geoid: str | os.PathLike[str] | None = None,
    init_height_m: float | None = None,
    generator: str | None = None,
    matcher: str = "sgm",
    reference: str | os.PathLike[str] | None = None,
    vertical: str = "ellipsoid",
    options: Mapping[str, Any] | None = None,
    quiet: bool = False,
    allow_poor: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    relative_orientation: str = "auto",
    coregister: str | os.PathLike[str] | None = "auto",
    coregister_accuracy_m: float = 10.0,
) -> dict[str, Any]:
    """Generate a DEM and ortho-images and write them to ``out_dir``; return the report.

    See :class:`StereoInputs` for the inputs and :func:`initial_dem` for the starting DEM;
    ``generator`` names the DEM generator (default: :func:`choose_dem_generator`),
    ``matcher`` the matcher it uses (a registry name); ``vertical`` is what ``dem.tif``'s
    heights are above: ``"ellipsoid"`` (WGS84) or ``"geoid"`` (the geoid grid ``geoid``,
    required then); ``options`` go to the generator
    (``posting_m``, ``ortho_res_m``, ``crs``, ``max_iterations`` ...). Tiles run on a
    :func:`~carto.framework.parallel.engine.open_engine` engine: ``workers`` processes of a
    local cluster (default: every core; 1: this process) or the ``dask.distributed``
    cluster at ``scheduler``. Intermediate files go to a work folder
    (:mod:`~carto.framework.workflows.resumable`), kept when the run fails or is
    interrupted; ``resume`` continues from it. The outputs are written from
    the generator's :class:`~carto.framework.dem_generation.base.DEMProduct` alone. With
    ``reference`` (a DEM file), the report gets its accuracy
    (:func:`carto.framework.evaluation.dem_accuracy.dem_accuracy`) and a difference map is drawn.
    A run whose DEM fails the checks of :mod:`~carto.framework.workflows.dem_checks` (too few
    nodes matched, far off its starting DEM) fails unless ``allow_poor``. The outputs are
    written into a staging folder that replaces ``out_dir`` only when all are complete
    (:func:`carto.framework.files.staging.staged_folder`).
    Before the generator runs, the right image is corrected to the left one
    (``relative_orientation``: a mode of
    :data:`~carto.framework.adjustment.relative_orientation.MODES`, see
    :func:`~carto.framework.adjustment.relative_orientation.relative_orientation`). The DEM
    is then co-registered (``coregister``: ``"auto"``, ``"none"`` or a reference DEM file,
    :func:`~carto.framework.workflows.dem_datum.coregistered`; a move beyond
    ``coregister_accuracy_m`` is a warning).
    """
    from carto.framework.parallel.engine import open_engine

    settings = dict(options or {})
    geographic = geographic_output(settings)  # a lon/lat grid: warped after the generator
    check_options(settings)
    check_names(generator, matcher)
    try:
        ro_settings = RelativeOrientationSettings(mode=relative_orientation)
    except InputError as exc:
        raise UsageError(str(exc)) from None
    coregister = resolve_coregister(coregister)
    if not (np.isfinite(coregister_accuracy_m) and coregister_accuracy_m > 0):
        raise UsageError(f"--coregister-accuracy must be > 0 m, got {coregister_accuracy_m:g}")
    if vertical not in ("ellipsoid", "geoid"):
        raise UsageError(f"--vertical must be 'ellipsoid' or 'geoid', got {vertical!r}")
    if vertical == "geoid" and geoid is None:
        raise UsageError("--vertical geoid needs the geoid grid: --geoid GTX")
    if "workers" in settings:  # the earlier form of the argument
        workers = int(settings.pop("workers"))
    sources = [
        inputs.source,
        inputs.left,
        inputs.right,
        inputs.left_model,
        inputs.right_model,
        inputs.models,
        init_dem,
        geoid,
        reference,
        None if str(coregister) in ("auto", "none") else coregister,
        *(scene_files(inputs.source) if inputs.source is not None else []),
    ]
    facts = {
        "generator": generator,
        "matcher": matcher,
        "init_height_m": init_height_m,
        "pair": list(inputs.pair) if inputs.pair else None,
        "sensor_type": inputs.sensor_type,
        "settings": {k: str(v) for k, v in sorted(settings.items())},
        "allow_poor": allow_poor,
        "vertical": vertical,
        "relative_orientation": relative_orientation,
        "coregister": str(coregister),
        "coregister_accuracy_m": coregister_accuracy_m,
    }
    work: Path | None = None
    started = utc_now()
    try:
        with staged_folder(out_dir, "dem", inputs=sources) as stage:
            work = open_work(out_dir, fingerprint(sources, facts), resume, quiet)
            with open_engine(workers, scheduler, quiet=quiet) as engine:
                report = _dem_into(
                    stage,
                    inputs,
                    init_dem=init_dem,
                    geoid=geoid,
                    init_height_m=init_height_m,
                    generator=generator,
                    matcher=matcher,
                    reference=reference,
                    vertical=vertical,
                    settings=settings,
                    quiet=quiet,
                    allow_poor=allow_poor,
                    engine=engine,
                    work=work,
                    ro_settings=ro_settings,
                    coregister=coregister,
                    coregister_accuracy_m=coregister_accuracy_m,
                )
            if geographic is not None:
                report = geographic.apply(stage, report)
            report = record_run(stage / "report.json", report, sources, started, "dem")
            item = dem_item(stage, report, Path(out_dir).resolve().name)
            write_json_atomic(stage / ITEM_FILE, item)
    except BaseException as exc:
        if work is not None:
            settle_work(work, exc)
        raise
    shutil.rmtree(work, ignore_errors=True)
    return report


def _dem_into(
    out: Path,
    inputs: StereoInputs,
    *,
    init_dem: str | os.PathLike[str] | None,
    geoid: str | os.PathLike[str] | None,
    init_height_m: float | None,
    generator: str | None,
    matcher: str,
    reference: str | os.PathLike[str] | None,
    vertical: str,
    settings: dict[str, Any],
    quiet: bool,
    allow_poor: bool,
    engine: Any,
    work: Path,
    ro_settings: RelativeOrientationSettings,
    coregister: str | Path,
    coregister_accuracy_m: float,
) -> dict[str, Any]:
    """:func:`dem_product` writing into ``out`` (its staging folder), tiles on ``engine``,
    intermediate files in ``work``."""
    from carto.framework.adjustment.relative_orientation import relative_orientation

    t0 = time.perf_counter()
    pair = open_pair(inputs)
    rasters, sensors, scene_dem = pair.rasters, pair.sensors, pair.init_dem
    generator = choose_dem_generator(generator, pair.types)
    component = get_registry().get("dem-generator", generator)
    resolved = component.settings({k: v for k, v in settings.items() if v is not None})
    if inputs.source is not None and inputs.models is None:
        progress(
            "dem",
            "no --models: using the scene's delivered (system-level) models; give a carto "
            "adjust output folder for a DEM of the adjusted accuracy",
            quiet,
        )
    start = initial_dem(init_dem, geoid, init_height_m, scene_dem)
    names = list(sensors)
    images = _prepared_images(rasters, sensors, start, work, engine)
    checked, warnings = checked_pair(
        images, [sensors[n] for n in names], start, allow_poor=allow_poor
    )
    control = datum_gcps(inputs.models, names)
    oriented = relative_orientation(
        dict(zip(names, images, strict=True)),
        sensors,
        start,
        ro_settings,
        gcps=control,
        constant_dem=init_height_m is not None,
        engine=engine,
        progress=lambda line: progress("dem", line, quiet),
    )
    sensors = {**sensors, names[0]: oriented.left or sensors[names[0]], names[1]: oriented.right}
    chosen_matcher = get_registry().get("matcher", matcher)
    posting = settings.get("posting_m")
    progress(
        "dem",
        f"{generator}: {names[0]} (left) and {names[1]} (right)"
        + (f", posting {posting:g} m" if isinstance(posting, int | float) else "")
        + f", matcher {matcher}",
        quiet,
    )
    progress("dem", f"tiles on {engine.description}", quiet)
    product = component.generate(
        images,
        [sensors[n] for n in names],
        init_dem=start,
        matcher=chosen_matcher,
        progress=lambda line: progress("dem", line, quiet),
        scheduler=engine,
        work_dir=work / "generator",
        keep_failed_tiles=allow_poor,
        **settings,
    )
    release = getattr(engine, "release", None)
    if release is not None:  # the workers' memory back before the outputs are written
        release()
    _check_product(product, generator, len(names))
    warnings += poor_dem(product) + departs_from_start(product.dem, start)
    warnings += mismatched(product) + off_the_gcps(product.dem, control)
    if product.failed_tiles:
        warnings.append(
            f"{len(product.failed_tiles)} tiles failed and have no heights "
            f"({product.failed_tiles[0]})"
        )
    if warnings and not allow_poor:
        raise InputError(f"dem: {'; '.join(warnings)} (--allow-poor writes it anyway)")
    for warning in warnings:
        progress("dem", f"warning: {warning}", False)  # warnings print under --quiet too
    geoid_grid = Geoid.open(geoid) if geoid else None
    dem, coregistration = coregistered(
        product.dem,
        coregister,
        start=start,
        auto=auto_coregisters(inputs.models, init_height_m is not None),
        geoid=geoid_grid,
        accuracy_m=coregister_accuracy_m,
        say=lambda line: progress("dem", line, quiet),
    )
    if coregistration and coregistration.get("warning"):
        warnings.append(coregistration["warning"])
    if init_dem is not None and not states_vertical(init_dem):
        warnings.append(
            f"the starting DEM {init_dem} does not say what its heights are above (no "
            "vertical CRS or VERTICAL_REFERENCE tag): read as heights above the WGS84 "
            "ellipsoid; if they are above the geoid (SRTM, Copernicus), tag it (gdal_edit.py "
            "-mo VERTICAL_REFERENCE=geoid:EGM96) and give --geoid"
        )
        progress("dem", f"warning: {warnings[-1]}", False)
    written = dem.to_geoid(geoid_grid) if vertical == "geoid" else dem
    vertical_reference = vertical_tag(written.vertical)
    files = _write_rasters(out, written, product, {n: rasters[n] for n in names}, generator)
    del written
    from carto.framework.raster.quicklook import difference_png, hillshade_png

    files["hillshade"] = hillshade_png(out / "dem.tif", out / "dem_hillshade.png", "DEM").name
    report: dict[str, Any] = {
        "generator": generator,
        "matcher": matcher,
        "images": {n: str(rasters[n]) for n in names},
        "settings": {
            **{k: v for k, v in settings.items() if isinstance(v, str | int | float)},
            "generator": resolved_settings(resolved),
            "relative_orientation": resolved_settings(ro_settings),
        },
        "workers": engine.workers,
        "engine": engine.description,
        "failed_tiles": list(product.failed_tiles),
        "initial_dem": start.name,
        "pair_check": checked.as_dict(),
        "relative_orientation": oriented.record,
        "coregistration": coregistration,
        "dem_grid": {
            "crs": product.dem_grid.crs.to_string(),
            "posting_m": product.dem_grid.resolution[0],
            "shape": list(product.dem_grid.shape),
        },
        "ortho_resolution_m": product.ortho_grid.resolution[0],
        "vertical_reference": vertical_reference,
        "quality_bands": [layer.name for layer in product.quality if layer.grid == "dem"],
        "matching_bands": [layer.name for layer in product.quality if layer.grid == "ortho"],
        "quality_layers": {
            layer.name: {
                "file": f"{'quality' if layer.grid == 'dem' else 'matching'}"
                f"{LAYER_FILES[layer.kind][0]}.tif",
                "kind": layer.kind,
                "description": layer.description,
            }
            for layer in product.quality
        },
        "converged": product.converged,
        "matched_fraction": product.matched_fraction,
        "warnings": warnings,
        "iterations": product.iteration_dicts(),
        "files": files,
    }
    clash = sorted(set(product.extras) & set(report))
    if clash:
        raise InputError(
            f"DEM generator {generator!r}: extras {', '.join(clash)} collide with report fields"
        )
    report.update(product.extras)
    if reference is not None:
        from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks

        comparison = dem_accuracy_by_blocks(dem, reference, geoid=geoid_grid)
        report["accuracy"] = comparison.report
        files["difference"] = difference_png(
            comparison.preview,
            out / "dem_difference.png",
            f"DEM - {Path(reference).name}",
            figures=comparison.report,
        ).name
    report["seconds"] = time.perf_counter() - t0
    write_report(out / "report.json", report)
    return report


def _prepared_images(
    rasters: Mapping[str, Path],
    sensors: Mapping[str, Sensor],
    start: DEM,
    work: Path,
    engine: Any,
) -> list[Any]:
    """Each image read by windows, checked and prepared (staggered arrays merged) in
    ``work``, in the order of ``sensors``."""
    from carto.framework.imaging.preparation import prepare_image
    from carto.framework.raster.image_source import RasterImage, check_image_source

    images = []
    for n, sensor in sensors.items():
        source = RasterImage.open(rasters[n])
        check_image_source(source, str(rasters[n]))
        images.append(
            prepare_image(
                source,
                sensor,
                start,
                work / "prepared" / n,
                engine,
                desc=f"merge staggered arrays of {n}",
            )
        )
    return images


def _check_product(product: Any, generator: str, n_images: int) -> None:
    """Refuse what a generator returned unless it is a DEMProduct of one ortho per image."""
    from carto.framework.dem_generation.base import DEMProduct

    if not isinstance(product, DEMProduct):
        raise InputError(
            f"DEM generator {generator!r} returned {type(product).__name__}, not a DEMProduct"
        )
    if len(product.orthos) != n_images:
        raise InputError(
            f"DEM generator {generator!r} returned {len(product.orthos)} ortho-images for "
            f"{n_images} images"
        )


def _write_rasters(
    out: Path, dem: DEM, product: Any, rasters: Mapping[str, Path], generator: str
) -> dict[str, str]:
    """dem.tif (``dem``'s heights), one ortho-image per image (left, right: the order of
    ``rasters``) in its image's radiometry, quality.tif and matching.tif (the product's
    layers on the DEM and ortho grids) as COGs in ``out``; their file names by key."""
    from carto.framework.imaging.ortho import write_ortho

    files = {
        "dem": write_ortho(
            out / "dem.tif",
            dem.heights.astype(np.float32),
            product.dem_grid,
            vertical=dem.vertical,
            tags={"CARTO_PRODUCT": "dem", "CARTO_GENERATOR": generator},
            band_descriptions=["height"],
        ).name
    }
    for side, name, ortho in zip(("left", "right"), rasters, product.orthos, strict=True):
        files[f"ortho_{side}"] = write_ortho(
            out / f"ortho_{side}.tif",
            ortho,
            product.ortho_grid,
            out_dtype=_radiometry(rasters[name]),
            tags={"CARTO_PRODUCT": "ortho", "CARTO_IMAGE": name},
        ).name
    for key, on, grid in (
        ("quality", "dem", product.dem_grid),
        ("matching", "ortho", product.ortho_grid),
    ):
        for kind, (suffix, dtype, nodata) in LAYER_FILES.items():
            layers = [layer for layer in product.quality if layer.grid == on and layer.kind == kind]
            if not layers:
                continue
            name = f"{key}{suffix}"
            files[name] = write_ortho(
                out / f"{name}.tif",
                [layer.values for layer in layers],
                grid,
                tags={
                    "CARTO_PRODUCT": key,
                    **{f"BAND_{k}": layer.description for k, layer in enumerate(layers, 1)},
                },
                nodata=nodata,
                out_dtype=dtype,
                band_descriptions=[layer.name for layer in layers],
                band_units=["metre" if layer.name.endswith("_m") else None for layer in layers],
                overview_resampling="nearest",
            ).name
    return files


LAYER_FILES = {
    "measure": ("", None, None),
    "count": ("_counts", "uint16", 65535),
    "flag": ("_flags", "uint8", 255),
}
"""Per kind of quality layer: the file-name suffix, the band type and nodata (GeoTIFF bands
of one file share one type: flags as float32 made matching.tif 14 MB, issue 34)."""
