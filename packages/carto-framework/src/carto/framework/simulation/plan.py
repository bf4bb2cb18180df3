"""What a scene preset decides and what the user chooses: the inputs of the scene simulator.

A plugin's scene preset (:class:`carto.framework.simulation.preset.ScenePreset`) describes an
acquisition as a :class:`ScenePlan`: orbit, trajectory segments (:class:`SegmentPlan`) with
their attitude laws, and the views (:class:`ViewPlan`) acquired during them. The user's
choices (``carto simulate`` options) are :class:`SimulationOptions`; the error sources of the
product are an :class:`ErrorModel`. :func:`carto.framework.simulation.simulate.simulate_scene`
renders a plan into a scene folder.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import attrs

from carto.framework.errors import InputError
from carto.framework.geometry import orbit
from carto.framework.products.ancillary import CameraSpec
from carto.framework.simulation.reference.attitude import AttitudeLaw

# ----------------------------------------------------------------------------- errors
LARGEST_ERROR_SIZE = {
    "deg": 2.0, "deg_s": 0.05, "m": 10_000.0, "px": 100.0, "ppm": 10_000.0, "s": 1.0,
}  # fmt: skip
"""The largest one-sigma size of an error source by its unit (``--error-size``): 2 deg of
attitude is 20 km on the ground from 618 km, 0.05 deg/s drifts that far in 40 s, 10 km of
ephemeris or GCP error and 100 px of image error move a point off a scene, 1 % of scale
(10^4 ppm) and 1 s of line timing are no product's. Beyond them a simulated product no
longer sees its target, and a typing slip (1e308) is refused instead of simulated."""


def largest_error_size(name: str) -> float:
    """:data:`LARGEST_ERROR_SIZE` of the error source ``name`` (by its unit suffix)."""
    for unit in sorted(LARGEST_ERROR_SIZE, key=len, reverse=True):
        if name.endswith("_" + unit):
            return LARGEST_ERROR_SIZE[unit]
    return math.inf


def check_error_size(name: str, value: float) -> None:
    """Refuse an override of one error size (``--error-size NAME=VALUE``): an unknown
    source, or a size that is not a number between 0 and :func:`largest_error_size`.

    Raises:
        InputError: naming the source and the value.
    """
    known = sorted(f.name for f in attrs.fields(ErrorModel) if f.name != "jitter_hz")
    if name not in known:
        raise InputError(f"unknown error source {name!r}; known: {', '.join(known)}")
    if not (math.isfinite(value) and value >= 0):
        raise InputError(f"error size {name}={value}: must be a number >= 0")
    most = largest_error_size(name)
    if value > most:
        raise InputError(
            f"error size {name}={value:g}: beyond {most:g}, the largest the simulator takes "
            f"(it must be between 0 and {most:g}: a product so far off no longer sees its "
            "target)"
        )


@attrs.frozen
class ErrorModel:
    """Error sources of a simulated product (design brief section 4); 0 switches one off.

    Attributes (one-sigma sizes; each drawn value is normal with that sigma unless said):
        ephemeris_bias_m: position bias per axis (along, across, radial), metres.
        attitude_bias_deg: attitude bias per axis (roll, pitch, yaw).
        attitude_drift_deg_s: attitude drift per axis.
        attitude_smooth_deg: amplitude of the smooth higher-order (tau^2, tau^3) attitude
            error over a segment (agile platforms).
        jitter_deg: amplitude of attitude jitter (sinusoids at ``jitter_hz``, about the body
            axes) in the true motion, which the 8 Hz attitude samples do not carry; each
            frequency's amplitude is drawn in 0.5-1 times this over ``sqrt(k + 1)`` (k: its
            rank in ``jitter_hz``).
        misalignment_deg: residual camera alignment error per axis (Fore/Aft relative).
        gcp_planimetric_m: GCP ground error, planimetric RMS (east and north each
            ``/sqrt(2)``).
        gcp_height_m: GCP height error.
        gcp_image_px: GCP image measurement error per image axis, pixels.

    Errors outside every adjuster's parameterisation (``--errors full``):
        attitude_wander_deg: low-frequency attitude measurement error per axis, three
            sinusoids of periods 15-90 s (amplitudes drawn in 0.5-1 times this): what a
            polynomial of low order cannot follow.
        focal_length_ppm: true focal length against the product's nominal one.
        detector_line_offset_px: along-track position of the detector line in the focal
            plane, in detector pitches.
        principal_point_px: across-track position of the optical axis on the line, pixels.
        ccd_rotation_deg: rotation of the detector line in the focal plane.
        line_time_offset_s: true line times against the product's (a clock offset).
        line_period_ppm: true line period against the product's.
        ephemeris_noise_m: white noise per axis on each ephemeris sample.
        checkpoint_image_px: checkpoint image measurement error per image axis, pixels.
    """

    ephemeris_bias_m: float = 0.0
    attitude_bias_deg: float = 0.0
    attitude_drift_deg_s: float = 0.0
    attitude_smooth_deg: float = 0.0
    jitter_deg: float = 0.0
    jitter_hz: tuple[float, ...] = (1.7, 4.3)
    misalignment_deg: float = 0.0
    gcp_planimetric_m: float = 0.0
    gcp_height_m: float = 0.0
    gcp_image_px: float = 0.0
    attitude_wander_deg: float = 0.0
    focal_length_ppm: float = 0.0
    detector_line_offset_px: float = 0.0
    principal_point_px: float = 0.0
    ccd_rotation_deg: float = 0.0
    line_time_offset_s: float = 0.0
    line_period_ppm: float = 0.0
    ephemeris_noise_m: float = 0.0
    checkpoint_image_px: float = 0.0

    @classmethod
    def realistic(cls, *, agile: bool = False) -> ErrorModel:
        """The sizes of the design brief, section 4 (``agile`` adds the Cartosat-2 terms):
        errors of the adjusters' own form, plus GCP measurement errors."""
        return cls(
            ephemeris_bias_m=15.0,
            attitude_bias_deg=0.02,
            attitude_drift_deg_s=2e-5,
            attitude_smooth_deg=0.002 if agile else 0.0,
            jitter_deg=2e-5 if agile else 0.0,
            misalignment_deg=0.002,
            gcp_planimetric_m=0.7,
            gcp_height_m=1.0,
            gcp_image_px=0.3,
        )

    @classmethod
    def full(cls, *, agile: bool = False) -> ErrorModel:
        """:meth:`realistic` plus the errors no adjuster's parameters have: attitude jitter of
        1-100 Hz (RMS about 0.25 px on the ground for Cartosat-1, 1 px for Cartosat-2), attitude
        wander of 0.0002 deg (about 2.4 m from 690 km), a 50 ppm focal length, half a pixel
        of detector-line and principal-point offsets, 10 arcsec of line rotation, 0.1 ms of
        clock offset, 10 ppm of line period, 0.3 m of ephemeris noise and 0.3 px of
        checkpoint measurement noise."""
        return attrs.evolve(
            cls.realistic(agile=agile),
            jitter_deg=1e-4 if agile else 6e-5,
            jitter_hz=(1.3, 4.7, 11.9, 29.0, 67.0, 97.0),
            attitude_wander_deg=2e-4,
            focal_length_ppm=50.0,
            detector_line_offset_px=0.5,
            principal_point_px=0.5,
            ccd_rotation_deg=10.0 / 3600.0,
            line_time_offset_s=1e-4,
            line_period_ppm=10.0,
            ephemeris_noise_m=0.3,
            checkpoint_image_px=0.3,
        )

    @classmethod
    def none(cls) -> ErrorModel:
        """No errors: the product carries the true values."""
        return cls()

    @classmethod
    def named(cls, profile: str, *, agile: bool = False) -> ErrorModel:
        """``"none"``, ``"realistic"`` or ``"full"``."""
        if profile == "none":
            return cls.none()
        if profile == "realistic":
            return cls.realistic(agile=agile)
        if profile == "full":
            return cls.full(agile=agile)
        from carto.framework.errors import InputError

        raise InputError(f"--errors must be 'none', 'realistic' or 'full', got {profile!r}")

    def as_dict(self) -> dict[str, Any]:
        return attrs.asdict(
            self, value_serializer=lambda _i, _a, v: list(v) if isinstance(v, tuple) else v
        )


# ----------------------------------------------------------------------------- the plan
@attrs.frozen
class ViewPlan:
    """One image of a segment.

    Attributes:
        name: image name (``"fore"``, ``"nadir"``, ``"swath2"`` ...).
        camera: nominal camera constants (as the product states them).
        n_lines_full: lines of the full acquisition (the window is cut from it).
        period_s: line period, seconds (constant over the image).
        centre_dt_s: time of the full image's middle line; None: the time at which the
            camera sees the view's target (found on the true trajectory).
        target: (lon_deg, lat_deg) the window is centred on; None: the scene target.
    """

    name: str
    camera: CameraSpec
    n_lines_full: int
    period_s: float
    centre_dt_s: float | None = None
    target: tuple[float, float] | None = None


@attrs.frozen
class SegmentPlan:
    """A trajectory segment (one ancillary file) and the views acquired during it.

    Attributes:
        name: segment name (file ``<name>.ancillary.json``).
        span_s: time range of the ancillary samples (s since the epoch).
        attitude: the true attitude law, in the reference geometry's terms
            (:mod:`carto.framework.simulation.reference.attitude`).
        views: the images of the segment.
    """

    name: str
    span_s: tuple[float, float]
    attitude: AttitudeLaw
    views: tuple[ViewPlan, ...]


@attrs.frozen
class ScenePlan:
    """Everything a preset decides; :func:`~carto.framework.simulation.simulate.simulate_scene`
    does the rest.

    Attributes:
        preset: preset name; platform: platform name (written in the products).
        epoch_utc: the epoch (the platform is over the target then).
        elements: orbit elements at the epoch.
        target: (lon_deg, lat_deg) the views are centred on.
        segments: trajectory segments.
        gsd_m: nominal ground sampling distance (sets texture and DEM postings).
        agile: the platform is agile (adds the agile error terms).
        default_terrain: terrain preset used when none is given.
        default_size: default window (width, height) in pixels.
        default_gcps, default_checkpoints: default numbers of control points.
        blur_sigma_px: optical blur (Gaussian sigma, in pixels of the nominal GSD) applied to
            the ground texture before rendering, i.e. the point spread function projected on
            the ground (blurring the raw image instead would mix the odd and even arrays,
            which see the ground at different times); 0 for none.
        noise_dn: read noise (one sigma) in digital numbers.
        control_min_views: control points are placed where at least this many images see
            them (None: all images; 1 for paint-brush swaths that only overlap pairwise).
    """

    preset: str
    platform: str
    epoch_utc: str
    elements: orbit.OrbitElements
    target: tuple[float, float]
    segments: tuple[SegmentPlan, ...]
    gsd_m: float
    agile: bool = False
    default_terrain: str = "hilly"
    default_size: tuple[int, int] = (2000, 2000)
    default_gcps: int = 1
    default_checkpoints: int = 50
    blur_sigma_px: float = 0.4
    noise_dn: float = 1.5
    control_min_views: int | None = None


@attrs.frozen
class SimulationOptions:
    """User choices for :func:`~carto.framework.simulation.simulate.simulate_scene`
    (``carto simulate`` options)."""

    seed: int = 0
    terrain: str | None = None
    dem_path: Path | None = None
    size: tuple[int, int] | None = None
    errors: str = "realistic"
    n_gcps: int | None = None
    n_checkpoints: int | None = None
    supersample: int = 2
    band_lines: int = 512
    band_samples: int = 2048
    """Image lines and samples rendered at a time, each block from the terrain and texture
    windows under it (memory and progress granularity; any block size gives the same
    scene)."""
    point_targets: bool = False
    error_sizes: tuple[tuple[str, float], ...] = ()
    """Overrides of single error sizes on top of ``errors``, e.g. ``(("attitude_bias_deg",
    0.05),)``; 0 switches a source off."""
    platform_seed: int | None = None
    """Seed of the platform's residual camera misalignment (a property of the satellite,
    the same in every scene it takes: scenes simulated with one ``platform_seed`` share it, as
    an in-flight calibration needs); None: drawn from ``seed`` with the other errors."""
