"""For matcher plugins: the matcher base, its settings and results, the semi-global matcher
and the precision helpers of dense matching (see :mod:`carto.framework.sdk`)."""

from carto.framework.matching.base import (
    DenseSettings,
    Matcher,
    Matches,
    MatchSettings,
    OffsetField,
    rows_of,
)
from carto.framework.matching.precision import (
    levels_for_reach,
    limit_along_base,
    offset_sigma_px,
    refine_along_base,
)
from carto.framework.matching.sgm_matcher import SGMMatcher

__all__ = [
    "DenseSettings",
    "MatchSettings",
    "Matcher",
    "Matches",
    "OffsetField",
    "SGMMatcher",
    "levels_for_reach",
    "limit_along_base",
    "offset_sigma_px",
    "refine_along_base",
    "rows_of",
]
