"""Multi-view matching: candidate points of a reference ortho matched in every other view.

Step 4 of the tie-point pipeline (:mod:`~carto.framework.matching.tiepoints`), on ortho-images
on one grid (system-level orthos, :func:`~carto.framework.imaging.preparation.system_orthos`).
:func:`match_views` matches in all views at once: the shift between the reference ortho and
each other one by masked correlation over all shifts
(:func:`~carto.framework.matching.shifts.coarse_shift`), then normalised cross-correlation in a
4-level pyramid (:func:`~carto.framework.matching.pyramid.pyramid_match`), least-squares
matching with an affine geometry and a left-right check, reference -> every other view; gross
errors removed by a geometric test: the offsets of a point in all views must be those of one
ground point, a smooth field plus the parallax of one height error
(:func:`inconsistent_points`, :func:`ortho_parallax`); with three views or more, the position
found in each other view is matched again in every other one and must land where the
reference's match put it (within ``closure_px``): A -> B -> C must agree with A -> C, and
observations that no closure confirms are dropped. The result is a :class:`MultiViewMatches`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from itertools import permutations
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.matching.base import Matcher, MatchSettings, rows_of
from carto.framework.matching.inputs import as_image, as_points, nan_integral, windows_clean


@attrs.frozen(eq=False)
class MultiViewMatches:
    """Candidate points of the reference ortho and their positions in every view.

    Attributes:
        views: image names; ``views[0]`` is the reference.
        positions: ``(V, N, 2)`` ortho positions ``(line, sample)`` of each candidate in each
            view (``positions[0]`` are the candidates); NaN where the view has no accepted
            match.
        scores: ``(V, N)`` correlation score of each accepted match (the smaller of its two
            directions, and of its closure matches); the reference row holds the smallest
            score of the point's views. NaN where no match.
        closure: ``(V, N)`` True where a closure confirmed the observation (the reference
            row: where any view was confirmed).
    """

    views: tuple[str, ...]
    positions: NDArray[np.float64]
    scores: NDArray[np.float64]
    closure: NDArray[np.bool_]

    @property
    def n_views(self) -> NDArray[np.intp]:
        """Number of views (reference included) in which each point has a position."""
        return np.isfinite(self.positions[..., 0]).sum(axis=0)


def _covered(
    image: NDArray[np.float32], positions: NDArray[np.float64], size: int
) -> NDArray[np.bool_]:
    """True where the ``size x size`` window around each position is inside ``image`` and
    free of NaN."""
    out = np.zeros(positions.shape[0], bool)
    finite = np.isfinite(positions).all(axis=1)
    start = np.floor(np.where(finite[:, None], positions, 0.0)).astype(np.intp) - size // 2
    inside = finite & (start >= 0).all(axis=1)
    inside &= (start[:, 0] + size <= image.shape[0]) & (start[:, 1] + size <= image.shape[1])
    idx = np.flatnonzero(inside)
    table = nan_integral(image)
    out[idx] = windows_clean(table, start[idx, 0], start[idx, 1], size)
    return out


_OUTLIER_LIMITS = {True: (10.0, 3.0), False: (15.0, 5.0)}
"""(factor, floor px) of the gross-error test with and without parallax vectors."""

ParallaxFunction = Callable[[str, NDArray[np.float64]], NDArray[np.float64]]
"""``(view, ortho positions (N, 2)) -> (N, 2)``: how far a point moves in that view's ortho
per metre of height above the DEM, ortho pixels per metre (:func:`ortho_parallax`)."""


def _neighbour_median(
    points: NDArray[np.float64], values: NDArray[np.float64], k: int = 8
) -> NDArray[np.float64]:
    """Median of ``values`` over the ``k`` nearest other points (NaN for fewer than k + 1
    points)."""
    from scipy.spatial import cKDTree

    if points.shape[0] <= k:
        return np.full(values.shape, np.nan)
    _, nearest = cKDTree(points).query(points, k=k + 1)
    return np.median(values[nearest[:, 1:]], axis=1)


def inconsistent_points(
    points: NDArray[np.float64],
    offsets: NDArray[np.float64],
    parallax: NDArray[np.float64] | None = None,
    factor: float | None = None,
    floor_px: float | None = None,
) -> NDArray[np.bool_]:
    """Points whose offsets to the other views are not those of one ground point (gross
    errors).

    The offsets between system-level orthos are a smooth field (the orientation errors) plus
    the stereo parallax of the DEM's error at each point. So each view's smooth part, the
    median offset of the point's 8 nearest matches in that view, is removed, leaving ``e_v``
    (ortho pixels). With ``parallax`` (each view's parallax vector ``P_v`` relative to the
    reference, px/m: :func:`ortho_parallax`) the point's height error ``dh`` is fitted to all
    its views by least squares and the residual is ``e_v - P_v dh``; a single other view
    explains any error along its parallax by some height, so ``dh`` must also be plausible:
    its parallax ``|dh| max |P_v|`` is tested like the residuals. Without ``parallax`` the
    residual is ``e_v`` itself. A point fails when a residual (or its height's parallax)
    exceeds ``max(floor_px, factor * median over the points)``; defaults: ``factor`` 10 and
    ``floor_px`` 3 with parallax vectors (on the simulated hilly scenes correct matches have
    median residuals of 0.4 px, 99 % below 2.5 px), 15 and 5 without (correct matches
    deviate from their neighbours by up to 19 px there: the parallax of the DEM's errors).
    Regional errors shared by the neighbours (a misregistered area) are not detected.

    Args:
        points: ``(N, 2)`` reference positions.
        offsets: ``(V, N, 2)`` positions in each other view minus ``points``, NaN where none.
        parallax: ``(V, N, 2)`` parallax vectors (0 where unknown), or None.
        factor, floor_px: the limits.

    Returns:
        ``(N,)`` True for the inconsistent points.
    """
    default_factor, default_floor = _OUTLIER_LIMITS[parallax is not None]
    factor = default_factor if factor is None else float(factor)
    floor_px = default_floor if floor_px is None else float(floor_px)
    n_views, n = offsets.shape[:2]
    resid = np.full((n_views, n, 2), np.nan)
    for v in range(n_views):
        ok = np.flatnonzero(np.isfinite(offsets[v, :, 0]))
        if ok.size:
            resid[v, ok] = offsets[v, ok] - _neighbour_median(points[ok], offsets[v, ok])
    bad = np.zeros(n, bool)
    if parallax is not None:
        seen = np.isfinite(resid[..., 0])
        p = np.where(seen[..., None], parallax, 0.0)
        e = np.where(seen[..., None], resid, 0.0)
        norm = np.sum(p * p, axis=(0, 2))
        dh = np.where(norm > 1e-8, np.sum(e * p, axis=(0, 2)) / np.maximum(norm, 1e-8), 0.0)
        resid = resid - parallax * dh[None, :, None]
        # the height error must be plausible too (a single other view explains any error
        # along its parallax by some height): compared, in pixels, like the residuals
        shift = np.abs(dh) * np.sqrt(np.max(np.sum(p * p, axis=2), axis=0))
        fitted = norm > 1e-8
        if fitted.any():
            limit = max(float(floor_px), float(factor) * float(np.median(shift[fitted])))
            bad |= fitted & (shift > limit)
    size = np.hypot(resid[..., 0], resid[..., 1])
    worst = np.max(np.where(np.isfinite(size), size, -1.0), axis=0)
    known = worst >= 0.0
    if known.any():
        limit = max(float(floor_px), float(factor) * float(np.median(worst[known])))
        bad |= known & (worst > limit)
    return bad


def ortho_parallax(
    grid: Any, sensors: Mapping[str, Sensor], dem: Any, reference: str
) -> ParallaxFunction:
    """The parallax vectors of system-level orthos
    (:func:`~carto.framework.imaging.preparation.system_orthos`), relative to the reference's.

    The ortho of view ``v`` shows at ``q`` the raw pixel ``f_v(q) = sensor(q, DEM(q))``. A
    ground point ``dh`` metres above the DEM projects to ``sensor(x, DEM(x) + dh) ~ f_v(x) +
    J_h dh`` and so appears in the ortho at ``x + M^-1 J_h dh``, ``M = df_v/dq`` (the ortho
    mapping's Jacobian, DEM slope included) and ``J_h = d sensor/dh``, both by finite
    differences (1 ortho pixel, 1 m). Returns ``(view, positions) -> k_view(positions) -
    k_reference(positions)`` in ortho pixels per metre: where a match in that view's ortho
    moves, relative to the reference's, when the DEM is ``dh`` too low.
    """

    def raw(name: str, q: NDArray[np.float64], dh: float = 0.0) -> NDArray[np.float64]:
        lon, lat = grid.lonlat(q[:, 0] - 0.5, q[:, 1] - 0.5)
        # extrapolated beyond the image border: a point near it keeps its derivatives
        line, sample, _ = sensors[name].project(lon, lat, dem.height(lon, lat) + dh)
        return np.stack([line, sample], axis=1)

    def k_vector(name: str, q: NDArray[np.float64]) -> NDArray[np.float64]:
        base = raw(name, q)
        step_r, step_c = np.array([1.0, 0.0]), np.array([0.0, 1.0])
        jac = np.stack([raw(name, q + step_r) - base, raw(name, q + step_c) - base], axis=2)
        j_h = raw(name, q, 1.0) - base
        out = np.full(q.shape, np.nan)
        ok = np.isfinite(jac).all(axis=(1, 2)) & np.isfinite(j_h).all(axis=1)
        ok &= np.abs(np.linalg.det(np.where(ok[:, None, None], jac, np.eye(2)))) > 1e-12
        if ok.any():
            out[ok] = np.linalg.solve(jac[ok], j_h[ok][..., None])[..., 0]
        return out

    def parallax(name: str, positions: NDArray[np.float64]) -> NDArray[np.float64]:
        return k_vector(name, positions) - k_vector(reference, positions)

    return parallax


def match_views(
    orthos: Mapping[str, NDArray],
    reference: str,
    points: ArrayLike,
    *,
    template: int = 15,
    search: int = 11,
    levels: int = 4,
    min_score: float = 0.7,
    tolerance_px: float = 0.5,
    closure_px: float = 0.5,
    closure_search: int = 3,
    require_closure: bool = True,
    outlier_factor: float | None = None,
    outlier_floor_px: float | None = None,
    parallax: ParallaxFunction | None = None,
    guesses: Mapping[str, tuple[float, float]] | None = None,
    subpixel: str = "lsm-affine",
    matcher: Matcher | None = None,
) -> MultiViewMatches:
    """Match candidate points of the reference ortho in every other view, with closures.

    1. First guess per view: :func:`~carto.framework.matching.shifts.coarse_shift` of the reference
       against it (or ``guesses[view]``, ``(d_line, d_sample)`` ortho pixels).
    2. Reference -> view: ``matcher.match_points`` (default the ``"ncc"`` matcher:
       :func:`~carto.framework.matching.pyramid.pyramid_match`) with ``levels``,
       ``template``, ``search``, ``subpixel``, both directions within ``tolerance_px``,
       scores >= ``min_score`` both ways (:class:`~carto.framework.matching.base.MatchSettings`).
    2b. Gross errors: points whose offsets one ground point cannot explain are dropped
       (:func:`inconsistent_points`, with the views' parallax vectors when ``parallax`` is
       given; ``outlier_factor`` and ``outlier_floor_px`` override its limits).
    3. Closures (three views or more): for every ordered pair of other views ``(u, v)`` in
       which a point was matched, its position in ``u`` is matched in ``v``
       (``matcher.match_points`` on one level, one direction, around the position the
       reference's match gave, ``+-closure_search`` pixels, ``subpixel``, score >=
       ``min_score``: :func:`~carto.framework.matching.ncc.match_ncc` for ``"ncc"``); the pair is
       consistent when, in both directions, the position found agrees with the reference's
       match within ``closure_px`` ortho pixels (A -> B -> C agrees with A -> C). An
       observation is confirmed by any consistent pair it is part of.
    4. With ``require_closure`` (default), an observation is kept only when confirmed, or
       when no closure was possible: no other view covers the point (its ortho has no data
       in the ``template + 2 search`` window around the point's expected position, the
       reference position plus the first guess). With three views a disagreement drops both
       other views (it cannot tell which is wrong); with more, only the views that agree
       with none. A view that covers the point but found no match makes the others
       unconfirmable: they are dropped too (the point is doubtful). Two views: no closure.

    The closure is an independent check only where the views differ: a match that is wrong
    because of the reference's own template (its texture resembles another place) is
    repeated identically in every view and closes; one that is wrong because of one view's
    content (view-specific texture: water, shadows, clouds, noise) does not.

    Args:
        orthos: view name -> ortho-image, all on one grid.
        reference: the view whose ``points`` are matched.
        points: ``(N, 2)`` distinct candidates on the reference ortho ``(line, sample)``.
        template, search, levels, min_score, tolerance_px, subpixel: matching options
            (:func:`~carto.framework.matching.pyramid.pyramid_match`; ``tolerance_px`` is its
            left-right tolerance).
        closure_px, closure_search, require_closure: the closure check.
        outlier_factor, outlier_floor_px, parallax: the gross-error test of step 2b
            (``parallax``: :func:`ortho_parallax`).
        guesses: first guesses by view, instead of the coarse shift.
        matcher: the matcher of steps 2 and 3 (default: a new ``"ncc"`` matcher).
    """
    if matcher is None:
        matcher = _ncc_matcher()
    primary = match_settings(template, search, levels, min_score, tolerance_px, subpixel)
    closing = attrs.evolve(primary, search_px=closure_search, levels=1, two_way=False)
    pts = _checked_points(orthos, reference, points, closure_px)
    views = (reference, *(n for n in orthos if n != reference))
    images = [as_image(orthos[v], v) for v in views]
    found = _reference_matches(matcher, images, views, pts, guesses, primary)
    _drop_inconsistent(found, views, parallax, outlier_factor, outlier_floor_px)
    closure = _closure_check(matcher, images, found, closing, float(closure_px), require_closure)
    return found.result(views, closure)


def _ncc_matcher() -> Matcher:
    """The default matcher of :func:`match_views`: a new ``"ncc"`` matcher."""
    from carto.framework.matching.ncc_matcher import NCCMatcher

    return NCCMatcher()


def match_settings(
    template: int,
    search: int,
    levels: int,
    min_score: float,
    tolerance_px: float,
    subpixel: str,
) -> MatchSettings:
    """The settings of :func:`match_views`' reference -> view matches (step 2: both
    directions) from its matching options; its closures (step 3) take them on one level, in
    one direction, ``+-closure_search`` pixels."""
    return MatchSettings(
        template_px=template,
        search_px=search,
        levels=levels,
        min_score=min_score,
        two_way=True,
        tolerance_px=tolerance_px,
        subpixel=subpixel,
    )


def _checked_points(
    orthos: Mapping[str, NDArray], reference: str, points: ArrayLike, closure_px: float
) -> NDArray[np.float64]:
    """The candidate points of :func:`match_views` as ``(N, 2)``, once its inputs are checked
    (InputError otherwise)."""
    if reference not in orthos:
        raise InputError(f"tie points: reference {reference!r} is not one of the images")
    if not float(closure_px) > 0.0:
        raise InputError(f"closure_px must be > 0 pixels, got {closure_px}")
    pts = as_points(points, "points")
    if np.unique(pts, axis=0).shape[0] != pts.shape[0]:
        raise InputError("tie points: the candidate points must be distinct")
    return pts


@attrs.frozen(eq=False)
class _ViewMatches:
    """The reference's candidates matched in every view, as :func:`match_views` filters them
    (the arrays are updated in place).

    Attributes:
        positions: ``(V, N, 2)`` ortho positions; ``positions[0]`` are the candidates; NaN
            where a view has no accepted match.
        scores: ``(V, N)`` scores of the accepted matches, NaN elsewhere (the reference row
            until :meth:`result`).
        covered: ``(V, N)`` True where a view has data around the point's expected position,
            or a match.
    """

    positions: NDArray[np.float64]
    scores: NDArray[np.float64]
    covered: NDArray[np.bool_]

    def result(self, views: tuple[str, ...], closure: NDArray[np.bool_]) -> MultiViewMatches:
        """The :class:`MultiViewMatches`, the reference row of the scores the smallest of the
        point's views."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # points without any match
            self.scores[0] = np.nanmin(self.scores[1:], axis=0)
        return MultiViewMatches(views, self.positions, self.scores, closure)


def _first_guess(
    images: Sequence[NDArray],
    views: Sequence[str],
    k: int,
    guesses: Mapping[str, tuple[float, float]] | None,
) -> NDArray[np.float64]:
    """The first guess ``(d_line, d_sample)`` of view ``k`` against the reference (step 1 of
    :func:`match_views`): ``guesses[view]``, else the coarse shift."""
    from carto.framework.matching.shifts import coarse_shift

    if guesses is not None and views[k] in guesses:
        return np.asarray(guesses[views[k]], np.float64).reshape(2)
    d_line, d_sample, _ = coarse_shift(images[0], images[k])
    return np.array([d_line, d_sample])


def _reference_matches(
    matcher: Matcher,
    images: Sequence[NDArray],
    views: Sequence[str],
    pts: NDArray[np.float64],
    guesses: Mapping[str, tuple[float, float]] | None,
    primary: MatchSettings,
) -> _ViewMatches:
    """Steps 1 and 2 of :func:`match_views`: the candidates ``pts`` of the reference
    (``images[0]``) matched in every other view, and where each view covers them (data in the
    ``template + 2 search`` window around the expected position)."""
    n_v, n = len(views), pts.shape[0]
    positions = np.full((n_v, n, 2), np.nan)
    scores = np.full((n_v, n), np.nan)
    covered = np.zeros((n_v, n), bool)
    positions[0] = pts
    window_px = primary.template_px + 2 * primary.search_px
    for k in range(1, n_v):
        guess = _first_guess(images, views, k, guesses)
        found = matcher.match_points(
            images[0], images[k], pts, guess_offsets=guess, settings=primary
        )
        rows = rows_of(pts, found)
        positions[k, rows] = np.stack([found.right_line, found.right_sample], axis=1)
        scores[k, rows] = found.score
        covered[k] = _covered(images[k], pts + guess, window_px)
    covered |= np.isfinite(scores)
    return _ViewMatches(positions, scores, covered)


def _drop_inconsistent(
    found: _ViewMatches,
    views: Sequence[str],
    parallax: ParallaxFunction | None,
    outlier_factor: float | None,
    outlier_floor_px: float | None,
) -> None:
    """Step 2b of :func:`match_views`, in place: the points whose offsets one ground point
    cannot explain (gross errors, :func:`inconsistent_points`) lose their other views."""
    pts = found.positions[0]
    offsets = found.positions[1:] - pts[None]
    vectors = None if parallax is None else _parallax_vectors(parallax, views, found.positions)
    bad = inconsistent_points(pts, offsets, vectors, outlier_factor, outlier_floor_px)
    found.positions[1:, bad] = np.nan
    found.scores[1:, bad] = np.nan


def _closure_check(
    matcher: Matcher,
    images: Sequence[NDArray],
    found: _ViewMatches,
    closing: MatchSettings,
    closure_px: float,
    require_closure: bool,
) -> NDArray[np.bool_]:
    """Steps 3 and 4 of :func:`match_views`: the ``(V, N)`` closure flags (the reference row:
    any view confirmed); the scores of confirmed observations take their closures' into
    account and, with ``require_closure``, the unconfirmed ones that could have been are
    dropped (in place). No closure with fewer than three views."""
    n_v, n = found.scores.shape
    closure = np.zeros((n_v, n), bool)
    if n_v >= 3:
        closure[1:], confirm_score = _closures(
            matcher, images, found.positions, found.scores, closing, closure_px
        )
        found.scores[:] = np.where(closure, np.fmin(found.scores, confirm_score), found.scores)
        if require_closure:
            # a closure was possible for view k where another non-reference view covers it
            others = found.covered[1:].sum(axis=0)[None, :] - found.covered[1:]
            drop = np.zeros((n_v, n), bool)
            drop[1:] = np.isfinite(found.scores[1:]) & ~closure[1:] & (others > 0)
            found.positions[drop] = np.nan
            found.scores[drop] = np.nan
    closure[0] = closure[1:].any(axis=0)
    return closure


def _parallax_vectors(
    parallax: Callable[[str, NDArray], NDArray], views: Sequence[str], positions: NDArray
) -> NDArray:
    """Each other view's parallax direction at its matched positions (``(V-1, N, 2)``; zero
    where unknown): what a height error moves a point along."""
    vectors = np.full((len(views) - 1, positions.shape[1], 2), np.nan)
    for k in range(1, len(views)):
        ok = np.isfinite(positions[k, :, 0])
        if ok.any():
            vectors[k - 1, ok] = parallax(views[k], positions[k, ok])
    vectors[~np.isfinite(vectors).all(axis=2)] = 0.0
    return vectors


def _closures(
    matcher: Matcher,
    images: Sequence[NDArray],
    positions: NDArray,
    scores: NDArray,
    closing: MatchSettings,
    closure_px: float,
) -> tuple[NDArray, NDArray]:
    """The closure of every other view of each point (it matches another view to where the
    reference's match put it, both ways) and the best score that confirms it:
    ``((V-1, N) bool, (V, N))``."""
    n_v, n = scores.shape
    # agree[u, v]: the position in u, matched in v, lands on the reference's match in v
    agree = np.zeros((n_v, n_v, n), bool)
    pair_score = np.full((n_v, n_v, n), np.nan)
    for u, v in permutations(range(1, n_v), 2):
        both = np.flatnonzero(np.isfinite(scores[u]) & np.isfinite(scores[v]))
        if both.size == 0:
            continue
        found = matcher.match_points(
            images[u],
            images[v],
            positions[u, both],
            guess_offsets=positions[v, both] - positions[u, both],
            settings=closing,
        )
        rows = both[rows_of(positions[u, both], found)]
        miss = np.hypot(
            found.right_line - positions[v, rows, 0], found.right_sample - positions[v, rows, 1]
        )
        agree[u, v, rows] = miss <= closure_px
        pair_score[u, v, rows] = found.score
    consistent = agree & agree.transpose(1, 0, 2)
    closure = consistent[1:, 1:].any(axis=1)
    with np.errstate(invalid="ignore"):
        best_pair = np.where(consistent, np.fmin(pair_score, pair_score.transpose(1, 0, 2)), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        confirm_score = np.nanmax(best_pair, axis=1)
    return closure, confirm_score
