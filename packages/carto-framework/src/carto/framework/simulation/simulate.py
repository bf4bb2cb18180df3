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
from carto.framework.geometry import frames, orbit
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan import LineScanner
from carto.framework.geometry.linescan_timing import LineTiming
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory
from carto.framework.products.ancillary import Ancillary, CameraSpec, ImageSpec
from carto.framework.products.scene import SCENE_FORMAT, SCENE_VERSION
from carto.framework.simulation import acquisition
from carto.framework.simulation.control import control_points
from carto.framework.simulation.plan import (
    ErrorModel,
    ScenePlan,
    SegmentPlan,
    SimulationOptions,
    ViewPlan,
)

FloatArray = NDArray[np.float64]
TRUTH_STEP_S = 0.025
"""Sampling of the true motion (40 Hz: resolves jitter up to ~10 Hz with Lagrange)."""
DN_MAX = 1023


def _progress(message: str) -> None:
    print(f"carto simulate: {message}", file=sys.stderr, flush=True)


class _Stage:
    def __init__(self, what: str, quiet: bool) -> None:
        self.what, self.quiet = what, quiet

    def __enter__(self) -> _Stage:
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        if not self.quiet and exc[0] is None:
            _progress(f"{self.what} ({time.perf_counter() - self.t0:.1f} s)")


# ----------------------------------------------------------------------------- engine
@attrs.frozen(eq=False)
class _Truth:
    """True trajectory of a segment and its dense ECI samples."""

    trajectory: Trajectory
    dt: FloatArray
    p_eci: FloatArray
    v_eci: FloatArray


def _true_segment(
    plan: ScenePlan,
    seg: SegmentPlan,
    errors: ErrorModel,
    rng: np.random.Generator,
    p0: FloatArray,
    v0: FloatArray,
) -> _Truth:
    epoch = frames.utc_to_j2000_s(plan.epoch_utc)
    lo, hi = seg.span_s
    # the truth also covers a full image beyond the span (long windows of a view near its
    # end; the samples stay on the same lattice, so the truth inside the span is unchanged)
    pad = max((v.n_lines_full * v.period_s for v in seg.views), default=0.0)
    lo, hi = lo - pad, hi + pad
    dt = np.arange(math.floor(lo / TRUTH_STEP_S) - 8, math.ceil(hi / TRUTH_STEP_S) + 9) * (
        TRUTH_STEP_S
    )
    p, v = orbit.propagate(p0, v0, dt)
    r = seg.law(dt, p, v)
    if errors.jitter_deg > 0:
        phases = rng.uniform(0, 2 * np.pi, (3, len(errors.jitter_hz)))
        amps = np.radians(errors.jitter_deg) * rng.uniform(0.5, 1.0, (3, len(errors.jitter_hz)))
        j = np.zeros((3, dt.size))
        for k, f in enumerate(errors.jitter_hz):
            j += amps[:, k, None] * np.sin(2 * np.pi * f * dt[None, :] + phases[:, k, None])
        r = frames.rpy_to_matrix(j[0], j[1], j[2]) @ r
    traj = Trajectory.from_samples(
        epoch,
        EphemerisSamples(dt, p, v, "eci"),
        AttitudeSamples(dt, frames.matrix_to_quat(r), "orbit"),
        interpolation="lagrange",
        lagrange_points=8,
    )
    return _Truth(traj, dt, p, v)


def _measured_ancillary(
    plan: ScenePlan, seg: SegmentPlan, truth: _Truth, drawn: dict, images: Sequence[ImageSpec]
) -> Ancillary:
    """Ancillary samples every 125 ms as the platform measures them (with the errors)."""
    epoch = frames.utc_to_j2000_s(plan.epoch_utc)
    lo, hi = seg.span_s
    for image in images:  # windows of many lines may reach beyond the planned span
        t_first = float(image.timing.time(0.0))
        t_last = float(image.timing.time(float(image.n_lines)))
        if t_first < lo + 0.5:  # keep four samples before the first line
            lo = min(lo, t_first - 1.0)
        if t_last > hi - 0.5:
            hi = max(hi, t_last + 1.0)
    step = acquisition.ANCILLARY_STEP_S
    dt = np.arange(math.floor(lo / step), math.ceil(hi / step) + 1) * step
    p_eci, v_eci = truth.trajectory.state_eci(dt)
    r_true = seg.law(dt, p_eci, v_eci)  # the attitude sensors see the smooth motion
    # attitude error e(t) in the orbit frame: measured = rpy(e)^T @ true, so that the
    # correction rpy(e) @ measured restores the truth exactly
    t_mid, t_half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    tau = (dt - t_mid) / t_half
    e = (
        np.asarray(drawn["attitude_bias_rad"])[:, None]
        + np.asarray(drawn["attitude_drift_rad_s"])[:, None] * dt[None, :]
        + np.asarray(drawn["attitude_tau2_rad"])[:, None] * tau[None, :] ** 2
        + np.asarray(drawn["attitude_tau3_rad"])[:, None] * tau[None, :] ** 3
    )
    r_meas = np.swapaxes(frames.rpy_to_matrix(e[0], e[1], e[2]), -1, -2) @ r_true
    # ephemeris bias along / across / radial: measured = true - R_orbit (along, across, -radial)
    b = np.asarray(drawn["ephemeris_bias_m"])
    r_o2i = frames.orbit_to_eci_matrix(p_eci, v_eci)
    p_meas_eci = p_eci - np.einsum("nij,j->ni", r_o2i, np.array([b[0], b[1], -b[2]]))
    p_ecef, v_ecef = frames.eci_to_ecef(epoch + dt, p_meas_eci, v_eci)
    cams = {v.camera.name: v.camera for v in seg.views}
    return Ancillary(
        plan.platform,
        plan.epoch_utc,
        EphemerisSamples(dt, p_ecef, v_ecef, "ecef"),
        AttitudeSamples(dt, frames.matrix_to_quat(r_meas), "orbit"),
        cams,
        {i.name: i for i in images},
    )


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


def _true_camera(spec: CameraSpec, misalignment_rad: Sequence[float]) -> Camera:
    nominal = spec.camera("odd")
    align = tuple(a + m for a, m in zip(nominal.alignment_rpy_rad, misalignment_rad, strict=True))
    return attrs.evolve(nominal, alignment_rpy_rad=align)


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


def _footprint_bounds(
    sensors: Sequence[LineScanner], h_range: tuple[float, float], margin_m: float
) -> tuple[float, float, float, float]:
    lons, lats = [], []
    for s in sensors:
        n_l, n_s = s.image_shape
        line = np.array([0, 0, n_l, n_l, n_l / 2, 0, n_l / 2, n_l], float)
        sample = np.array([0, n_s, 0, n_s, 0, n_s / 2, n_s, n_s / 2], float)
        for h in h_range:
            lon, lat = s.image_to_ground(line, sample, np.full(line.size, h))
            lons.append(lon)
            lats.append(lat)
    lon = np.concatenate(lons)
    lat = np.concatenate(lats)
    m_lat = margin_m / 111_320.0
    m_lon = m_lat / math.cos(math.radians(float(np.mean(lat))))
    return (
        float(lon.min() - m_lon),
        float(lat.min() - m_lat),
        float(lon.max() + m_lon),
        float(lat.max() + m_lat),
    )


def _radiometry(
    refl: NDArray[np.float32], plan: ScenePlan, rng: np.random.Generator
) -> NDArray[np.uint16]:
    """Reflectance -> 10-bit DN: gain/offset, shot and read noise, quantisation."""
    img = np.nan_to_num(refl.astype(np.float32), nan=0.0)
    dn = 40.0 + 900.0 * img
    noise = rng.normal(0.0, 1.0, dn.shape).astype(np.float32)
    dn = dn + noise * np.sqrt(plan.noise_dn**2 + 0.05 * dn)
    return np.clip(np.rint(dn), 0, DN_MAX).astype(np.uint16)


def simulate_scene(
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
    if options.errors not in ("realistic", "none"):
        raise InputError(f"--errors must be 'realistic' or 'none', got {options.errors!r}")
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
    errors = (
        ErrorModel.realistic(agile=plan.agile)
        if options.errors == "realistic"
        else ErrorModel.none()
    )
    if options.error_sizes:
        known = {f.name for f in attrs.fields(ErrorModel) if f.name != "jitter_hz"}
        for name, value in options.error_sizes:
            if name not in known:
                raise InputError(
                    f"unknown error source {name!r}; known: {', '.join(sorted(known))}"
                )
            if not (math.isfinite(value) and value >= 0):
                raise InputError(f"error size {name}={value}: must be a number >= 0")
        errors = attrs.evolve(errors, **dict(options.error_sizes))
    streams = np.random.SeedSequence(int(options.seed)).spawn(8)
    rng_err, rng_jit, rng_terrain, rng_tex, rng_ctl, rng_noise, rng_init = (
        np.random.default_rng(s) for s in streams[:7]
    )
    epoch = frames.utc_to_j2000_s(plan.epoch_utc)
    p0, v0 = orbit.elements_to_state(plan.elements)
    cameras = sorted({v.camera.name for s in plan.segments for v in s.views})
    drawn = _draw_errors(errors, rng_err, len(plan.segments), cameras)
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

    # --- true geometry: full images, then windows centred on the target
    h_range = _terrain_range(terrain_name, options.dem_path)
    h_mid = 0.5 * sum(h_range)
    with _Stage("true trajectories", quiet):
        truths, full_sensors, views = [], {}, {}
        for seg in plan.segments:
            truth = _true_segment(plan, seg, errors, rng_jit, p0, v0)
            truths.append(truth)
            for view in seg.views:
                cam = _true_camera(view.camera, drawn["camera_misalignment_rad"][view.camera.name])
                if view.centre_dt_s is None:
                    t_c = acquisition.crossing_time(
                        truth.trajectory,
                        cam,
                        *(view.target or plan.target),
                        h_mid,
                        t_range_s=seg.span_s,
                    )
                else:
                    t_c = view.centre_dt_s
                timing = LineTiming.constant(
                    t_c - (view.n_lines_full / 2.0 - 0.5) * view.period_s, view.period_s
                )
                full_sensors[view.name] = LineScanner(
                    view.name, view.n_lines_full, timing, cam, truth.trajectory
                )
                views[view.name] = view

    def place(h_target: float) -> dict[str, LineScanner]:
        """Windows centred on the target seen at height ``h_target``."""
        placed = {}
        for name, full in full_sensors.items():
            t_line, t_sample, _ = full.project(*(views[name].target or plan.target), h_target)
            first_line, first_sample, height, width = _window(
                views[name], size, float(t_line), float(t_sample)
            )
            timing = LineTiming.constant(
                float(full.timing.time(first_line + 0.5)), views[name].period_s
            )
            placed[name] = LineScanner(
                name,
                height,
                timing,
                full.camera,
                full.trajectory,
                first_sample=first_sample,
                width=width,
                first_line=first_line,
            )
        return placed

    # the terrain must cover the windows wherever the target's true height puts them
    candidates = [place(h) for h in h_range]
    sensors_all = [s for c in candidates for s in c.values()]
    bounds = _footprint_bounds(sensors_all, h_range, margin_m=20 * plan.gsd_m)
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
    true_sensors = place(h_target if np.isfinite(h_target) else h_mid)
    if any(v.target is not None for v in views.values()):
        true_sensors = place(h_mid)  # several targets: centre on the middle height
    specs = {
        name: ImageSpec(
            name,
            views[name].camera.name,
            f"{name}.tif",
            s.n_lines,
            s.n_samples,
            s.first_line,
            s.first_sample,
            s.timing,
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
            true_sensors, terrain, n_gcps, n_check, errors, rng_ctl, plan.control_min_views
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
        for seg, truth, seg_err in zip(plan.segments, truths, drawn["segments"], strict=True):
            anc = _measured_ancillary(plan, seg, truth, seg_err, [specs[v.name] for v in seg.views])
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
                "note": "attitude errors: measured R_body_to_orbit = rpy(e)^T @ true, with "
                "e = bias + drift * dt_s + tau2 * tau^2 + tau3 * tau^3 (tau over the "
                "ancillary samples of the segment); ephemeris: measured = true - "
                "R_orbit_to_ecef @ (along, across, -radial)",
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
