"""Automatic tie points between images of one area, matched on system-level ortho-images.

Raw images of different views differ too much in scale, rotation and relief displacement for
area-based matching; their ortho-images made with the system-level models (the ancillary data,
before adjustment) on a coarse DEM differ only by the orientation errors (a smooth shift of
up to some hundred metres) and by the DEM's errors (stereo parallax). So (design brief,
Radhadevi et al. 2010):

1. merge the staggered odd/even arrays of raw Cartosat images
(:mod:`~carto.framework.geometry.stagger`)
   so that every column follows the image model;
2. orthorectify every image on one map grid over the DEM with its system-level model
   (:func:`system_orthos`);
3. candidate points on the reference ortho (:func:`candidate_points`): the Forstner interest
   operator (:func:`~carto.framework.matching.ncc.forstner_points`), the best two of each cell of
   ``spacing_px`` ortho pixels (the second one is a spare: the final selection keeps one
   per cell), with the cell's centre as a fall-back where the operator finds nothing (or a
   plain grid);
4. match in all views at once (:func:`match_views`): the shift between the reference ortho
   and each other one by masked correlation over all shifts
   (:func:`~carto.framework.matching.ncc.coarse_shift`), then normalised cross-correlation in a
   4-level pyramid, least-squares matching with an affine geometry and a left-right check,
   reference -> every other view; gross errors removed by a geometric test: the offsets of
   a point in all views must be those of one ground point, a smooth field plus the parallax
   of one height error (:func:`inconsistent_points`, :func:`ortho_parallax`); with three
   views or more, the position found in each other view is matched again in every other
   one and must land where the reference's match put it (within ``closure_px``): A -> B ->
   C must agree with A -> C, and observations that no closure confirms are dropped;
5. keep a well-distributed subset: per cell of ``spacing_px`` the ``per_cell`` points seen in
   most views, best score first (:func:`~carto.framework.matching.ncc.spread_order`);
6. transform each match back to raw image coordinates: the ortho pixel's map position and DEM
   height, projected with the very model that made that ortho, is where the raw image shows
   that ortho pixel, whatever the model's errors.

:class:`OrthoTiePointMatcher` (name ``"ortho-forstner"``) exposes the pipeline as a matcher
component, so a plugin can offer another.

Accuracy, against independent truth (:func:`tie_point_errors`: the ground point the true
reference model sees on the true DEM at the reference raw coordinates, projected by the true
models), simulated hilly scenes with realistic errors (``benchmarks/tiepoints.py``, 2000 x
2000 px, seed 3): Cartosat-2 triplet 2216 points, none of the 4200 observations wrong by more
than 1 px, 0.095 px RMS (median 0.06 px), 5 s (of which 1.5 s the orthos); Cartosat-1 pair
1865 points, none wrong, 0.12 px RMS, 2 s. Grid candidates: 6-8 % fewer points, 0.11-0.12 px
RMS. The limit is the terrain: the coarse DEM's height errors displace the orthos of
different views against each other, and this parallax varies across a template (a relative
scale of up to 50 % on steep slopes); translation-only least-squares matching measures the
displacement where the template's texture is, not at its centre (0.27-0.29 px RMS, 0.8 %
of the observations more than 1 px off), hence the affine model.
"""

from __future__ import annotations

import inspect
import math
import warnings
from collections.abc import Callable, Mapping
from itertools import permutations
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.preparation import system_orthos
from carto.framework.matching.base import Matcher, Matches

CANDIDATE_METHODS = ("forstner", "grid")
"""Ways :func:`candidate_points` chooses the points to match."""

TABLE_COLUMNS = ("id", "image", "line", "sample", "score", "sigma_px")
"""Columns of the tie-point table (long format: one row per point and image)."""


# ----------------------------------------------------------------------------- ortho-images


# ----------------------------------------------------------------------------- candidates
def _cells(shape: tuple[int, int], spacing_px: float) -> tuple[int, int]:
    return (
        max(1, round(shape[0] / float(spacing_px))),
        max(1, round(shape[1] / float(spacing_px))),
    )


def _finite_at(image: NDArray[np.float32], points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """True where the pixel holding each point has data."""
    index = (points - 0.5).astype(np.intp)
    return np.isfinite(image[index[:, 0], index[:, 1]])


def candidate_points(
    image: ArrayLike,
    spacing_px: float = 40.0,
    *,
    method: str = "forstner",
    per_cell: int = 2,
    window: int = 5,
    min_roundness: float = 0.5,
    weight_quantile: float = 0.5,
) -> NDArray[np.float64]:
    """Points of ``image`` worth matching, ``(N, 2)`` ``(line, sample)`` (first pixel centre
    at 0.5), spread over cells of about ``spacing_px`` pixels.

    ``method="forstner"``: :func:`~carto.framework.matching.ncc.forstner_points` (box ``window``,
    ``min_roundness``, weight above the ``weight_quantile`` of the image's weights,
    suppression radius ``window``, least-squares corner location), the best ``per_cell`` of
    each cell (the quantile only removes the weakest half: the cells choose the best); a
    cell where the operator finds nothing (no texture, or only straight edges) gets its
    centre pixel instead, where that pixel holds data (the fall-back grid). ``"grid"``:
    :func:`~carto.framework.matching.ncc.grid_points` every ``spacing_px`` with a margin of two
    thirds of it, where the pixel holds data.
    """
    from carto.framework.matching.ncc import _as_image, forstner_points, grid_points

    img = _as_image(image, "image")
    if method not in CANDIDATE_METHODS:
        raise InputError(f"candidates {method!r} is not one of {', '.join(CANDIDATE_METHODS)}")
    spacing = float(spacing_px)
    if not spacing >= 4.0:
        raise InputError(f"spacing_px must be >= 4 pixels, got {spacing_px}")
    if method == "grid":
        points = grid_points(img.shape, spacing, margin=2 * spacing / 3)
        return points[_finite_at(img, points)]
    cells = _cells(img.shape, spacing)
    size = np.array([img.shape[0] / cells[0], img.shape[1] / cells[1]])
    points = forstner_points(
        img,
        window=window,
        min_roundness=min_roundness,
        weight_quantile=weight_quantile,
        grid_cells=cells,
        per_cell=per_cell,
    )
    occupied = np.zeros(cells, bool)
    index = np.minimum((points // size).astype(np.intp), np.array(cells) - 1)
    occupied[index[:, 0], index[:, 1]] = True
    empty_r, empty_c = np.nonzero(~occupied)
    centres = np.floor((np.stack([empty_r, empty_c], axis=1) + 0.5) * size) + 0.5
    return np.concatenate([points, centres[_finite_at(img, centres)]])


# ----------------------------------------------------------------------------- matching
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


def _rows_of(points: NDArray[np.float64], matches: Matches) -> NDArray[np.intp]:
    """Row in ``points`` of each match (matches keep their left point unchanged)."""
    key = points[:, 0] + 1j * points[:, 1]
    order = np.argsort(key, kind="stable")
    found = matches.left_line + 1j * matches.left_sample
    return order[np.searchsorted(key[order], found)]


def _covered(
    image: NDArray[np.float32], positions: NDArray[np.float64], size: int
) -> NDArray[np.bool_]:
    """True where the ``size x size`` window around each position is inside ``image`` and
    free of NaN."""
    from carto.framework.matching.ncc import _nan_integral, _windows_clean

    out = np.zeros(positions.shape[0], bool)
    finite = np.isfinite(positions).all(axis=1)
    start = np.floor(np.where(finite[:, None], positions, 0.0)).astype(np.intp) - size // 2
    inside = finite & (start >= 0).all(axis=1)
    inside &= (start[:, 0] + size <= image.shape[0]) & (start[:, 1] + size <= image.shape[1])
    idx = np.flatnonzero(inside)
    table = _nan_integral(image)
    out[idx] = _windows_clean(table, start[idx, 0], start[idx, 1], size)
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
    """The parallax vectors of system-level orthos (:func:`system_orthos`), relative to the
    reference's.

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
) -> MultiViewMatches:
    """Match candidate points of the reference ortho in every other view, with closures.

    1. First guess per view: :func:`~carto.framework.matching.ncc.coarse_shift` of the reference
       against it (or ``guesses[view]``, ``(d_line, d_sample)`` ortho pixels).
    2. Reference -> view: :func:`~carto.framework.matching.ncc.pyramid_match` (``levels``,
       ``template``, ``search``, ``subpixel``, both directions within ``tolerance_px``,
       scores >= ``min_score`` both ways).
    2b. Gross errors: points whose offsets one ground point cannot explain are dropped
       (:func:`inconsistent_points`, with the views' parallax vectors when ``parallax`` is
       given; ``outlier_factor`` and ``outlier_floor_px`` override its limits).
    3. Closures (three views or more): for every ordered pair of other views ``(u, v)`` in
       which a point was matched, its position in ``u`` is matched in ``v``
       (:func:`~carto.framework.matching.ncc.match_ncc` around the position the reference's match
       gave, ``+-closure_search`` pixels, ``subpixel``, score >= ``min_score``); the pair is
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
            (:func:`~carto.framework.matching.ncc.pyramid_match`; ``tolerance_px`` is its left-right
            tolerance).
        closure_px, closure_search, require_closure: the closure check.
        outlier_factor, outlier_floor_px, parallax: the gross-error test of step 2b
            (``parallax``: :func:`ortho_parallax`).
        guesses: first guesses by view, instead of the coarse shift.
    """
    from carto.framework.matching.ncc import (
        _as_image,
        _as_points,
        coarse_shift,
        match_ncc,
        pyramid_match,
    )

    if reference not in orthos:
        raise InputError(f"tie points: reference {reference!r} is not one of the images")
    if not float(closure_px) > 0.0:
        raise InputError(f"closure_px must be > 0 pixels, got {closure_px}")
    pts = _as_points(points, "points")
    if np.unique(pts, axis=0).shape[0] != pts.shape[0]:
        raise InputError("tie points: the candidate points must be distinct")
    views = (reference, *(n for n in orthos if n != reference))
    images = [_as_image(orthos[v], v) for v in views]
    n_v, n = len(views), pts.shape[0]
    positions = np.full((n_v, n, 2), np.nan)
    scores = np.full((n_v, n), np.nan)
    covered = np.zeros((n_v, n), bool)
    positions[0] = pts
    for k in range(1, n_v):
        if guesses is not None and views[k] in guesses:
            guess = np.asarray(guesses[views[k]], np.float64).reshape(2)
        else:
            d_line, d_sample, _ = coarse_shift(images[0], images[k])
            guess = np.array([d_line, d_sample])
        found = pyramid_match(
            images[0],
            images[k],
            pts,
            levels=levels,
            template=template,
            search=search,
            subpixel=subpixel,
            min_score=min_score,
            guess_offsets=guess,
            tolerance=tolerance_px,
        )
        rows = _rows_of(pts, found)
        positions[k, rows] = np.stack([found.right_line, found.right_sample], axis=1)
        scores[k, rows] = found.score
        covered[k] = _covered(images[k], pts + guess, template + 2 * search)
    covered |= np.isfinite(scores)
    # gross errors: offsets that one ground point cannot explain
    offsets = positions[1:] - pts[None]
    vectors = None
    if parallax is not None:
        vectors = np.full(offsets.shape, np.nan)
        for k in range(1, n_v):
            ok = np.isfinite(positions[k, :, 0])
            if ok.any():
                vectors[k - 1, ok] = parallax(views[k], positions[k, ok])
        unknown = ~np.isfinite(vectors).all(axis=2)
        vectors[unknown] = 0.0
    bad = inconsistent_points(pts, offsets, vectors, outlier_factor, outlier_floor_px)
    positions[1:, bad] = np.nan
    scores[1:, bad] = np.nan
    closure = np.zeros((n_v, n), bool)
    if n_v >= 3:
        # agree[u, v]: the position in u, matched in v, lands on the reference's match in v
        agree = np.zeros((n_v, n_v, n), bool)
        pair_score = np.full((n_v, n_v, n), np.nan)
        for u, v in permutations(range(1, n_v), 2):
            both = np.flatnonzero(np.isfinite(scores[u]) & np.isfinite(scores[v]))
            if both.size == 0:
                continue
            found = match_ncc(
                images[u],
                images[v],
                positions[u, both],
                template=template,
                search=closure_search,
                subpixel=subpixel,
                min_score=min_score,
                guess_offsets=positions[v, both] - positions[u, both],
            )
            rows = both[_rows_of(positions[u, both], found)]
            miss = np.hypot(
                found.right_line - positions[v, rows, 0], found.right_sample - positions[v, rows, 1]
            )
            agree[u, v, rows] = miss <= float(closure_px)
            pair_score[u, v, rows] = found.score
        consistent = agree & agree.transpose(1, 0, 2)
        closure[1:] = consistent[1:, 1:].any(axis=1)
        with np.errstate(invalid="ignore"):
            best_pair = np.where(
                consistent, np.fmin(pair_score, pair_score.transpose(1, 0, 2)), np.nan
            )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
            confirm_score = np.nanmax(best_pair, axis=1)
        scores = np.where(closure, np.fmin(scores, confirm_score), scores)
        if require_closure:
            # a closure was possible for view k where another non-reference view covers it
            others = covered[1:].sum(axis=0)[None, :] - covered[1:]
            drop = np.zeros((n_v, n), bool)
            drop[1:] = np.isfinite(scores[1:]) & ~closure[1:] & (others > 0)
            positions[drop] = np.nan
            scores[drop] = np.nan
    closure[0] = closure[1:].any(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # points without any match
        scores[0] = np.nanmin(scores[1:], axis=0)
    return MultiViewMatches(views, positions, scores, closure)


# ----------------------------------------------------------------------------- the pipeline
def _empty_table() -> dict[str, NDArray]:
    return {k: np.empty(0, object if k in ("id", "image") else float) for k in TABLE_COLUMNS}


def automatic_tie_points(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    *,
    reference: str | None = None,
    resolution_m: float | None = None,
    spacing_px: float = 40.0,
    min_score: float = 0.7,
    sigma_px: float = 0.3,
    points: NDArray | None = None,
    candidates: str = "forstner",
    per_cell: int = 1,
    min_views: int = 2,
    template: int = 15,
    search: int = 11,
    levels: int = 4,
    tolerance_px: float = 0.5,
    closure_px: float = 0.5,
    require_closure: bool = True,
    subpixel: str = "lsm-affine",
    forstner: Mapping[str, Any] | None = None,
    min_points: int = 300,
) -> dict[str, NDArray]:
    """Tie points of ``sensors``' images, as a long table ``id, image, line, sample, score,
    sigma_px`` (raw image coordinates; one row per point and image).

    The method is the module's (system-level orthos, Forstner candidates, multi-view matching
    with closures, a well-distributed subset, back to raw coordinates).

    Args:
        rasters: image name -> raster file or array (raw, as recorded).
        sensors: image name -> system-level model of that image.
        dem: the coarse DEM to orthorectify on (ellipsoidal heights).
        reference: image whose ortho the others are matched against (default: the first).
        resolution_m: ortho resolution (default: the coarsest image's ground sampling).
        spacing_px: cell size of the candidates and of the final selection, ortho pixels;
            when fewer than ``min_points`` points are kept (a small common area), the
            matching is repeated with denser cells, down to :data:`MIN_SPACING_PX`.
        min_score: smallest accepted correlation (both directions, and the closures).
        sigma_px: a-priori standard deviation given to each measurement.
        points: candidate points on the reference ortho ``(N, 2)`` (row, col in ortho pixels,
            first pixel centre at 0.5) instead of :func:`candidate_points`.
        candidates: ``"forstner"`` or ``"grid"`` (see :func:`candidate_points`).
        per_cell: points kept per cell of ``spacing_px`` (those in most views, best score
            first); ``0`` keeps all.
        min_views: points seen in fewer images are dropped.
        template, search, levels, tolerance_px, closure_px, require_closure, subpixel: see
            :func:`match_views` (``subpixel="lsm"`` for translation-only least-squares
            matching: faster, but see the module docstring for its accuracy).
        forstner: options of :func:`candidate_points` (``window``, ``min_roundness``,
            ``weight_quantile``, ``per_cell``).

    Returns:
        the table; ``score`` is the correlation score of the point's match in that image
        (the reference row: the smallest of its images'). Ids are ``A`` and the candidate's
        index.
    """

    names = list(sensors)
    if len(names) < 2:
        raise InputError("tie points need at least two images")
    ref = reference or names[0]
    if ref not in sensors:
        raise InputError(f"tie points: reference {ref!r} is not one of {', '.join(names)}")
    grid, orthos = system_orthos(rasters, sensors, dem, resolution_m)
    given = points
    spacing = float(spacing_px)
    while True:
        table = tie_points_on_orthos(
            grid,
            orthos,
            sensors,
            dem,
            ref,
            spacing,
            given,
            candidates,
            forstner,
            dict(
                template=template,
                search=search,
                levels=levels,
                min_score=min_score,
                tolerance_px=tolerance_px,
                closure_px=closure_px,
                require_closure=require_closure,
                subpixel=subpixel,
            ),
            per_cell,
            min_views,
            sigma_px,
        )
        n = len(set(table["id"].tolist()))
        # a small common area (large system-level misregistration, partial overlap) leaves
        # few cells: denser candidates, down to MIN_SPACING_PX, until min_points are kept
        if given is not None or n >= min_points or spacing <= MIN_SPACING_PX:
            return table
        spacing = max(MIN_SPACING_PX, spacing * math.sqrt(max(n, 1) / min_points))


MIN_SPACING_PX = 16.0
"""Densest candidate spacing :func:`automatic_tie_points` goes to when too few points are kept."""


def tie_points_on_orthos(
    grid: Any,
    orthos: Mapping[str, NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    ref: str,
    spacing_px: float,
    points: NDArray | None,
    candidates: str,
    forstner: Mapping[str, Any] | None,
    matching: Mapping[str, Any],
    per_cell: int,
    min_views: int,
    sigma_px: float,
) -> dict[str, NDArray]:
    """Candidates, multi-view matching and selection on orthos already made on ``grid``
    (steps 3-6 of the module docstring; arguments as :func:`automatic_tie_points`'s, with
    ``matching`` the options of :func:`match_views`): the tie-point table, raw coordinates
    computed with the very models that made the orthos. Also used on small ortho chips
    (:mod:`~carto.framework.matching.gcp_transfer`)."""
    from carto.framework.matching.ncc import spread_order

    if points is None:
        points = candidate_points(
            orthos[ref], spacing_px, method=candidates, **dict(forstner or {})
        )
    points = np.asarray(points, np.float64).reshape(-1, 2)
    if points.shape[0] == 0:
        return _empty_table()
    mv = match_views(
        orthos,
        ref,
        points,
        **matching,
        parallax=ortho_parallax(grid, sensors, dem, ref),
    )
    # back to raw image coordinates, with the model that made each ortho
    raw = np.full(mv.positions.shape, np.nan)
    for k, name in enumerate(mv.views):
        ok = np.isfinite(mv.positions[k, :, 0])
        if not ok.any():
            continue
        px = mv.positions[k, ok]
        lon, lat = grid.lonlat(px[:, 0] - 0.5, px[:, 1] - 0.5)
        line, sample = sensors[name].ground_to_image(lon, lat, dem.height(lon, lat))
        raw[k, ok] = np.stack([line, sample], axis=1)
    seen = np.isfinite(raw).all(axis=2)
    n_seen = seen.sum(axis=0)
    keep = np.flatnonzero(seen[0] & (n_seen >= max(int(min_views), 2)))
    if keep.size == 0:
        return _empty_table()
    if per_cell:
        weight = n_seen[keep] + 0.5 * np.nan_to_num(mv.scores[0, keep], nan=-1.0)
        order = spread_order(
            points[keep], weight, grid.shape, _cells(grid.shape, spacing_px), per_cell
        )
        keep = np.sort(keep[order])
    point_pos, view_idx = np.nonzero(seen[:, keep].T)  # row-major: by point, then view
    point_idx = keep[point_pos]
    ids = np.array([f"A{i:05d}" for i in keep], object)
    return {
        "id": ids[point_pos],
        "image": np.array(mv.views, object)[view_idx],
        "line": raw[view_idx, point_idx, 0],
        "sample": raw[view_idx, point_idx, 1],
        "score": mv.scores[view_idx, point_idx],
        "sigma_px": np.full(point_idx.size, float(sigma_px)),
    }


def tie_point_errors(
    table: Mapping[str, NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    reference: str | None = None,
) -> NDArray[np.float64]:
    """Distance, pixels, of every row of a tie-point table from where ``sensors`` put the
    point: for validation against independent truth (true models and DEM of a simulation).

    The point's ground position is where ``sensors[reference]`` sees ``dem`` at the point's
    reference row (:meth:`~carto.framework.geometry.sensor.Sensor.locate_on_dem`); each other row is
    compared with that position projected by its image's sensor. The reference coordinates
    themselves come from the system-level ortho, so they are not checked; what is checked is
    that every other image's coordinates show the ground the reference coordinates show.

    Args:
        table: long table ``id, image, line, sample`` (:func:`automatic_tie_points`).
        sensors: image name -> model (the true ones).
        dem: DEM with ellipsoidal heights (the true one).
        reference: the reference image (default: the image of each point's first row).

    Returns:
        one value per row; NaN for the reference rows, points without a reference row, and
        points whose ground position cannot be found.
    """
    ids = np.asarray(table["id"], object)
    images = np.asarray(table["image"], object)
    rc = np.stack([np.asarray(table["line"], float), np.asarray(table["sample"], float)], 1)
    out = np.full(ids.size, np.nan)
    if ids.size == 0:
        return out
    uniq, inverse = np.unique(ids, return_inverse=True)
    if reference is None:  # the first row of each point
        order = np.argsort(inverse, kind="stable")
        ref_row = order[np.searchsorted(inverse[order], np.arange(uniq.size))]
    else:
        ref_row = np.full(uniq.size, -1)
        rows = np.flatnonzero(images == reference)
        ref_row[inverse[rows]] = rows
    has_ref = ref_row >= 0
    ground = np.full((uniq.size, 3), np.nan)
    for name in np.unique(images[ref_row[has_ref]]):
        pts = np.flatnonzero(has_ref & (images[np.maximum(ref_row, 0)] == name))
        lon, lat, h = sensors[str(name)].locate_on_dem(
            rc[ref_row[pts], 0], rc[ref_row[pts], 1], dem
        )
        ground[pts] = np.stack([lon, lat, h], axis=1)
    is_ref = np.zeros(ids.size, bool)
    is_ref[ref_row[has_ref]] = True
    for name in np.unique(images):
        rows = np.flatnonzero((images == name) & ~is_ref)
        if rows.size == 0:
            continue
        g = ground[inverse[rows]]
        line, sample = sensors[str(name)].ground_to_image(g[:, 0], g[:, 1], g[:, 2])
        out[rows] = np.hypot(rc[rows, 0] - line, rc[rows, 1] - sample)
    return out


# ----------------------------------------------------------------------------- component
_PIPELINE_DEFAULTS: dict[str, Any] = {
    p.name: p.default
    for p in inspect.signature(automatic_tie_points).parameters.values()
    if p.kind is inspect.Parameter.KEYWORD_ONLY
}


class OrthoTiePointMatcher(Matcher):
    """Tie points on system-level ortho-images: Forstner candidates, NCC, closures.

    :meth:`tie_points` runs :func:`automatic_tie_points` on a block of raw images;
    :meth:`match` matches two images already in one geometry (e.g. two orthos on one grid):
    Forstner candidates of the left image (:func:`candidate_points`), the first guess from
    :func:`~carto.framework.matching.ncc.coarse_shift`, pyramid NCC with least-squares sub-pixel
    refinement and the left-right check.

    Args:
        options: keyword options of :func:`automatic_tie_points` (``spacing_px``,
            ``min_score``, ``candidates``, ``template`` ...); those that apply to two images
            are used by :meth:`match` too.
    """

    name = "ortho-forstner"
    description = (
        "tie points on system-level ortho-images: Forstner candidates, pyramid NCC with "
        "least-squares sub-pixel, left-right and multi-view closure checks"
    )

    def __init__(self, **options: Any) -> None:
        unknown = sorted(set(options) - set(_PIPELINE_DEFAULTS))
        if unknown:
            raise InputError(
                f"{self.name}: unknown option(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(_PIPELINE_DEFAULTS))}"
            )
        self.options = dict(options)

    def tie_points(
        self,
        rasters: Mapping[str, Path | NDArray],
        sensors: Mapping[str, Sensor],
        dem: Any,
        **options: Any,
    ) -> dict[str, NDArray]:
        """The tie-point table of :func:`automatic_tie_points` with this matcher's options
        (``options`` override them)."""
        return automatic_tie_points(rasters, sensors, dem, **{**self.options, **options})

    def match(self, left: NDArray, right: NDArray) -> Matches:
        """Match two images in one geometry (e.g. orthos on one grid): the candidates of the
        left image (:func:`candidate_points`, or the ``points`` option) matched as the two-view
        case of :func:`match_views` (coarse shift, pyramid, left-right check, gross-error
        test); the options are this matcher's."""
        from carto.framework.matching.ncc import _as_image

        o = {**_PIPELINE_DEFAULTS, **self.options}
        left_img = _as_image(left, "left")
        points = o["points"]
        if points is None:
            points = candidate_points(
                left_img, o["spacing_px"], method=o["candidates"], **dict(o["forstner"] or {})
            )
        points = np.asarray(points, np.float64).reshape(-1, 2)
        if points.shape[0] == 0:
            return Matches([], [], [], [], [])
        mv = match_views(
            {"left": left_img, "right": _as_image(right, "right")},
            "left",
            points,
            template=o["template"],
            search=o["search"],
            levels=o["levels"],
            min_score=o["min_score"],
            tolerance_px=o["tolerance_px"],
            subpixel=o["subpixel"],
        )
        ok = np.isfinite(mv.positions[1, :, 0])
        right_pts = mv.positions[1, ok]
        return Matches(
            points[ok, 0], points[ok, 1], right_pts[:, 0], right_pts[:, 1], mv.scores[1, ok]
        )


def overlap_fraction(a: Sensor, b: Sensor, h_m: float = 0.0, n: int = 24) -> float:
    """Fraction of image ``a``'s footprint (at height ``h_m``) that image ``b`` also sees:
    an ``n x n`` grid of ``a``'s pixels located at ``h_m`` and projected into ``b``."""
    n_l, n_s = a.image_shape
    line, sample = np.meshgrid(
        (np.arange(n) + 0.5) * n_l / n, (np.arange(n) + 0.5) * n_s / n, indexing="ij"
    )
    lon, lat = a.image_to_ground(line.ravel(), sample.ravel(), np.full(n * n, h_m))
    _, _, inside = b.project(lon, lat, np.full(n * n, h_m))
    return float(np.mean(inside))


def overlapping_pairs(
    sensors: Mapping[str, Sensor], h_m: float = 0.0, min_fraction: float = 0.02
) -> list[tuple[str, str]]:
    """Pairs of images that see a common ground area (at height ``h_m``) of at least
    ``min_fraction`` of either footprint (:func:`overlap_fraction`)."""
    names = list(sensors)
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            f = max(
                overlap_fraction(sensors[a], sensors[b], h_m),
                overlap_fraction(sensors[b], sensors[a], h_m),
            )
            if f >= min_fraction:
                pairs.append((a, b))
    return pairs


def block_tie_points(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    **options: Any,
) -> dict[str, NDArray]:
    """Tie points of a block whose images need not all overlap one reference (paint-brush
    swaths, strips): when the first image shares at least half its footprint with every
    other, one multi-view :func:`automatic_tie_points`; otherwise :func:`automatic_tie_points`
    on every overlapping pair (:func:`overlapping_pairs`), with point ids prefixed by the pair
    so that they stay distinct."""
    h_mid = float(np.nanmedian(dem.heights)) if hasattr(dem, "heights") else 0.0
    names = list(sensors)
    if len(names) <= 2:
        return automatic_tie_points(rasters, sensors, dem, **options)
    # one multi-view matching when the first image shares most of its area with every other
    # (a triplet); otherwise pairwise (the narrow overlaps of adjacent swaths)
    ref = sensors[names[0]]
    if all(overlap_fraction(ref, sensors[n], h_mid) >= 0.5 for n in names[1:]):
        return automatic_tie_points(rasters, sensors, dem, **options)
    pairs = overlapping_pairs(sensors, h_mid)
    tables = []
    for a, b in pairs:
        t = automatic_tie_points(
            {a: rasters[a], b: rasters[b]}, {a: sensors[a], b: sensors[b]}, dem, **options
        )
        t["id"] = np.array([f"{a}-{b}:{i}" for i in t["id"]], object)
        tables.append(t)
    if not tables:
        raise InputError("tie points: no two images of the block overlap")
    keys = tables[0].keys()
    return {k: np.concatenate([t[k] for t in tables]) for k in keys}
