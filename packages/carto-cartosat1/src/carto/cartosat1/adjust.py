"""Adjuster ``cartosat1-combined``: the tied-camera (combined) adjustment of a Cartosat-1 pair.

Fore and Aft sit on one rigid body; after the in-flight calibration of their relative
alignment (held in each camera's payload -> body alignment) the remaining error is the body's,
common to both. So the unknowns are **one** set of attitude corrections (bias + drift: roll,
pitch, yaw polynomials of order ``attitude_order`` in normalised time) for the pair, not one per
image. A conjugate point is seen about 52 s apart in Fore and Aft, so it constrains the drift
like two GCPs; a single GCP then fixes the absolute position (Radhadevi et al. 2010).

Modes:
    ``combined``: one shared set of body corrections (the default), plus the residual
        relative alignment of the second camera (what in-flight calibration leaves, a-priori
        ``sqrt(2) * RESIDUAL_ALIGNMENT_SIGMA_DEG`` per axis) as a weighted unknown.
    ``separate``: independent corrections per camera (the classical model, for comparison).
    ``calibration``: the shared body corrections plus the alignment of every camera but the
        first relative to the body, loosely weighted (in-flight calibration, needs many
        GCPs); the estimate is folded into the cameras' calibrated alignment of the returned
        sensors.

The attitude corrections are weighted by the ancillary data's accuracy
(:mod:`carto.cartosat1.constants`: bias 0.02 deg, drift 2e-5 deg/s per axis); options
``bias_sigma_deg``, ``drift_sigma_deg_s`` and ``alignment_sigma_deg`` (per camera) override
them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs

from carto.cartosat1 import constants
from carto.framework.adjust import (
    Adjuster,
    AdjustmentResult,
    AttitudePrior,
    Observations,
    adjust_bundle,
    line_scanner_corrections,
)
from carto.framework.errors import InputError
from carto.framework.linescan import LineScanner
from carto.framework.sensor import Sensor

MODES = ("combined", "separate", "calibration")


def prepare_sensors(
    sensors: Mapping[str, Sensor],
    mode: str = "combined",
    attitude_order: int = 1,
    estimate_position: bool = False,
    bias_sigma_deg: float = constants.ATTITUDE_BIAS_SIGMA_DEG,
    drift_sigma_deg_s: float = constants.ATTITUDE_DRIFT_SIGMA_DEG_S,
    alignment_sigma_deg: float = constants.RESIDUAL_ALIGNMENT_SIGMA_DEG,
) -> dict[str, LineScanner]:
    """The sensors with the free parameters of the chosen mode (see the module docstring)."""
    if mode not in MODES:
        raise InputError(
            f"cartosat1-combined: mode must be one of {', '.join(MODES)}, got {mode!r}"
        )
    prior = AttitudePrior.from_degrees(bias_sigma_deg, drift_sigma_deg_s)
    # the second camera's alignment relative to the first: residual (combined) or loose
    # (calibration: the default sigma of the camera model)
    relative = math.radians(alignment_sigma_deg) * math.sqrt(2.0)
    names = list(sensors)
    return {
        name: line_scanner_corrections(
            name,
            sensor,
            "cartosat1-combined",
            attitude_order=attitude_order,
            estimate_position=estimate_position,
            independent=mode == "separate",
            free_camera=mode in ("combined", "calibration") and name != names[0],
            prior=prior,
            alignment_sigma_rad=relative if mode == "combined" else None,
        )
        for name, sensor in sensors.items()
    }


class Cartosat1Adjuster(Adjuster):
    """Tied Fore/Aft adjustment with one set of body-attitude corrections (bias + drift)."""

    name = "cartosat1-combined"
    description = "Cartosat-1 tied-camera adjustment: one body attitude correction for Fore+Aft"

    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        mode = options.pop("mode", "combined")
        prepared = prepare_sensors(
            sensors,
            mode,
            int(options.pop("attitude_order", 1)),
            bool(options.pop("estimate_position", False)),
            float(options.pop("bias_sigma_deg", constants.ATTITUDE_BIAS_SIGMA_DEG)),
            float(options.pop("drift_sigma_deg_s", constants.ATTITUDE_DRIFT_SIGMA_DEG_S)),
            float(options.pop("alignment_sigma_deg", constants.RESIDUAL_ALIGNMENT_SIGMA_DEG)),
        )
        result = adjust_bundle(prepared, observations, **options)
        if mode == "calibration":
            calibrated = {
                n: attrs.evolve(s, camera=s.camera.with_calibrated_alignment())
                for n, s in result.sensors.items()
            }
            result = attrs.evolve(result, sensors=calibrated)
        return result
