"""Adjuster ``cartosat2-bba``: bundle block adjustment of agile Cartosat-2 images.

All images of a block (a fore/nadir/aft triplet, the swaths of a paint-brush set) are adjusted
together (Radhadevi et al. 2010, eq. 5-6): the unknowns are per-image corrections to the
imaging-event parameters (attitude polynomials of order 0-3 in normalised time, optionally a
position bias) and the ground coordinates of every tie point; GCPs and the a-priori values of
the parameters are weighted observations. The shared engine
(:func:`carto.framework.adjustment.bundle.adjust_bundle`) eliminates the 3 x 3 point blocks (Schur
complement), so the cost grows linearly with the number of tie points.

The default attitude order is 2 (bias, drift and a quadratic term per image): the step-and-stare
attitude of an agile view, with its jitter, leaves systematic height errors of several metres
after a linear correction on a 2000-line window (measured with ``benchmarks/bba_scaling.py``),
which the quadratic term removes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from carto.cartosat2 import constants
from carto.framework.adjustment.base import Adjuster, AdjustmentResult
from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.observations import Observations
from carto.framework.adjustment.priors import AncillaryPrior, line_scanner_corrections
from carto.framework.geometry.linescan import LineScanner
from carto.framework.geometry.sensor import Sensor

PRIOR = AncillaryPrior.from_degrees(
    constants.ATTITUDE_BIAS_SIGMA_DEG,
    constants.ATTITUDE_DRIFT_SIGMA_DEG_S,
    constants.ATTITUDE_SMOOTH_SIGMA_DEG,
)
"""A-priori attitude accuracy of Cartosat-2 products (bias, drift, smooth variation)."""


def prepare_sensors(
    sensors: Mapping[str, Sensor],
    attitude_order: int = 2,
    estimate_position: bool = False,
    prior: AncillaryPrior | None = None,
) -> dict[str, LineScanner]:
    """Independent corrections per image (parameter names prefixed by the image name),
    weighted by ``prior`` (default: the Cartosat-2 ancillary accuracy, :data:`PRIOR`)."""
    return {
        name: line_scanner_corrections(
            name,
            sensor,
            "cartosat2-bba",
            attitude_order=attitude_order,
            estimate_position=estimate_position,
            independent=True,
            prior=PRIOR if prior is None else prior,
        )
        for name, sensor in sensors.items()
    }


class Cartosat2BlockAdjuster(Adjuster):
    """Bundle block adjustment of agile views: per-image attitude polynomials, tie points."""

    name = "cartosat2-bba"
    description = "Cartosat-2 bundle block adjustment: per-image attitude polynomials, ties"

    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        prior = AncillaryPrior.from_degrees(
            float(options.pop("bias_sigma_deg", constants.ATTITUDE_BIAS_SIGMA_DEG)),
            float(options.pop("drift_sigma_deg_s", constants.ATTITUDE_DRIFT_SIGMA_DEG_S)),
            float(options.pop("smooth_sigma_deg", constants.ATTITUDE_SMOOTH_SIGMA_DEG)),
        )
        prepared = prepare_sensors(
            sensors,
            int(options.pop("attitude_order", 2)),
            bool(options.pop("estimate_position", False)),
            prior,
        )
        options.pop("mode", None)
        return adjust_bundle(prepared, observations, **options)
