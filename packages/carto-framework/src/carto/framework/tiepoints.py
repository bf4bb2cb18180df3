"""Automatic tie points between images of one area, matched on system-level ortho-images.

Raw images of different views differ too much in scale, rotation and relief displacement for
area-based matching; their ortho-images made with the system-level models (the ancillary data,
before adjustment) on a coarse DEM differ only by the orientation errors (a smooth shift of
up to some hundred metres) and by the DEM's errors. So (design brief, Radhadevi et al. 2010):

1. merge the staggered odd/even arrays of raw Cartosat images (:mod:`~carto.framework.stagger`)
   so that every column follows the image model;
2. orthorectify every image on one map grid over the DEM with its system-level model
   (:func:`system_orthos`);
3. candidate points on the reference ortho (:func:`candidate_points`): the Forstner interest
   operator (:func:`~carto.framework.match.forstner_points`), the best two per cell of
   ``spacing_px`` ortho pixels, with the cell's centre as a fall-back where the operator
   finds nothing (or a plain grid);
4. match in all views at once (:func:`match_views`): the shift between the reference ortho
   and each other one by masked correlation over all shifts
   (:func:`~carto.framework.match.coarse_shift`), then normalised cross-correlation in a
   pyramid with least-squares sub-pixel refinement and a left-right check, reference ->
   every other view; with three views or more, the position found in each other view is
   matched again in every other one and must land where the reference's match put it
   (within ``closure_px``): A -> B -> C must agree with A -> C. Observations that no such
   closure confirms are dropped, which removes the wrong matches a single pair cannot reveal;
5. keep a well-distributed subset: per cell of ``spacing_px`` the ``per_cell`` points seen in
   most views, best score first (:func:`~carto.framework.match.spread_order`);
6. transform each match back to raw image coordinates: the ortho pixel's map position and DEM
   height, projected with the very model that made that ortho, is where the raw image shows
   that ortho pixel, whatever the model's errors.

:class:`OrthoTiePointMatcher` (name ``"ortho-forstner"``) exposes the pipeline as a matcher
component, so a plugin can offer another.

Accuracy (``tests/framework/test_tiepoints.py``, ``benchmarks/tiepoints.py``), against
independent truth (the ground point the true reference model sees on the true DEM at the
reference raw coordinates, projected by the true models): see the benchmark's output. The
accuracy limit is the terrain: the coarse DEM's height errors displace the orthos of
different views against each other (stereo parallax), and a template measures the mean
displacement over its window, not the one at its centre; corners (Forstner points) hold
their texture near the centre and are located better than grid points.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Mapping
from itertools import permutations
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.linescan import LineScanner
from carto.framework.match import Matcher, Matches
from carto.framework.sensor import Sensor

CANDIDATE_METHODS = ("forstner", "grid")
"""Ways :func:`candidate_points` chooses the points to match."""

TABLE_COLUMNS = ("id", "image", "line", "sample", "score", "sigma_px")
"""Columns of the tie-point table (long format: one row per point and image)."""


def read_raster(path: Path) -> NDArray[np.float32]:
    """The first band of a raster as float32 (nodata as NaN)."""
    import rasterio

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(path) as ds:
                data = ds.read(1, masked=True)
    except rasterio.errors.RasterioError as exc:
        raise InputError(f"{path}: cannot read raster: {exc}") from None
    return np.ma.filled(data.astype(np.float32), np.nan)


def prepared_image(raw: NDArray, sensor: Sensor, dem: Any) -> NDArray[np.float32]:
    """The raw image with staggered arrays merged onto the model's geometry (line scanners
    of a staggered camera); other images as they are."""
    if (
        isinstance(sensor, LineScanner)
        and sensor.camera.stagger_tan
        and (sensor.camera.array == "odd")
    ):
        from carto.framework.stagger import merge_staggered

        return merge_staggered(raw, sensor, dem, step=8).image
    return np.asarray(raw, np.float32)


def ground_sampling_m(sensor: Sensor, h_m: float = 0.0) -> float:
    """The ground distance between neighbouring pixels at the image centre (mean of the two
    directions), metres."""
    from carto.framework import frames

    n_l, n_s = sensor.image_shape
    line = np.array([n_l / 2, n_l / 2 + 1, n_l / 2])
    sample = np.array([n_s / 2, n_s / 2, n_s / 2 + 1])
    lon, lat = sensor.image_to_ground(line, sample, h_m)
    xyz = frames.geodetic_to_ecef(lon, lat, h_m)
    return float(0.5 * (np.linalg.norm(xyz[1] - xyz[0]) + np.linalg.norm(xyz[2] - xyz[0])))


# ----------------------------------------------------------------------------- ortho-images
def system_orthos(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    resolution_m: float | None = None,
) -> tuple[Any, dict[str, NDArray[np.float32]]]:
    """Every image orthorectified with its (system-level) model on one grid over ``dem``.

    Args:
        rasters: image name -> raster file or array (raw, as recorded).
        sensors: image name -> model of that image.
        dem: DEM with ellipsoidal heights.
        resolution_m: grid resolution (default: the coarsest image's ground sampling at the
            DEM's median height).

    Returns:
        ``(grid, orthos)``: the :class:`~carto.framework.ortho.OrthoGrid` covering all
        footprints, and image name -> float32 ortho (NaN outside the image or the DEM).
    """
    from carto.framework.ortho import OrthoGrid, orthorectify

    names = list(sensors)
    missing = [n for n in names if n not in rasters]
    if missing:
        raise InputError(f"tie points: no raster for image(s) {', '.join(missing)}")
    h_mid = float(np.nanmedian(dem.heights)) if hasattr(dem, "heights") else 0.0
    res = resolution_m or max(ground_sampling_m(sensors[n], h_mid) for n in names)
    grid = OrthoGrid.covering([sensors[n] for n in names], dem, res)
    orthos = {}
    for name in names:
        raw = rasters[name]
        raw = read_raster(Path(raw)) if not isinstance(raw, np.ndarray) else raw
        image = prepared_image(raw, sensors[name], dem)
        orthos[name] = orthorectify(image, sensors[name], grid, dem)
    return grid, orthos


# ----------------------------------------------------------------------------- candidates
def _cells(shape: tuple[int, int], spacing_px: float) -> tuple[int, int]:
    return (
        max(1, round(shape[0] / float(spacing_px))),
        max(1, round(shape[1] / float(spacing_px))),
    )


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

    ``method="forstner"``: :func:`~carto.framework.match.forstner_points` (box ``window``,
    ``min_roundness``, weight above the ``weight_quantile`` of the image's weights,
    suppression radius ``window``, least-squares corner location), the best ``per_cell`` of
    each cell; a cell where the operator finds nothing (little or only linear texture) gets
    its centre pixel instead, where that pixel holds data (the fall-back grid). ``"grid"``:
    the centre pixels of the cells (:func:`~carto.framework.match.grid_points`).
    """
    from carto.framework.match import _as_image, forstner_points, grid_points

    img = _as_image(image, "image")
    if method not in CANDIDATE_METHODS:
        raise InputError(f"candidates {method!r} is not one of {', '.join(CANDIDATE_METHODS)}")
    spacing = float(spacing_px)
    if not spacing >= 4.0:
        raise InputError(f"spacing_px must be >= 4 pixels, got {spacing_px}")
    cells = _cells(img.shape, spacing)
    size = (img.shape[0] / cells[0], img.shape[1] / cells[1])
    centres = np.stack(
        np.meshgrid(
            np.floor((np.arange(cells[0]) + 0.5) * size[0]) + 0.5,
            np.floor((np.arange(cells[1]) + 0.5) * size[1]) + 0.5,
            indexing="ij",
        ),
        axis=-1,
    ).reshape(-1, 2)
    finite = np.isfinite(img[(centres[:, 0] - 0.5).astype(int), (centres[:, 1] - 0.5).astype(int)])
    if method == "grid":
        points = grid_points(img.shape, spacing, margin=2 * spacing / 3)
        return points[
            np.isfinite(img[(points[:, 0] - 0.5).astype(int), (points[:, 1] - 0.5).astype(int)])
        ]
    points = forstner_points(
        img,
        window=window,
        min_roundness=min_roundness,
        weight_quantile=weight_quantile,
        grid_cells=cells,
        per_cell=per_cell,
    )
    cell_of = np.clip((points[:, 0] / size[0]).astype(int), 0, cells[0] - 1) * cells[1] + np.clip(
        (points[:, 1] / size[1]).astype(int), 0, cells[1] - 1
    )
    empty = np.ones(cells[0] * cells[1], bool)
    empty[cell_of] = False
    return np.concatenate([points, centres[empty & finite]])


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
    from carto.framework.match import _nan_integral, _windows_clean

    out = np.zeros(positions.shape[0], bool)
    finite = np.isfinite(positions).all(axis=1)
    start = np.floor(np.where(finite[:, None], positions, 0.0)).astype(np.intp) - size // 2
    inside = finite & (start >= 0).all(axis=1)
    inside &= (start[:, 0] + size <= image.shape[0]) & (start[:, 1] + size <= image.shape[1])
    idx = np.flatnonzero(inside)
    table = _nan_integral(image)
    out[idx] = _windows_clean(table, start[idx, 0], start[idx, 1], size)
    return out


def match_views(
    orthos: Mapping[str, NDArray],
    reference: str,
    points: ArrayLike,
    *,
    template: int = 15,
    search: int = 11,
    levels: int = 3,
    min_score: float = 0.7,
    tolerance_px: float = 0.5,
    closure_px: float = 0.5,
    closure_search: int = 3,
    require_closure: bool = True,
    guesses: Mapping[str, tuple[float, float]] | None = None,
    subpixel: str = "lsm-affine",
) -> MultiViewMatches:
    """Match candidate points of the reference ortho in every other view, with closures.

    1. First guess per view: :func:`~carto.framework.match.coarse_shift` of the reference
       against it (or ``guesses[view]``, ``(d_line, d_sample)`` ortho pixels).
    2. Reference -> view: :func:`~carto.framework.match.pyramid_match` (``levels``,
       ``template``, ``search``, ``subpixel``, both directions within ``tolerance_px``,
       scores >= ``min_score`` both ways).
    3. Closures (three views or more): for every ordered pair of other views ``(u, v)`` in
       which a point was matched, its position in ``u`` is matched in ``v``
       (:func:`~carto.framework.match.match_ncc` around the position the reference's match
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
       unconfirmable: they are dropped too (the point is doubtful). Two views: no closure,
       the left-right check only.

    Args:
        orthos: view name -> ortho-image, all on one grid.
        reference: the view whose ``points`` are matched.
        points: ``(N, 2)`` distinct candidates on the reference ortho ``(line, sample)``.
        template, search, levels, min_score, tolerance_px, subpixel: matching options
            (:func:`~carto.framework.match.pyramid_match`; ``tolerance_px`` is its left-right
            tolerance).
        closure_px, closure_search, require_closure: the closure check.
        guesses: first guesses by view, instead of the coarse shift.
    """
    from carto.framework.match import _as_image, _as_points, coarse_shift, match_ncc, pyramid_match

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
    levels: int = 3,
    tolerance_px: float = 0.5,
    closure_px: float = 0.5,
    require_closure: bool = True,
    subpixel: str = "lsm-affine",
    forstner: Mapping[str, Any] | None = None,
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
        spacing_px: cell size of the candidates and of the final selection, ortho pixels.
        min_score: smallest accepted correlation (both directions, and the closures).
        sigma_px: a-priori standard deviation given to each measurement.
        points: candidate points on the reference ortho ``(N, 2)`` (row, col in ortho pixels,
            first pixel centre at 0.5) instead of :func:`candidate_points`.
        candidates: ``"forstner"`` or ``"grid"`` (see :func:`candidate_points`).
        per_cell: points kept per cell of ``spacing_px`` (those in most views, best score
            first); ``0`` keeps all.
        min_views: points seen in fewer images are dropped.
        template, search, levels, tolerance_px, closure_px, require_closure: see
            :func:`match_views`.
        forstner: options of :func:`candidate_points` (``window``, ``min_roundness``,
            ``weight_quantile``, ``per_cell``).

    Returns:
        the table; ``score`` is the correlation score of the point's match in that image
        (the reference row: the smallest of its images'). Ids are ``A`` and the candidate's
        index.
    """
    from carto.framework.match import spread_order

    names = list(sensors)
    if len(names) < 2:
        raise InputError("tie points need at least two images")
    ref = reference or names[0]
    if ref not in sensors:
        raise InputError(f"tie points: reference {ref!r} is not one of {', '.join(names)}")
    grid, orthos = system_orthos(rasters, sensors, dem, resolution_m)
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
        template=template,
        search=search,
        levels=levels,
        min_score=min_score,
        tolerance_px=tolerance_px,
        closure_px=closure_px,
        require_closure=require_closure,
        subpixel=subpixel,
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
    ids = np.array([f"A{i:05d}" for i in range(points.shape[0])], object)
    return {
        "id": ids[point_idx],
        "image": np.array(mv.views, object)[view_idx],
        "line": raw[view_idx, point_idx, 0],
        "sample": raw[view_idx, point_idx, 1],
        "score": mv.scores[view_idx, point_idx],
        "sigma_px": np.full(point_idx.size, float(sigma_px)),
    }


# ----------------------------------------------------------------------------- component
_PIPELINE_OPTIONS = frozenset(
    p.name
    for p in inspect.signature(automatic_tie_points).parameters.values()
    if p.kind is inspect.Parameter.KEYWORD_ONLY
)


class OrthoTiePointMatcher(Matcher):
    """Tie points on system-level ortho-images: Forstner candidates, NCC, closures.

    :meth:`tie_points` runs :func:`automatic_tie_points` on a block of raw images;
    :meth:`match` matches two images already in one geometry (e.g. two orthos on one grid):
    Forstner candidates of the left image (:func:`candidate_points`), the first guess from
    :func:`~carto.framework.match.coarse_shift`, pyramid NCC with least-squares sub-pixel
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
        unknown = sorted(set(options) - _PIPELINE_OPTIONS)
        if unknown:
            raise InputError(
                f"{self.name}: unknown option(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(_PIPELINE_OPTIONS))}"
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
        from carto.framework.match import _as_image, coarse_shift, pyramid_match

        o = self.options
        left_img, right_img = _as_image(left, "left"), _as_image(right, "right")
        points = o.get("points")
        if points is None:
            points = candidate_points(
                left_img,
                o.get("spacing_px", 40.0),
                method=o.get("candidates", "forstner"),
                **dict(o.get("forstner") or {}),
            )
        d_line, d_sample, _ = coarse_shift(left_img, right_img)
        return pyramid_match(
            left_img,
            right_img,
            points,
            levels=o.get("levels", 3),
            template=o.get("template", 15),
            search=o.get("search", 11),
            subpixel="lsm",
            min_score=o.get("min_score", 0.7),
            guess_offsets=(d_line, d_sample),
            tolerance=o.get("tolerance_px", 0.5),
        )
