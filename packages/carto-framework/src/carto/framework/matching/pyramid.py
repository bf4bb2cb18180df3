"""Coarse-to-fine matching over image pyramids.

:func:`pyramid_match`: coarse-to-fine over ``cv2.pyrDown`` pyramids, offsets of a level
(cleaned by a local median) are the guesses of the next one; the full-resolution level is
matched by the correlation of :mod:`~carto.framework.matching.ncc` (both directions by default:
:func:`~carto.framework.matching.ncc.match_bidirectional`). Points, offsets and scores follow
the conventions of :mod:`~carto.framework.matching.ncc`.
"""

from __future__ import annotations

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.matching.base import Matches
from carto.framework.matching.inputs import check_int, nan_integral
from carto.framework.matching.ncc import (
    PreparedPair,
    check_options,
    check_tolerance,
    correlate_pair,
    found_matches,
    peak_method,
    prepared_pair,
)


def _regularise(
    points: NDArray[np.float64],
    offsets: NDArray[np.float64],
    ok: NDArray[np.bool_],
    fallback: NDArray[np.float64],
    max_deviation: float,
    k: int = 9,
) -> NDArray[np.float64]:
    """Offsets for every point: the found ones, unless they differ from the median of their
    ``k`` nearest found neighbours by more than ``max_deviation`` (then that median); points
    without a match get the median of their neighbours' (or ``fallback`` when none matched)."""
    good = np.flatnonzero(ok)
    if good.size == 0:
        return fallback.copy()
    from scipy.spatial import cKDTree

    finite = np.isfinite(points).all(axis=1)
    query = np.where(finite[:, None], points, 0.0)
    tree = cKDTree(points[good])
    kk = min(k, good.size)
    _, nearest = tree.query(query, k=kk)
    nearest = np.asarray(nearest).reshape(points.shape[0], kk)
    median = np.median(offsets[good][nearest], axis=1)
    deviation = np.hypot(*(offsets - median).T)
    keep = ok & (deviation <= max_deviation)
    return np.where(keep[:, None], offsets, median)


def pyramid_match(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    *,
    levels: int = 3,
    template: int = 15,
    search: int = 11,
    subpixel: str = "parabola",
    min_score: float = 0.6,
    coarse_min_score: float = 0.5,
    guess_offsets: ArrayLike | None = None,
    bidirectional: bool = True,
    tolerance: float = 0.5,
) -> Matches:
    """Coarse-to-fine matching over image pyramids (``cv2.pyrDown``, factor 2 per level).

    At the coarsest level the points are matched with the given guesses (scaled); the offsets
    found are cleaned (each compared with the median of its 9 nearest neighbours: more than
    2 pixels of that level away, or unmatched, it is replaced by the median) and passed, scaled
    by two, as the guesses of the next level. The full-resolution level is matched with
    :func:`~carto.framework.matching.ncc.match_bidirectional` (or
    :func:`~carto.framework.matching.ncc.match_ncc` when ``bidirectional`` is False). The
    search reach is about ``search * (2**levels - 1)`` pixels around the guesses (77 px for the
    defaults); give larger offsets as ``guess_offsets`` (e.g. from
    :func:`~carto.framework.matching.shifts.global_shift`). The coarse levels use the parabola
    when ``subpixel`` is least-squares matching (their offsets are only guesses).

    Args:
        levels: number of pyramid levels including the full resolution (1 = no pyramid);
            reduced where the images get smaller than two search windows.
        coarse_min_score: smallest score accepted at the coarse levels.
        template, search, subpixel, min_score, guess_offsets: as
            :func:`~carto.framework.matching.ncc.match_ncc`.
        bidirectional, tolerance: the left-right check of
            :func:`~carto.framework.matching.ncc.match_bidirectional`.

    Returns:
        the full-resolution matches, in the input order.
    """
    check_options(template, search, subpixel, min_score)
    levels = check_int(levels, "levels", 1)
    check_tolerance(tolerance)
    pair = prepared_pair(left, right, points_left, guess_offsets)
    pyramid = _pyramid(pair.left, pair.right, levels, template + 2 * search)
    offsets = _coarse_offsets(
        pyramid, pair, template, search, peak_method(subpixel), float(coarse_min_score)
    )
    found = correlate_pair(
        attrs.evolve(pair, guess=offsets),
        template,
        search,
        subpixel,
        float(min_score),
        float(tolerance) if bidirectional else None,
    )
    return found_matches(pair.points, found)


def _pyramid(
    left: NDArray[np.float32], right: NDArray[np.float32], levels: int, need: int
) -> list[tuple[NDArray[np.float32], NDArray[np.float32]]]:
    """The ``(left, right)`` images of each pyramid level, full resolution first
    (``cv2.pyrDown``): at most ``levels``, fewer where a level's images would get smaller than
    two windows of ``need`` pixels."""
    import cv2

    pyramid = [(left, right)]
    while len(pyramid) < levels:
        a, b = pyramid[-1]
        if min(*a.shape, *b.shape) < 2 * need:
            break
        pyramid.append((cv2.pyrDown(a), cv2.pyrDown(b)))
    return pyramid


def _coarse_offsets(
    pyramid: list[tuple[NDArray[np.float32], NDArray[np.float32]]],
    pair: PreparedPair,
    template: int,
    search: int,
    peak: str,
    coarse_min_score: float,
) -> NDArray[np.float64]:
    """The guesses of the full-resolution level: the coarse levels matched from the coarsest
    down (sub-pixel by ``peak``), starting from the pair's guesses, each level's offsets
    (full-resolution pixels, cleaned by :func:`_regularise`) the guesses of the next; the
    pair's own guesses without coarse levels."""
    points, offsets = pair.points, pair.guess
    for level in range(len(pyramid) - 1, 0, -1):
        a, b = pyramid[level]
        scale = 2.0**level
        coarse = PreparedPair(
            a, b, points / scale, offsets / scale, nan_integral(a), nan_integral(b)
        )
        found = correlate_pair(coarse, template, search, peak, coarse_min_score, None)
        level_offsets = (found.right - points / scale) * scale
        offsets = _regularise(points, level_offsets, found.ok, offsets, 2.0 * scale)
    return offsets
