"""Area-based matching by normalised cross-correlation, with sub-pixel peak estimators.

A :class:`~carto.framework.matching.base.Matcher` finds corresponding points between two
images; matches come back as a :class:`~carto.framework.matching.base.Matches` value. This
module holds the correlation that Carto's own matcher
(:class:`~carto.framework.matching.ncc_matcher.NCCMatcher`, name ``"ncc"``) is built from:

* :func:`match_ncc`: normalised cross-correlation (OpenCV ``matchTemplate`` with
  ``TM_CCOEFF_NORMED``: Pearson's correlation coefficient, invariant to gain and offset) of a
  ``template x template`` window around each left point over the offsets ``-search..+search``
  (lines and samples) around an optional per-point guess in the right image. The integer peak
  is refined to sub-pixel by a parabola through the peak and its two neighbours in each
  direction, or a 2-D quadratic fitted to the 3 x 3 neighbourhood (:func:`subpixel_peak`), or
  least-squares matching (:mod:`~carto.framework.matching.lsm`; ``"lsm"``: Gauss-Newton on
  translation, gain and offset with the right image resampled by cubic convolution, started
  from the parabola; ``"lsm-affine"``: then an affine geometry, compiled, giving the
  displacement at the point itself where it varies across the template, e.g. with relief
  parallax between views). A point is dropped when its template or search window leaves the
  image or holds NaN, when its template has no texture (constant), when the best score is
  below ``min_score``, or when the peak is on the border of the search range (the true peak
  may lie beyond it).
* :func:`match_bidirectional`: left -> right, then right -> left from the positions found;
  matches that do not come back within ``tolerance`` pixels are dropped.

:func:`correlate_points` and :func:`correlate_bidirectional` are the same on prepared inputs
(per input point, :class:`Found`; :func:`prepared_pair` checks and prepares them, the options
are a :class:`Correlation`, :func:`correlate_pair` runs either), for the other area-based
matchers:
:func:`~carto.framework.matching.pyramid.pyramid_match` (coarse-to-fine over image pyramids).
First guesses of a global translation come from :mod:`~carto.framework.matching.shifts`
(phase correlation, masked correlation of reduced images), candidate points from
:mod:`~carto.framework.matching.candidates` (a grid) and
:mod:`~carto.framework.matching.forstner` (interest points).

Conventions
    * Image coordinates follow the project convention: continuous ``(line, sample)``, the
      centre of the first pixel at ``(0.5, 0.5)`` (see :mod:`carto.framework.geometry.sensor`).
      Arrays of points are ``(N, 2)`` with columns ``(line, sample)``.
    * Offsets are ``right - left`` in pixels: the content at ``p`` in the left image is at
      ``p + offset`` in the right one.
    * The template is centred on the pixel that holds the point (centre ``floor(p) + 0.5``);
      the offset found there is applied to the point itself, so the point's fraction of a
      pixel is kept.
    * Scores are correlation coefficients in [-1, 1] (the integer peak's value).

Accuracy (measured, ``tests/framework/test_match.py``): the 3-point fits are biased by the
asymmetry of the correlation peak of a small template (peak locking): 0.06 px RMS for the
parabola, 0.04-0.05 px for the 2-D quadratic, on exact sub-pixel translations of a
multi-scale texture; least-squares matching brings it to 0.011 px RMS (0.022 px in a smooth
affine + sinusoidal displacement field, 0.013 px with ``"lsm-affine"``; under a 4-8 % scale
and shear 0.09 px, 0.004 px with ``"lsm-affine"``).
:class:`~carto.framework.matching.ncc_matcher.NCCMatcher` uses ``"lsm"``.

Speed: searches up to +-6 px are correlated for every point in one compiled pass (numba,
parallel: 250 000 points/s for 15 x 15 templates and +-3 px on 2 cores), wider ones by one
``matchTemplate`` call per point (about 60 000 points/s at +-11 px); least-squares matching
about 14 000 points/s (one core); the affine refinement adds 0.03-0.1 ms per point (numba,
parallel).
"""

from __future__ import annotations

import math

import attrs
import numba
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.base import Matches
from carto.framework.matching.inputs import (
    as_image,
    as_points,
    check_int,
    nan_integral,
    windows_clean,
)
from carto.framework.matching.lsm import Templates, lsm_affine_refine, lsm_refine

# ----------------------------------------------------------------------------- helpers
SUBPIXEL_METHODS = ("parabola", "quadratic", "lsm", "lsm-affine", "none")
"""Sub-pixel peak estimators of :func:`match_ncc`."""

_FLAT_STD = 1e-6  # templates with a standard deviation below this (relative) have no texture

# least-squares 2-D quadratic on the 3 x 3 neighbourhood of a peak: rows of the pseudo-inverse
# map the 9 scores (row-major, offsets -1, 0, 1) to (a0, a_x, a_y, a_xx, a_xy, a_yy)
_DY, _DX = np.mgrid[-1:2, -1:2]
_QUAD_PINV = np.linalg.pinv(
    np.stack(
        [
            np.ones(9),
            _DX.ravel(),
            _DY.ravel(),
            _DX.ravel() ** 2,
            (_DX * _DY).ravel(),
            _DY.ravel() ** 2,
        ],
        axis=1,
    ).astype(np.float64)
)


def subpixel_peak(neighbourhood: NDArray[np.float64], method: str) -> NDArray[np.float64]:
    """Sub-pixel ``(d_line, d_sample)`` of peaks from their 3 x 3 score neighbourhoods
    ``(M, 3, 3)``: ``method`` ``"parabola"``, ``"quadratic"`` or ``"none"`` (zero)."""
    n = neighbourhood
    out = np.zeros((n.shape[0], 2))
    if method == "none" or n.shape[0] == 0:
        return out
    with np.errstate(divide="ignore", invalid="ignore"):
        den_r = n[:, 0, 1] - 2.0 * n[:, 1, 1] + n[:, 2, 1]
        den_c = n[:, 1, 0] - 2.0 * n[:, 1, 1] + n[:, 1, 2]
        dr = np.where(den_r < 0.0, 0.5 * (n[:, 0, 1] - n[:, 2, 1]) / den_r, 0.0)
        dc = np.where(den_c < 0.0, 0.5 * (n[:, 1, 0] - n[:, 1, 2]) / den_c, 0.0)
        out[:, 0] = np.clip(dr, -0.5, 0.5)
        out[:, 1] = np.clip(dc, -0.5, 0.5)
        if method == "quadratic":
            a = n.reshape(-1, 9) @ _QUAD_PINV.T  # (a0, a_x, a_y, a_xx, a_xy, a_yy)
            hxx, hxy, hyy = 2.0 * a[:, 3], a[:, 4], 2.0 * a[:, 5]
            det = hxx * hyy - hxy * hxy
            ok = (hxx < 0.0) & (det > 0.0)
            dx = (-hyy * a[:, 1] + hxy * a[:, 2]) / det
            dy = (hxy * a[:, 1] - hxx * a[:, 2]) / det
            ok &= (np.abs(dx) <= 1.0) & (np.abs(dy) <= 1.0)
            out[:, 0] = np.where(ok, dy, out[:, 0])
            out[:, 1] = np.where(ok, dx, out[:, 1])
    return out


def peak_method(subpixel: str) -> str:
    """The peak estimator of a sub-pixel method (least-squares matching starts from the
    parabola)."""
    return "parabola" if subpixel in ("lsm", "lsm-affine") else subpixel


@attrs.frozen
class Found:
    """Per input point: right position (NaN where no match) and score (NaN likewise)."""

    right: NDArray[np.float64]
    score: NDArray[np.float64]

    @property
    def ok(self) -> NDArray[np.bool_]:
        return np.isfinite(self.score)


@attrs.frozen(eq=False)
class PreparedPair:
    """The checked inputs of a correlation (:func:`prepared_pair`).

    Attributes:
        left, right: the images, float32 (NaN = no data).
        points: ``(N, 2)`` ``(line, sample)`` in the left image.
        guess: ``(N, 2)`` expected offsets ``right - left``, pixels.
        nan_left, nan_right: the images' NaN tables
            (:func:`~carto.framework.matching.inputs.nan_integral`).
    """

    left: NDArray[np.float32]
    right: NDArray[np.float32]
    points: NDArray[np.float64]
    guess: NDArray[np.float64]
    nan_left: NDArray[np.integer] | None
    nan_right: NDArray[np.integer] | None

    def reversed(self, points: NDArray[np.float64], guess: NDArray[np.float64]) -> PreparedPair:
        """The pair the other way round (right -> left), from ``points`` of the right image
        with the ``guess`` offsets ``left - right``."""
        return PreparedPair(self.right, self.left, points, guess, self.nan_right, self.nan_left)


@attrs.frozen
class Correlation:
    """The options of a correlation (:func:`correlate_points`), as :func:`match_ncc` takes
    them (:func:`checked_correlation`).

    Attributes:
        template: side of the square template, odd, pixels.
        search: the search reaches ``+-search`` pixels around the guess in both directions.
        subpixel: the sub-pixel estimator, one of :data:`SUBPIXEL_METHODS`.
        min_score: smallest accepted correlation score.
    """

    template: int
    search: int
    subpixel: str
    min_score: float


def correlate_points(pair: PreparedPair, options: Correlation) -> Found:
    """The correlation of :func:`match_ncc` on prepared inputs, one row per input point."""
    left, right, points, guess = pair.left, pair.right, pair.points, pair.guess
    template, search, subpixel = options.template, options.search, options.subpixel
    n = points.shape[0]
    right_pts = np.full((n, 2), np.nan)
    scores = np.full(n, np.nan)
    half = template // 2
    size = 2 * (half + search) + 1
    ok = np.isfinite(points).all(axis=1) & np.isfinite(guess).all(axis=1)
    pts = np.where(ok[:, None], points, 0.0)
    g = np.rint(np.where(ok[:, None], guess, 0.0))
    # the template is centred on the pixel holding the point (centre at index + 0.5)
    centre = np.floor(pts).astype(np.intp)
    t0 = centre - half
    s0 = centre + g.astype(np.intp) - half - search
    h_l, w_l = left.shape
    h_r, w_r = right.shape
    ok &= (t0[:, 0] >= 0) & (t0[:, 1] >= 0)
    ok &= (t0[:, 0] + template <= h_l) & (t0[:, 1] + template <= w_l)
    ok &= (s0[:, 0] >= 0) & (s0[:, 1] >= 0)
    ok &= (s0[:, 0] + size <= h_r) & (s0[:, 1] + size <= w_r)
    idx = np.flatnonzero(ok)
    clean = windows_clean(pair.nan_left, t0[idx, 0], t0[idx, 1], template)
    clean &= windows_clean(pair.nan_right, s0[idx, 0], s0[idx, 1], size)
    idx = idx[clean]
    if idx.size == 0:
        return Found(right_pts, scores)
    templates = sliding_window_view(left, (template, template))[t0[idx, 0], t0[idx, 1]]
    spread = templates.reshape(idx.size, -1).std(axis=1)
    level = np.abs(templates.reshape(idx.size, -1).mean(axis=1))
    textured = spread > _FLAT_STD * np.maximum(level, 1.0)
    idx, templates = idx[textured], templates[textured]
    n_off = 2 * search + 1
    surface = _surfaces(left, right, t0[idx], s0[idx], templates, size)
    surface[np.isnan(surface)] = -1.0
    flat = surface.reshape(idx.size, -1)
    peak = flat.argmax(axis=1)
    best = flat[np.arange(idx.size), peak].astype(np.float64)
    pr, pc = np.divmod(peak, n_off)
    inner = (pr > 0) & (pr < n_off - 1) & (pc > 0) & (pc < n_off - 1)
    good = inner & (best >= options.min_score)
    idx, pr, pc, best, surface = idx[good], pr[good], pc[good], best[good], surface[good]
    rows = pr[:, None, None] + np.arange(-1, 2)[None, :, None]
    cols = pc[:, None, None] + np.arange(-1, 2)[None, None, :]
    neighbourhood = surface[np.arange(idx.size)[:, None, None], rows, cols].astype(np.float64)
    sub = subpixel_peak(neighbourhood, peak_method(subpixel))
    offset = g[idx] + np.stack([pr, pc], axis=1) - search + sub
    if subpixel in ("lsm", "lsm-affine"):
        refined = Templates(left, right, t0[idx], template)
        offset = lsm_refine(refined, offset)
        if subpixel == "lsm-affine":
            offset = lsm_affine_refine(refined, offset, points[idx])
    right_pts[idx] = points[idx] + offset
    scores[idx] = best
    return Found(right_pts, scores)


def _surfaces(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    t0: NDArray[np.intp],
    s0: NDArray[np.intp],
    templates: NDArray[np.float32],
    size: int,
) -> NDArray[np.float32]:
    """The correlation surfaces ``(n, n_off, n_off)`` of the templates at ``t0`` over the
    search windows at ``s0``: one compiled pass for narrow searches, OpenCV's
    ``matchTemplate`` per point for wide ones (:data:`_COMPILED_MAX_OFFSETS`)."""
    import cv2

    template = templates.shape[-1]
    n_off = size - template + 1
    if n_off <= _COMPILED_MAX_OFFSETS:
        return _ncc_surfaces(
            np.ascontiguousarray(left, np.float32),
            np.ascontiguousarray(right, np.float32),
            np.ascontiguousarray(t0),
            np.ascontiguousarray(s0),
            template,
            size,
        )
    surface = np.empty((len(t0), n_off, n_off), np.float32)
    for k, ((r, c), tmpl) in enumerate(zip(s0, templates, strict=True)):
        surface[k] = cv2.matchTemplate(
            right[r : r + size, c : c + size], tmpl, cv2.TM_CCOEFF_NORMED
        )
    return surface


_COMPILED_MAX_OFFSETS = 13
"""Widest search (offsets per axis) correlated by :func:`_ncc_surfaces`; wider ones by
OpenCV, whose per-point call is then the cheaper (measured: 2.7x faster at +-3 px, equal at
+-6, 0.4x at +-11, for 15 x 15 templates)."""


@numba.njit(parallel=True, cache=True, nogil=True)
def _ncc_surfaces(
    left: NDArray, right: NDArray, t0: NDArray, s0: NDArray, template: int, size: int
) -> NDArray:  # pragma: no cover - compiled
    """``(n, n_off, n_off)``: OpenCV's ``TM_CCOEFF_NORMED`` of the template at ``t0[k]`` of
    ``left`` over the ``size x size`` window at ``s0[k]`` of ``right`` (the same formula and
    the same treatment of flat windows, summed in float64), every point in one pass."""
    n = t0.shape[0]
    n_off = size - template + 1
    area = template * template
    out = np.empty((n, n_off, n_off), np.float32)
    for k in numba.prange(n):
        tmpl = np.empty((template, template))
        mean = 0.0
        for i in range(template):
            for j in range(template):
                tmpl[i, j] = left[t0[k, 0] + i, t0[k, 1] + j]
                mean += tmpl[i, j]
        mean /= area
        norm = 0.0
        for i in range(template):
            for j in range(template):
                tmpl[i, j] -= mean
                norm += tmpl[i, j] * tmpl[i, j]
        norm = math.sqrt(norm)
        for a in range(n_off):
            for b in range(n_off):
                s1 = 0.0
                s2 = 0.0
                cross = 0.0
                for i in range(template):
                    for j in range(template):
                        v = right[s0[k, 0] + a + i, s0[k, 1] + b + j]
                        s1 += v
                        s2 += v * v
                        cross += tmpl[i, j] * v
                t = math.sqrt(max(s2 - s1 * s1 / area, 0.0)) * norm
                if abs(cross) < t:
                    out[k, a, b] = cross / t
                elif abs(cross) < t * 1.125:
                    out[k, a, b] = 1.0 if cross > 0 else -1.0
                else:  # a flat window: OpenCV's 0
                    out[k, a, b] = 0.0
    return out


def found_matches(points: NDArray[np.float64], found: Found) -> Matches:
    """The :class:`~carto.framework.matching.base.Matches` of the points that were found, in
    the input order."""
    ok = found.ok
    return Matches(
        points[ok, 0], points[ok, 1], found.right[ok, 0], found.right[ok, 1], found.score[ok]
    )


def check_options(template: int, search: int, subpixel: str, min_score: float) -> None:
    """InputError unless the options of :func:`match_ncc` are valid."""
    if check_int(template, "template", 3) % 2 == 0:
        raise InputError(f"template must be odd (a centred window), got {template}")
    check_int(search, "search", 1)
    if subpixel not in SUBPIXEL_METHODS:
        raise InputError(f"subpixel {subpixel!r} is not one of {', '.join(SUBPIXEL_METHODS)}")
    if not -1.0 <= float(min_score) <= 1.0:
        raise InputError(f"min_score must be within [-1, 1], got {min_score}")


def checked_correlation(template: int, search: int, subpixel: str, min_score: float) -> Correlation:
    """The options of :func:`match_ncc` as a :class:`Correlation`, or InputError
    (:func:`check_options`)."""
    check_options(template, search, subpixel, min_score)
    return Correlation(template, search, subpixel, float(min_score))


def as_guesses(guess_offsets: ArrayLike | None, n: int) -> NDArray[np.float64]:
    """The ``guess_offsets`` of :func:`match_ncc` as an ``(n, 2)`` array (zero when None; one
    ``(2,)`` offset for all points), or InputError."""
    if guess_offsets is None:
        return np.zeros((n, 2))
    guess = np.asarray(guess_offsets, dtype=np.float64)
    if guess.shape == (2,):
        guess = np.broadcast_to(guess, (n, 2))
    if guess.shape != (n, 2):
        raise InputError(
            f"guess_offsets must be (N, 2) like the points ({n}, 2) or one (2,) offset, "
            f"got {guess.shape}"
        )
    return np.array(guess)


def check_tolerance(tolerance: float) -> None:
    """InputError unless the left-right ``tolerance`` of :func:`match_bidirectional` is valid."""
    if not float(tolerance) > 0.0:
        raise InputError(f"tolerance must be > 0 pixels, got {tolerance}")


def prepared_pair(
    left: ArrayLike, right: ArrayLike, points_left: ArrayLike, guess_offsets: ArrayLike | None
) -> PreparedPair:
    """The images, points and guesses of :func:`match_ncc` checked and prepared, or
    InputError."""
    left_img, right_img = as_image(left, "left"), as_image(right, "right")
    points = as_points(points_left, "points_left")
    guess = as_guesses(guess_offsets, points.shape[0])
    return PreparedPair(
        left_img, right_img, points, guess, nan_integral(left_img), nan_integral(right_img)
    )


def correlate_pair(pair: PreparedPair, options: Correlation, tolerance: float | None) -> Found:
    """The correlation of a prepared pair around its guesses, one row per point: both
    directions within ``tolerance`` pixels (:func:`correlate_bidirectional`), or left -> right
    only when ``tolerance`` is None (:func:`correlate_points`)."""
    if tolerance is None:
        return correlate_points(pair, options)
    return correlate_bidirectional(pair, options, tolerance)


def _matched(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    guess_offsets: ArrayLike | None,
    options: Correlation,
    tolerance: float | None,
) -> Matches:
    """The matches of :func:`match_ncc` (``tolerance`` None) or :func:`match_bidirectional`
    with checked options: the inputs prepared (:func:`prepared_pair`) and correlated
    (:func:`correlate_pair`)."""
    pair = prepared_pair(left, right, points_left, guess_offsets)
    return found_matches(pair.points, correlate_pair(pair, options, tolerance))


# ----------------------------------------------------------------------------- matching
def match_ncc(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    *,
    template: int = 15,
    search: int = 11,
    subpixel: str = "parabola",
    min_score: float = 0.6,
    guess_offsets: ArrayLike | None = None,
) -> Matches:
    """Match points of the left image in the right one by normalised cross-correlation.

    Args:
        left, right: single-band images (2-D, any real dtype; NaN = no data).
        points_left: ``(N, 2)`` ``(line, sample)`` in the left image.
        template: side of the square template, odd, pixels.
        search: the search reaches ``+-search`` pixels around the guess in both directions.
        subpixel: ``"parabola"`` (default; separable 3-point parabolas), ``"quadratic"``
            (2-D least-squares quadratic on the 3 x 3 neighbourhood; falls back to the
            parabolas where it has no maximum), ``"lsm"`` (least-squares matching from the
            parabola's estimate; points where it fails keep that estimate; the most accurate,
            see the module docstring), ``"lsm-affine"`` (least-squares matching with an
            affine geometry, from the ``"lsm"`` estimate: the offset of the point itself where
            the displacement varies across the template) or ``"none"`` (integer offsets).
        min_score: smallest accepted correlation score.
        guess_offsets: ``(N, 2)`` (or one ``(2,)``) expected offsets ``right - left``,
            pixels; rounded to integers to centre the search. Default zero.

    Returns:
        the matches, in the input order, of the points that pass all the tests (see the module
        docstring); scores are the integer-peak correlation coefficients.

    Raises:
        InputError: malformed images, points, guesses or options.
    """
    options = checked_correlation(template, search, subpixel, min_score)
    return _matched(left, right, points_left, guess_offsets, options, None)


def correlate_bidirectional(pair: PreparedPair, options: Correlation, tolerance: float) -> Found:
    """The correlation of :func:`match_bidirectional` on prepared inputs, one row per input
    point."""
    forward = correlate_points(pair, options)
    ok = forward.ok
    back_guess = np.where(ok[:, None], pair.points - forward.right, 0.0)
    back_points = np.where(ok[:, None], forward.right, np.nan)
    # the check needs no more than the parabola's accuracy, except where the forward position
    # is the affine estimate at the point: a distorted template's translation peak may lie up
    # to a pixel away from it (and comparing like with like rejects the fewest good matches)
    subpixel = options.subpixel
    back = attrs.evolve(
        options, subpixel=subpixel if subpixel == "lsm-affine" else peak_method(subpixel)
    )
    backward = correlate_points(pair.reversed(back_points, back_guess), back)
    closure = np.hypot(*(backward.right - pair.points).T)
    keep = backward.ok & (closure <= tolerance)
    score = np.where(keep, np.minimum(forward.score, backward.score), np.nan)
    right_pts = np.where(keep[:, None], forward.right, np.nan)
    return Found(right_pts, score)


def match_bidirectional(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    *,
    tolerance: float = 0.5,
    template: int = 15,
    search: int = 11,
    subpixel: str = "parabola",
    min_score: float = 0.6,
    guess_offsets: ArrayLike | None = None,
) -> Matches:
    """:func:`match_ncc` left -> right, then right -> left from the positions found.

    A match is kept when the backward match lands within ``tolerance`` pixels of the left
    point it started from: a consistency check that removes most wrong matches on nearly
    repeated patterns and occlusions (on an exactly periodic pattern both directions pick a
    period at random and a wrong pair survives as often as a right one). The backward pass uses
    the parabola when ``subpixel`` is ``"lsm"`` (the check needs no more), least-squares
    matching with an affine geometry when it is ``"lsm-affine"`` (the forward position is then
    the displacement at the point, which the translation peak of a distorted template misses
    by up to a pixel). The score is the smaller of the two directions' scores. Other arguments
    as :func:`match_ncc`.
    """
    options = checked_correlation(template, search, subpixel, min_score)
    check_tolerance(tolerance)
    return _matched(left, right, points_left, guess_offsets, options, float(tolerance))
