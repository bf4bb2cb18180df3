"""For adjuster plugins: the adjuster base and its result, the bundle adjustment (with
jitter terms), its observations, the a-priori weights of line-scanner corrections and the
per-image attitude trends (see :mod:`carto.framework.sdk`)."""

from carto.framework.adjustment.adjuster_settings import BundleSettings
from carto.framework.adjustment.base import Adjuster, AdjustmentResult
from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.image_trends import trend_document, with_image_trends
from carto.framework.adjustment.jitter import adjust_with_jitter
from carto.framework.adjustment.observations import Observations
from carto.framework.adjustment.priors import (
    SELF_CALIBRATION_SIGMAS,
    AncillaryPrior,
    line_scanner_corrections,
    with_self_calibration,
)

__all__ = [
    "SELF_CALIBRATION_SIGMAS",
    "Adjuster",
    "AdjustmentResult",
    "AncillaryPrior",
    "BundleSettings",
    "Observations",
    "adjust_bundle",
    "adjust_with_jitter",
    "line_scanner_corrections",
    "trend_document",
    "with_image_trends",
    "with_self_calibration",
]
