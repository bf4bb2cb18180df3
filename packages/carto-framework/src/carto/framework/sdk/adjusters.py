"""For adjuster plugins: the adjuster base and its result, the bundle adjustment (with
jitter terms), its observations, the a-priori weights of line-scanner corrections and the
per-image attitude trends (see :mod:`carto.framework.sdk`)."""

from collections.abc import Mapping
from typing import Any

import attrs

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
from carto.framework.sdk.common import positive
from carto.framework.settings import names, optional

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
    "self_calibration_field",
    "trend_document",
    "with_image_trends",
    "with_self_calibration",
]


def self_calibration_field(name: str) -> Any:
    """A field of an adjuster's settings: option ``name``, the interior corrections to
    estimate (:func:`with_self_calibration`): a list of :data:`SELF_CALIBRATION_SIGMAS` names
    (or text separated by commas) or a mapping name -> a-priori sigma; None (the default):
    the adjuster's choice."""
    as_names = optional(names(name, tuple(SELF_CALIBRATION_SIGMAS)))

    def convert(value: Any) -> Any:
        if isinstance(value, Mapping):
            sigma = positive(f"{name} sigma")
            return {str(k): sigma(v) for k, v in value.items()}
        return as_names(value)

    return attrs.field(default=None, converter=convert)
