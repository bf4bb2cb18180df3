"""Automatic tie points between images of one area, matched on system-level ortho-images.

Raw images of different views differ too much in scale, rotation and relief displacement for
area-based matching; their ortho-images made with the system-level models (the ancillary data,
before adjustment) on a coarse DEM differ only by the orientation errors (a smooth shift of
up to some hundred metres) and by the DEM's errors (stereo parallax). So (design brief,
Radhadevi et al. 2010):

1. merge the staggered odd/even arrays of raw Cartosat images
   (:mod:`~carto.framework.geometry.linescan.stagger`) so that every column follows the image model;
2. orthorectify every image on one map grid over the DEM with its system-level model
   (:func:`~carto.framework.imaging.preparation.system_orthos`); a grid larger than
   ``tile_px`` is processed by tiles, tasks of a tile engine that orthorectify only their
   windows from images read by windows (:mod:`~carto.framework.matching.tiled_ties`: the
   memory does not grow with the scene, the points are those of one piece);
3. candidate points on the reference ortho
   (:func:`~carto.framework.matching.candidates.candidate_points`): the Forstner interest
   operator (:func:`~carto.framework.matching.forstner.forstner_points`), the best two of each
   cell of ``spacing_px`` ortho pixels (the second one is a spare: the final selection keeps one
   per cell), with the cell's centre as a fall-back where the operator finds nothing (or a
   plain grid);
4. match in all views at once (:func:`~carto.framework.matching.multiview.match_views`): the
   shift between the reference ortho and each other one by masked correlation over all shifts
   (:func:`~carto.framework.matching.shifts.coarse_shift`), then normalised cross-correlation in a
   4-level pyramid, least-squares matching with an affine geometry and a left-right check,
   reference -> every other view; gross errors removed by a geometric test: the offsets of
   a point in all views must be those of one ground point, a smooth field plus the parallax
   of one height error (:func:`~carto.framework.matching.multiview.inconsistent_points`,
   :func:`~carto.framework.matching.multiview.ortho_parallax`); with three views or more, the
   position found in each other view is matched again in every other one and must land where
   the reference's match put it (within ``closure_px``): A -> B -> C must agree with A -> C,
   and observations that no closure confirms are dropped;
5. keep a well-distributed subset: per cell of ``spacing_px`` the ``per_cell`` points seen in
   most views, best score first (:func:`~carto.framework.matching.forstner.spread_order`);
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

import functools
import inspect
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.preparation import block_grid, prepared_sources
from carto.framework.matching.base import Matcher, Matches, MatchSettings
from carto.framework.matching.candidates import Spacing, candidate_points, spacing_axes
from carto.framework.matching.inputs import as_image
from carto.framework.matching.multiview import match_settings, match_views
from carto.framework.matching.ncc_matcher import NCCMatcher
from carto.framework.matching.tiled_ties import (
    TABLE_COLUMNS,
    TILE_PX,
    tie_points_on_orthos,
    tiled_tie_points,
)

__all__ = [
    "MIN_SPACING_PX",
    "TABLE_COLUMNS",
    "OrthoTiePointMatcher",
    "automatic_tie_points",
    "block_tie_points",
    "overlap_fraction",
    "overlapping_pairs",
    "tie_point_errors",
    "tie_points_on_orthos",
]


def automatic_tie_points(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    *,
    reference: str | None = None,
    resolution_m: float | None = None,
    spacing_px: Spacing = 40.0,
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
    matcher: Matcher | None = None,
    tile_px: int = TILE_PX,
    engine: Any = None,
    work_dir: Path | None = None,
    prepared: bool = False,
) -> dict[str, NDArray]:
    """Tie points of ``sensors``' images, as a long table ``id, image, line, sample, score,
    sigma_px`` (raw image coordinates; one row per point and image), by the module's method
    (system-level orthos, Forstner candidates, multi-view matching with closures, a
    well-distributed subset, back to raw coordinates).

    Args:
        rasters: image name -> raster file or array (raw, as recorded).
        sensors: image name -> system-level model of that image.
        dem: the coarse DEM to orthorectify on (ellipsoidal heights).
        reference: image whose ortho the others are matched against (default: the first).
        resolution_m: ortho resolution (default: the coarsest image's ground sampling).
        spacing_px: cell size of the candidates and of the final selection, ortho pixels
            (or ``(rows, cols)``); when fewer than ``min_points`` points are kept (a small
            common area), it is repeated with denser cells, down to :data:`MIN_SPACING_PX`.
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
        matcher: the matcher of the pairwise matches (default ``"ncc"``; ``carto adjust
            --matcher`` chooses it from the registry), see :func:`match_views`.
        tile_px: a grid larger than this (ortho pixels) is matched by tiles of this side,
            tasks of ``engine`` (:mod:`~carto.framework.matching.tiled_ties`: bounded memory
            whatever the scene); a smaller one in one piece.
        engine: the :class:`~carto.framework.parallel.engine.TileEngine` of the tiles and of
            the stagger merge (default: this process).
        work_dir: folder for the prepared (stagger-merged) images of raster files (default:
            they are prepared in memory).
        prepared: ``rasters`` are prepared already
            (:func:`~carto.framework.imaging.preparation.prepared_sources`).

    Returns:
        the table; ``score`` is the correlation score of the point's match in that image
        (the reference row: the smallest of its images'). Ids are ``A`` and the candidate's
        index.
    """
    settings = _pipeline_settings(locals())  # the arguments by name (no other local yet)
    ref = _checked_reference(sensors, reference)
    grid = block_grid(rasters, sensors, dem, resolution_m)
    images = rasters if prepared else prepared_sources(rasters, sensors, dem, work_dir, engine)
    views = {n: images[n] for n in sensors}
    match = functools.partial(tiled_tie_points, views, sensors, dem, grid, ref)
    return _denser_until_enough(match, settings, spacing_px, min_points, engine, tile_px)


_TWO_VIEW_OPTIONS = ("template", "search", "levels", "min_score", "tolerance_px", "subpixel")
"""The arguments of :func:`automatic_tie_points` that are options of :func:`match_views` and
apply to two images (:func:`~carto.framework.matching.multiview.match_settings`)."""

_MATCHING_OPTIONS = (*_TWO_VIEW_OPTIONS, "closure_px", "require_closure", "matcher")
"""The arguments of :func:`automatic_tie_points` that are options of :func:`match_views`."""

_SELECTION_OPTIONS = ("points", "candidates", "forstner", "per_cell", "min_views", "sigma_px")
"""The arguments of :func:`automatic_tie_points` that choose the candidates and the points
kept, as the ``settings`` of :func:`tiled_tie_points` name them."""


def _pipeline_settings(arguments: Mapping[str, Any]) -> dict[str, Any]:
    """The ``settings`` of :func:`tiled_tie_points` (candidates, ``matching``: the options of
    :func:`match_views`, selection) out of the arguments of :func:`automatic_tie_points`."""
    settings = {k: arguments[k] for k in _SELECTION_OPTIONS}
    settings["matching"] = {k: arguments[k] for k in _MATCHING_OPTIONS}
    return settings


def _checked_reference(sensors: Mapping[str, Sensor], reference: str | None) -> str:
    """The reference image (default: the first), refused unless one of at least two."""
    names = list(sensors)
    if len(names) < 2:
        raise InputError("tie points need at least two images")
    ref = reference or names[0]
    if ref not in sensors:
        raise InputError(f"tie points: reference {ref!r} is not one of {', '.join(names)}")
    return ref


def _denser_until_enough(
    match: Callable[..., dict[str, NDArray]],
    settings: Mapping[str, Any],
    spacing_px: Spacing,
    min_points: int,
    engine: Any,
    tile_px: int,
) -> dict[str, NDArray]:
    """The tie-point table of ``match`` (:func:`tiled_tie_points` on the block, given the
    cell spacing, ``settings``, ``engine`` and ``tile_px``), matched again with denser cells
    while fewer than ``min_points`` points are kept (unless the candidates are given)."""
    given = settings["points"]
    spacing: Spacing = spacing_px
    while True:
        table = match(spacing, settings, engine=engine, tile_px=tile_px)
        n = len(set(table["id"].tolist()))
        # a small common area (large system-level misregistration, partial overlap) leaves
        # few cells: denser candidates, down to MIN_SPACING_PX, until min_points are kept
        steps = spacing_axes(spacing)
        if given is not None or n >= min_points or max(steps) <= MIN_SPACING_PX:
            return table
        factor = math.sqrt(max(n, 1) / min_points)
        spacing = tuple(max(MIN_SPACING_PX, min(s, s * factor)) for s in steps)


MIN_SPACING_PX = 16.0
"""Densest candidate spacing :func:`automatic_tie_points` goes to when too few points are kept."""


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
    if p.kind is inspect.Parameter.KEYWORD_ONLY and p.name not in ("engine", "work_dir", "prepared")
}


class OrthoTiePointMatcher(NCCMatcher):
    """Tie points on system-level ortho-images: Forstner candidates, NCC, closures.

    :meth:`tie_points` runs :func:`automatic_tie_points` on a block of raw images;
    :meth:`match` matches two images already in one geometry (e.g. two orthos on one grid):
    Forstner candidates of the left image (:func:`candidate_points`), the first guess from
    :func:`~carto.framework.matching.shifts.coarse_shift`, pyramid NCC with least-squares
    sub-pixel refinement and the left-right check. Given points and dense matching are the
    ``"ncc"`` matcher's (:meth:`match_points` with this matcher's options as the default
    settings, no global shift; :meth:`match_dense`).

    Args:
        options: keyword options of :func:`automatic_tie_points` (``spacing_px``,
            ``min_score``, ``candidates``, ``template`` ...); those that apply to two images
            are used by :meth:`match` and :meth:`match_points` too.
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
        super().__init__(use_global_shift=False)
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
        o = {**_PIPELINE_DEFAULTS, **self.options}
        left_img = as_image(left, "left")
        points = o["points"]
        if points is None:
            points = candidate_points(
                left_img, o["spacing_px"], method=o["candidates"], **dict(o["forstner"] or {})
            )
        points = np.asarray(points, np.float64).reshape(-1, 2)
        if points.shape[0] == 0:
            return Matches([], [], [], [], [])
        mv = match_views(
            {"left": left_img, "right": as_image(right, "right")},
            "left",
            points,
            **self._two_view_options(),
        )
        ok = np.isfinite(mv.positions[1, :, 0])
        right_pts = mv.positions[1, ok]
        return Matches(
            points[ok, 0], points[ok, 1], right_pts[:, 0], right_pts[:, 1], mv.scores[1, ok]
        )

    def settings(self) -> MatchSettings:
        """The default settings of :meth:`match_points`: this matcher's options that apply to
        two images (``template``, ``search``, ``levels``, ``min_score``, ``tolerance_px``,
        ``subpixel``), as :func:`match_views` takes them."""
        return match_settings(**self._two_view_options())

    def _two_view_options(self) -> dict[str, Any]:
        """This matcher's options of :func:`match_views` that apply to two images."""
        o = {**_PIPELINE_DEFAULTS, **self.options}
        return {k: o[k] for k in _TWO_VIEW_OPTIONS}


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
    so that they stay distinct.

    ``options`` are :func:`automatic_tie_points`'s; with ``engine`` and ``work_dir`` raster
    files are prepared once (:func:`~carto.framework.imaging.preparation.prepared_sources`)
    and matched by tiles on the engine."""
    h_mid = float(np.nanmedian(dem.heights)) if hasattr(dem, "heights") else 0.0
    names = list(sensors)
    if not options.pop("prepared", False):
        missing = [n for n in sensors if n not in rasters]
        if missing:
            raise InputError(f"no raster for image(s) {', '.join(missing)}")
        rasters = prepared_sources(
            rasters, sensors, dem, options.get("work_dir"), options.get("engine")
        )
    options["prepared"] = True
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
