"""Coarse-to-fine matching over image pyramids.

:func:`pyramid_match`: coarse-to-fine over ``cv2.pyrDown`` pyramids, with the settings of a
matcher (:class:`~carto.framework.matching.base.MatchSettings`); offsets of a level
(cleaned by a local median) are the guesses of the next one; the full-resolution level is
matched by the correlation of :mod:`~carto.framework.matching.ncc` (both directions by default:
:func:`~carto.framework.matching.ncc.match_bidirectional`). Points, offsets and scores follow
the conventions of :mod:`~carto.framework.matching.ncc`.
"""

from __future__ import annotations

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.matching.base import Matches, MatchSettings
from carto.framework.matching.inputs import nan_integral
from carto.framework.matching.ncc import (
    Correlation,
    PreparedPair,
    checked_correlation,
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
    settings: MatchSettings,
    *,
    coarse_min_score: float = 0.5,
    guess_offsets: ArrayLike | None = None,
) -> Matches:
    """Coarse-to-fine matching over image pyramids (``cv2.pyrDown``, factor 2 per level).

    At the coarsest level the points are matched with the given guesses (scaled); the offsets
    found are cleaned (each compared with the median of its 9 nearest neighbours: more than
    2 pixels of that level away, or unmatched, it is replaced by the median) and passed, scaled
    by two, as the guesses of the next level. A coarse level matches at most one point per
    cell of half a template (:func:`_thinned`: closer points share most of their template);
    the others take the median of their nearest matched neighbours, as unmatched points do.
    The full-resolution level is matched with
    :func:`~carto.framework.matching.ncc.match_bidirectional` (or
    :func:`~carto.framework.matching.ncc.match_ncc` without ``two_way``; one level without it
    is plain :func:`~carto.framework.matching.ncc.match_ncc`). The search reach is about
    ``search_px * (2**levels - 1)`` pixels around the guesses (77 px for the defaults of three
    levels and 11 px); give larger offsets as ``guess_offsets`` (e.g. from
    :func:`~carto.framework.matching.shifts.global_shift`). The coarse levels use the parabola
    when ``subpixel`` is least-squares matching (their offsets are only guesses).

    Args:
        settings: ``levels`` (pyramid levels including the full resolution, 1 = no pyramid;
            reduced where the images get smaller than two search windows), ``template_px``,
            ``search_px``, ``subpixel``, ``min_score`` (as ``template``, ``search``,
            ``subpixel``, ``min_score`` of :func:`~carto.framework.matching.ncc.match_ncc`),
            ``two_way`` and ``tolerance_px`` (the left-right check of
            :func:`~carto.framework.matching.ncc.match_bidirectional`).
        coarse_min_score: smallest score accepted at the coarse levels.
        guess_offsets: as :func:`~carto.framework.matching.ncc.match_ncc`.

    Returns:
        the full-resolution matches, in the input order.
    """
    s = settings
    options = checked_correlation(s.template_px, s.search_px, s.subpixel, s.min_score)
    pair = prepared_pair(left, right, points_left, guess_offsets)
    pyramid = _pyramid(pair.left, pair.right, int(s.levels), s.template_px + 2 * s.search_px)
    coarse = attrs.evolve(
        options, subpixel=peak_method(s.subpixel), min_score=float(coarse_min_score)
    )
    offsets = _coarse_offsets(pyramid, pair, coarse)
    tolerance = float(s.tolerance_px) if s.two_way else None
    found = correlate_pair(attrs.evolve(pair, guess=offsets), options, tolerance)
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
    coarse: Correlation,
) -> NDArray[np.float64]:
    """The guesses of the full-resolution level: the coarse levels matched from the coarsest
    down (with the ``coarse`` options), starting from the pair's guesses, each level's offsets
    (full-resolution pixels, cleaned by :func:`_regularise`) the guesses of the next; the
    pair's own guesses without coarse levels."""
    points, offsets = pair.points, pair.guess
    for level in range(len(pyramid) - 1, 0, -1):
        a, b = pyramid[level]
        scale = 2.0**level
        some = _thinned(points / scale, coarse.template // 2)
        level_pair = PreparedPair(
            a, b, points[some] / scale, offsets[some] / scale, nan_integral(a), nan_integral(b)
        )
        found = correlate_pair(level_pair, coarse, None)
        level_offsets = np.full_like(offsets, np.nan)
        level_offsets[some] = (found.right - points[some] / scale) * scale
        ok = np.zeros(len(points), bool)
        ok[some] = found.ok
        offsets = _regularise(points, level_offsets, ok, offsets, 2.0 * scale)
    return offsets


def _thinned(points: NDArray[np.float64], cell: int) -> NDArray[np.intp]:
    """The indices of at most one point per ``cell x cell`` pixel cell (the first of each, in
    order): a coarse level matches no more points than its templates can tell apart (a
    template shares half its pixels with one ``template // 2`` away); the others take the
    median of their nearest matched neighbours (:func:`_regularise`)."""
    finite = np.flatnonzero(np.isfinite(points).all(axis=1))
    if cell <= 1 or finite.size == 0:
        return finite
    cells = np.floor(points[finite] / cell).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    _, first = np.unique(key, return_index=True)
    return finite[np.sort(first)]
