"""Fusion of co-registered DEMs node by node: N pairs of a triplet or a strip, one height.

Every pair's DEM gives, at a node, a height ``h_i`` with a predicted standard deviation
``sigma_i`` (the generator's ``sigma_m`` layer: matching precision over the pair's local
B/H) and whether it was measured there or only filled. :func:`fuse_heights` combines them
the way ASP's ``dem_mosaic --median``/CARS's point-cloud fusion do in spirit, with the
pairs' own precision:

1. the measured heights' weighted median (weights ``1/sigma_i^2``) is a first estimate that
   one wrong pair cannot move;
2. a height further from it than ``k_sigma`` times its expected distance
   ``sqrt(sigma_i^2 + sigma_0^2)`` (``sigma_0`` the weighted mean's own sigma) is an outlier:
   a blunder, an occlusion the pair filled by matching something else;
3. the fused height is the weighted mean of the heights kept, its sigma the weighted mean's,
   inflated by the heights' own scatter when the pairs disagree more than their sigmas say
   (Birge ratio above one);
4. a node no pair measured keeps the best-predicted pair's filled height, flagged filled.

With two pairs that disagree there is no majority: the median is the better-predicted pair's
height, so that one is kept. Layers returned beside the height: pairs kept (``count``),
spread of the kept heights (max - min, m), fused sigma (m) and the filled flag.
"""

from __future__ import annotations

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.arrays import FloatArray
from carto.framework.errors import InputError
from carto.framework.settings import checked, positive

__all__ = ["FusedHeights", "FusionSettings", "fuse_heights", "weighted_median"]


@attrs.frozen
class FusionSettings:
    """How pairs' heights are fused.

    Attributes:
        k_sigma: a height further from the weighted median than this many expected standard
            deviations is rejected.
        sigma_floor_m: the least sigma a pair's height is given, m: a generator's very
            small predicted sigma must not make one pair outvote the others alone.
        feather_posts: over this many DEM posts from the edge of a pair's heights, its
            weight grows from almost 0 to 1 (its sigma is divided by the square root of the
            ramp), so that where pairs of neighbouring swaths or scenes meet the DEM passes
            from one to the other without a seam (0: no feathering).
        align_pairs: before fusing, cancel the constant step between the pairs' DEMs
            (measured where they overlap), holding the pair of the widest base: pairs
            whose left images differ can stand on datums a few metres apart when the
            models are not those of one block adjustment.
    """

    k_sigma: float = attrs.field(
        default=3.0, validator=checked(positive, "fusion k_sigma {!r}: give a positive number")
    )
    sigma_floor_m: float = attrs.field(
        default=0.05,
        validator=checked(positive, "fusion sigma_floor_m {!r}: give a positive number, m"),
    )
    feather_posts: int = attrs.field(
        default=16,
        validator=checked(
            lambda v: 0 <= v <= 1024, "fusion feather_posts {!r}: give 0 to 1024 posts"
        ),
    )
    align_pairs: bool = True


@attrs.frozen
class FusedHeights:
    """The fused DEM window and its quality layers (all of the nodes' shape).

    Attributes:
        height_m: fused height, NaN where no pair has a height.
        sigma_m: its predicted standard deviation, NaN where no height.
        count: pairs whose measured height was kept (0 where filled or empty).
        spread_m: max - min of the kept heights (0 with one pair, NaN with none).
        filled: True where no pair measured the node and a filled height stands.
    """

    height_m: FloatArray
    sigma_m: FloatArray
    count: NDArray[np.int32]
    spread_m: FloatArray
    filled: NDArray[np.bool_]


def weighted_median(values: FloatArray, weights: FloatArray) -> FloatArray:
    """Weighted median along axis 0 (the lower one at an exact half), NaN where every
    weight is zero. Entries with zero weight take no part (their value may be NaN)."""
    values = np.asarray(values, np.float64)
    weights = np.where(np.isfinite(values), np.asarray(weights, np.float64), 0.0)
    keyed = np.where(weights > 0, values, np.inf)
    order = np.argsort(keyed, axis=0, kind="stable")
    sorted_values = np.take_along_axis(keyed, order, axis=0)
    cumulative = np.cumsum(np.take_along_axis(weights, order, axis=0), axis=0)
    total = cumulative[-1]
    first = np.argmax(cumulative >= 0.5 * total[None], axis=0)
    median = np.take_along_axis(sorted_values, first[None], axis=0)[0]
    return np.where(total > 0, median, np.nan)


def fuse_heights(
    heights_m: FloatArray,
    sigmas_m: FloatArray,
    measured: NDArray[np.bool_],
    settings: FusionSettings | None = None,
) -> FusedHeights:
    """Fuse N pairs' heights node by node (see the module docstring).

    Args:
        heights_m: (N, rows, cols) heights on one grid, NaN = none.
        sigmas_m: (N, rows, cols) predicted standard deviations, m (NaN or <= 0 = unknown:
            the height is then used only as a filled one).
        measured: (N, rows, cols) True where the pair measured the node (not filled).
        settings: rejection threshold and sigma floor.
    """
    settings = settings or FusionSettings()
    h, s, measured = _checked(heights_m, sigmas_m, measured)
    s = np.maximum(s, settings.sigma_floor_m)
    use = measured & np.isfinite(h) & np.isfinite(s)
    w = np.where(use, 1.0 / np.where(use, s, 1.0) ** 2, 0.0)
    centre = weighted_median(h, w)
    sigma_centre = 1.0 / np.sqrt(np.maximum(w.sum(axis=0), 1e-300))
    tolerance = settings.k_sigma * np.sqrt(s**2 + sigma_centre[None] ** 2)
    keep = use & (np.abs(np.where(use, h, 0.0) - centre[None]) <= tolerance)
    return _weighted_mean(h, w * keep, keep, _filled_heights(h, s))


def _checked(
    heights_m: FloatArray, sigmas_m: FloatArray, measured: NDArray[np.bool_]
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    h = np.asarray(heights_m, np.float64)
    s = np.asarray(sigmas_m, np.float64)
    m = np.asarray(measured, bool)
    if h.ndim != 3 or h.shape[0] < 1:
        raise InputError(f"DEM fusion: heights of shape {h.shape}, want (pairs, rows, cols)")
    if s.shape != h.shape or m.shape != h.shape:
        raise InputError(
            f"DEM fusion: heights {h.shape}, sigmas {s.shape} and measured {m.shape} "
            "must have one shape"
        )
    s = np.where(s > 0, s, np.nan)
    return h, s, m


def _filled_heights(h: FloatArray, s: FloatArray) -> FloatArray:
    """At every node, the height of the pair with the smallest sigma that has one (any
    pair's height where no sigma is known)."""
    has = np.isfinite(h)
    # no height: never chosen; a height without a sigma: after every one with a sigma
    key = np.where(has, np.where(np.isfinite(s), s, np.finfo(np.float64).max), np.inf)
    best = np.argmin(key, axis=0)
    return np.take_along_axis(h, best[None], axis=0)[0]


def _weighted_mean(
    h: FloatArray, w: FloatArray, keep: NDArray[np.bool_], filled_h: FloatArray
) -> FusedHeights:
    count = keep.sum(axis=0).astype(np.int32)
    total = w.sum(axis=0)
    hz = np.where(keep, h, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (w * hz).sum(axis=0) / total
        sigma = 1.0 / np.sqrt(total)
        chi2 = (w * (hz - mean[None]) ** 2).sum(axis=0)
        birge = np.where(count > 1, np.sqrt(chi2 / np.maximum(count - 1, 1)), 1.0)
    sigma = sigma * np.maximum(birge, 1.0)
    high = np.where(keep, h, -np.inf).max(axis=0)
    low = np.where(keep, h, np.inf).min(axis=0)
    measured = count > 0
    filled = ~measured & np.isfinite(filled_h)
    return FusedHeights(
        height_m=np.where(measured, mean, filled_h),
        sigma_m=np.where(measured, sigma, np.nan),
        count=count,
        spread_m=np.where(measured, high - low, np.nan),
        filled=filled,
    )
