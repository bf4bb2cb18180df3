"""Adjuster ``cartosat1-combined``: the tied-camera (combined) adjustment of a Cartosat-1 pair.

Fore and Aft sit on one rigid body; after the in-flight calibration of their relative
alignment (held in each camera's payload -> body alignment) the remaining error is the body's,
common to both. So the unknowns are **one** set of attitude corrections (bias + drift: roll,
pitch, yaw polynomials of order ``attitude_order`` in normalised time) for the pair, not one per
image. A conjugate point is seen about 52 s apart in Fore and Aft, so it constrains the drift
like two GCPs; a single GCP then fixes the absolute position (Radhadevi et al. 2010).

Modes:
    ``combined``: one shared set of body corrections (the default), plus the residual
        alignment of the other camera relative to the reference camera (the first image's, or
        the calibration's; what in-flight calibration leaves, a-priori
        ``sqrt(2) * RESIDUAL_ALIGNMENT_SIGMA_DEG`` per axis) as a weighted unknown.
    ``separate``: independent corrections per camera (the classical model, for comparison).
    ``calibration``: the shared body corrections plus the alignment of every camera but the
        reference (the first image's) relative to the body, loosely weighted (in-flight
        calibration, needs many GCPs); the estimate is folded into the cameras' calibrated
        alignment of the returned sensors and returned as the product ``calibration``
        (``calibration.json``, see :mod:`carto.cartosat1.calibration`).

Option ``calibration`` (a ``calibration.json``, an adjustment folder holding one, or a list of
them, averaged) puts an earlier in-flight calibration of the same satellite into the cameras;
the tied adjustment then weights the residual alignment by that calibration's sigma.

The position bias is estimated too (``estimate_position``, default true): Fore and Aft see the
ground from different distances, so a position error is not one rotation for both.

Option ``image_trend_order`` (combined mode; default 2, 0: off) adds each image's own attitude
trend but the reference camera's: Legendre polynomials of orders 1..K of the image's time per
axis, a-priori ``image_trend_sigma_deg`` (default :data:`constants.IMAGE_TREND_SIGMA_DEG`)
(:mod:`carto.framework.adjustment.image_trends`). The images, 52 s apart, do not share attitude
motion of shorter periods; without these terms its across-track trend in the Fore image drove
the shared yaw drift and tilted the heights across the swath. The adjusted models carry the
trends: the result's sensors are the estimated ones (the trend applied to first order), and
:func:`carto.framework.adjustment.image_trends.fold_image_trends` (what ``carto adjust`` does
before writing them) folds each trend into its image's attitude polynomials, under image-own
parameter names.

Option ``relative_calibration`` (combined mode; default ``["scale"]``; a list as for
``self_calibration``, empty: off) adds interior corrections to the other cameras only, relative
to the reference camera: tie points see the difference of the Fore and Aft focal lengths (an
across-track parallax growing across the swath; 50 ppm each puts 0.4 px at the swath's edges),
not their common error. Without it the tied model bent the pitch and the position (along-track
bias 50-110 m, 3-7 a-priori sigmas) to fit that parallax (``--errors full``, plains 2 and
hilly 0 of ``benchmarks/cartosat1_accuracy.py``).

Option ``jitter_hz`` (``"auto"``: frequencies found in the residuals, or a list of Hz; off by
default) adds periodic attitude jitter terms (:mod:`carto.framework.adjustment.jitter`, a-priori
RMS amplitude ``jitter_amplitude_deg``, default :data:`JITTER_AMPLITUDE_DEG`).

Option ``self_calibration`` (a list of ``scale``, ``line_offset``, ``centre_offset``, or a
mapping of them to a-priori sigmas; off by default: one scene with one GCP cannot separate a
camera's detector-line offset from its pitch alignment) adds interior corrections per camera
(:func:`carto.framework.adjustment.priors.with_self_calibration`).

The corrections are weighted by the ancillary data's accuracy
(:mod:`carto.cartosat1.constants`: attitude bias 0.02 deg, drift 2e-5 deg/s, position 15 m per
axis); options ``bias_sigma_deg``, ``drift_sigma_deg_s``, ``ephemeris_sigma_m`` and
``alignment_sigma_deg`` (per camera) override them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs

from carto.cartosat1 import constants
from carto.cartosat1.calibration import AlignmentCalibration, load_calibration
from carto.framework.sdk.adjusters import (
    Adjuster,
    AdjustmentResult,
    AncillaryPrior,
    BundleSettings,
    Observations,
    adjust_bundle,
    adjust_with_jitter,
    line_scanner_corrections,
    self_calibration_field,
    trend_document,
    with_image_trends,
    with_self_calibration,
)
from carto.framework.sdk.common import (
    InputError,
    UsageError,
    choice,
    flag,
    integer,
    optional,
    positive_field,
)
from carto.framework.sdk.sensors import LineScanner, Sensor

MODES = ("combined", "separate", "calibration")


def _check_one_body(sensors: Mapping[str, LineScanner]) -> None:
    """Refuse a tied adjustment of images whose trajectories do not share their correction
    parameters: an adjusted model whose image trend was folded in carries its own
    (``aft.trajectory.``), and re-adjusting it with the tied model silently adjusted that
    image alone, on its priors (an outside probe: DEM NMAD 1.47 m against 0.17 m, issue 31)."""
    prefixes = {name: s.trajectory.prefix for name, s in sensors.items()}
    if len(set(prefixes.values())) > 1:
        own = ", ".join(f"{n}: {p!r}" for n, p in sorted(prefixes.items()))
        raise InputError(
            "cartosat1-combined: the images' trajectories are not one body's (their "
            f"correction parameters are named {own}: models adjusted before, with their "
            "image trends folded in); adjust the scene from its ancillary data, or use "
            "--mode separate"
        )


def prepare_sensors(
    sensors: Mapping[str, Sensor],
    mode: str = "combined",
    attitude_order: int = 1,
    estimate_position: bool = True,
    bias_sigma_deg: float = constants.ATTITUDE_BIAS_SIGMA_DEG,
    drift_sigma_deg_s: float = constants.ATTITUDE_DRIFT_SIGMA_DEG_S,
    alignment_sigma_deg: float = constants.RESIDUAL_ALIGNMENT_SIGMA_DEG,
    ephemeris_sigma_m: float = constants.EPHEMERIS_BIAS_SIGMA_M,
    calibration: AlignmentCalibration | None = None,
) -> dict[str, LineScanner]:
    """The sensors with the free parameters of the chosen mode (see the module docstring).

    With a ``calibration`` (:mod:`carto.cartosat1.calibration`) the cameras get its
    alignments, its reference camera stays fixed and, in ``combined`` mode, the others'
    residual alignments are weighted by its sigmas (instead of ``alignment_sigma_deg``)."""
    if mode not in MODES:
        raise InputError(
            f"cartosat1-combined: mode must be one of {', '.join(MODES)}, got {mode!r}"
        )
    prior = AncillaryPrior.from_degrees(
        bias_sigma_deg, drift_sigma_deg_s, ephemeris_bias_m=ephemeris_sigma_m
    )
    for name, sensor in sensors.items():
        if not isinstance(sensor, LineScanner):
            raise InputError(
                f"cartosat1-combined adjusts rigorous line scanners; image {name!r} is "
                f"{type(sensor).__name__} (use the rpc-bias adjuster)"
            )
    if calibration is not None and mode == "separate":
        raise InputError(
            "cartosat1-combined: a calibration ties the cameras; mode separate gives each its "
            "own corrections, so it would have no effect (use mode combined)"
        )
    if calibration is not None and mode == "calibration":
        raise InputError(
            "cartosat1-combined: mode calibration estimates the alignment afresh; combine "
            "calibrations of several scenes with --calibration A --calibration B instead"
        )
    if calibration is not None:
        sensors = calibration.apply(sensors)
    if mode != "separate":
        _check_one_body(sensors)
    reference = reference_camera(sensors, calibration)
    # the other cameras' alignment relative to the reference: residual (combined) or loose
    # (calibration: the default sigma of the camera model)
    relative = math.radians(alignment_sigma_deg) * math.sqrt(2.0)
    prepared = {
        name: line_scanner_corrections(
            name,
            sensor,
            "cartosat1-combined",
            attitude_order=attitude_order,
            estimate_position=estimate_position,
            independent=mode == "separate",
            free_camera=mode in ("combined", "calibration")
            and isinstance(sensor, LineScanner)
            and sensor.camera.name != reference,
            prior=prior,
            alignment_sigma_rad=relative if mode == "combined" else None,
        )
        for name, sensor in sensors.items()
    }
    if calibration is not None and mode == "combined":
        sigmas = calibration.alignment_sigmas()
        prepared = {
            n: attrs.evolve(
                s,
                camera=s.camera.with_parameters(
                    sigmas={p.name: sigmas[p.name] for p in s.camera.parameters if p.name in sigmas}
                ),
            )
            for n, s in prepared.items()
        }
    return prepared


def reference_camera(
    sensors: Mapping[str, Sensor], calibration: AlignmentCalibration | None = None
) -> str | None:
    """The camera the others' residual alignment (and image trends) are relative to: the
    calibration's, else the first image's."""
    if calibration is not None:
        return calibration.reference_camera
    first = next(iter(sensors.values()), None)
    return first.camera.name if isinstance(first, LineScanner) else None


JITTER_AMPLITUDE_DEG = 6e-5
"""A-priori RMS amplitude of Cartosat-1 attitude jitter per axis and frequency (a few tenths of
a pixel on the ground)."""


@attrs.frozen
class Cartosat1Settings(BundleSettings):
    """The options of ``cartosat1-combined`` (see the module docstring) and the bundle's;
    ``None``: the mode's default."""

    mode: str = attrs.field(default="combined", converter=choice("mode", MODES))
    calibration: Any = attrs.field(default=None)
    self_calibration: tuple[str, ...] | Mapping[str, float] | None = self_calibration_field(
        "self_calibration"
    )
    relative_calibration: tuple[str, ...] | Mapping[str, float] | None = self_calibration_field(
        "relative_calibration"
    )
    image_trend_order: int | None = attrs.field(
        default=None, converter=optional(integer("image_trend_order", 0, 2))
    )
    image_trend_sigma_deg: float = positive_field(
        "image_trend_sigma_deg", constants.IMAGE_TREND_SIGMA_DEG
    )
    attitude_order: int = attrs.field(default=1, converter=integer("attitude_order", 0, 3))
    estimate_position: bool = attrs.field(default=True, converter=flag("estimate_position"))
    bias_sigma_deg: float = positive_field("bias_sigma_deg", constants.ATTITUDE_BIAS_SIGMA_DEG)
    drift_sigma_deg_s: float = positive_field(
        "drift_sigma_deg_s", constants.ATTITUDE_DRIFT_SIGMA_DEG_S
    )
    alignment_sigma_deg: float = positive_field(
        "alignment_sigma_deg", constants.RESIDUAL_ALIGNMENT_SIGMA_DEG
    )
    ephemeris_sigma_m: float = positive_field("ephemeris_sigma_m", constants.EPHEMERIS_BIAS_SIGMA_M)
    jitter_hz: Any = attrs.field(default=None)
    jitter_amplitude_deg: float = positive_field("jitter_amplitude_deg", JITTER_AMPLITUDE_DEG)

    def __attrs_post_init__(self) -> None:
        if self.image_trend_order and self.mode != "combined":
            raise UsageError(
                "option image_trend_order: image trends are relative to the reference camera's "
                f"image in a tied adjustment (mode combined); mode {self.mode} takes 0"
            )

    @property
    def trend_order(self) -> int:
        """The image trends' order: the option, else 2 in combined mode, 0 otherwise."""
        if self.image_trend_order is not None:
            return self.image_trend_order
        return 2 if self.mode == "combined" else 0

    @property
    def relative(self) -> Any:
        """The relative calibration: the option, else the scale in combined mode."""
        if self.relative_calibration is not None:
            return self.relative_calibration
        return ["scale"] if self.mode == "combined" else []


class Cartosat1Adjuster(Adjuster):
    """Tied Fore/Aft adjustment: one set of body corrections (attitude bias + drift, position
    bias) for both cameras."""

    name = "cartosat1-combined"
    description = "Cartosat-1 tied-camera adjustment: one body correction for Fore+Aft"
    Settings = Cartosat1Settings
    warm_start = True

    def adjust(
        self,
        sensors: Mapping[str, Sensor],
        observations: Observations,
        *,
        start: AdjustmentResult | None = None,
        **options: Any,
    ) -> AdjustmentResult:
        s = self.settings(options)
        calibration = load_calibration(s.calibration) if s.calibration is not None else None
        prepared = prepare_sensors(
            sensors,
            s.mode,
            s.attitude_order,
            s.estimate_position,
            s.bias_sigma_deg,
            s.drift_sigma_deg_s,
            s.alignment_sigma_deg,
            s.ephemeris_sigma_m,
            calibration,
        )
        prepared = with_self_calibration(prepared, s.self_calibration, self.name)
        reference = reference_camera(prepared, calibration)
        others = [
            n
            for n, sensor in prepared.items()
            if isinstance(sensor, LineScanner) and sensor.camera.name != reference
        ]
        if s.relative:
            prepared |= with_self_calibration(
                {n: prepared[n] for n in others}, s.relative, self.name
            )
        trend_sigma = math.radians(s.image_trend_sigma_deg)
        prepared = with_image_trends(prepared, s.trend_order, trend_sigma, images=others)
        if s.jitter_hz:
            amplitude = math.radians(s.jitter_amplitude_deg)
            result = adjust_with_jitter(
                prepared, observations, s.jitter_hz, amplitude, start=start, **s.bundle_options()
            )
        else:
            result = adjust_bundle(prepared, observations, start=start, **s.bundle_options())
        trends = trend_document(result.sensors, list(result.parameters), result.sigmas)
        if trends is not None:
            result = attrs.evolve(result, products={**result.products, "image_trends": trends})
        if s.mode == "calibration":
            calibrated = {
                n: attrs.evolve(sensor, camera=sensor.camera.with_calibrated_alignment())
                for n, sensor in result.sensors.items()
            }
            result = attrs.evolve(result, sensors=calibrated)
            cal = AlignmentCalibration.from_result(result, platform="Cartosat-1")
            result = attrs.evolve(result, products={"calibration": cal.as_dict()})
        return result
