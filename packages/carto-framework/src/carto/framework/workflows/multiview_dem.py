"""``carto dem`` on three or more images: every useful pair through the DEM generator, then
one DEM fused node by node, and one ortho-image per image on it (on the fused DEM's grid,
over the image's own footprint).

Pairs. Given explicitly (``--pairs A:B,B:C``), or every two of the images (a scene's images,
all of them by default when it has three or more, or ``--images A B C``) whose

- footprints overlap by at least :data:`MIN_OVERLAP` of the smaller one, and
- base-to-height ratio is at least :data:`MIN_B_OVER_H` (2 tan of half the angle between
  the two lines of sight at the common footprint's centre: a narrower pair measures heights
  with an error too large to help the others), and at least
  :data:`MIN_SHARE_OF_BEST_B_OVER_H` of the best candidate's.

For a Cartosat-2 triplet that is fore/nadir, nadir/aft and fore/aft (B/H about 0.5, 0.5 and
1.0). A pair named explicitly that fails either test is an error; an automatic one is left
out, with its figures in ``report.json``. Each pair's left image is the one closer to nadir,
as for one pair.

Each pair runs as ``carto dem --pair`` does (tiles, workers, relative orientation, checks) into
``pairs/LEFT_RIGHT`` of the output, the narrowest base first. A pair that fails from the
starting DEM is run again from the fused DEM of the pairs done before it (narrower ones): a
wide pair over buildings that a building-less starting DEM cannot bring together (its
ortho-images disagree, the pair checks refuse it) matches from the narrower pairs' DEM, which
has the buildings. A pair that fails again is reported and left out, and the others still
fuse. Fusion (:func:`~carto.framework.merging.fusion.fuse_heights`) weights each pair's
height by its predicted sigma (the generator's ``sigma_m`` layer; 1 m for a generator without
one), rejects outliers against the weighted median, and ignores filled nodes where another
pair measured. It runs tile by tile over the pairs' DEM files: memory depends on the tile,
not on the scene. ``--keep-pairs`` keeps the pairs' folders.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.errors import CartoError, InputError, UsageError
from carto.framework.geometry.sensor import Sensor
from carto.framework.merging.fusion import FusionSettings

__all__ = [
    "MIN_B_OVER_H",
    "MIN_OVERLAP",
    "PairChoice",
    "choose_pairs",
    "pair_geometry",
    "parse_pairs",
]

VIEW_JITTER_MODES = ("auto", "none")
"""``MultiViewRequest.view_jitter`` (``carto dem --view-jitter``)."""
MIN_B_OVER_H = 0.05
"""Pairs with a smaller base-to-height ratio are not used (their height error is more than
ten times their matching error in pixels of the ground sampling)."""
MIN_OVERLAP = 0.2
"""Pairs whose footprints share less than this share of the smaller one are not used."""
MIN_SHARE_OF_BEST_B_OVER_H = 0.25
"""An automatic pair whose B/H is under this share of the best candidate's is not used: its
heights would have over four times the error (e.g. the neighbouring swaths' fore views of a
stereo paint-brush set, B/H 0.09 beside their own fore/aft pairs' 1.1)."""


@attrs.frozen
class PairChoice:
    """A candidate pair and its geometry: ``left`` (closer to nadir), ``right``, their
    base-to-height ratio and the share of the smaller footprint both images see."""

    left: str
    right: str
    b_over_h: float
    overlap: float

    @property
    def usable(self) -> bool:
        return self.b_over_h >= MIN_B_OVER_H and self.overlap >= MIN_OVERLAP

    @property
    def folder(self) -> str:
        return f"{self.left}_{self.right}"

    def as_dict(self) -> dict[str, Any]:
        return {
            "left": self.left,
            "right": self.right,
            "b_over_h": round(self.b_over_h, 4),
            "overlap": round(self.overlap, 4),
        }


def _ecef(lon: Any, lat: Any, h: Any) -> np.ndarray:
    from carto.framework.geometry import frames

    return np.asarray(frames.geodetic_to_ecef(lon, lat, h), np.float64)


def _sight(sensor: Sensor, lon: float, lat: float, h_m: float) -> np.ndarray | None:
    """Unit line of sight (ground to sensor, ECEF) of ``sensor`` at a ground point, or None
    when the point is outside its image."""
    line, sample = sensor.ground_to_image(np.array([lon]), np.array([lat]), np.array([h_m]))
    n_l, n_s = sensor.image_shape
    if not (np.isfinite(line[0]) and 0 <= line[0] <= n_l and 0 <= sample[0] <= n_s):
        return None
    lo2, la2 = sensor.image_to_ground(line, sample, np.array([h_m + 1000.0]))
    d = _ecef(lo2, la2, h_m + 1000.0) - _ecef(lon, lat, h_m)
    d = np.ravel(d)
    return d / np.linalg.norm(d)


def _footprint_points(sensor: Sensor, h_m: float, n: int = 17) -> tuple[np.ndarray, np.ndarray]:
    n_l, n_s = sensor.image_shape
    lines, samples = np.meshgrid(np.linspace(0, n_l, n), np.linspace(0, n_s, n), indexing="ij")
    h = np.full(lines.size, h_m)
    lon, lat = sensor.image_to_ground(lines.ravel(), samples.ravel(), h)
    return np.asarray(lon), np.asarray(lat)


def _inside(sensor: Sensor, lon: np.ndarray, lat: np.ndarray, h_m: float) -> np.ndarray:
    line, sample = sensor.ground_to_image(lon, lat, np.full(lon.shape, h_m))
    n_l, n_s = sensor.image_shape
    with np.errstate(invalid="ignore"):
        return (line >= 0) & (line <= n_l) & (sample >= 0) & (sample <= n_s)


def pair_geometry(
    sensors: Mapping[str, Sensor], first: str, second: str, h_m: float = 0.0
) -> PairChoice:
    """The pair of ``first`` and ``second``: left the one closer to nadir, B/H and overlap
    (see the module docstring); B/H 0 where the footprints share no point."""
    a, b = sensors[first], sensors[second]
    lon_a, lat_a = _footprint_points(a, h_m)
    lon_b, lat_b = _footprint_points(b, h_m)
    overlap = max(
        min(
            float(_inside(b, lon_a, lat_a, h_m).mean()), float(_inside(a, lon_b, lat_b, h_m).mean())
        ),
        0.0,
    )
    both = _inside(b, lon_a, lat_a, h_m)
    b_over_h = 0.0
    off_nadir = {first: 0.0, second: 0.0}
    if both.any():
        lon, lat = float(np.mean(lon_a[both])), float(np.mean(lat_a[both]))
        sight = {n: _sight(sensors[n], lon, lat, h_m) for n in (first, second)}
        if all(s is not None for s in sight.values()):
            from carto.framework.geometry import frames

            angle = math.acos(float(np.clip(np.dot(sight[first], sight[second]), -1.0, 1.0)))
            b_over_h = 2.0 * math.tan(angle / 2.0)
            up = np.ravel(frames.ellipsoid_normal(lon, lat))
            off_nadir = {
                n: math.acos(float(np.clip(np.dot(s, up), -1, 1))) for n, s in sight.items()
            }
    left, right = sorted((first, second), key=lambda n: off_nadir[n])
    return PairChoice(left, right, b_over_h, overlap)


def parse_pairs(text: str) -> tuple[tuple[str, str], ...]:
    """``"A:B,B:C"`` as ``(("A", "B"), ("B", "C"))``.

    Raises:
        UsageError: an item that is not two different names joined by ``:``.
    """
    pairs = []
    for item in text.split(","):
        names = item.strip().split(":")
        if len(names) != 2 or not all(names) or names[0] == names[1]:
            raise UsageError(f"--pairs {text!r}: {item!r} is not two images joined by ':'")
        pairs.append((names[0], names[1]))
    if len(set(frozenset(p) for p in pairs)) < len(pairs):
        raise UsageError(f"--pairs {text!r}: a pair is given twice")
    return tuple(pairs)


def choose_pairs(
    sensors: Mapping[str, Sensor],
    *,
    images: Sequence[str] | None = None,
    pairs: Sequence[tuple[str, str]] | None = None,
    h_m: float = 0.0,
) -> tuple[tuple[PairChoice, ...], tuple[PairChoice, ...]]:
    """The pairs to run and those left out (see the module docstring).

    Raises:
        UsageError: an image that is not one of ``sensors``; fewer than two images.
        InputError: an explicit pair that does not overlap or has too small a B/H; no
            usable pair among the images.
    """
    known = ", ".join(sensors)
    named = [n for p in pairs for n in p] if pairs else list(images or sensors)
    for name in named:
        if name not in sensors:
            raise UsageError(f"image {name!r} is not in the scene (its images: {known})")
    if pairs:
        chosen = tuple(pair_geometry(sensors, a, b, h_m) for a, b in pairs)
        for p in chosen:
            _check_explicit(p)
        return chosen, ()
    if len(set(named)) < 2:
        raise UsageError(f"a DEM needs two images or more, got {', '.join(named) or 'none'}")
    candidates = [pair_geometry(sensors, a, b, h_m) for a, b in itertools.combinations(named, 2)]
    best = max((p.b_over_h for p in candidates if p.usable), default=0.0)
    used = tuple(
        p for p in candidates if p.usable and p.b_over_h >= MIN_SHARE_OF_BEST_B_OVER_H * best
    )
    if not used:
        figures = "; ".join(
            f"{p.left}/{p.right}: B/H {p.b_over_h:.3f}, overlap {p.overlap:.0%}" for p in candidates
        )
        raise InputError(f"no usable stereo pair among {', '.join(named)} ({figures})")
    return used, tuple(p for p in candidates if p not in used)


def _check_explicit(p: PairChoice) -> None:
    if p.overlap < MIN_OVERLAP:
        raise InputError(
            f"pair {p.left}:{p.right}: the images overlap by {p.overlap:.0%} of the smaller "
            f"footprint (at least {MIN_OVERLAP:.0%} needed)"
        )
    if p.b_over_h < MIN_B_OVER_H:
        raise InputError(
            f"pair {p.left}:{p.right}: B/H {p.b_over_h:.3f} is below {MIN_B_OVER_H} (the lines of "
            "sight are nearly parallel: heights would be too poor)"
        )


@attrs.frozen
class MultiViewRequest:
    """A multi-view ``carto dem`` run.

    Attributes:
        out_dir: the output folder.
        source: the scene folder.
        models: a ``carto adjust`` output with adjusted models (None: the scene's).
        sensor_type: force a sensor type for the models.
        images: the images to pair (None: all of the scene's).
        pairs: explicit pairs (then ``images`` is not used).
        keep_pairs: keep each pair's DEM folder under ``pairs/``.
        fusion: how the pairs' heights are fused.
        tile_px: side of the fusion's tiles, DEM posts.
        view_jitter: ``auto``: every view's along-track error fitted to the pairs' heights
            before the fusion (:mod:`carto.framework.workflows.view_jitter`); ``none``: off.
    """

    out_dir: Path = attrs.field(converter=Path)
    source: Path = attrs.field(converter=Path)
    models: Path | None = attrs.field(default=None, converter=attrs.converters.optional(Path))
    sensor_type: str | None = None
    images: tuple[str, ...] | None = None
    pairs: tuple[tuple[str, str], ...] | None = None
    keep_pairs: bool = False
    fusion: FusionSettings = attrs.field(factory=FusionSettings)
    tile_px: int = 1024
    view_jitter: str = "auto"

    def __attrs_post_init__(self) -> None:
        if self.view_jitter not in VIEW_JITTER_MODES:
            raise UsageError(f"--view-jitter: expected auto or none, got {self.view_jitter!r}")
        if self.images is not None and self.pairs is not None:
            raise UsageError("--images and --pairs exclude each other: give one")


def failed_pair_record(
    pair: PairChoice, exc: CartoError, first: CartoError | None = None
) -> dict[str, Any]:
    """What ``report.json`` says of a pair that failed (``first``: its failure from the
    starting DEM when it failed again from the fused DEM of the pairs before it)."""
    record = {**pair.as_dict(), "status": "failed", "error": _line(exc)}
    if first is not None:
        record["error_from_starting_dem"] = _line(first)
    return record


def _line(exc: CartoError) -> str:
    return str(exc).splitlines()[0]


def pair_record(pair: PairChoice, report: Mapping[str, Any], kept: bool) -> dict[str, Any]:
    """What ``report.json`` says of a pair that ran: its geometry and its DEM's figures."""
    accuracy = report.get("accuracy") or {}
    return {
        **pair.as_dict(),
        "status": "done",
        "folder": f"pairs/{pair.folder}" if kept else None,
        "matched_fraction": report.get("matched_fraction"),
        "completeness": report.get("completeness"),
        "nmad_m": accuracy.get("nmad_m"),
        "median_m": accuracy.get("median_m"),
    }


# ----------------------------------------------------------------------------- the run
@attrs.frozen(eq=False)
class _SceneViews:
    """The scene's images: their models (the adjusted ones when a ``carto adjust`` folder
    is given), their raster files, and the median height of the starting DEM (0 without
    one), where pairs are judged."""

    sensors: dict[str, Sensor]
    rasters: dict[str, Path]
    h_m: float
    types: tuple[Any, ...] = ()


def _scene_views(request: MultiViewRequest) -> _SceneViews:
    from carto.framework.files.staging import require_complete_output
    from carto.framework.products.scene import Scene
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows.opening import open_product
    from carto.framework.workflows.stereo_pair import adjusted_model

    if not (request.source / "scene.json").is_file():
        raise UsageError(
            f"{request.source}: not a scene folder; several images are given as a scene "
            "(carto simulate or a product folder) with --images or --pairs"
        )
    scene = Scene.open(request.source)
    models = None if request.models is None else require_complete_output(request.models, "adjust")
    product = open_product(scene.root, request.sensor_type)
    sensors = {
        name: adjusted_model(models, name, sensor) for name, sensor in product.sensors.items()
    }
    init = scene.manifest.get("init_dem")
    h_m = float(np.nanmedian(DEM.open(scene.path(init)).heights)) if init else 0.0
    types = tuple(product.types[n] for n in sorted(product.types))
    return _SceneViews(sensors, {n: scene.raster(n) for n in sensors}, h_m, types)


def multiview_dem_product(request: MultiViewRequest, **dem_options: Any) -> dict[str, Any]:
    """Run ``carto dem`` on three or more images (see the module docstring); ``dem_options``
    are those of :func:`~carto.framework.workflows.dem.dem_product` (each pair gets them)."""
    from carto.framework.files.staging import staged_folder
    from carto.framework.workflows.run_record import record_run, utc_now
    from carto.framework.workflows.view_jitter import pair_relative_orientation, view_jitter_reason

    quiet = bool(dem_options.get("quiet", False))
    views = _scene_views(request)
    h_m = dem_options.get("init_height_m")
    h_m = views.h_m if h_m is None else float(h_m)
    pairs, left_out = choose_pairs(
        views.sensors, images=request.images, pairs=request.pairs, h_m=h_m
    )
    dem_options = _on_one_crs(dem_options, views, [views.sensors[n] for n in _images_of(pairs)])
    reason = view_jitter_reason(
        request.view_jitter, views.sensors, [(p.left, p.right) for p in pairs]
    )
    ro = dem_options.get("relative_orientation", "auto")
    dem_options = {
        **dem_options,
        "relative_orientation": pair_relative_orientation(ro, reason is None),
    }
    started = utc_now()
    inputs = [
        request.source,
        request.models,
        dem_options.get("init_dem"),
        dem_options.get("geoid"),
        dem_options.get("reference"),
    ]
    with staged_folder(request.out_dir, "dem", inputs=[p for p in inputs if p]) as stage:
        records, done = _run_pairs(stage, request, pairs, dem_options, quiet)
        fitted, corrections = _view_jitter(views, done, dem_options, reason, quiet)
        report = _fused_into(stage, request, views, done, dem_options, quiet, corrections)
        report["view_jitter"] = fitted
        report["pairs"] = records
        report["pairs_left_out"] = [p.as_dict() for p in left_out]
        if not request.keep_pairs:
            import shutil

            shutil.rmtree(stage / "pairs", ignore_errors=True)
        report = record_run(stage / "report.json", report, [p for p in inputs if p], started, "dem")
    return report


def _view_jitter(
    views: _SceneViews,
    done: Sequence[tuple[PairChoice, Path]],
    dem_options: Mapping[str, Any],
    reason: str | None,
    quiet: bool,
) -> tuple[dict[str, Any], list[Any] | None]:
    """The views' along-track errors fitted to the pairs' heights (the report's
    ``view_jitter``, with the pairs' relative orientation) and each pair's height correction
    (None: not fitted, and why)."""
    from carto.framework.adjustment.view_jitter import ViewJitterSettings
    from carto.framework.raster.dem import Geoid
    from carto.framework.workflows.reporting import progress
    from carto.framework.workflows.view_jitter import view_jitter_of_pairs

    used = {"pairs_relative_orientation": dem_options.get("relative_orientation", "auto")}
    if reason is None and len(done) < 2:
        reason = "one pair was made: nothing to compare its heights with"
    if reason is not None:
        return {"applied": False, "reason": reason, **used}, None
    progress("dem", "fitting every view's along-track error to the pairs' heights", quiet)
    geoid = Geoid.open(dem_options["geoid"]) if dem_options.get("geoid") else None
    folders = [(p.left, p.right, folder) for p, folder in done]
    fit, corrections, kept = view_jitter_of_pairs(folders, views.sensors, geoid)
    if fit is None:
        least = ViewJitterSettings().min_nodes
        cause = f"fewer than {least} nodes measured by two pairs"
        return {"applied": False, "reason": cause, **used}, None
    return {"applied": True, **used, **kept, **fit.as_dict()}, corrections


def _images_of(pairs: Sequence[PairChoice]) -> list[str]:
    return sorted({n for p in pairs for n in (p.left, p.right)})


def common_crs(sensors: Sequence[Sensor], h_m: float) -> str:
    """The CRS a single pair's DEM of all these images would get (``footprint_box``'s
    default: the WGS84 UTM zone of the centre of their footprints at ``h_m``), for every
    pair's DEM, whichever zone each pair's own centre is in."""
    from carto.framework.imaging.ortho_grid import footprint_box
    from carto.framework.raster.dem import DEM

    crs, _ = footprint_box(list(sensors), DEM.constant(h_m))
    return str(crs.to_string())


def _on_one_crs(
    dem_options: Mapping[str, Any], views: _SceneViews, sensors: Sequence[Sensor]
) -> dict[str, Any]:
    """``dem_options`` with the generator's ``crs`` option set to :func:`common_crs` unless
    given: the pairs of a strip (three Cartosat-1 scenes are 90 km long) may sit in two UTM
    zones, and their DEMs must share one CRS to be fused. A generator without a ``crs``
    option makes each pair's DEM in its own CRS: the fusion refuses DEMs in two."""
    from carto.framework.plugins.registry import get_registry
    from carto.framework.workflows.dem import choose_dem_generator

    options = dict(dem_options.get("options") or {})
    if options.get("crs") is not None:
        return dict(dem_options)
    name = choose_dem_generator(dem_options.get("generator"), views.types)
    settings = getattr(get_registry().get("dem-generator", name), "Settings", None)
    if settings is None or "crs" not in attrs.fields_dict(settings):
        return dict(dem_options)
    options["crs"] = common_crs(sensors, views.h_m)
    return {**dem_options, "options": options}


def _run_pairs(
    stage: Path,
    request: MultiViewRequest,
    pairs: Sequence[PairChoice],
    dem_options: Mapping[str, Any],
    quiet: bool,
) -> tuple[list[dict[str, Any]], list[tuple[PairChoice, Path]]]:
    from carto.framework.parallel.process_memory import release_free_memory
    from carto.framework.workflows.dem import dem_product
    from carto.framework.workflows.reporting import progress
    from carto.framework.workflows.stereo_pair import StereoInputs

    records: list[dict[str, Any]] = []
    done: list[tuple[PairChoice, Path]] = []
    ordered = sorted(pairs, key=lambda p: p.b_over_h)
    for k, pair in enumerate(ordered, 1):
        release_free_memory(f"before pair {pair.folder}")  # what the pairs before freed
        progress(
            "dem",
            f"pair {k}/{len(pairs)}: {pair.left} / {pair.right} (B/H {pair.b_over_h:.2f})",
            quiet,
        )
        folder = stage / "pairs" / pair.folder
        inputs = StereoInputs(
            source=request.source,
            models=request.models,
            sensor_type=request.sensor_type,
            pair=(pair.left, pair.right),
        )
        options = {**dem_options, "resume": False}
        try:
            report = dem_product(folder, inputs, **options)
            start = None
        except CartoError as exc:
            progress("dem", f"pair {pair.left} / {pair.right} failed: {exc}", quiet)
            if not done:
                records.append(failed_pair_record(pair, exc))
                continue
            start = _fused_start(stage / "work" / f"start_{pair.folder}", request, done)
            names = ", ".join(start["pairs"])
            progress("dem", f"pair {pair.left} / {pair.right} again from the DEM of {names}", quiet)
            retry = {**options, "init_dem": start["dem"], "init_height_m": None}
            try:
                report = dem_product(folder, inputs, **retry)
            except CartoError as again:
                progress("dem", f"pair {pair.left} / {pair.right} failed again: {again}", quiet)
                records.append(failed_pair_record(pair, again, first=exc))
                continue
            start = {"pairs": start["pairs"], "error_from_starting_dem": _line(exc)}
        record = pair_record(pair, report, request.keep_pairs)
        if start is not None:
            record["start"] = start
        records.append(record)
        done.append((pair, folder))
    if not done:
        causes = "; ".join(f"{r['left']}/{r['right']}: {r['error']}" for r in records)
        raise InputError(f"dem: every pair failed ({causes})")
    return records, done


def _fused_start(
    out: Path, request: MultiViewRequest, done: Sequence[tuple[PairChoice, Path]]
) -> dict[str, Any]:
    """The fused DEM of the pairs ``done`` (aligned and fused as the product is), written
    into ``out`` as the starting DEM of a pair that failed from the scene's."""
    from carto.framework.merging.fused_files import fuse_dem_folders

    out.mkdir(parents=True, exist_ok=True)
    fuse_dem_folders(
        [folder for _, folder in done],
        out,
        request.fusion,
        tile_px=request.tile_px,
        offsets_m=_pair_offsets(request, done, _pair_steps(done)),
    )
    return {"dem": out / "dem.tif", "pairs": [f"{p.left}/{p.right}" for p, _ in done]}


def _pair_offsets(
    request: MultiViewRequest, done: Sequence[tuple[PairChoice, Path]], steps: Sequence[Any]
) -> Any:
    """The constant steps that align the pairs' DEMs on the widest pair's, from the steps
    between them (:func:`_pair_steps`; :attr:`FusionSettings.align_pairs`, zeros when off)."""
    from carto.framework.merging.mosaic import step_offsets

    if not request.fusion.align_pairs:
        return np.zeros(len(done))
    best = max(range(len(done)), key=lambda k: done[k][0].b_over_h)
    return step_offsets(steps, len(done), held=best)


_QUALITY_LAYERS: dict[str, dict[str, str]] = {
    "sigma_m": {
        "file": "quality.tif",
        "kind": "measure",
        "description": "predicted standard deviation of the fused height, m",
    },
    "spread_m": {
        "file": "quality.tif",
        "kind": "measure",
        "description": "max - min of the pairs' heights kept, m",
    },
    "pairs": {
        "file": "quality_counts.tif",
        "kind": "count",
        "description": "pairs whose measured height was kept",
    },
    "filled": {
        "file": "quality_flags.tif",
        "kind": "flag",
        "description": "1: no pair measured the node, 0: measured",
    },
}
"""The fused DEM's quality layers, as ``report.json`` describes them."""


def _fused_into(
    stage: Path,
    request: MultiViewRequest,
    views: _SceneViews,
    done: Sequence[tuple[PairChoice, Path]],
    dem_options: Mapping[str, Any],
    quiet: bool,
    corrections: Sequence[Any] | None = None,
) -> dict[str, Any]:
    """Fuse the pairs' DEMs (less ``corrections``, each pair's height correction, when
    given; then the views' fit holds each view's bias and no offset aligns the pairs)."""
    from carto.framework.merging.fused_files import fuse_dem_folders
    from carto.framework.workflows.fused_orthos import engine_options, orthos_on_fused
    from carto.framework.workflows.reporting import progress

    folders = [folder for _, folder in done]
    steps = _pair_steps(done)
    offsets = _pair_offsets(request, done, steps) if corrections is None else np.zeros(len(done))
    progress("dem", f"fusing {len(folders)} pair DEM(s)", quiet)
    fusion = fuse_dem_folders(
        folders,
        stage,
        request.fusion,
        tile_px=request.tile_px,
        offsets_m=offsets,
        corrections=corrections,
    )
    files = {
        "dem": "dem.tif",
        "quality": "quality.tif",
        "quality_counts": "quality_counts.tif",
        "quality_flags": "quality_flags.tif",
    }
    images = sorted({n for pair, _ in done for n in (pair.left, pair.right)})
    views = attrs.evolve(
        views,
        sensors={n: views.sensors[n] for n in images},
        rasters={n: views.rasters[n] for n in images},
    )
    pair_ortho = done[0][1] / "ortho_left.tif"
    engine = engine_options(dem_options)
    files.update(orthos_on_fused(stage, views.sensors, views.rasters, pair_ortho, engine, quiet))
    report: dict[str, Any] = {
        "generator": "fusion",
        "images": images,
        "fusion": {**attrs.asdict(request.fusion), **fusion},
        "quality_layers": {name: dict(layer) for name, layer in _QUALITY_LAYERS.items()},
        "vertical_reference": fusion["vertical_reference"],
    }
    names = [f"{pair.left}/{pair.right}" for pair, _ in done]
    report["pair_offsets_m"] = {n: round(float(o), 4) for n, o in zip(names, offsets, strict=True)}
    report["seams"] = [
        {
            "first": names[step.first],
            "second": names[step.second],
            "median_step_m": round(step.median_m, 4),
            "nmad_m": round(step.nmad_m, 4),
            "nodes": step.pixels,
            "median_step_after_m": None
            if corrections is not None  # see view_jitter's pairs_disagreement_nmad_m
            else round(step.median_m + offsets[step.second] - offsets[step.first], 4),
        }
        for step in steps
    ]
    files.update(_evaluated(stage, report, dem_options))
    report["files"] = files
    return report


def _pair_steps(done: Sequence[tuple[PairChoice, Path]]) -> list[Any]:
    """The vertical step between every two pairs' DEMs where they overlap (median and NMAD
    of ``second - first``): the seams of neighbouring swaths, the agreement of a triplet's
    pairs."""
    from carto.framework.merging.grid import union_grid
    from carto.framework.merging.mosaic import MosaicSettings, seam_steps
    from carto.framework.merging.sources import open_sources

    sources = open_sources([folder / "dem.tif" for _, folder in done])
    return seam_steps(sources, union_grid(sources), MosaicSettings())


def _evaluated(
    stage: Path, report: dict[str, Any], dem_options: Mapping[str, Any]
) -> dict[str, str]:
    from carto.framework.raster.quicklook import hillshade_png

    files = {"hillshade": hillshade_png(stage / "dem.tif", stage / "dem_hillshade.png", "DEM").name}
    reference = dem_options.get("reference")
    if reference is not None:
        from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks

        comparison = dem_accuracy_by_blocks(
            stage / "dem.tif", reference, geoid=dem_options.get("geoid")
        )
        report["accuracy"] = comparison.report
    return files
