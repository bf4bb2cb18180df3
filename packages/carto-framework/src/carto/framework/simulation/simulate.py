"""The scene simulator: physically faithful pushbroom acquisitions with known truth.

A plugin's scene preset describes an acquisition as a
:class:`~carto.framework.simulation.plan.ScenePlan` (orbit, trajectory segments with their
attitude laws, cameras, views); :func:`simulate_scene` renders it:

1. the **true** platform motion: the orbit propagated with two-body + J2 and sampled densely
   (every 25 ms), the attitude law plus optional jitter; Lagrange interpolation of these
   samples is the true trajectory;
2. terrain (a procedural preset or a user DEM) and a seeded ground texture covering the views,
   both evaluated window by window (:mod:`carto.framework.simulation.scene_tiles`): memory is
   bounded by a band of lines, not by the scene, and any band size gives the same bytes;
3. each view rendered through its true model as the detectors see it (odd/even arrays
   staggered), blurred, with noise, quantised to 10 bits, band by band into its GeoTIFF;
4. the **product**: ancillary files with ephemeris and attitude every 125 ms *as measured*,
   i.e. with the errors of :class:`~carto.framework.simulation.plan.ErrorModel` (ephemeris
   bias, attitude bias and drift, smooth higher-order attitude error, camera misalignment), the
   nominal camera constants;
5. control: GCPs (ground and image measurement noise) and independent checkpoints (true
   coordinates, :mod:`carto.framework.simulation.control`), an SRTM-like initial DEM, and
   ``truth/`` (true DEM, true ortho-image, true model files, the drawn errors).

Every random draw comes from its own stream of ``numpy.random.SeedSequence(seed)``, so the same
seed gives a byte-identical scene, and switching one error source off leaves the others' draws
unchanged. The scene folder layout and file formats are in ``docs/formats.md``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.files.documents import write_json_atomic
from carto.framework.files.point_table import write_point_table
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.products.ancillary import ImageSpec
from carto.framework.products.scene import SCENE_FORMAT, SCENE_VERSION
from carto.framework.simulation import truth_geometry as tg
from carto.framework.simulation.control import control_points
from carto.framework.simulation.error_draws import draw_product_errors
from carto.framework.simulation.plan import (
    ErrorModel,
    ScenePlan,
    SimulationOptions,
    ViewPlan,
    check_error_size,
)
from carto.framework.simulation.reference.attitude import AttitudeLaw
from carto.framework.simulation.reference.pushbroom import ReferenceImager
from carto.framework.simulation.truth_products import ERRORS_NOTE, measured_ancillary

FloatArray = NDArray[np.float64]
DN_MAX = 1023


def _progress(message: str, quiet: bool = False) -> None:
    logging.getLogger("carto.simulate").info(message)
    if not quiet:
        print(f"carto simulate: {message}", file=sys.stderr, flush=True)


class _Stage:
    def __init__(self, what: str, quiet: bool) -> None:
        self.what, self.quiet = what, quiet

    def __enter__(self) -> _Stage:
        self.t0 = time.perf_counter()
        logging.getLogger("carto.simulate").debug("%s: started", self.what)
        return self

    def __exit__(self, *exc: object) -> None:
        if exc[0] is None:
            _progress(f"{self.what} ({time.perf_counter() - self.t0:.1f} s)", self.quiet)


# ----------------------------------------------------------------------------- engine
def _window(
    view: ViewPlan, size: tuple[int, int], target_line: float, target_sample: float
) -> tuple[int, int, int, int]:
    """``(first_line, first_sample, height, width)``: the window of the full image centred on
    the target's projection (at the terrain's middle height)."""
    width, height = size
    n_det = view.camera.n_detectors
    if not (1 <= width <= n_det and 1 <= height <= view.n_lines_full):
        raise InputError(
            f"--size {width} {height}: must be within the full image "
            f"{n_det} x {view.n_lines_full} of {view.name}"
        )
    c_s = target_sample if np.isfinite(target_sample) else n_det / 2.0
    c_l = target_line if np.isfinite(target_line) else view.n_lines_full / 2.0
    first_sample = int(np.clip(round(c_s - width / 2.0), 0, n_det - width))
    first_line = int(np.clip(round(c_l - height / 2.0), 0, view.n_lines_full - height))
    return first_line, first_sample, height, width


def _radiometry(
    refl: NDArray[np.float32], plan: ScenePlan, rng: np.random.Generator
) -> NDArray[np.uint16]:
    """Reflectance -> 10-bit DN: gain/offset, shot and read noise, quantisation."""
    img = np.nan_to_num(refl.astype(np.float32), nan=0.0)
    dn = 40.0 + 900.0 * img
    noise = rng.normal(0.0, 1.0, dn.shape).astype(np.float32)
    dn = dn + noise * np.sqrt(plan.noise_dn**2 + 0.05 * dn)
    return np.clip(np.rint(dn), 0, DN_MAX).astype(np.uint16)


@attrs.frozen
class _Settings:
    """The run's choices resolved from the options and the plan's defaults, validated."""

    errors: ErrorModel
    terrain_name: str
    size: tuple[int, int]
    n_gcps: int
    n_check: int


@attrs.frozen(eq=False)
class _Streams:
    """One random stream per purpose, spawned from ``SeedSequence(seed)``: switching one
    error source off leaves the others' draws unchanged."""

    err: np.random.Generator
    jit: np.random.Generator
    terrain: np.random.Generator
    tex: np.random.Generator
    ctl: np.random.Generator
    noise: np.random.Generator
    init: np.random.Generator
    full: np.random.Generator

    @classmethod
    def from_seed(cls, seed: int) -> _Streams:
        streams = np.random.SeedSequence(int(seed)).spawn(8)
        return cls(*(np.random.default_rng(s) for s in streams))


@attrs.frozen(eq=False)
class _Reference:
    """The true geometry of every view, by view name: the jittered attitude laws (one per
    segment), the full-image reference imagers, the views, their true model cameras and the
    index of their segment."""

    world: tg.World
    laws: list[AttitudeLaw]
    full_imagers: dict[str, ReferenceImager]
    views: dict[str, ViewPlan]
    cameras: dict[str, Camera]
    seg_of: dict[str, int]


@attrs.frozen(eq=False)
class _Truth:
    """What the truth stage yields for rendering: the true DEM's height range and steepest
    slope, and the ground texture."""

    h_lo_m: float
    h_hi_m: float
    max_slope: float
    ground: Any


@attrs.frozen(eq=False)
class _TrueScene:
    """The scene the last stages render and write: the terrain (and its manifest name), and
    by view name the true line-scanner model and the product's image."""

    terrain: Any
    terrain_name: str
    sensors: dict[str, LineScanner]
    specs: dict[str, ImageSpec]


@attrs.frozen
class _Written:
    """The product files the manifest names: ancillary file by view, truth model path by
    view (relative to the scene folder) and the true ortho-image."""

    anc_files: dict[str, str]
    models: dict[str, Path]
    ortho: Path


@attrs.frozen(eq=False)
class _Run:
    """What every stage reads: the plan, the user's options, the settings resolved from
    both, the scene folder and whether progress is printed."""

    plan: ScenePlan
    options: SimulationOptions
    settings: _Settings
    out: Path
    quiet: bool


def _check_seeds(options: SimulationOptions) -> None:
    """Refuse a seed that is not an integer >= 0."""
    for name in ("seed", "platform_seed"):
        value = getattr(options, name)
        wrong = isinstance(value, bool) or not isinstance(value, int) or value < 0
        if value is not None and wrong:
            raise InputError(f"--{name.replace('_', '-')} must be an integer >= 0, got {value!r}")


def _settings(plan: ScenePlan, options: SimulationOptions) -> _Settings:
    """The options checked and completed with the plan's defaults."""
    from carto.framework.simulation import terrain as terrain_mod

    errors = ErrorModel.named(options.errors, agile=plan.agile)
    terrain_name = options.terrain or plan.default_terrain
    if options.dem_path is None and terrain_name not in terrain_mod.TERRAINS:
        raise InputError(
            f"unknown terrain {terrain_name!r}; available: {', '.join(terrain_mod.TERRAINS)}"
        )
    size = options.size or plan.default_size
    n_gcps = plan.default_gcps if options.n_gcps is None else options.n_gcps
    n_check = plan.default_checkpoints if options.n_checkpoints is None else options.n_checkpoints
    if n_gcps < 0 or n_check < 0:
        raise InputError("--gcps and --checkpoints must be >= 0")
    _check_seeds(options)
    if options.error_sizes:
        for name, value in options.error_sizes:
            check_error_size(name, value)
        errors = attrs.evolve(errors, **dict(options.error_sizes))
    return _Settings(errors, terrain_name, size, n_gcps, n_check)


def _check_size(plan: ScenePlan, size: tuple[int, int]) -> None:
    """Refuse a window larger than a view's full image."""
    for seg in plan.segments:
        for view in seg.views:
            if not (size[0] <= view.camera.n_detectors and size[1] <= view.n_lines_full):
                raise InputError(
                    f"--size {size[0]} {size[1]}: must be within the full image "
                    f"{view.camera.n_detectors} x {view.n_lines_full} of {view.name}"
                )


def _reference(
    plan: ScenePlan,
    errors: ErrorModel,
    drawn: dict[str, Any],
    h_mid_m: float,
    rng: np.random.Generator,
) -> _Reference:
    """The true orbit and attitude (jitter drawn from ``rng``, recorded in ``drawn``) and every
    view's full-image reference imager, pointed at its target seen at ``h_mid_m``."""
    w = tg.world(plan)
    laws, full_imagers, views, cameras, seg_of = [], {}, {}, {}, {}
    for seg in plan.segments:
        law = tg.jittered(seg.attitude, errors.jitter_deg, errors.jitter_hz, rng)
        laws.append(law)
        if law is not seg.attitude:  # the jitter drawn, for whoever rebuilds the truth
            drawn["segments"][len(laws) - 1]["attitude_jitter"] = {
                "amplitude_rad": [list(a) for a in law.amplitude_rad],
                "frequency_hz": list(law.frequency_hz),
                "phase_rad": [list(p) for p in law.phase_rad],
            }
        for view in seg.views:
            mis = drawn["camera_misalignment_rad"][view.camera.name]
            interior = drawn["camera_interior"][view.camera.name]
            period = view.period_s * (1.0 + 1e-6 * drawn["line_timing"][view.name]["period_ppm"])
            full_imagers[view.name] = tg.full_imager(
                w,
                view,
                tg.camera_geometry(view.camera, mis, interior),
                law,
                seg,
                view.target or plan.target,
                h_mid_m,
                period_s=period,
            )
            views[view.name] = view
            cameras[view.name] = tg.model_camera(view.camera, mis, interior)
            seg_of[view.name] = len(laws) - 1
    return _Reference(w, laws, full_imagers, views, cameras, seg_of)


def _place(
    ref: _Reference, plan: ScenePlan, size: tuple[int, int], h_target: float
) -> dict[str, tuple[ReferenceImager, int]]:
    """Windows centred on the target seen at height ``h_target``."""
    placed = {}
    for name, full in ref.full_imagers.items():
        target = ref.views[name].target or plan.target
        t_line, t_sample = full.ground_to_image(target[0], target[1], h_target)
        first_line, first_sample, height, width = _window(
            ref.views[name], size, float(t_line), float(t_sample)
        )
        placed[name] = (tg.window(full, first_line, first_sample, height, width), first_line)
    return placed


def _terrain(
    run: _Run, bounds: tuple[float, float, float, float], rng: np.random.Generator
) -> tuple[Any, str]:
    """The terrain over ``bounds`` (the user's DEM or a seeded procedural preset) and the name
    the manifest gives it."""
    from carto.framework.raster.dem import DEM
    from carto.framework.simulation import terrain as terrain_mod

    options, terrain_name = run.options, run.settings.terrain_name
    dem_posting = max(2.0 * run.plan.gsd_m, 1.0)
    if options.dem_path is not None:
        terrain: Any = terrain_mod.GridTerrain(
            terrain_mod.terrain_from_dem(DEM.open(options.dem_path), bounds, dem_posting)
        )
        return terrain, f"file:{Path(options.dem_path).name}"
    terrain = terrain_mod.ProceduralTerrain(
        terrain_name, bounds, dem_posting, int(rng.integers(2**31))
    )
    return terrain, terrain_name


def _terrain_and_windows(
    run: _Run, ref: _Reference, h_range: tuple[float, float], rng: np.random.Generator
) -> tuple[Any, str, dict[str, tuple[ReferenceImager, int]]]:
    """The terrain (and its manifest name) and the image windows, centred on the target seen
    at its true height on that terrain (the middle height when views have their own
    targets)."""
    plan, options, size = run.plan, run.options, run.settings.size
    h_mid = 0.5 * sum(h_range)
    # the terrain must cover the windows wherever the target's true height puts them
    candidates = [_place(ref, plan, size, h) for h in h_range]
    imagers_all = [im for c in candidates for im, _ in c.values()]
    bounds = tg.footprint_bounds(imagers_all, h_range, margin_m=20 * plan.gsd_m)
    label = run.settings.terrain_name if options.dem_path is None else options.dem_path
    with _Stage(f"terrain {label}", run.quiet):
        terrain, terrain_name = _terrain(run, bounds, rng)
    if any(v.target is not None for v in ref.views.values()):
        h_place = h_mid  # several targets: centre on the middle height
    else:
        h_target = float(terrain.height(*plan.target))
        h_place = h_target if np.isfinite(h_target) else h_mid
    return terrain, terrain_name, _place(ref, plan, size, h_place)


def _true_sensors(
    ref: _Reference, placed: dict[str, tuple[ReferenceImager, int]]
) -> dict[str, LineScanner]:
    """The true line-scanner model of every placed window."""
    return {
        name: tg.truth_scanner(
            im,
            ref.cameras[name],
            tg.truth_trajectory(ref.world, ref.laws[ref.seg_of[name]], tg.image_span(im)),
            first_line,
        )
        for name, (im, first_line) in placed.items()
    }


def _image_specs(
    true_sensors: dict[str, LineScanner], views: dict[str, ViewPlan], drawn: dict[str, Any]
) -> dict[str, ImageSpec]:
    """The product's images; their line timing: the clock's offset and the nominal period."""
    return {
        name: ImageSpec(
            name,
            views[name].camera.name,
            f"{name}.tif",
            s.n_lines,
            s.n_samples,
            s.first_line,
            s.first_sample,
            LineTiming.constant(
                float(s.timing.time(0.5)) - drawn["line_timing"][name]["offset_s"],
                views[name].period_s,
            ),
        )
        for name, s in true_sensors.items()
    }


def _render_all(
    run: _Run, scene: _TrueScene, truth: _Truth, rng_noise: np.random.Generator
) -> None:
    """Render every view, band by band, into its GeoTIFF (noise from ``rng_noise``)."""
    from carto.framework.simulation import scene_tiles

    plan, options, quiet = run.plan, run.options, run.quiet
    for name, sensor in scene.sensors.items():
        with _Stage(
            f"rendered {name} ({sensor.image_shape[1]} x {sensor.image_shape[0]} px)", quiet
        ):
            scene_tiles.render_image(
                run.out / scene.specs[name].raster,
                sensor,
                scene.terrain,
                truth.ground,
                h_range=(truth.h_lo_m, truth.h_hi_m),
                max_slope=truth.max_slope,
                supersample=options.supersample,
                band_lines=options.band_lines,
                band_samples=options.band_samples,
                to_dn=lambda refl: _radiometry(refl, plan, rng_noise),
                tags={
                    "NBITS_USED": "10",
                    "CARTO_IMAGE": name,
                    "CARTO_ARRAYS": "odd/even staggered (raw)",
                },
                quiet=quiet,
            )


def _truth_and_ground(run: _Run, terrain: Any, rng_tex: np.random.Generator) -> _Truth:
    """Write the true DEM (its height range and steepest slope bound the rendering) and make
    the seeded ground texture."""
    from carto.framework.simulation import scene_tiles
    from carto.framework.simulation.texture import GroundTexture

    with _Stage("truth DEM", run.quiet):
        h_lo, h_hi, max_slope = scene_tiles.write_truth_dem(
            run.out / "truth" / "dem.tif", terrain, quiet=run.quiet
        )
    with _Stage("ground texture", run.quiet):
        ground = GroundTexture(terrain, 0.5 * run.plan.gsd_m, int(rng_tex.integers(2**31)))
    return _Truth(h_lo, h_hi, max_slope, ground)


def _marked_ground(
    ground: Any, plan: ScenePlan, options: SimulationOptions, targets: tuple[Any, ...]
) -> Any:
    """The texture with the control points' targets painted (``--point-targets``) and the
    optics' blur."""
    if options.point_targets and targets[0].size:
        ground = ground.with_targets(
            targets[0], targets[1], radius_m=2.5 * plan.gsd_m, contrast=0.8
        )
    if plan.blur_sigma_px > 0:
        ground = ground.blurred(plan.blur_sigma_px * plan.gsd_m / ground.posting_m)
    return ground


def _write_ancillary(
    run: _Run, w: tg.World, drawn: dict[str, Any], specs: dict[str, ImageSpec]
) -> dict[str, str]:
    """One ancillary file per segment, as measured (with the drawn errors); its file name by
    view."""
    plan, errors = run.plan, run.settings.errors
    anc_files = {}
    for seg, seg_err in zip(plan.segments, drawn["segments"], strict=True):
        anc = measured_ancillary(
            plan.platform,
            w,
            seg.span_s,
            seg.attitude,
            seg_err,
            {v.camera.name: v.camera for v in seg.views},
            [specs[v.name] for v in seg.views],
            ephemeris_noise_m=errors.ephemeris_noise_m,
        )
        path = anc.write(run.out / f"{seg.name}.ancillary.json")
        for v in seg.views:
            anc_files[v.name] = path.name
    return anc_files


def _write_truth(
    run: _Run, scene: _TrueScene, drawn: dict[str, Any], truth: _Truth
) -> tuple[dict[str, Path], Path]:
    """``truth/``: the true models (their paths relative to ``out``), the true ortho-image
    (where the images see the ground) and the drawn errors."""
    from carto.framework.simulation import scene_tiles

    out = run.out
    truth_dir = out / "truth"
    models = {}
    for name, sensor in scene.sensors.items():
        models[name] = sensor.save(truth_dir / f"{name}.model.json").relative_to(out)
    ortho = scene_tiles.write_true_ortho(
        truth_dir / "ortho.tif",
        truth.ground,
        scene.terrain.bounds_lonlat,
        run.plan.gsd_m,
        outlines=scene_tiles.footprint_outlines(scene.sensors, (truth.h_lo_m, truth.h_hi_m)),
        quiet=run.quiet,
    )
    write_json_atomic(
        truth_dir / "errors.json",
        {
            "error_model": run.settings.errors.as_dict(),
            "drawn": drawn,
            "note": ERRORS_NOTE,
        },
    )
    return models, ortho


def _manifest(run: _Run, scene: _TrueScene, written: _Written) -> dict[str, Any]:
    """``scene.json``: what was simulated and where each file of the scene is."""
    plan, options, settings, specs = run.plan, run.options, run.settings, scene.specs
    size = settings.size
    return {
        "format": SCENE_FORMAT,
        "version": SCENE_VERSION,
        "preset": plan.preset,
        "platform": plan.platform,
        "seed": int(options.seed),
        "platform_seed": None if options.platform_seed is None else int(options.platform_seed),
        "terrain": scene.terrain_name,
        "size": [int(size[0]), int(size[1])],
        "errors": options.errors,
        "error_model": settings.errors.as_dict(),
        "epoch_utc": plan.epoch_utc,
        "target": {"lon_deg": plan.target[0], "lat_deg": plan.target[1]},
        "images": {
            n: {
                "raster": specs[n].raster,
                "ancillary": written.anc_files[n],
                "camera": specs[n].camera,
                "array": "odd",
                "truth_model": str(written.models[n]),
            }
            for n in specs
        },
        "gcps": "gcps.csv",
        "checkpoints": "checkpoints.csv",
        "init_dem": "init_dem.tif",
        "truth": {
            "dem": "truth/dem.tif",
            "ortho": str(written.ortho.relative_to(run.out)),
            "errors": "truth/errors.json",
        },
        "vertical_reference": "ellipsoid WGS84",
        "pixel_convention": "first pixel centre at (0.5, 0.5); image coordinates of "
        "control points refer to the odd-array model",
        "counts": {"gcps": settings.n_gcps, "checkpoints": settings.n_check},
        "epoch_j2000_s": frames.utc_to_j2000_s(plan.epoch_utc),
    }


def simulate_scene(
    plan: ScenePlan,
    out_dir: str | os.PathLike[str],
    options: SimulationOptions = SimulationOptions(),  # noqa: B008 (frozen, immutable)
    *,
    quiet: bool = False,
) -> Path:
    """Render ``plan`` into the scene folder ``out_dir``; return the path of ``scene.json``.

    The stages (module docstring): settings and error draws, the true geometry, the terrain
    under the windows, the true models, truth DEM and texture, control points, rendering,
    then the products and ``truth/``."""
    from carto.framework.simulation import scene_tiles

    out = Path(out_dir)
    settings = _settings(plan, options)
    run = _Run(plan, options, settings, out, quiet)
    errors, size = settings.errors, settings.size
    streams = _Streams.from_seed(options.seed)
    drawn = draw_product_errors(plan, errors, streams.err, streams.full, options.platform_seed)
    out.mkdir(parents=True, exist_ok=True)
    _check_size(plan, size)

    # --- true geometry (the reference): full images, then windows centred on the target
    h_range = _terrain_range(settings.terrain_name, options.dem_path)
    h_mid = 0.5 * sum(h_range)
    with _Stage("true orbit and attitude (reference geometry)", quiet):
        ref = _reference(plan, errors, drawn, h_mid, streams.jit)

    terrain, terrain_name, placed = _terrain_and_windows(run, ref, h_range, streams.terrain)
    with _Stage("true line-scanner models", quiet):
        true_sensors = _true_sensors(ref, placed)
    specs = _image_specs(true_sensors, ref.views, drawn)
    scene = _TrueScene(terrain, terrain_name, true_sensors, specs)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    truth = _truth_and_ground(run, terrain, streams.tex)

    # --- control points (before rendering: point targets may mark them)
    with _Stage("control points", quiet):
        gcp_rows, check_rows, targets = control_points(
            true_sensors,
            terrain,
            settings.n_gcps,
            settings.n_check,
            errors,
            streams.ctl,
            plan.control_min_views,
            exact={name: im for name, (im, _) in placed.items()},
        )
    truth = attrs.evolve(truth, ground=_marked_ground(truth.ground, plan, options, targets))

    # --- render band by band, then the products (the texture computed once for all)
    with _texture_spill(truth.ground):
        _render_all(run, scene, truth, streams.noise)
        with _Stage("ancillary, control, initial DEM and truth", quiet):
            anc_files = _write_ancillary(run, ref.world, drawn, specs)
            write_point_table(out / "gcps.csv", gcp_rows, precision=15)
            write_point_table(out / "checkpoints.csv", check_rows, precision=15)
            scene_tiles.write_init_dem(out / "init_dem.tif", terrain, streams.init)
            models, ortho = _write_truth(run, scene, drawn, truth)
    manifest = _manifest(run, scene, _Written(anc_files, models, ortho))
    return write_json_atomic(out / "scene.json", manifest)


@contextlib.contextmanager
def _texture_spill(ground: Any) -> Iterator[None]:
    """Within the block, ``ground``'s texture tiles are computed once and read back from a
    scratch file in the system's temporary folder when needed again (every image and the
    true ortho see the same ground); the file is removed after. Without room for the whole
    texture grid twice over there, tiles are computed again as before."""
    import shutil
    import tempfile

    from carto.framework.simulation.tile_cache import TileSpill

    need = 2 * 5 * ground.shape[0] * ground.shape[1]  # float32 reflectance and a mask byte
    if shutil.disk_usage(tempfile.gettempdir()).free < need:
        yield
        return
    with tempfile.TemporaryDirectory(prefix="carto-texture-") as tmp:
        spill = TileSpill(Path(tmp) / "tiles.bin")
        ground.spill_tiles(spill)
        try:
            yield
        finally:
            ground.spill_tiles(None)
            spill.close()


def _terrain_range(name: str, dem_path: Path | None) -> tuple[float, float]:
    from carto.framework.raster.dem import DEM
    from carto.framework.simulation import terrain as terrain_mod

    if dem_path is not None:
        lo, hi = DEM.open(dem_path).height_range
        return float(lo), float(hi)
    preset = terrain_mod.TERRAINS[name]
    return float(preset.h_min_m), float(preset.h_max_m)
