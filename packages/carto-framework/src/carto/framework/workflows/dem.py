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
from carto.framework.files.staging import staged_folder
from carto.framework.geometry.sensor import SensorType
from carto.framework.parallel.process_memory import release_free_memory
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
    resolve_coregister,
)
from carto.framework.workflows.dem_options import check_names, check_options
from carto.framework.workflows.geographic_output import geographic_output
from carto.framework.workflows.reporting import progress, resolved_settings, write_report
from carto.framework.workflows.resumable import fingerprint, open_work, settle_work
from carto.framework.workflows.run_record import record_run, utc_now
from carto.framework.workflows.stereo_pair import (
    OrientedPair,
    StereoInputs,
    StereoPair,
    open_pair,
    oriented_pair,
)

__all__ = [
    "StereoInputs",
    "StereoPair",
    "choose_dem_generator",
    "dem_product",
    "open_pair",
]


def radiometry(path: str | os.PathLike[str]) -> Any:
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
    relative_orientation: str | Mapping[str, Any] = "auto",
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
    :data:`~carto.framework.adjustment.relative_orientation.MODES`, or the fields of
    :class:`~carto.framework.adjustment.relative_orientation.RelativeOrientationSettings` as a
    mapping, e.g. ``{"mode": "line", "platform_jitter": False}``; see
    :func:`~carto.framework.adjustment.relative_orientation.relative_orientation`). The DEM
    is then co-registered (``coregister``: ``"auto"``, ``"none"`` or a reference DEM file,
    :func:`~carto.framework.workflows.dem_datum.coregistered`; a move beyond
    ``coregister_accuracy_m`` is a warning).
    """
    settings = dict(options or {})
    geographic = geographic_output(settings)  # a lon/lat grid: warped after the generator
    check_options(settings)
    check_names(generator, matcher)
    ro_settings, coregister = _checked_datum(
        relative_orientation, coregister, coregister_accuracy_m, vertical, geoid
    )
    if "workers" in settings:  # the earlier form of the argument
        workers = int(settings.pop("workers"))
    run = _DemRun(
        inputs=inputs,
        init_dem=init_dem,
        geoid=geoid,
        init_height_m=init_height_m,
        generator=generator,
        matcher=matcher,
        reference=reference,
        vertical=vertical,
        settings=settings,
        allow_poor=allow_poor,
        relative_orientation=relative_orientation,
        ro_settings=ro_settings,
        coregister=coregister,
        coregister_accuracy_m=coregister_accuracy_m,
    )
    return _staged_run(out_dir, run, geographic, workers, scheduler, resume, quiet)


@attrs.frozen(eq=False)
class _DemRun:
    """What a DEM run was asked, checked (the arguments of :func:`dem_product`; ``settings``:
    the generator's options, ``ro_settings``: the relative orientation's, ``coregister``:
    what :func:`~carto.framework.workflows.dem_datum.resolve_coregister` made of it)."""

    inputs: StereoInputs
    init_dem: str | os.PathLike[str] | None
    geoid: str | os.PathLike[str] | None
    init_height_m: float | None
    generator: str | None
    matcher: str
    reference: str | os.PathLike[str] | None
    vertical: str
    settings: dict[str, Any]
    allow_poor: bool
    relative_orientation: str | Mapping[str, Any]
    ro_settings: RelativeOrientationSettings
    coregister: str | Path
    coregister_accuracy_m: float

    def sources(self) -> list[Any]:
        """The files the run reads (None where one is not given): they fingerprint its work
        folder and the staging folder records them."""
        inputs, coregister = self.inputs, self.coregister
        return [
            inputs.source,
            inputs.left,
            inputs.right,
            inputs.left_model,
            inputs.right_model,
            inputs.models,
            self.init_dem,
            self.geoid,
            self.reference,
            None if str(coregister) in ("auto", "none") else coregister,
            *(scene_files(inputs.source) if inputs.source is not None else []),
        ]

    def facts(self) -> dict[str, Any]:
        """The run's arguments beside its files, for the work folder's fingerprint."""
        return {
            "generator": self.generator,
            "matcher": self.matcher,
            "init_height_m": self.init_height_m,
            "pair": list(self.inputs.pair) if self.inputs.pair else None,
            "sensor_type": self.inputs.sensor_type,
            "settings": {k: str(v) for k, v in sorted(self.settings.items())},
            "allow_poor": self.allow_poor,
            "vertical": self.vertical,
            "relative_orientation": (
                self.relative_orientation
                if isinstance(self.relative_orientation, str)
                else {k: self.relative_orientation[k] for k in sorted(self.relative_orientation)}
            ),
            "coregister": str(self.coregister),
            "coregister_accuracy_m": self.coregister_accuracy_m,
        }


def _staged_run(
    out_dir: str | os.PathLike[str],
    run: _DemRun,
    geographic: Any,
    workers: int | None,
    scheduler: str | None,
    resume: bool,
    quiet: bool,
) -> dict[str, Any]:
    """The run in a staging folder that replaces ``out_dir`` when complete, its
    intermediate files in a work folder (kept when the run fails or is interrupted,
    continued with ``resume``), tiles on an engine of ``workers`` or at ``scheduler``; the
    outputs warped to a lon/lat grid by ``geographic`` (None: not); the report."""
    from carto.framework.parallel.engine import open_engine

    sources = run.sources()
    work: Path | None = None
    started = utc_now()
    try:
        with staged_folder(out_dir, "dem", inputs=sources) as stage:
            work = open_work(out_dir, fingerprint(sources, run.facts()), resume, quiet)
            with open_engine(workers, scheduler, quiet=quiet) as engine:
                report = _dem_into(stage, run, quiet=quiet, engine=engine, work=work)
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


def _checked_datum(
    relative_orientation: str | Mapping[str, Any],
    coregister: str | os.PathLike[str] | None,
    coregister_accuracy_m: float,
    vertical: str,
    geoid: str | os.PathLike[str] | None,
) -> tuple[RelativeOrientationSettings, str | Path]:
    """The relative orientation's settings and the co-registration's choice
    (:func:`~carto.framework.workflows.dem_datum.resolve_coregister`) of a run, its datum
    arguments checked (a :class:`UsageError` for a bad one)."""
    if isinstance(relative_orientation, str):
        relative_orientation = {"mode": relative_orientation}
    known = {f.name for f in attrs.fields(RelativeOrientationSettings)}
    unknown = sorted(set(relative_orientation) - known)
    if unknown:
        raise UsageError(
            f"relative orientation: unknown setting(s) {', '.join(unknown)} "
            f"(known: {', '.join(sorted(known))})"
        )
    try:
        ro_settings = RelativeOrientationSettings(**relative_orientation)
    except InputError as exc:
        raise UsageError(str(exc)) from None
    choice = resolve_coregister(coregister)
    if not (np.isfinite(coregister_accuracy_m) and coregister_accuracy_m > 0):
        raise UsageError(f"--coregister-accuracy must be > 0 m, got {coregister_accuracy_m:g}")
    if vertical not in ("ellipsoid", "geoid"):
        raise UsageError(f"--vertical must be 'ellipsoid' or 'geoid', got {vertical!r}")
    if vertical == "geoid" and geoid is None:
        raise UsageError("--vertical geoid needs the geoid grid: --geoid GTX")
    return ro_settings, choice


def _dem_into(out: Path, run: _DemRun, *, quiet: bool, engine: Any, work: Path) -> dict[str, Any]:
    """:func:`dem_product` writing into ``out`` (its staging folder), tiles on ``engine``,
    intermediate files in ``work``."""
    t0 = time.perf_counter()
    from carto.framework.raster.quicklook import prepare_figures

    prepare_figures()  # for the hillshade, meanwhile
    inputs = run.inputs
    pair = open_pair(inputs)
    generator = choose_dem_generator(run.generator, pair.types)
    component = get_registry().get("dem-generator", generator)
    resolved = component.settings({k: v for k, v in run.settings.items() if v is not None})
    if inputs.source is not None and inputs.models is None:
        progress(
            "dem",
            "no --models: using the scene's delivered (system-level) models; give a carto "
            "adjust output folder for a DEM of the adjusted accuracy",
            quiet,
        )
    start = initial_dem(run.init_dem, run.geoid, run.init_height_m, pair.init_dem)
    oriented = oriented_pair(
        pair, start, inputs.models, run.ro_settings, run.init_height_m is not None,
        run.allow_poor, engine, work, quiet,
    )  # fmt: skip
    product = _generated(component, generator, oriented, run, engine, work, quiet)
    warnings = oriented.warnings + _product_warnings(product, start, oriented.control)
    if warnings and not run.allow_poor:
        raise InputError(f"dem: {'; '.join(warnings)} (--allow-poor writes it anyway)")
    for warning in warnings:
        progress("dem", f"warning: {warning}", False)  # warnings print under --quiet too
    geoid_grid = Geoid.open(run.geoid) if run.geoid else None
    dem, coregistration = coregistered(
        product.dem,
        run.coregister,
        start=start,
        auto=auto_coregisters(inputs.models, run.init_height_m is not None),
        geoid=geoid_grid,
        accuracy_m=run.coregister_accuracy_m,
        say=lambda line: progress("dem", line, quiet),
    )
    if coregistration and coregistration.get("warning"):
        warnings.append(coregistration["warning"])
    for warning in _unstated_vertical(run.init_dem):
        warnings.append(warning)
        progress("dem", f"warning: {warning}", False)
    written = dem.to_geoid(geoid_grid) if run.vertical == "geoid" else dem
    vertical_reference = vertical_tag(written.vertical)
    rasters = {n: oriented.rasters[n] for n in oriented.names}
    release_free_memory("before the DEM's files")
    files = _write_files(out, written, product, rasters, generator)
    del written
    release_free_memory("after the DEM's files")
    report: dict[str, Any] = {
        "generator": generator,
        "matcher": run.matcher,
        "images": {n: str(r) for n, r in rasters.items()},
        "settings": {
            **{k: v for k, v in run.settings.items() if isinstance(v, str | int | float)},
            "generator": resolved_settings(resolved),
            "relative_orientation": resolved_settings(run.ro_settings),
        },
        "workers": engine.workers,
        "engine": engine.description,
        **_product_record(product, oriented, coregistration, vertical_reference),
        "warnings": warnings,
        "iterations": product.iteration_dicts(),
        "files": files,
    }
    _add_extras(report, product, generator)
    if run.reference is not None:
        _compare_with_reference(out, report, dem, run.reference, geoid_grid)
    report["seconds"] = time.perf_counter() - t0
    write_report(out / "report.json", report)
    return report


def _generated(
    component: Any,
    generator: str,
    pair: OrientedPair,
    run: _DemRun,
    engine: Any,
    work: Path,
    quiet: bool,
) -> Any:
    """The generator's product of the pair (checked), the engine's workers' memory
    released."""
    matcher, settings = run.matcher, run.settings
    names = pair.names
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
        pair.images,
        [pair.sensors[n] for n in names],
        init_dem=pair.start,
        matcher=chosen_matcher,
        progress=lambda line: progress("dem", line, quiet),
        scheduler=engine,
        work_dir=work / "generator",
        keep_failed_tiles=run.allow_poor,
        **settings,
    )
    release = getattr(engine, "release", None)
    if release is not None:  # the workers' memory back before the outputs are written
        release()
    _check_product(product, generator, len(names))
    return product


def _product_warnings(product: Any, start: DEM, control: dict[str, Any] | None) -> list[str]:
    """What makes a DEM poor (:mod:`~carto.framework.workflows.dem_checks`) and its failed
    tiles."""
    warnings = poor_dem(product) + departs_from_start(product.dem, start)
    warnings += mismatched(product) + off_the_gcps(product.dem, control)
    if product.failed_tiles:
        warnings.append(
            f"{len(product.failed_tiles)} tiles failed and have no heights "
            f"({product.failed_tiles[0]})"
        )
    return warnings


def _unstated_vertical(init_dem: str | os.PathLike[str] | None) -> list[str]:
    """A warning for a starting DEM file that does not say what its heights are above."""
    if init_dem is None or states_vertical(init_dem):
        return []
    return [
        f"the starting DEM {init_dem} does not say what its heights are above (no "
        "vertical CRS or VERTICAL_REFERENCE tag): read as heights above the WGS84 "
        "ellipsoid; if they are above the geoid (SRTM, Copernicus), tag it (gdal_edit.py "
        "-mo VERTICAL_REFERENCE=geoid:EGM96) and give --geoid"
    ]


def _product_record(
    product: Any,
    pair: OrientedPair,
    coregistration: dict[str, Any] | None,
    vertical_reference: str,
) -> dict[str, Any]:
    """What ``report.json`` says of the product, the pair and the datum (in its order)."""
    return {
        "failed_tiles": list(product.failed_tiles),
        "initial_dem": pair.start.name,
        "pair_check": pair.checked.as_dict(),
        "relative_orientation": pair.orientation,
        "coregistration": coregistration,
        "dem_grid": {
            "crs": product.dem_grid.crs.to_string(),
            "posting_m": product.dem_grid.resolution[0],
            "shape": list(product.dem_grid.shape),
        },
        "ortho_resolution_m": product.ortho_grid.resolution[0],
        "vertical_reference": vertical_reference,
        **_quality_record(product),
        "converged": product.converged,
        "matched_fraction": product.matched_fraction,
    }


def _add_extras(report: dict[str, Any], product: Any, generator: str) -> None:
    """The generator's extra report fields into ``report`` (refused where they collide)."""
    clash = sorted(set(product.extras) & set(report))
    if clash:
        raise InputError(
            f"DEM generator {generator!r}: extras {', '.join(clash)} collide with report fields"
        )
    report.update(product.extras)


def _compare_with_reference(
    out: Path,
    report: dict[str, Any],
    dem: DEM,
    reference: str | os.PathLike[str],
    geoid: Geoid | None,
) -> None:
    """The DEM's accuracy against ``reference`` into ``report`` and its difference map into
    ``out`` (named in ``report["files"]``)."""
    from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks
    from carto.framework.raster.quicklook import difference_png

    comparison = dem_accuracy_by_blocks(dem, reference, geoid=geoid)
    report["accuracy"] = comparison.report
    report["files"]["difference"] = difference_png(
        comparison.preview,
        out / "dem_difference.png",
        f"DEM - {Path(reference).name}",
        figures=comparison.report,
    ).name


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


def _write_files(
    out: Path, dem: DEM, product: Any, rasters: Mapping[str, Path], generator: str
) -> dict[str, str]:
    """:func:`_write_rasters`, and the hillshade PNG of ``dem`` drawn meanwhile in a thread
    (matplotlib's import and drawing, about 1.5 s, while GDAL writes the COGs)."""
    from concurrent.futures import ThreadPoolExecutor

    from carto.framework.raster.quicklook import hillshade_png

    with ThreadPoolExecutor(1, thread_name_prefix="hillshade") as pool:
        shade = pool.submit(hillshade_png, dem, out / "dem_hillshade.png", "DEM")
        files = _write_rasters(out, dem, product, rasters, generator)
        files["hillshade"] = shade.result().name
    return files


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
            out_dtype=radiometry(rasters[name]),
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


def _quality_record(product: Any) -> dict[str, Any]:
    """What ``report.json`` says of a product's quality layers: the bands on the DEM grid
    (``quality_bands``) and on the ortho grid (``matching_bands``), and per layer its file,
    kind and description (``quality_layers``)."""
    return {
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
    }


LAYER_FILES = {
    "measure": ("", None, None),
    "count": ("_counts", "uint16", 65535),
    "flag": ("_flags", "uint8", 255),
}
"""Per kind of quality layer: the file-name suffix, the band type and nodata (GeoTIFF bands
of one file share one type: flags as float32 made matching.tif 14 MB, issue 34)."""
