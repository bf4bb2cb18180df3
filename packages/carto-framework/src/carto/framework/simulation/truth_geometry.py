"""A scene plan's true geometry, from the reference geometry
(:mod:`carto.framework.simulation.reference`): the platform's orbit and attitude, one
:class:`~carto.framework.simulation.reference.pushbroom.ReferenceImager` per view (the truth of
control-point image coordinates and image footprints), and the line-scanner models the fast
renderer draws the images through: the model chain fed with the reference's motion sampled
every 25 ms, with light time and aberration, which a test holds to the reference (0.01 px).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import attrs
import numpy as np

from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.light_path import LightPath
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory
from carto.framework.products.ancillary import CameraSpec
from carto.framework.simulation.plan import ScenePlan, SegmentPlan, ViewPlan
from carto.framework.simulation.reference import attitude as ref_attitude
from carto.framework.simulation.reference import earth
from carto.framework.simulation.reference.camera import CameraGeometry
from carto.framework.simulation.reference.orbit import OrbitSpec, ReferenceOrbit
from carto.framework.simulation.reference.pushbroom import LineTimes, ReferenceImager

TRUTH_STEP_S = 0.025
"""Sampling of the true motion the renderer's models interpolate (40 Hz, Lagrange), or finer
for attitude jitter: 20 samples per period of the fastest sinusoid (:func:`truth_step`)."""
PHYSICAL_LIGHT_PATH = LightPath(light_time=True, aberration=True)


@attrs.frozen(eq=False)
class World:
    """The Earth's orientation and the platform's orbit over a scene's time span."""

    epoch_utc: str
    orientation: earth.EarthOrientation
    orbit: ReferenceOrbit

    @property
    def epoch_j2000_s(self) -> float:
        return frames.utc_to_j2000_s(self.epoch_utc)


def scene_span(plan: ScenePlan) -> tuple[float, float]:
    """Every instant the scene's truth may need: the segments' spans, a full image beyond."""
    pad = max((v.n_lines_full * v.period_s for s in plan.segments for v in s.views), default=0.0)
    lo = min(s.span_s[0] for s in plan.segments) - pad - 5.0
    hi = max(s.span_s[1] for s in plan.segments) + pad + 5.0
    return lo, hi


def world(plan: ScenePlan) -> World:
    """The reference orbit over the plan's target (its altitude and inclination)."""
    lo, hi = scene_span(plan)
    lo, hi = min(lo, -1.0), max(hi, 1.0)
    orientation = earth.EarthOrientation.over(plan.epoch_utc, (lo - 2.0, hi + 2.0))
    spec = OrbitSpec(
        plan.epoch_utc,
        float(plan.target[0]),
        float(plan.target[1]),
        float(plan.elements.semi_major_axis_m - earth.EARTH_RADIUS_M),
        math.degrees(plan.elements.inclination_rad),
        descending=True,
    )
    return World(plan.epoch_utc, orientation, ReferenceOrbit.fly(spec, (lo, hi), orientation))


def jittered(
    law: ref_attitude.AttitudeLaw, jitter_deg: float, jitter_hz: Sequence[float], rng
) -> ref_attitude.AttitudeLaw:
    """``law`` with attitude jitter of ``jitter_deg`` at ``jitter_hz`` (the k-th frequency's
    amplitude drawn in 0.5-1 times ``jitter_deg / sqrt(k + 1)``, random phases); ``law``
    itself when ``jitter_deg`` is 0."""
    if not jitter_deg > 0:
        return law
    phases = rng.uniform(0, 2 * np.pi, (3, len(jitter_hz)))
    rank = np.arange(len(jitter_hz))
    amps = np.radians(jitter_deg) * rng.uniform(0.5, 1.0, (3, len(jitter_hz))) / np.sqrt(rank + 1)
    return ref_attitude.Jittered(
        law,
        tuple(map(tuple, amps.tolist())),
        tuple(float(f) for f in jitter_hz),
        tuple(map(tuple, phases.tolist())),
    )


NO_INTERIOR_ERRORS = {
    "focal_ppm": 0.0,
    "line_offset_px": 0.0,
    "principal_point_px": 0.0,
    "rotation_rad": 0.0,
}


def camera_geometry(
    spec: CameraSpec,
    misalignment_rad: Sequence[float],
    interior: Mapping[str, float] = NO_INTERIOR_ERRORS,
) -> CameraGeometry:
    """The true camera: the product's nominal constants with the residual misalignment and
    the interior-orientation errors (focal length, detector-line and principal-point offsets
    in detector pitches, line rotation)."""
    align = tuple(
        a + math.degrees(m) for a, m in zip(spec.alignment_rpy_deg, misalignment_rad, strict=True)
    )
    return CameraGeometry(
        spec.n_detectors,
        spec.focal_length_m * (1.0 + 1e-6 * interior["focal_ppm"]),
        spec.pitch_m,
        spec.stagger_m,
        spec.along_offset_m + interior["line_offset_px"] * spec.pitch_m,
        tuple(spec.mounting_rpy_deg),
        align,
        across_offset_m=interior["principal_point_px"] * spec.pitch_m,
        rotation_rad=interior["rotation_rad"],
    )


def model_camera(
    spec: CameraSpec,
    misalignment_rad: Sequence[float],
    interior: Mapping[str, float] = NO_INTERIOR_ERRORS,
) -> Camera:
    """The same true camera as a model :class:`Camera` (odd array): a straight line, so the
    tangents of its look directions are linear in the sample (the even array's small
    across-track shift under a rotated line, ``stagger sin(rotation) / f``, is left out:
    below 1e-8 rad)."""
    geo = camera_geometry(spec, misalignment_rad, interior)
    half = 0.5 * geo.n_detectors
    c, si = math.cos(geo.rotation_rad), math.sin(geo.rotation_rad)
    f = geo.focal_length_m
    x0, a, k = geo.along_offset_m, geo.across_offset_m, half * geo.pitch_m
    # y0(u) = -u k + a; x = x0 c - y0 si; y = x0 si + y0 c
    nominal = spec.camera("odd")
    return attrs.evolve(
        nominal,
        tan_psi_x_coeffs=((x0 * c - a * si) / f, k * si / f),
        tan_psi_y_coeffs=((x0 * si + a * c) / f, -k * c / f),
        stagger_tan=geo.stagger_m * c / f,
        alignment_rpy_rad=tuple(math.radians(d) for d in geo.alignment_rpy_deg),
    )


def full_imager(
    w: World,
    view: ViewPlan,
    camera: CameraGeometry,
    law: ref_attitude.AttitudeLaw,
    seg: SegmentPlan,
    target: tuple[float, float],
    h_target_m: float,
    period_s: float | None = None,
) -> ReferenceImager:
    """The view's whole acquisition (every detector, ``n_lines_full`` lines), centred in time
    on the instant the camera sees the target (or on the plan's ``centre_dt_s``); ``period_s``:
    the true line period (default the plan's)."""
    period = view.period_s if period_s is None else float(period_s)
    if view.centre_dt_s is None:
        lo, hi = seg.span_s
        probe = ReferenceImager(
            view.name,
            camera,
            LineTimes(lo, (hi - lo) / view.n_lines_full),
            view.n_lines_full,
            camera.n_detectors,
            0,
            w.orbit,
            law,
            w.orientation,
        )
        line, _ = probe.ground_to_image(target[0], target[1], h_target_m)
        t_c = float(probe.timing.time(line))
    else:
        t_c = float(view.centre_dt_s)
    t0 = t_c - (view.n_lines_full / 2.0 - 0.5) * period
    return ReferenceImager(
        view.name,
        camera,
        LineTimes(t0, period),
        view.n_lines_full,
        camera.n_detectors,
        0,
        w.orbit,
        law,
        w.orientation,
    )


def window(
    full: ReferenceImager, first_line: int, first_sample: int, height: int, width: int
) -> ReferenceImager:
    """A window of a full acquisition (its own line times and first detector)."""
    return attrs.evolve(
        full,
        timing=LineTimes(float(full.timing.time(first_line + 0.5)), full.timing.period_s),
        n_lines=int(height),
        width=int(width),
        first_sample=int(first_sample),
    )


def truth_step(law: ref_attitude.AttitudeLaw) -> float:
    """The sampling step that resolves ``law``: :data:`TRUTH_STEP_S`, or 20 samples per
    period of its fastest jitter."""
    if isinstance(law, ref_attitude.Jittered) and law.frequency_hz:
        return min(TRUTH_STEP_S, 1.0 / (20.0 * max(law.frequency_hz)))
    return TRUTH_STEP_S


def image_span(imager: ReferenceImager, margin_lines: float = 3000.0) -> tuple[float, float]:
    """The instants a model of the image needs: its lines, half an image or ``margin_lines``
    beyond each end (the ground -> image table's reach), and a second more."""
    margin = max(0.5 * imager.n_lines, margin_lines)
    lo = float(imager.timing.time(-margin)) - 1.0
    hi = float(imager.timing.time(imager.n_lines + margin)) + 1.0
    return lo, hi


def truth_trajectory(w: World, law: ref_attitude.AttitudeLaw, span_s: tuple[float, float]):
    """The model trajectory of the true motion over ``span_s``: GCRS position, velocity and
    body -> GCRS attitude every :func:`truth_step`, interpolated by Lagrange polynomials."""
    step = truth_step(law)
    lo = math.floor(span_s[0] / step) - 8
    hi = math.ceil(span_s[1] / step) + 9
    dt = np.arange(lo, hi) * step
    dt = dt[(dt >= w.orbit.span_s[0]) & (dt <= w.orbit.span_s[1])]
    p, v = w.orbit.state(dt)
    q = law.body_to_gcrs(dt, w.orbit, w.orientation)
    return Trajectory.from_samples(
        w.epoch_j2000_s,
        EphemerisSamples(dt, p, v, "eci"),
        AttitudeSamples(dt, q, "eci"),
        interpolation="lagrange",
        lagrange_points=8,
    )


def truth_scanner(
    imager: ReferenceImager, camera: Camera, trajectory: Trajectory, first_line: int
) -> LineScanner:
    """The line-scanner model of a reference image (what the renderer draws through and
    ``truth/*.model.json`` keeps)."""
    t = imager.timing
    return LineScanner(
        imager.name,
        imager.n_lines,
        LineTiming.constant(float(t.time(0.5)), t.period_s),
        camera,
        trajectory,
        first_sample=imager.first_sample,
        width=imager.width,
        first_line=int(first_line),
        light_path=PHYSICAL_LIGHT_PATH,
    )


def footprint_bounds(
    imagers: Sequence[ReferenceImager], h_range: tuple[float, float], margin_m: float
) -> tuple[float, float, float, float]:
    """``(west, south, east, north)`` of the images' corners and edge midpoints at the
    heights of ``h_range``, widened by ``margin_m``."""
    lons, lats = [], []
    for s in imagers:
        n_l, n_s = s.image_shape
        line = np.array([0, 0, n_l, n_l, n_l / 2, 0, n_l / 2, n_l], float)
        sample = np.array([0, n_s, 0, n_s, 0, n_s / 2, n_s, n_s / 2], float)
        for h in h_range:
            lon, lat, _ = s.image_to_ground(line, sample, np.full(line.size, h))
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


__all__ = [
    "PHYSICAL_LIGHT_PATH",
    "TRUTH_STEP_S",
    "World",
    "camera_geometry",
    "footprint_bounds",
    "full_imager",
    "image_span",
    "jittered",
    "model_camera",
    "scene_span",
    "truth_scanner",
    "truth_step",
    "truth_trajectory",
    "window",
    "world",
]
