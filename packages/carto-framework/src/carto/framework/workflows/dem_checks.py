"""The checks a DEM run's result passes before it is delivered (``--allow-poor`` writes it
anyway, with the reasons in ``report.json`` ``warnings``): enough of its nodes matched
(:func:`poor_dem`), and the terrain its starting DEM says it is (:func:`departs_from_start`).
Each threshold says why it is where it is."""

from __future__ import annotations

from typing import Any

import numpy as np

from carto.framework.errors import InputError
from carto.framework.raster.dem import DEM

MIN_MATCHED_FRACTION = 0.05
"""A DEM run that measured less than this share of the nodes fails (``--allow-poor`` writes
it): the images did not match (no texture, no overlap, clouds, wrong models)."""


def poor_dem(product: Any) -> list[str]:
    """Why a DEM is too poor to deliver (empty when it is not)."""
    matched = product.matched_fraction
    share = product.measured_fraction if matched is None else matched
    if not np.isfinite(share):
        share = 0.0
    if share < MIN_MATCHED_FRACTION:
        what = "matched" if matched is not None else "measured"
        return [
            f"only {100 * share:.1f} % of the DEM nodes were {what} (< "
            f"{100 * MIN_MATCHED_FRACTION:g} %): the images did not match (no texture, "
            "clouds, no overlap or wrong models?)"
        ]
    return []


DEPARTURE_NMAD_M = 30.0
"""A DEM whose difference to its starting DEM has an NMAD beyond this fails (``--allow-poor``
writes it): an SRTM-like start is 3-4 m NMAD off the terrain (the simulated scenes) and the
DEMs of the benchmarks agree with it to about that; a pair of two different scenes gave a
DEM of NMAD 74 m against its truth, matched at 31-45 % of the nodes (issue 31)."""
DEPARTURE_MEDIAN_M = 50.0
"""... or whose median difference is beyond this (a start's bias: up to 11 m on the
simulated scenes, 4 m on Ventoux; a geoid grid taken as the start: 575 m)."""


def departs_from_start(dem: DEM, start: DEM) -> list[str]:
    """Why a DEM is not the terrain its starting DEM says it is (empty when it is, or when
    the start is a constant height, which says nothing of the relief)."""
    from carto.framework.evaluation.dem_accuracy import dem_accuracy

    if not np.nanstd(start.heights) > 0 or not np.isfinite(dem.heights).any():
        return []
    try:
        diff = dem_accuracy(dem, start)
    except InputError:  # no common valid node: the coverage checks say so
        return []
    nmad, median = float(diff["nmad_m"]), float(diff["median_m"])
    if nmad > DEPARTURE_NMAD_M or abs(median) > DEPARTURE_MEDIAN_M:
        return [
            f"the DEM departs from its starting DEM far beyond both DEMs' accuracy (NMAD "
            f"{nmad:.1f} m, median {median:+.1f} m; at most {DEPARTURE_NMAD_M:g} m and "
            f"{DEPARTURE_MEDIAN_M:g} m): images of two places, a wrong model or a wrong "
            "starting DEM?"
        ]
    return []
