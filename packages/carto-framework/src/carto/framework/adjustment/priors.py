"""A-priori weights of line-scanner corrections from the ancillary data's accuracy
(:class:`AncillaryPrior`, :func:`line_scanner_corrections`) and the optional self-calibration
of their cameras (:func:`with_self_calibration`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs

from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.sensor import Sensor


@attrs.frozen
class AncillaryPrior:
    """A-priori accuracy of a platform's ancillary data (attitude and ephemeris), in physical
    units: the weights with which their corrections enter an adjustment (one sigma each).

    Attributes:
        bias_rad: constant attitude error per axis (the ``c0`` corrections).
        drift_rad_s: attitude drift per axis; the ``c1`` coefficient of normalised time gets
            ``drift_rad_s * t_half_s`` of the trajectory.
        higher_rad: amplitude of smooth higher-order variation over the segment (``c2``,
            ``c3``).
        alignment_rad: residual camera alignment error per axis, per camera (after in-flight
            calibration); used for camera alignments an adjuster leaves free.
        ephemeris_bias_m: constant position error per axis (the position ``c0`` corrections,
            when an adjuster estimates them).
    """

    bias_rad: float
    drift_rad_s: float
    higher_rad: float = 1e-5
    alignment_rad: float = 1e-4
    ephemeris_bias_m: float = 30.0

    @classmethod
    def from_degrees(
        cls,
        bias_deg: float,
        drift_deg_s: float,
        higher_deg: float = math.degrees(1e-5),
        alignment_deg: float = math.degrees(1e-4),
        ephemeris_bias_m: float = 30.0,
    ) -> AncillaryPrior:
        r = math.radians
        return cls(r(bias_deg), r(drift_deg_s), r(higher_deg), r(alignment_deg), ephemeris_bias_m)

    def __attrs_post_init__(self) -> None:
        for name in ("bias_rad", "drift_rad_s", "higher_rad", "alignment_rad", "ephemeris_bias_m"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise InputError(f"ancillary prior: {name} must be > 0, got {value}")


def line_scanner_corrections(
    name: str,
    sensor: Sensor,
    adjuster: str,
    *,
    attitude_order: int,
    estimate_position: bool,
    independent: bool,
    free_camera: bool = False,
    prior: AncillaryPrior | None = None,
    alignment_sigma_rad: float | None = None,
) -> Sensor:
    """A line scanner set up for an adjuster: attitude corrections of ``attitude_order``,
    optional position bias, parameter names prefixed by the image ``name`` when
    ``independent`` (otherwise sensors on one trajectory share them), camera alignment free
    or fixed. ``prior`` sets the a-priori sigmas of the attitude and position corrections
    and of a free camera alignment (``alignment_sigma_rad`` overrides the latter); without it
    the trajectory's and camera's defaults stay. Other sensors raise :class:`InputError` naming
    ``adjuster``."""
    from carto.framework.geometry.linescan.scanner import LineScanner

    if not 0 <= attitude_order <= 3:
        raise InputError(f"{adjuster}: attitude_order must be 0..3, got {attitude_order}")
    if not isinstance(sensor, LineScanner):
        raise InputError(
            f"{adjuster} adjusts rigorous line scanners; image {name!r} is "
            f"{type(sensor).__name__} (use the rpc-bias adjuster)"
        )
    traj = sensor.trajectory.with_correction_orders(
        attitude=attitude_order, position=0 if estimate_position else -1
    )
    if independent:
        traj = traj.with_prefix(f"{name}.trajectory.")
    if prior is not None:
        by_power = (prior.bias_rad, prior.drift_rad_s * traj.t_half_s, prior.higher_rad)
        att = f"{traj.prefix}attitude."
        pos = f"{traj.prefix}position."
        traj = traj.with_parameters(
            sigmas={
                p.name: by_power[min(int(p.name.rpartition(".c")[2]), 2)]
                for p in traj.parameters
                if p.name.startswith(att)
            }
            | {p.name: prior.ephemeris_bias_m for p in traj.parameters if p.name.startswith(pos)}
        )
    cam = sensor.camera.with_parameters(
        free={p.name: free_camera for p in sensor.camera.parameters}
    )
    if free_camera and (alignment_sigma_rad is not None or prior is not None):
        sigma = alignment_sigma_rad if alignment_sigma_rad is not None else prior.alignment_rad
        cam = cam.with_parameters(sigmas={p.name: sigma for p in cam.parameters})
    return attrs.evolve(sensor, trajectory=traj, camera=cam)


SELF_CALIBRATION_SIGMAS = {"scale": 1e-4, "line_offset": 1e-5, "centre_offset": 1e-5}
"""Default a-priori sigmas of the interior (self-calibration) corrections of a line scanner's
camera: 100 ppm of focal length, 1e-5 rad (about 3 Cartosat-1 pixels) of detector-line and
principal-point offset
(:meth:`~carto.framework.geometry.camera.Camera.with_interior_parameters`)."""


def with_self_calibration(
    sensors: Mapping[str, LineScanner], kinds: Any, adjuster: str
) -> dict[str, LineScanner]:
    """The sensors with free interior corrections of their cameras: ``kinds`` is a list of
    names of :data:`SELF_CALIBRATION_SIGMAS` (their default sigmas) or a mapping name ->
    sigma; None or empty: the sensors unchanged. Cameras shared by several images share the
    corrections (their parameter names are the camera's)."""
    if not kinds:
        return dict(sensors)
    if isinstance(kinds, str):
        kinds = [k.strip() for k in kinds.split(",") if k.strip()]
    if isinstance(kinds, Mapping):
        sigmas = {str(k): float(v) for k, v in kinds.items()}
    else:
        sigmas = {}
        for k in kinds:
            if k not in SELF_CALIBRATION_SIGMAS:
                raise InputError(
                    f"{adjuster}: unknown self-calibration {k!r}; known: "
                    f"{', '.join(SELF_CALIBRATION_SIGMAS)}"
                )
            sigmas[k] = SELF_CALIBRATION_SIGMAS[k]
    return {
        name: attrs.evolve(s, camera=s.camera.with_interior_parameters(sigmas))
        for name, s in sensors.items()
    }
