"""Workflows behind the commands: the steps ``carto adjust`` chains, with their outputs.

``adjust_product`` opens a scene (or a configuration file naming images, models, GCPs and tie
points), selects GCPs, finds tie points automatically when asked, runs an adjuster from the
registry and writes: the adjusted model files (rigorous models) or corrected RPC files,
corrected RPCs fitted to every adjusted rigorous model (``<image>_RPC.TXT``, which GDAL reads as
the sidecar of ``<image>.tif``), a residual plot (``residuals.png``) and ``report.json``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.control_checks import check_control, check_tie_points
from carto.framework.adjustment.dem_heights import (
    WEAK_INTERSECTION_DEG,
    flat_heights,
    with_dem_heights,
)
from carto.framework.adjustment.image_trends import fold_image_trends
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import AdjustmentError, InputError
from carto.framework.files.control_table import read_tie_table
from carto.framework.files.documents import write_json_atomic
from carto.framework.files.point_table import write_point_table
from carto.framework.files.staging import staged_folder
from carto.framework.geometry.sensor import SensorType
from carto.framework.matching.gcp_transfer import (
    GCP_OFFSET_COLUMNS,
    GCP_OFFSET_SIGMA_PX,
    gcp_offsets,
)
from carto.framework.plugins.registry import get_registry
from carto.framework.workflows.adjust_checks import (
    corrections_beyond_priors,
    gcps_not_transferred,
    gcps_off_the_dem,
    gcps_rejected,
    poor_adjustment,
)
from carto.framework.workflows.configuration import configuration_files, read_configuration
from carto.framework.workflows.opening import (
    check_installed,
    open_product,
)
from carto.framework.workflows.reporting import jsonable, progress, resolved_settings, write_report
from carto.framework.workflows.residual_plot import residual_misfit, residual_plot
from carto.framework.workflows.run_record import record_run, utc_now

Table = dict[str, NDArray]


def select_gcps(table: Table, n: int | None) -> Table:
    """``n`` GCPs of a long-format table (all when ``n`` is None): one -> the one nearest the
    centroid of all; more -> the first ``n`` ids in file order (the simulator lists them
    spread over the scene)."""
    ids = list(dict.fromkeys(table["id"].tolist()))
    if n is None or n >= len(ids):
        if n is not None and n > len(ids):
            raise InputError(f"--gcps {n}: the product has only {len(ids)} GCPs")
        return table
    if n < 0:
        raise InputError(f"--gcps must be >= 0, got {n}")
    if n == 0:
        return {k: v[:0] for k, v in table.items()}
    if n == 1:
        lon = np.array([table["lon_deg"][table["id"] == i][0] for i in ids])
        lat = np.array([table["lat_deg"][table["id"] == i][0] for i in ids])
        keep = {ids[int(np.argmin((lon - lon.mean()) ** 2 + (lat - lat.mean()) ** 2))]}
    else:
        keep = set(ids[:n])
    m = np.array([i in keep for i in table["id"]])
    return {k: v[m] for k, v in table.items()}


def choose_adjuster(requested: str | None, types: Mapping[str, SensorType]) -> str:
    """The adjuster of a run: the one named, else the default the images' sensor types name
    (they must agree), else an error that asks for ``--adjuster``."""
    if requested is not None:
        return requested
    defaults = {t.default_adjuster for t in types.values()}
    if len(defaults) == 1 and None not in defaults:
        return defaults.pop()
    named = ", ".join(sorted(f"{n}: {t.name}" for n, t in types.items()))
    raise InputError(
        f"no default adjuster for these images (sensor types {named}); name one with --adjuster"
    )


RESERVED_OUTPUTS = frozenset(
    {"report", "models", "rpc", "residual_plot", "tie_points", "gcp_offsets"}
)
"""Names an adjuster's products cannot take (the workflow's own outputs)."""


def adjust_product(
    source: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    n_gcps: int | None = None,
    adjuster: str | None = None,
    ties: str = "auto",
    options: Mapping[str, Any] | None = None,
    sensor_type: str | None = None,
    matcher: str | None = None,
    trajectory: str | None = None,
    quiet: bool = False,
    allow_poor: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
) -> dict[str, Any]:
    """Adjust a scene or configured product and write the outputs; return the report.

    Args:
        source: a scene folder (``carto simulate``) or a JSON configuration (see
            ``carto adjust --help``).
        out_dir: output folder.
        n_gcps: number of GCPs to use (None: all that the product has).
        adjuster: adjuster name (default: the one the images' sensor types name).
        ties: ``"auto"`` (automatic tie points), ``"none"``, or a CSV file
            (``id,image,line,sample[,sigma_px]``).
        options: adjuster options (mode, attitude_order ...).
        sensor_type: open the product with this sensor type (default: the one that
            recognises it).
        matcher: the matcher of the tie points and of the GCP transfer (a registry name;
            default: the configuration's ``"matcher"``, else ``"ncc"``).
        trajectory: the trajectory model to fit the products' trajectories with (a registry
            name; default: the one the ancillary data name).
        allow_poor: write the outputs of a poor adjustment (no tie point found when they were
            asked for, sigma0 above :data:`POOR_SIGMA0`) with warnings in the report, instead
            of failing with :class:`~carto.framework.errors.AdjustmentError`.
        workers, scheduler: the tile engine of the tie points, the stagger merge and the GCP
            transfer (:func:`~carto.framework.parallel.engine.open_engine`: ``workers``
            processes of a local cluster, default every core, 1 in this process; or the
            running cluster at ``scheduler``). Images are read by windows and matched by
            tiles (:mod:`~carto.framework.matching.tiled_ties`): the memory does not grow
            with the scene. Prepared images go to a work folder in the staging folder,
            removed at the end.

    The outputs are written into a staging folder that replaces ``out_dir`` only when all are
    complete (:func:`carto.framework.files.staging.staged_folder`).
    """
    import shutil

    from carto.framework.parallel.engine import open_engine
    from carto.framework.products.scene import scene_files

    check_installed(
        ("adjuster", "--adjuster", adjuster),
        ("trajectory", "--trajectory", trajectory),
        ("matcher", "--matcher", matcher),
    )
    src = Path(source)
    inputs = [src, *configuration_files(src), *scene_files(src)]
    if ties not in ("auto", "none"):
        inputs.append(Path(ties))
    calibration = (options or {}).get("calibration") or []
    if isinstance(calibration, str | os.PathLike):  # one file or folder, or a list of them
        calibration = [calibration]
    inputs += [Path(c) for c in calibration]
    with (
        staged_folder(out_dir, "adjust", inputs=inputs) as stage,
        open_engine(workers, scheduler, quiet=quiet) as engine,
    ):
        work = stage / ".work"
        started = utc_now()
        try:
            report = _adjust_into(
                stage,
                src,
                n_gcps=n_gcps,
                adjuster=adjuster,
                ties=ties,
                options=options,
                sensor_type=sensor_type,
                matcher=matcher,
                trajectory=trajectory,
                quiet=quiet,
                allow_poor=allow_poor,
                engine=engine,
                work=work,
            )
        finally:
            shutil.rmtree(work, ignore_errors=True)
        return record_run(stage / "report.json", report, inputs, started, "adjust")


def _adjust_into(  # noqa: C901, PLR0915 (issue 32: to split)
    out: Path,
    src: Path,
    *,
    n_gcps: int | None,
    adjuster: str | None,
    ties: str,
    options: Mapping[str, Any] | None,
    sensor_type: str | None,
    matcher: str | None,
    trajectory: str | None,
    quiet: bool,
    allow_poor: bool,
    engine: Any,
    work: Path,
) -> dict[str, Any]:
    """:func:`adjust_product` writing into the folder ``out`` (its staging folder), tasks on
    ``engine``, prepared images in ``work``."""
    from carto.framework.evaluation.checkpoints import (
        checkpoint_accuracy,
        monoplot_accuracy,
        predicted_checkpoint_sigma,
    )
    from carto.framework.products.scene import Scene

    t0 = time.perf_counter()
    options = dict(options or {})
    gcp_transfer = _auto_flag(options.pop("gcp_transfer", "auto"), "gcp_transfer")
    offset_sigma_px = float(options.pop("gcp_offset_sigma_px", GCP_OFFSET_SIGMA_PX))
    if not (math.isfinite(offset_sigma_px) and offset_sigma_px > 0):
        raise InputError(f"gcp_offset_sigma_px must be > 0, got {offset_sigma_px}")
    tie_heights_flag = _auto_flag(options.pop("tie_heights", "auto"), "tie_heights")
    height_sigma_m = float(options.pop("height_sigma_m", 30.0))
    height_offset_sigma_m = float(options.pop("height_offset_sigma_m", 0.0))
    checkpoints = None
    dem = None
    flat_height_m = None
    rasters: dict[str, Path] = {}
    if src.is_dir() or src.name == "scene.json":
        scene = Scene.open(src)
        opened = open_product(scene.root, sensor_type, trajectory_model=trajectory)
        sensors, types = opened.sensors, opened.types
        gcps = scene.control("gcps")
        checkpoints = scene.control("checkpoints")
        if gcps is not None:
            check_control(gcps, sensors, "gcps")
        if checkpoints is not None:
            check_control(checkpoints, sensors, "checkpoints")
        rasters = {n: scene.raster(n) for n in scene.image_names}
        init = scene.manifest.get("init_dem")
        if init:
            from carto.framework.raster.dem import DEM

            dem = DEM.open(scene.path(init))
    elif src.suffix.lower() == ".json":
        config = read_configuration(src, sensor_type, trajectory)
        sensors, types, rasters, gcps = config.sensors, config.types, config.rasters, config.gcps
        dem, flat_height_m = config.dem, config.flat_height_m
        matcher = matcher or config.matcher or "ncc"
    else:
        raise InputError(f"{src}: expected a scene folder or a JSON configuration file")
    matcher = matcher or "ncc"
    chosen_matcher = get_registry().get("matcher", matcher)
    name = choose_adjuster(adjuster, types)
    component = get_registry().get("adjuster", name)
    resolved = component.settings({**options, "dem": None})  # before any work
    gcps = select_gcps(gcps, n_gcps) if gcps is not None else None
    n_used = len(set(gcps["id"].tolist())) if gcps is not None else 0
    early = gcps_off_the_dem(gcps, dem) if gcps is not None and flat_height_m is None else []
    if early and not allow_poor:
        raise InputError(f"{src}: {'; '.join(early)} (--allow-poor adjusts anyway)")
    images: dict[str, Any] = {}

    def prepared() -> dict[str, Any]:
        """The images read by windows, stagger-merged once (for the ties and the transfer)."""
        from carto.framework.imaging.preparation import prepared_sources

        if not images:
            images.update(prepared_sources(rasters, sensors, dem, work / "prepared", engine))
        return images

    # tie points
    tie_table: Table | None = None
    if ties == "auto":
        from carto.framework.matching.tiepoints import block_tie_points

        if dem is None:
            raise InputError(
                "automatic tie points need a DEM (the scene's init_dem.tif or "
                '"dem" in the configuration)'
            )
        progress(
            "adjust",
            f"matching tie points on system-level ortho-images ({engine.description})",
            quiet,
        )
        tie_table = block_tie_points(
            prepared(), sensors, dem, matcher=chosen_matcher, engine=engine, prepared=True
        )
    elif ties != "none":
        tie_table = read_tie_table(ties, images=list(sensors))
        check_tie_points(tie_table, sensors)
    n_ties = len(set(tie_table["id"].tolist())) if tie_table is not None else 0
    obs = Observations.from_tables(gcps, tie_table)
    # a DEM height on a tie point fixes what tie points cannot: a shift along the stereo
    # parallax looks like a height change, and rays that meet at a small angle (the overlap
    # of adjacent swaths) let the point slide along them. With GCPs, on well intersecting
    # points, it would only pull the block towards the coarse DEM's errors. So by default
    # ("auto"): every tie point without GCPs, else only those seen in an image without GCP
    # or whose rays meet at less than WEAK_INTERSECTION_DEG; True: every one; False: none.
    tie_heights = flat_heights(tie_heights_flag, flat_height_m, n_used)
    if dem is not None and tie_table is not None and tie_heights is not False:
        weak = WEAK_INTERSECTION_DEG if (tie_heights == "auto" and n_used > 0) else None
        obs = with_dem_heights(
            obs, sensors, dem, height_sigma_m, height_offset_sigma_m, below_angle_deg=weak
        )
    # GCP transfer: the offset of each hand-measured GCP between images, by matching,
    # carries its stereo parallax at matching precision (see gcp_transfer.gcp_offsets)
    transfer: dict[str, Any] = {"requested": gcp_transfer, "ran": False}
    if gcp_transfer is False:
        transfer["why_not"] = "turned off"
    elif gcps is None or not len(gcps["id"]):
        transfer["why_not"] = "no GCP"
    elif dem is None or any(n not in rasters for n in sensors):
        transfer["why_not"] = "it needs every image's raster and a DEM"
        if gcp_transfer is True:
            raise InputError(f"gcp_transfer: {transfer['why_not']}")
    progress(
        "adjust",
        f"adjusting {len(sensors)} images with {name} ({n_used} GCPs, {n_ties} tie points)",
        quiet,
    )
    result = component.adjust(sensors, obs, dem=dem, **options)
    tie_sigma = estimated_tie_sigma(obs, result) if ties == "auto" else None
    if tie_sigma is not None:  # the matched tie points' precision, from the data
        obs = tie_sigma.observations
        result = component.adjust(sensors, obs, dem=dem, **options)
    first_outliers: list[str] = []  # the first adjustment's, kept out of the second
    offsets = dropped_offsets = None
    if "why_not" not in transfer:
        # matched on chips orthorectified with the adjusted models (the system-level ones
        # may be hundreds of metres apart), then the adjustment again with the offsets;
        # GCPs the first adjustment rejected stay out
        progress("adjust", "matching the GCPs between images (GCP transfer)", quiet)
        rejected = set(result.outliers)
        kept = np.array([g not in rejected for g in gcps["id"]], bool)
        try:
            offsets, dropped_offsets = gcp_offsets(
                {k: np.asarray(v)[kept] for k, v in gcps.items()},
                prepared(),
                result.sensors,
                dem,
                sigma_px=offset_sigma_px,
                matcher=chosen_matcher,
                prepared=True,
            )
        except InputError as exc:
            if gcp_transfer is True:
                raise
            transfer["why_not"] = str(exc)  # e.g. a raster that does not fit its model
        if offsets is not None and not offsets["id"].size:
            transfer["why_not"] = "no GCP could be matched"
        elif offsets is not None:
            transfer["ran"] = True
            obs = obs.with_offsets(
                *(offsets[c] for c in GCP_OFFSET_COLUMNS if c != "score")  # as with_offsets
            )
            if rejected:
                first_outliers = sorted(rejected)
                obs = obs.without_points(first_outliers)
            result = component.adjust(sensors, obs, dem=dem, **options)
    warnings = early + poor_adjustment(result.sigma0, ties, n_ties, len(sensors))
    warnings += corrections_beyond_priors(result)
    if offsets is not None:
        warnings += gcps_not_transferred(int(offsets["id"].size), len(dropped_offsets or ()))
    if gcps is not None:
        rejected = {*first_outliers, *result.outliers}
        warnings += gcps_rejected(sorted({str(v).strip() for v in gcps["id"]}), rejected)
    if warnings and not allow_poor:
        raise AdjustmentError(f"{src}: {'; '.join(warnings)} (--allow-poor writes it anyway)")
    for warning in warnings:
        progress("adjust", f"warning: {warning}", quiet)
    # outputs
    files = _write_models(result, types, out, quiet)
    for product, document in result.products.items():
        if product in RESERVED_OUTPUTS or not product.isidentifier():
            raise InputError(f"adjuster {name}: product name {product!r} is not allowed")
        if isinstance(document, dict) and document.get("sources") == []:
            document = document | {"sources": [str(src)]}  # what the adjuster did not know
        files[product] = write_json_atomic(out / f"{product}.json", jsonable(document)).name
    misfit = residual_misfit(result)
    plot = residual_plot(
        result,
        out / "residuals.png",
        f"{name}: {n_used} GCPs, {n_ties} tie points, sigma0 {result.sigma0:.2f}",
        misfit,
    )
    for flag in misfit["flags"]:
        progress("adjust", f"model misfit: {flag}", quiet)
    report: dict[str, Any] = {
        "source": str(Path(src).absolute()),
        "adjuster": name,
        "matcher": matcher,
        # the trajectory model asked for (None: the one each product names)
        "trajectory_model": trajectory,
        "options": {
            k: v
            for k, v in options.items()
            if isinstance(v, str | int | float)
            or (isinstance(v, list) and all(isinstance(x, str) for x in v))
        },
        # every setting of the adjuster, defaults included
        "settings": {
            "adjuster": resolved_settings(resolved),
            "gcp_transfer": gcp_transfer,
            "tie_heights": tie_heights_flag,
            "height_sigma_m": height_sigma_m,
            "height_offset_sigma_m": height_offset_sigma_m,
            "gcp_offset_sigma_px": offset_sigma_px,
        },
        "gcps_used": n_used,
        "tie_points": n_ties,
        "tie_sigma_px": tie_sigma.record() if tie_sigma is not None else None,
        "dem_height_constraints": int(obs.height_id.size),
        "sigma0": result.sigma0,
        # sigma0 in pixels: the a-posteriori sigma of one image measurement
        "sigma0_px": result.sigma0 * float(np.sqrt(np.mean(obs.sigma_px**2)))
        if obs.sigma_px.size
        else None,
        "outliers": list(dict.fromkeys([*first_outliers, *result.outliers])),
        "warnings": warnings,
        "converged": result.converged,
        "iterations": result.iterations,
        "adjustment": result.summary(),
        "misfit": misfit,
        "files": {**files, "residual_plot": plot.name},
        "seconds": round(time.perf_counter() - t0, 1),
        "workers": engine.workers,
        "engine": engine.description,
    }
    if checkpoints is not None and len(checkpoints["id"]):
        report["checkpoints_per_image"] = monoplot_accuracy(result.sensors, checkpoints)
        acc = checkpoint_accuracy(result.sensors, checkpoints)
        pred = predicted_checkpoint_sigma(result, checkpoints)
        before = checkpoint_accuracy(sensors, checkpoints)
        report["checkpoints"] = {
            k: acc[k]
            for k in (
                "count",
                "rmse_along_m",
                "rmse_across_m",
                "rmse_planimetric_m",
                "rmse_height_m",
            )
        } | {
            "predicted_sigma_planimetric_m": pred["predicted_sigma_planimetric_m"],
            "predicted_sigma_height_m": pred["predicted_sigma_height_m"],
        }
        report["checkpoints_before"] = {
            k: before[k]
            for k in (
                "count",
                "rmse_along_m",
                "rmse_across_m",
                "rmse_planimetric_m",
                "rmse_height_m",
            )
        }
    if gcps is not None and gcps["id"].size:  # the datum of a later relative orientation
        write_point_table(out / "gcps.csv", gcps)
        report["files"]["gcps"] = "gcps.csv"
    if tie_table is not None:  # with the sigma they were adjusted with (reused: the same)
        if tie_sigma is not None and "sigma_px" in tie_table:
            scale = tie_sigma.estimated_px / tie_sigma.a_priori_px
            tie_table = {**tie_table, "sigma_px": np.asarray(tie_table["sigma_px"]) * scale}
        write_point_table(out / "tie_points.csv", tie_table)
        report["files"]["tie_points"] = "tie_points.csv"
    report["gcp_transfer"] = transfer
    if offsets is not None:
        res = result.offset_residuals
        used = np.isfinite(res["d_line"]) if res else np.zeros(0, bool)
        report["gcp_offsets"] = {
            "count": int(offsets["id"].size),
            "used": int(used.sum()),
            "sigma_px": offset_sigma_px,
            # per coordinate, as sigma_px
            "residual_rms_px": float(
                np.sqrt(np.mean(np.r_[res["d_line"][used], res["d_sample"][used]] ** 2))
            )
            if used.any()
            else None,
            "not_kept": dropped_offsets,
        }
        if offsets["id"].size:
            write_point_table(out / "gcp_offsets.csv", offsets)
            report["files"]["gcp_offsets"] = "gcp_offsets.csv"
    write_report(out / "report.json", report)
    return report


@attrs.frozen(eq=False)
class TieSigma:
    """The a-priori sigma of automatic tie points estimated from a first adjustment."""

    observations: Observations
    a_priori_px: float
    estimated_px: float

    def record(self) -> dict[str, float]:
        return {"a_priori": self.a_priori_px, "estimated": round(self.estimated_px, 4)}


TIE_SIGMA_TOLERANCE = 0.1
"""A tie group whose a-posteriori sigma is within this share of its a-priori one keeps it."""


def estimated_tie_sigma(obs: Observations, result: AdjustmentResult) -> TieSigma | None:
    """Automatic tie points' a-priori sigma (a matcher's default, 0.3 px) replaced by what the
    adjustment measures of them (their variance component, where their redundancy lets it
    judge: :mod:`~carto.framework.adjustment.variance_components`); None when it agrees.

    The demo's matched tie points are 10 x better than 0.3 px (sigma0 0.106 and a misfit
    warning on every run), the Reunion pair's 3 x: the a-priori was wrong, not the model
    (issue 34 item 5). GCP measurements keep their sigmas."""
    component = next((c for c in result.variance_components if c.group == "tie_image"), None)
    if component is None or component.applied != component.factor:
        return None
    scale = math.sqrt(component.factor)
    if not (math.isfinite(scale) and scale > 0) or abs(scale - 1.0) <= TIE_SIGMA_TOLERANCE:
        return None
    ties = ~np.isin(obs.point_id, obs.control_id)
    if not ties.any():
        return None
    before = float(np.median(obs.sigma_px[ties]))
    sigma = np.where(ties, obs.sigma_px * scale, obs.sigma_px)
    return TieSigma(attrs.evolve(obs, sigma_px=sigma), before, before * scale)


def _auto_flag(value: Any, name: str) -> str | bool:
    """An ``"auto"``/true/false option, checked (0 and 1 are not booleans here)."""
    if isinstance(value, bool) or value == "auto":
        return value
    raise InputError(f"{name} must be 'auto', true or false, got {value!r}")


def _write_models(
    result: AdjustmentResult, types: Mapping[str, SensorType], out: Path, quiet: bool
) -> dict[str, Any]:
    """Every adjusted sensor saved by the sensor type that opened it; the images whose type
    cannot save one are listed (``not_saved``) and named on stderr."""
    files: dict[str, Any] = {"models": {}, "rpc": {}, "not_saved": {}}
    h_range = _height_range(result)
    # image trends (:mod:`carto.framework.adjustment.image_trends`) into the models' polynomials
    for name, sensor in fold_image_trends(result.sensors).items():
        try:
            written = types[name].save(sensor, out, name, h_range_m=h_range)
        except NotImplementedError as exc:
            files["not_saved"][name] = str(exc)
            progress("adjust", f"image {name}: adjusted model not written: {exc}", quiet)
            continue
        if "model" in written:
            files["models"][name] = written["model"]
        if "rpc" in written:
            files["rpc"][name] = written["rpc"]
    return files


def _height_range(result: AdjustmentResult) -> tuple[float, float]:
    h = np.array([p[2] for p in result.points.values()]) if result.points else np.array([0.0])
    lo, hi = float(np.nanmin(h)), float(np.nanmax(h))
    pad = max(200.0, 0.5 * (hi - lo))
    return lo - pad, hi + pad
