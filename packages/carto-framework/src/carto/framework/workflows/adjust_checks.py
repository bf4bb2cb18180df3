"""The checks an adjustment passes before its models are delivered (``--allow-poor`` writes
them anyway, with the reasons in ``report.json`` ``warnings``): GCP heights that are this
terrain's (:func:`gcps_off_the_dem`, before adjusting), few GCPs rejected
(:func:`gcps_rejected`), residuals that fit the measurement sigmas and tie points found
(:func:`poor_adjustment`), and corrections within reach of the products' a-priori accuracy
(:func:`corrections_beyond_priors`). Each threshold says why it is where it is."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.files.control_table import ground_points
from carto.framework.raster.dem_measures import is_flat

POOR_SIGMA0 = 5.0
"""An adjustment whose sigma0 exceeds this fails (``--allow-poor`` writes it): its residuals
are several times the measurement sigmas, a corrupt input or a model that does not fit. Real
blocks with unmodelled jitter reach 1.5-3."""


GCP_DEM_LIMIT_M = 100.0
"""A GCP whose height is more than this off the DEM at its place is refused: SRTM-like
DEMs are off by metres, tens near cliffs, never hundreds; heights in feet (x 3.28: 1289 for
393 m), another datum or another place's point are. Left unchecked, GCP heights in feet put
the checkpoints 1.2 km off with no warning (issue 31)."""


def gcps_off_the_dem(gcps: Mapping[str, NDArray], dem: Any) -> list[str]:
    """Why the GCPs' heights are not this terrain's (empty when they are, or when there is no
    DEM of the terrain to tell): every GCP more than :data:`GCP_DEM_LIMIT_M` off the DEM."""
    if dem is None or is_flat(dem):  # none, or a flat height (above the ellipsoid or geoid)
        return []
    ids, lon, lat, h = ground_points(gcps)
    terrain = dem.height(lon, lat)
    signed = h - terrain
    off = np.abs(signed)
    bad = np.flatnonzero(np.nan_to_num(off, nan=0.0) > GCP_DEM_LIMIT_M)
    if bad.size == 0:
        return _gcps_shifted_from_the_dem(signed)
    worst = bad[np.argmax(off[bad])]
    return [
        f"{bad.size} of {ids.size} GCPs are more than {GCP_DEM_LIMIT_M:g} m off the DEM in "
        f"height (GCP {str(ids[worst])!r}: {h[worst]:.1f} m where the DEM says "
        f"{terrain[worst]:.1f} m; heights in feet? another vertical datum? another place?)"
    ]


GCP_DEM_MEDIAN_LIMIT_M = 25.0
"""... and two or more GCPs whose heights are, on median, more than this above or below the
DEM: SRTM-like DEMs are biased by metres (up to 11 m on the simulated scenes, 4 m at
Ventoux); heights above the geoid given as ellipsoidal are tens of metres off in most places
(38 m on a simulated scene, where checkpoints then came out 38 m off with exit 0: an outside
probe, issue 31)."""


def _gcps_shifted_from_the_dem(signed: NDArray) -> list[str]:
    """Why the GCPs' heights are shifted from the DEM's as a whole (see
    :data:`GCP_DEM_MEDIAN_LIMIT_M`)."""
    signed = signed[np.isfinite(signed)]
    if signed.size < 2 or abs(float(np.median(signed))) <= GCP_DEM_MEDIAN_LIMIT_M:
        return []
    median = float(np.median(signed))
    return [
        f"the GCPs' heights are {abs(median):.1f} m {'above' if median > 0 else 'below'} the "
        f"DEM on median ({signed.size} GCPs; at most {GCP_DEM_MEDIAN_LIMIT_M:g} m): heights "
        "above the geoid given as ellipsoidal, or another vertical datum?"
    ]


MAX_REJECTED_GCP_SHARE = 0.5
"""An adjustment that rejects this share (or more) of three or more GCPs fails: a wrong GCP
among several is an outlier, half of them wrong is a wrong table (heights in feet flagged 2
of 4 GCPs, and the adjustment went ahead with sigma0 2.6, issue 31)."""


def gcps_rejected(ids: list[str], rejected: set[str]) -> list[str]:
    """Why the GCP table is not this block's (empty when few of its GCPs were rejected)."""
    out = [i for i in ids if i in rejected]
    if len(ids) >= 3 and len(out) >= MAX_REJECTED_GCP_SHARE * len(ids):
        return [
            f"{len(out)} of {len(ids)} GCPs were rejected as outliers ({', '.join(out[:5])}"
            f"{', ...' if len(out) > 5 else ''}): the table does not fit the images (another "
            "scene, units, datum?)"
        ]
    return []


def poor_adjustment(sigma0: float, ties: str, n_ties: int, n_images: int) -> list[str]:
    """Why an adjustment is too poor to deliver (empty when it is not)."""
    reasons = []
    if ties == "auto" and n_images > 1 and n_ties == 0:
        reasons.append(
            "no tie point was found between the images (do they overlap? are the models and "
            "the DEM right?)"
        )
    if math.isfinite(sigma0) and sigma0 > POOR_SIGMA0:
        reasons.append(
            f"sigma0 {sigma0:.3g} is far above 1 (> {POOR_SIGMA0:g}): the measurements do "
            "not fit the models (wrong control, a corrupt model or image?)"
        )
    return reasons


PRIOR_LIMIT_SIGMAS = 5.0
"""An adjustment that corrects a parameter by more than this many of its a-priori sigmas
fails: the a-priori sigmas are the products' stated accuracy, and a correction far beyond
it says the control moved the block where its products cannot be (GCPs of another scene or
datum) or that the stated accuracy is wrong. Five sigmas happen once in two million
parameters when the sigmas are right. Measured (``benchmarks/results/prior_corrections.json``):
true control moves the simulated presets' parameters by at most 2.8 sigmas, ``--errors
full`` included (our simulator with its own a-priori sigmas: a best case), and the real
Ventoux right RPC's known +60-line bias by 3.2; GCPs moved 1 km east move them by 4.5-5.7
sigmas (half of the runs fail this check, three quarters some check), 2 km by 8.9-10.1
(every run fails). A table a few hundred metres off (GCPs of another scene of the same area:
366 m in issue 31) is within the products' stated accuracy: no check of the corrections can
tell it from the products' own error; only independent checkpoints can."""


def corrections_beyond_priors(result: AdjustmentResult) -> list[str]:
    """Why the corrections are not what the products' accuracy allows (empty when every
    parameter with an a-priori sigma moved by at most :data:`PRIOR_LIMIT_SIGMAS` of it, or
    when the adjuster gives no a-priori sigmas)."""
    sigma = np.asarray(result.prior_sigmas, np.float64)
    if sigma.size != len(result.parameters):
        return []
    moved = np.abs(np.asarray(result.values) - np.asarray(result.prior_values))
    judged = np.isfinite(sigma) & (sigma > 0)
    z = np.where(judged, moved / np.where(judged, sigma, 1.0), 0.0)
    bad = np.flatnonzero(z > PRIOR_LIMIT_SIGMAS)
    if not bad.size:
        return []
    worst = bad[np.argmax(z[bad])]
    return [
        f"{bad.size} of {int(judged.sum())} corrections are more than {PRIOR_LIMIT_SIGMAS:g} "
        f"a-priori sigmas (worst: {result.parameters[worst]} by {z[worst]:.1f} sigmas): "
        "the control moved the images where their products' accuracy cannot put them "
        "(GCPs of another scene, datum or units?)"
    ]


MIN_TRANSFERRED_SHARE = 0.5
"""An adjustment whose GCP transfer keeps less than this share of three or more image
offsets fails: where the GCPs are, the images must look alike once adjusted (97 % of 250
hand-measured GCPs matched on the simulated pairs, ``benchmarks/results/gcp_transfer.json``).
An outside probe found GCPs moved 1 km (0 of 4 kept) and GCPs of another scene (1 of 4)
adjusted with exit 0 and checkpoints 1000 m and 13 m off (issue 31)."""


def gcps_not_transferred(kept: int, not_kept: int) -> list[str]:
    """Why the GCPs are not where the images show them (empty when most offsets matched,
    or when fewer than three were tried)."""
    tried = kept + not_kept
    if tried < 3 or kept >= MIN_TRANSFERRED_SHARE * tried:
        return []
    return [
        f"the GCP transfer kept {kept} of {tried} image offsets (< "
        f"{100 * MIN_TRANSFERRED_SHARE:g} %): at the GCPs the adjusted images do not show the "
        "same ground (GCPs of another scene or place, wrong image coordinates?)"
    ]
