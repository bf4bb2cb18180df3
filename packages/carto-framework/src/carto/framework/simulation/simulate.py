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

import logging
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.files.documents import write_json_atomic
from carto.framework.files.point_table import write_point_table
from carto.framework.geometry import frames
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.products.ancillary import ImageSpec
from carto.framework.products.scene import SCENE_FORMAT, SCENE_VERSION
from carto.framework.simulation import truth_geometry as tg
from carto.framework.simulation.control import control_points
from carto.framework.simulation.plan import (
    ErrorModel,
    ScenePlan,
    SimulationOptions,
    ViewPlan,
    check_error_size,
)
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
def _draw_unmodelled(
    errors: ErrorModel,
    rng: np.random.Generator,
    n_segments: int,
    cameras: Sequence[str],
    views: Sequence[str],
) -> dict[str, Any]:
    """The draws of the errors outside the adjusters' parameters (``--errors full``). Every
    draw is made whatever the sizes (scaled by them), so switching one source off leaves the
    others unchanged."""
    deg = math.radians

    def normal(sigma: float, n: int | None = None) -> Any:
        z = rng.standard_normal(n)
        return (np.asarray(z) * sigma).tolist()

    interior = {
        c: {
            "focal_ppm": normal(errors.focal_length_ppm),
            "line_offset_px": normal(errors.detector_line_offset_px),
            "principal_point_px": normal(errors.principal_point_px),
            "rotation_rad": normal(deg(errors.ccd_rotation_deg)),
        }
        for c in cameras
    }
    timing = {
        v: {
            "offset_s": normal(errors.line_time_offset_s),
            "period_ppm": normal(errors.line_period_ppm),
        }
        for v in views
    }
    wander = [
        {
            "amplitude_rad": (
                deg(errors.attitude_wander_deg) * rng.uniform(0.5, 1.0, (3, 3))
            ).tolist(),
            "period_s": rng.uniform(15.0, 90.0, 3).tolist(),
            "phase_rad": rng.uniform(0.0, 2.0 * math.pi, (3, 3)).tolist(),
            "ephemeris_noise_seed": int(rng.integers(2**31)),
        }
        for _ in range(n_segments)
    ]
    return {"camera_interior": interior, "line_timing": timing, "segments": wander}


def _draw_errors(
    errors: ErrorModel, rng: np.random.Generator, n_segments: int, cameras: Sequence[str]
) -> dict[str, Any]:
    def draw(sigma: float) -> list[float]:
        """Three normal draws of ``sigma`` (none when the source is switched off)."""
        return (rng.normal(0.0, sigma, 3) if sigma else np.zeros(3)).tolist()

    deg = np.radians
    eph = draw(errors.ephemeris_bias_m)
    seg = [
        {
            "ephemeris_bias_m": eph,
            "attitude_bias_rad": draw(deg(errors.attitude_bias_deg)),
            "attitude_drift_rad_s": draw(deg(errors.attitude_drift_deg_s)),
            "attitude_tau2_rad": draw(deg(errors.attitude_smooth_deg)),
            "attitude_tau3_rad": draw(deg(errors.attitude_smooth_deg)),
        }
        for _ in range(n_segments)
    ]
    mis = {c: draw(deg(errors.misalignment_deg)) for c in cameras}
    return {"segments": seg, "camera_misalignment_rad": mis}


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


def simulate_scene(  # noqa: C901, PLR0915 (issue 32: to split)
    plan: ScenePlan,
    out_dir: str | os.PathLike[str],
    options: SimulationOptions = SimulationOptions(),  # noqa: B008 (frozen, immutable)
    *,
    quiet: bool = False,
) -> Path:
    """Render ``plan`` into the scene folder ``out_dir``; return the path of ``scene.json``."""
    from carto.framework.raster.dem import DEM
    from carto.framework.simulation import scene_tiles
    from carto.framework.simulation import terrain as terrain_mod
    from carto.framework.simulation.texture import GroundTexture

    out = Path(out_dir)
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
    for name in ("seed", "platform_seed"):
        value = getattr(options, name)
        wrong = isinstance(value, bool) or not isinstance(value, int) or value < 0
        if value is not None and wrong:
            raise InputError(f"--{name.replace('_', '-')} must be an integer >= 0, got {value!r}")
    if options.error_sizes:
        for name, value in options.error_sizes:
            check_error_size(name, value)
        errors = attrs.evolve(errors, **dict(options.error_sizes))
    streams = np.random.SeedSequence(int(options.seed)).spawn(8)
    rng_err, rng_jit, rng_terrain, rng_tex, rng_ctl, rng_noise, rng_init, rng_full = (
        np.random.default_rng(s) for s in streams
    )
    epoch = frames.utc_to_j2000_s(plan.epoch_utc)
    cameras = sorted({v.camera.name for s in plan.segments for v in s.views})
    drawn = _draw_errors(errors, rng_err, len(plan.segments), cameras)
    view_names = [v.name for seg in plan.segments for v in seg.views]
    unmodelled = _draw_unmodelled(errors, rng_full, len(plan.segments), cameras, view_names)
    drawn["camera_interior"] = unmodelled["camera_interior"]
    drawn["line_timing"] = unmodelled["line_timing"]
    for seg_draw, extra in zip(drawn["segments"], unmodelled["segments"], strict=True):
        seg_draw.update(
            {
                f"attitude_wander_{k}" if k != "ephemeris_noise_seed" else k: v
                for k, v in extra.items()
            }
        )
    if options.platform_seed is not None:
        platform_rng = np.random.default_rng(int(options.platform_seed))
        drawn["camera_misalignment_rad"] = {
            c: (platform_rng.normal(0.0, math.radians(errors.misalignment_deg), 3)).tolist()
            for c in cameras
        }
    out.mkdir(parents=True, exist_ok=True)

    for seg in plan.segments:
        for view in seg.views:
            if not (size[0] <= view.camera.n_detectors and size[1] <= view.n_lines_full):
                raise InputError(
                    f"--size {size[0]} {size[1]}: must be within the full image "
                    f"{view.camera.n_detectors} x {view.n_lines_full} of {view.name}"
                )

    # --- true geometry (the reference): full images, then windows centred on the target
    h_range = _terrain_range(terrain_name, options.dem_path)
    h_mid = 0.5 * sum(h_range)
    with _Stage("true orbit and attitude (reference geometry)", quiet):
        w = tg.world(plan)
        laws, full_imagers, views, cameras, seg_of = [], {}, {}, {}, {}
        for seg in plan.segments:
            law = tg.jittered(seg.attitude, errors.jitter_deg, errors.jitter_hz, rng_jit)
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
                period = view.period_s * (
                    1.0 + 1e-6 * drawn["line_timing"][view.name]["period_ppm"]
                )
                full_imagers[view.name] = tg.full_imager(
                    w,
                    view,
                    tg.camera_geometry(view.camera, mis, interior),
                    law,
                    seg,
                    view.target or plan.target,
                    h_mid,
                    period_s=period,
                )
                views[view.name] = view
                cameras[view.name] = tg.model_camera(view.camera, mis, interior)
                seg_of[view.name] = len(laws) - 1

    def place(h_target: float) -> dict[str, tuple[ReferenceImager, int]]:
        """Windows centred on the target seen at height ``h_target``."""
        placed = {}
        for name, full in full_imagers.items():
            target = views[name].target or plan.target
            t_line, t_sample = full.ground_to_image(target[0], target[1], h_target)
            first_line, first_sample, height, width = _window(
                views[name], size, float(t_line), float(t_sample)
            )
            placed[name] = (tg.window(full, first_line, first_sample, height, width), first_line)
        return placed

    # the terrain must cover the windows wherever the target's true height puts them
    candidates = [place(h) for h in h_range]
    imagers_all = [im for c in candidates for im, _ in c.values()]
    bounds = tg.footprint_bounds(imagers_all, h_range, margin_m=20 * plan.gsd_m)
    dem_posting = max(2.0 * plan.gsd_m, 1.0)
    with _Stage(f"terrain {terrain_name if options.dem_path is None else options.dem_path}", quiet):
        if options.dem_path is not None:
            terrain: Any = terrain_mod.GridTerrain(
                terrain_mod.terrain_from_dem(DEM.open(options.dem_path), bounds, dem_posting)
            )
            terrain_name = f"file:{Path(options.dem_path).name}"
        else:
            terrain = terrain_mod.ProceduralTerrain(
                terrain_name, bounds, dem_posting, int(rng_terrain.integers(2**31))
            )
    h_target = float(terrain.height(*plan.target))
    placed = place(h_target if np.isfinite(h_target) else h_mid)
    if any(v.target is not None for v in views.values()):
        placed = place(h_mid)  # several targets: centre on the middle height
    imagers = {name: im for name, (im, _) in placed.items()}
    with _Stage("true line-scanner models", quiet):
        true_sensors = {
            name: tg.truth_scanner(
                im,
                cameras[name],
                tg.truth_trajectory(w, laws[seg_of[name]], tg.image_span(im)),
                first_line,
            )
            for name, (im, first_line) in placed.items()
        }
    # the product's line timing: the clock's offset and the nominal period
    specs = {
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
    truth_dir = out / "truth"
    truth_dir.mkdir(parents=True, exist_ok=True)
    with _Stage("truth DEM", quiet):
        h_lo, h_hi, max_slope = scene_tiles.write_truth_dem(
            truth_dir / "dem.tif", terrain, quiet=quiet
        )
    with _Stage("ground texture", quiet):
        ground = GroundTexture(terrain, 0.5 * plan.gsd_m, int(rng_tex.integers(2**31)))

    # --- control points (before rendering: point targets may mark them)
    with _Stage("control points", quiet):
        gcp_rows, check_rows, targets = control_points(
            true_sensors,
            terrain,
            n_gcps,
            n_check,
            errors,
            rng_ctl,
            plan.control_min_views,
            exact=imagers,
        )
    if options.point_targets and targets[0].size:
        ground = ground.with_targets(
            targets[0], targets[1], radius_m=2.5 * plan.gsd_m, contrast=0.8
        )
    if plan.blur_sigma_px > 0:
        ground = ground.blurred(plan.blur_sigma_px * plan.gsd_m / ground.posting_m)

    # --- render, band by band
    for name, sensor in true_sensors.items():
        with _Stage(
            f"rendered {name} ({sensor.image_shape[1]} x {sensor.image_shape[0]} px)", quiet
        ):
            scene_tiles.render_image(
                out / specs[name].raster,
                sensor,
                terrain,
                ground,
                h_range=(h_lo, h_hi),
                max_slope=max_slope,
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

    # --- products
    with _Stage("ancillary, control, initial DEM and truth", quiet):
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
            path = anc.write(out / f"{seg.name}.ancillary.json")
            for v in seg.views:
                anc_files[v.name] = path.name
        write_point_table(out / "gcps.csv", gcp_rows, precision=15)
        write_point_table(out / "checkpoints.csv", check_rows, precision=15)
        scene_tiles.write_init_dem(out / "init_dem.tif", terrain, rng_init)
        models = {}
        for name, sensor in true_sensors.items():
            models[name] = sensor.save(truth_dir / f"{name}.model.json").relative_to(out)
        ortho = scene_tiles.write_true_ortho(
            truth_dir / "ortho.tif", ground, terrain.bounds_lonlat, plan.gsd_m, quiet=quiet
        )
        write_json_atomic(
            truth_dir / "errors.json",
            {
                "error_model": errors.as_dict(),
                "drawn": drawn,
                "note": ERRORS_NOTE,
            },
        )
    manifest = {
        "format": SCENE_FORMAT,
        "version": SCENE_VERSION,
        "preset": plan.preset,
        "platform": plan.platform,
        "seed": int(options.seed),
        "platform_seed": None if options.platform_seed is None else int(options.platform_seed),
        "terrain": terrain_name,
        "size": [int(size[0]), int(size[1])],
        "errors": options.errors,
        "error_model": errors.as_dict(),
        "epoch_utc": plan.epoch_utc,
        "target": {"lon_deg": plan.target[0], "lat_deg": plan.target[1]},
        "images": {
            n: {
                "raster": specs[n].raster,
                "ancillary": anc_files[n],
                "camera": specs[n].camera,
                "array": "odd",
                "truth_model": str(models[n]),
            }
            for n in true_sensors
        },
        "gcps": "gcps.csv",
        "checkpoints": "checkpoints.csv",
        "init_dem": "init_dem.tif",
        "truth": {
            "dem": "truth/dem.tif",
            "ortho": str(ortho.relative_to(out)),
            "errors": "truth/errors.json",
        },
        "vertical_reference": "ellipsoid WGS84",
        "pixel_convention": "first pixel centre at (0.5, 0.5); image coordinates of "
        "control points refer to the odd-array model",
        "counts": {"gcps": n_gcps, "checkpoints": n_check},
        "epoch_j2000_s": epoch,
    }
    return write_json_atomic(out / "scene.json", manifest)


def _terrain_range(name: str, dem_path: Path | None) -> tuple[float, float]:
    from carto.framework.raster.dem import DEM
    from carto.framework.simulation import terrain as terrain_mod

    if dem_path is not None:
        lo, hi = DEM.open(dem_path).height_range
        return float(lo), float(hi)
    preset = terrain_mod.TERRAINS[name]
    return float(preset.h_min_m), float(preset.h_max_m)
