"""Adjuster ``cartosat1-combined``: the tied-camera (combined) adjustment of a Cartosat-1 pair.

Fore and Aft sit on one rigid body; after the in-flight calibration of their relative
alignment (held in each camera's payload -> body alignment) the remaining error is the body's,
common to both. So the unknowns are **one** set of attitude corrections (bias + drift: roll,
pitch, yaw polynomials of order ``attitude_order`` in normalised time) for the pair, not one per
image. A conjugate point is seen about 52 s apart in Fore and Aft, so it constrains the drift
like two GCPs; a single GCP then fixes the absolute position (Radhadevi et al. 2010).

Modes:
    ``combined``: one shared set of body corrections (the default).
    ``separate``: independent corrections per camera (the classical model, for comparison).
    ``calibration``: the shared body corrections plus the alignment of every camera but the
        first relative to the body (in-flight calibration, needs many GCPs); the estimate is
        folded into the cameras' calibrated alignment of the returned sensors.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import attrs

from carto.framework.adjust import (
    Adjuster,
    AdjustmentResult,
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
) -> dict[str, LineScanner]:
    """The sensors with the free parameters of the chosen mode (see the module docstring)."""
    if mode not in MODES:
        raise InputError(
            f"cartosat1-combined: mode must be one of {', '.join(MODES)}, got {mode!r}"
        )
    names = list(sensors)
    return {
        name: line_scanner_corrections(
            name,
            sensor,
            "cartosat1-combined",
            attitude_order=attitude_order,
            estimate_position=estimate_position,
            independent=mode == "separate",
            free_camera=mode == "calibration" and name != names[0],
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
        )
        result = adjust_bundle(prepared, observations, **options)
        if mode == "calibration":
            calibrated = {
                n: attrs.evolve(s, camera=s.camera.with_calibrated_alignment())
                for n, s in result.sensors.items()
            }
            result = attrs.evolve(result, sensors=calibrated)
        return result
