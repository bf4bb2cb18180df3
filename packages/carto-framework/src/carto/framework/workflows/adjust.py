"""Workflows behind the commands: the steps ``carto adjust`` chains, with their outputs.

``adjust_product`` opens a scene (or a configuration file naming images, models, GCPs and tie
points), selects GCPs, finds tie points automatically when asked, runs an adjuster from the
registry and writes: the adjusted model files (rigorous models) or corrected RPC files,
corrected RPCs fitted to every adjusted rigorous model (``<image>_RPC.TXT``, which GDAL reads as
the sidecar of ``<image>.tif``), a residual plot (``residuals.png``) and ``report.json``.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import shutil
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

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
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import AdjustmentError, InputError
from carto.framework.files.control_table import read_tie_table
from carto.framework.files.staging import staged_folder
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.matching.gcp_transfer import (
    GCP_OFFSET_COLUMNS,
    GCP_OFFSET_SIGMA_PX,
    gcp_offsets,
)
from carto.framework.plugins.registry import get_registry
from carto.framework.settings import number
from carto.framework.workflows.adjust_checks import (
    corrections_beyond_priors,
    gcps_not_transferred,
    gcps_off_the_dem,
    gcps_rejected,
    poor_adjustment,
)
from carto.framework.workflows.adjust_outputs import (
    RESERVED_OUTPUTS as RESERVED_OUTPUTS,  # the workflow's own outputs (re-exported)
)
from carto.framework.workflows.adjust_outputs import Adjustment, AdjustRun, write_outputs
from carto.framework.workflows.configuration import configuration_files, read_configuration
from carto.framework.workflows.opening import (
    check_installed,
    open_product,
)
from carto.framework.workflows.reporting import progress, resolved_settings
from carto.framework.workflows.run_record import record_run, utc_now

if TYPE_CHECKING:
    from carto.framework.raster.dem import DEM

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
    from carto.framework.parallel.engine import open_engine

    check_installed(
        ("adjuster", "--adjuster", adjuster),
        ("trajectory", "--trajectory", trajectory),
        ("matcher", "--matcher", matcher),
    )
    src = Path(source)
    inputs = _input_files(src, ties, options)
    with (
        staged_folder(out_dir, "adjust", inputs=inputs) as stage,
        open_engine(workers, scheduler, quiet=quiet) as engine,
    ):
        started = utc_now()
        with _removed_at_end(stage / ".work") as work:
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
        return record_run(stage / "report.json", report, inputs, started, "adjust")


@contextlib.contextmanager
def _removed_at_end(folder: Path) -> Iterator[Path]:
    """``folder`` (the run's work folder: prepared images), removed when the block ends,
    however it ends."""
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _input_files(src: Path, ties: str, options: Mapping[str, Any] | None) -> list[Path]:
    """The files a run reads (the staging folder records them): the source, the files its
    configuration or scene names, a tie point table and the calibration files or folders."""
    from carto.framework.products.scene import scene_files

    inputs = [src, *configuration_files(src), *scene_files(src)]
    if ties not in ("auto", "none"):
        inputs.append(Path(ties))
    calibration = (options or {}).get("calibration") or []
    if isinstance(calibration, str | os.PathLike):  # one file or folder, or a list of them
        calibration = [calibration]
    inputs += [Path(c) for c in calibration]
    return inputs


DEM_OFFSET_SIGMA_M = 10.0
"""A-priori sigma, metres, of one offset common to the tie points' DEM heights when GCPs are
used (``height_offset_sigma_m`` "auto"): the DEM's errors are correlated over kilometres, so
its heights, taken as independent, would set the block's level to their mean at a formal
sigma of centimetres. A Cartosat-1 strip of three scenes with one GCP, 245 663 DEM-held tie
points: checkpoint heights 1.73 m (predicted 0.045 m) without the offset, 0.87 m (predicted
1.69 m) with it (benchmarks/results/README.md, session 54). Without GCPs the DEM is the datum:
no offset."""


@attrs.frozen(eq=False)
class _WorkflowOptions:
    """The options the workflow takes for itself out of ``options``; the rest
    (``adjuster_options``) go to the adjuster."""

    adjuster_options: dict[str, Any]
    gcp_transfer: str | bool
    gcp_offset_sigma_px: float
    tie_heights: str | bool
    height_sigma_m: float
    height_offset_sigma_m: float | None  # None: "auto" (DEM_OFFSET_SIGMA_M with GCPs)

    @classmethod
    def take(cls, options: Mapping[str, Any] | None) -> _WorkflowOptions:
        """The workflow's options out of ``options`` (checked), the rest left to the adjuster."""
        rest = dict(options or {})
        gcp_transfer = _auto_flag(rest.pop("gcp_transfer", "auto"), "gcp_transfer")
        offset_sigma_px = float(rest.pop("gcp_offset_sigma_px", GCP_OFFSET_SIGMA_PX))
        if not (math.isfinite(offset_sigma_px) and offset_sigma_px > 0):
            raise InputError(f"gcp_offset_sigma_px must be > 0, got {offset_sigma_px}")
        tie_heights = _auto_flag(rest.pop("tie_heights", "auto"), "tie_heights")
        height_sigma_m = float(rest.pop("height_sigma_m", 30.0))
        offset = rest.pop("height_offset_sigma_m", "auto")  # "auto" or a number >= 0
        height_offset_sigma_m = (
            None if offset == "auto" else number("height_offset_sigma_m", 0.0)(offset)
        )
        return cls(
            rest, gcp_transfer, offset_sigma_px, tie_heights, height_sigma_m, height_offset_sigma_m
        )

    def settings(self, resolved: Any) -> dict[str, Any]:
        """Every setting of the run for the report: the adjuster's (``resolved``, defaults
        included) and the workflow's."""
        return {
            "adjuster": resolved_settings(resolved),
            "gcp_transfer": self.gcp_transfer,
            "tie_heights": self.tie_heights,
            "height_sigma_m": self.height_sigma_m,
            "height_offset_sigma_m": (
                "auto" if self.height_offset_sigma_m is None else self.height_offset_sigma_m
            ),
            "gcp_offset_sigma_px": self.gcp_offset_sigma_px,
        }


@attrs.frozen(eq=False)
class _AdjustInputs:
    """What a run adjusts: the images' models, the sensor types that opened them, their
    rasters, the GCPs and checkpoints (long-format tables, None: none), the DEM (None: none)
    or the constant height of a flat scene (``flat_height_m``), and the matcher's name."""

    sensors: dict[str, Sensor]
    types: dict[str, SensorType]
    rasters: dict[str, Path]
    gcps: Table | None
    checkpoints: Table | None
    dem: DEM | None
    flat_height_m: float | None
    matcher: str


def _open_inputs(
    src: Path, sensor_type: str | None, trajectory: str | None, matcher: str | None
) -> _AdjustInputs:
    """The images, control and DEM of a scene folder or of a JSON configuration."""
    from carto.framework.products.scene import Scene

    if src.is_dir() or src.name == "scene.json":
        scene = Scene.open(src)
        opened = open_product(scene.root, sensor_type, trajectory_model=trajectory)
        gcps = scene.control("gcps")
        checkpoints = scene.control("checkpoints")
        if gcps is not None:
            check_control(gcps, opened.sensors, "gcps")
        if checkpoints is not None:
            check_control(checkpoints, opened.sensors, "checkpoints")
        rasters = {n: scene.raster(n) for n in scene.image_names}
        init = scene.manifest.get("init_dem")
        dem = None
        if init:
            from carto.framework.raster.dem import DEM

            dem = DEM.open(scene.path(init))
        return _AdjustInputs(
            opened.sensors, opened.types, rasters, gcps, checkpoints, dem, None, matcher or "ncc"
        )
    if src.suffix.lower() == ".json":
        config = read_configuration(src, sensor_type, trajectory)
        return _AdjustInputs(
            config.sensors,
            config.types,
            config.rasters,
            config.gcps,
            None,
            config.dem,
            config.flat_height_m,
            matcher or config.matcher or "ncc",
        )
    raise InputError(f"{src}: expected a scene folder or a JSON configuration file")


class _PreparedImages:
    """The images read by windows, stagger-merged once (for the ties and the transfer), on
    first use."""

    def __init__(self, inputs: _AdjustInputs, work: Path, engine: Any) -> None:
        self._inputs, self._work, self._engine = inputs, work, engine
        self._images: dict[str, Any] = {}

    def __call__(self) -> dict[str, Any]:
        from carto.framework.imaging.preparation import prepared_sources

        if not self._images:
            inputs = self._inputs
            self._images.update(
                prepared_sources(
                    inputs.rasters,
                    inputs.sensors,
                    inputs.dem,
                    self._work / "prepared",
                    self._engine,
                )
            )
        return self._images


def _adjust_into(
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
    t0 = time.perf_counter()
    opts = _WorkflowOptions.take(options)
    inputs = _open_inputs(src, sensor_type, trajectory, matcher)
    chosen_matcher = get_registry().get("matcher", inputs.matcher)
    name = choose_adjuster(adjuster, inputs.types)
    component = get_registry().get("adjuster", name)
    resolved = component.settings({**opts.adjuster_options, "dem": None})  # before any work
    gcps = select_gcps(inputs.gcps, n_gcps) if inputs.gcps is not None else None
    inputs = attrs.evolve(inputs, gcps=gcps)
    early = (
        gcps_off_the_dem(gcps, inputs.dem)
        if gcps is not None and inputs.flat_height_m is None
        else []
    )
    if early and not allow_poor:
        raise InputError(f"{src}: {'; '.join(early)} (--allow-poor adjusts anyway)")
    prepared = _PreparedImages(inputs, work, engine)
    tie_table = _tie_table(ties, inputs, chosen_matcher, prepared, engine, quiet)
    # the workers' memory back before the bundle adjustment: on a three-scene strip they
    # held 1.5 GB idle beside its 3.3 GB (benchmarks/results/strip_scale.json)
    engine.release()
    run = AdjustRun(
        src=src,
        adjuster=name,
        matcher=inputs.matcher,
        trajectory=trajectory,
        types=inputs.types,
        sensors=inputs.sensors,
        gcps=gcps,
        checkpoints=inputs.checkpoints,
        tie_table=tie_table,
        options=opts.adjuster_options,
        settings=opts.settings(resolved),
        gcp_offset_sigma_px=opts.gcp_offset_sigma_px,
    )
    obs = _observations(inputs, tie_table, opts, run.n_used)
    transfer = _transfer_status(opts.gcp_transfer, inputs)
    progress(
        "adjust",
        f"adjusting {len(inputs.sensors)} images with {name} ({run.n_used} GCPs, {run.n_ties} "
        "tie points)",
        quiet,
    )

    adjust = functools.partial(_run_adjuster, component, inputs, opts.adjuster_options)
    adjusted = _first_adjustment(adjust, obs, ties)
    if "why_not" not in transfer:
        adjusted = _with_gcp_transfer(
            adjusted, adjust, inputs, opts, transfer, chosen_matcher, prepared, quiet
        )
    warnings = _adjustment_warnings(early, adjusted, inputs, ties, run.n_ties)
    if warnings and not allow_poor:
        raise AdjustmentError(f"{src}: {'; '.join(warnings)} (--allow-poor writes it anyway)")
    for warning in warnings:
        progress("adjust", f"warning: {warning}", quiet)
    return write_outputs(out, run, adjusted, warnings, transfer, t0, engine, quiet)


def _run_adjuster(
    component: Any,
    inputs: _AdjustInputs,
    options: Mapping[str, Any],
    observations: Observations,
    start: AdjustmentResult | None = None,
) -> AdjustmentResult:
    """The adjuster run on the run's images and DEM with ``observations`` (from the result
    ``start`` when the adjuster can: its ``warm_start``)."""
    warm = {"start": start} if start is not None and component.warm_start else {}
    return component.adjust(inputs.sensors, observations, dem=inputs.dem, **warm, **options)


def _tie_table(
    ties: str,
    inputs: _AdjustInputs,
    matcher: Any,
    prepared: _PreparedImages,
    engine: Any,
    quiet: bool,
) -> Table | None:
    """The tie points of a run: matched on system-level ortho-images (``"auto"``), none
    (``"none"``) or read from the CSV file ``ties`` (checked)."""
    if ties == "auto":
        from carto.framework.matching.tiepoints import block_tie_points

        if inputs.dem is None:
            raise InputError(
                "automatic tie points need a DEM (the scene's init_dem.tif or "
                '"dem" in the configuration)'
            )
        progress(
            "adjust",
            f"matching tie points on system-level ortho-images ({engine.description})",
            quiet,
        )
        return block_tie_points(
            prepared(), inputs.sensors, inputs.dem, matcher=matcher, engine=engine, prepared=True
        )
    if ties != "none":
        tie_table = read_tie_table(ties, images=list(inputs.sensors))
        check_tie_points(tie_table, inputs.sensors)
        return tie_table
    return None


def _observations(
    inputs: _AdjustInputs, tie_table: Table | None, opts: _WorkflowOptions, n_used: int
) -> Observations:
    """The image observations of the GCPs and tie points, with DEM heights on tie points
    where they help."""
    obs = Observations.from_tables(inputs.gcps, tie_table)
    # a DEM height on a tie point fixes what tie points cannot: a shift along the stereo
    # parallax looks like a height change, and rays that meet at a small angle (the overlap
    # of adjacent swaths) let the point slide along them. With GCPs, on well intersecting
    # points, it would only pull the block towards the coarse DEM's errors. So by default
    # ("auto"): every tie point without GCPs, else only those seen in an image without GCP
    # or whose rays meet at less than WEAK_INTERSECTION_DEG; True: every one; False: none.
    tie_heights = flat_heights(opts.tie_heights, inputs.flat_height_m, n_used)
    if inputs.dem is not None and tie_table is not None and tie_heights is not False:
        weak = WEAK_INTERSECTION_DEG if (tie_heights == "auto" and n_used > 0) else None
        offset = opts.height_offset_sigma_m
        if offset is None:  # with GCPs the DEM holds the block's shape, the GCPs its level
            offset = DEM_OFFSET_SIGMA_M if n_used > 0 else 0.0
        obs = with_dem_heights(
            obs, inputs.sensors, inputs.dem, opts.height_sigma_m, offset, below_angle_deg=weak
        )
    return obs


def _transfer_status(gcp_transfer: str | bool, inputs: _AdjustInputs) -> dict[str, Any]:
    """What the report says of the GCP transfer before it runs: asked for, and why it will
    not run (``why_not``; absent: it will)."""
    # GCP transfer: the offset of each hand-measured GCP between images, by matching,
    # carries its stereo parallax at matching precision (see gcp_transfer.gcp_offsets)
    transfer: dict[str, Any] = {"requested": gcp_transfer, "ran": False}
    gcps = inputs.gcps
    if gcp_transfer is False:
        transfer["why_not"] = "turned off"
    elif gcps is None or not len(gcps["id"]):
        transfer["why_not"] = "no GCP"
    elif inputs.dem is None or any(n not in inputs.rasters for n in inputs.sensors):
        transfer["why_not"] = "it needs every image's raster and a DEM"
        if gcp_transfer is True:
            raise InputError(f"gcp_transfer: {transfer['why_not']}")
    return transfer


def _first_adjustment(
    adjust: Callable[..., AdjustmentResult], obs: Observations, ties: str
) -> Adjustment:
    """The adjustment, run again with the automatic tie points' sigma the first run
    measured when it differs from their a-priori one."""
    result = adjust(obs)
    tie_sigma = estimated_tie_sigma(obs, result) if ties == "auto" else None
    if tie_sigma is not None:  # the matched tie points' precision, from the data
        obs = tie_sigma.observations
        result = adjust(obs, result)
    return Adjustment(result, obs, tie_sigma)


def _with_gcp_transfer(
    adjusted: Adjustment,
    adjust: Callable[..., AdjustmentResult],
    inputs: _AdjustInputs,
    opts: _WorkflowOptions,
    transfer: dict[str, Any],
    matcher: Any,
    prepared: _PreparedImages,
    quiet: bool,
) -> Adjustment:
    """The GCPs matched between images and the adjustment again with their offsets
    (``transfer`` says whether it ran, or why not)."""
    # matched on chips orthorectified with the adjusted models (the system-level ones
    # may be hundreds of metres apart), then the adjustment again with the offsets;
    # GCPs the first adjustment rejected stay out
    progress("adjust", "matching the GCPs between images (GCP transfer)", quiet)
    gcps = inputs.gcps
    rejected = set(adjusted.result.outliers)
    kept = np.array([g not in rejected for g in gcps["id"]], bool)
    offsets = dropped_offsets = None
    try:
        offsets, dropped_offsets = gcp_offsets(
            {k: np.asarray(v)[kept] for k, v in gcps.items()},
            prepared(),
            adjusted.result.sensors,
            inputs.dem,
            sigma_px=opts.gcp_offset_sigma_px,
            matcher=matcher,
            prepared=True,
        )
    except InputError as exc:
        if opts.gcp_transfer is True:
            raise
        transfer["why_not"] = str(exc)  # e.g. a raster that does not fit its model
    adjusted = attrs.evolve(adjusted, offsets=offsets, dropped_offsets=dropped_offsets)
    if offsets is not None and not offsets["id"].size:
        transfer["why_not"] = "no GCP could be matched"
    elif offsets is not None:
        transfer["ran"] = True
        obs = adjusted.obs.with_offsets(
            *(offsets[c] for c in GCP_OFFSET_COLUMNS if c != "score")  # as with_offsets
        )
        first_outliers: list[str] = []
        if rejected:
            first_outliers = sorted(rejected)
            obs = obs.without_points(first_outliers)
        adjusted = attrs.evolve(
            adjusted, result=adjust(obs, adjusted.result), obs=obs, first_outliers=first_outliers
        )
    return adjusted


def _adjustment_warnings(
    early: list[str], adjusted: Adjustment, inputs: _AdjustInputs, ties: str, n_ties: int
) -> list[str]:
    """What makes an adjustment poor: GCPs off the DEM (``early``), a poor fit, corrections
    beyond their priors, GCPs not transferred and GCPs rejected."""
    result = adjusted.result
    warnings = early + poor_adjustment(result.sigma0, ties, n_ties, len(inputs.sensors))
    warnings += corrections_beyond_priors(result)
    if adjusted.offsets is not None:
        warnings += gcps_not_transferred(
            int(adjusted.offsets["id"].size), len(adjusted.dropped_offsets or ())
        )
    if inputs.gcps is not None:
        rejected = {*adjusted.first_outliers, *result.outliers}
        warnings += gcps_rejected(sorted({str(v).strip() for v in inputs.gcps["id"]}), rejected)
    return warnings


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
