"""The iterations of IOR at one resolution (:func:`iterate`): tiles orthorectified, matched and
intersected (:mod:`carto.ior.tiles`), their heights regularised into the next DEM, with the
per-node search bound along the base each update leaves (:func:`next_search_px`); and what
they report (:class:`IterationReport`, :class:`IORResult`). :func:`carto.ior.refine.
refine_dem` runs them for each coarse-to-fine stage and the final grid."""

from __future__ import annotations

import functools
import itertools
import time
from collections.abc import Callable
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import FloatArray, InputError, TaskFailure
from carto.framework.sdk.dem import DEM, ELLIPSOID, OrthoGrid
from carto.framework.sdk.matchers import Matcher
from carto.framework.sdk.sensors import Sensor, base_direction
from carto.ior.filling import node_footprint
from carto.ior.height_precision import smoothing_variance_factor
from carto.ior.regularise import regularise
from carto.ior.settings import IORSettings
from carto.ior.start import seen_by_both
from carto.ior.tiles import (
    NODE_QUALITY,
    ORTHO_LAYERS,
    TileJob,
    TileWork,
    run_tile,
    tile_arrays,
)
from carto.ior.workspace import RunState, Workspace


@attrs.frozen
class IterationReport:
    """One iteration: the mismatch of the ortho-images on the DEM it started from, and the
    update. ``median_abs_mismatch_px``: median |offset along the base| of the valid matches
    (what a height change removes), ortho pixels; ``matched_percent``: nodes with a valid
    match among the nodes both images cover; ``median_abs_dem_change_m``: median |height
    change| applied (0 when converged); ``median_across_base_px``: median offset across the
    base (a relative orientation error: no height change removes it)."""

    iteration: int
    median_abs_mismatch_px: float
    matched_percent: float
    median_abs_dem_change_m: float
    median_across_base_px: float
    seconds: float
    factor: int = 1
    median_search_px: float = float("nan")


@attrs.frozen(eq=False)
class IORResult:
    """The outcome of :func:`refine_dem`.

    Attributes:
        dem: the refined DEM (ellipsoidal heights, NaN outside the common area).
        dem_grid, ortho_grid: the grids of the DEM and of the ortho-images.
        ortho_left, ortho_right: float32 ortho-images on the final DEM (NaN = no data):
            arrays, or tiles in the run's work folder
            (:class:`~carto.framework.raster.tiled_layer.TiledLayer`).
        score, valid: the last matching's correlation score and validity, per ortho pixel
            (arrays or tiled layers).
        iterations: one report per iteration.
        converged: the mismatch fell below the threshold.
        b_over_h: base-to-height ratio at the scene centre.
        init_coverage: share of the images' common footprint where the initial DEM had a
            height.
        init_filled: share of that footprint whose starting height was filled (voids of
            the initial DEM, :func:`starting_surface`).
        failed_tiles: the tiles that failed (``"tile R,C: cause"``; their nodes have no
            height).
        node_quality: the last iteration's matched points per DEM node (tiled layers on
            ``dem_grid``, :data:`NODE_QUALITY`): ``count`` (points), ``spread_m``
            (their interquartile range / 1.349), ``node_score`` (mean correlation score),
            ``sigma_m`` (the predicted standard deviation of the DEM's height,
            :mod:`carto.ior.height_precision`).
        filled: per DEM node, a height the last iteration did not measure: a hole inside
            the measured area, filled by the regularised update (:mod:`carto.ior.filling`;
            beyond the measured area, nodes have no height).
        nodes: the node counts of the footprint (:meth:`~carto.ior.filling.NodeFootprint.
            counts`): measured, filled, left empty.
        surface: the last regularised heights at every node of ``dem_grid`` (no NaN; beyond
            the measured area, the start with the updates' smooth tails): what a finer
            stage starts from.
        guess: the last offset across the base, ``(d_row, d_col)`` ortho pixels (where the
            next search starts).
        search_px: the per-node search bound along the base of the last iteration, ortho
            pixels (NaN: none; None: none anywhere).
    """

    dem: DEM
    dem_grid: OrthoGrid
    ortho_grid: OrthoGrid
    ortho_left: Any
    ortho_right: Any
    score: Any
    valid: Any
    iterations: tuple[IterationReport, ...]
    converged: bool
    b_over_h: float
    init_coverage: float = 1.0
    init_filled: float = 0.0
    failed_tiles: tuple[str, ...] = ()
    node_quality: dict[str, Any] = attrs.field(factory=dict)
    filled: Any = None
    nodes: dict[str, Any] = attrs.field(factory=dict)
    surface: Any = None
    guess: tuple[float, float] = (0.0, 0.0)
    search_px: Any = None


def b_over_h(left: Sensor, right: Sensor, lon: float, lat: float, h: float) -> float:
    """Base-to-height ratio at a ground point (:func:`base_direction`)."""
    return base_direction(left, right, lon, lat, h)[0]


@attrs.frozen(eq=False)
class IORRun:
    """What every stage of one run (:func:`carto.ior.refine.refine_dem`) shares: the images
    (read by windows), their models, the tile engine, the dense matcher (None: the
    default), the progress callback and whether failed tiles are kept (else they stop the
    run)."""

    images: tuple[Any, Any]
    sensors: tuple[Sensor, Sensor]
    engine: Any
    matcher: Matcher | None = None
    progress: Callable[[str], None] | None = None
    keep_failed_tiles: bool = False


class TileFailure(InputError):
    """Tiles of an iteration failed after their retries (the cause of the first, and how
    many)."""


def tile_edges(n: int, tile_n: int) -> list[tuple[int, int]]:
    """The ``(start, stop)`` of each tile along an axis of ``n`` nodes: as few tiles as hold
    at most ``tile_n`` nodes each, of equal size to a node (no sliver at the end, so the
    tasks of a small grid share the workers evenly)."""
    edges = np.linspace(0, n, -(-n // tile_n) + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def _tile_plan(
    sensors: tuple[Sensor, Sensor], grid: OrthoGrid, heights: FloatArray, tile_n: int
) -> list[tuple[slice, slice]]:
    """The tiles (node slices) that both images see: the grid cut into equal tiles of at
    most ``tile_n`` nodes a side (:func:`tile_edges`), each tile's nodes sampled on an 9 x 9
    lattice (edges included) at the starting heights; tiles beyond the common footprint get
    no task."""
    n_r, n_c = grid.shape
    tiles = [
        (slice(r0, r1), slice(c0, c1))
        for r0, r1 in tile_edges(n_r, tile_n)
        for c0, c1 in tile_edges(n_c, tile_n)
    ]
    rr, cc, owner = [], [], []
    for k, (rows, cols) in enumerate(tiles):
        r = np.unique(np.linspace(rows.start, rows.stop - 1, 9).round().astype(int))
        c = np.unique(np.linspace(cols.start, cols.stop - 1, 9).round().astype(int))
        gr, gc = np.meshgrid(r, c, indexing="ij")
        rr.append(gr.ravel())
        cc.append(gc.ravel())
        owner.append(np.full(gr.size, k))
    rows_all, cols_all, who = np.concatenate(rr), np.concatenate(cc), np.concatenate(owner)
    lon, lat = grid.lonlat(rows_all, cols_all)
    seen = seen_by_both(sensors, lon, lat, heights[rows_all, cols_all])
    keep = np.zeros(len(tiles), bool)
    keep[np.unique(who[seen])] = True
    if not keep.any():  # let matching say what is wrong
        keep[:] = True
    return [t for t, k in zip(tiles, keep, strict=True) if k]


def _run_tiles(scheduler: Any, tasks: list[Any], desc: str, keys: list[str]) -> list[Any]:
    """Run tile tasks on a :class:`~carto.framework.parallel.engine.TileEngine` (with its
    progress bar) or on any callable scheduler (results in order)."""
    run = getattr(scheduler, "run", None)
    if run is not None:
        return list(run(tasks, desc=desc, keys=keys))
    return list(scheduler(tasks))


SEARCH_MARGIN_PX = 2.0
"""Pixels added to every per-node search bound: the sub-pixel refinement's reach and what a
node's neighbours may still move it."""


def next_search_px(
    search: NDArray[np.float32] | None,
    change_m: FloatArray,
    matched: NDArray[np.bool_],
    px_per_m: float,
) -> NDArray[np.float32]:
    """The per-node search bound along the base for the next iteration, ortho pixels: where
    the iteration matched, twice the height change it made (the error left is smaller than
    the change that removed most of it, while the iterations converge) in pixels, plus
    :data:`SEARCH_MARGIN_PX`; elsewhere the bound so far (NaN: none)."""
    bound = (2.0 * np.abs(change_m) * px_per_m + SEARCH_MARGIN_PX).astype(np.float32)
    before = search if search is not None else np.full(np.shape(change_m), np.nan, np.float32)
    return np.where(matched & np.isfinite(bound), bound, before).astype(np.float32)


def _stage_label(factor: int) -> str:
    return f"1/{factor} resolution, " if factor > 1 else ""


def iterate(
    run: IORRun,
    grids: tuple[OrthoGrid, OrthoGrid, int],
    s: IORSettings,
    state: RunState,
    space: Workspace,
    factor: int = 1,
    apply_last: bool = False,
) -> IORResult:
    """The iterations of :func:`refine_dem` from ``state`` on, on ``grids`` (the DEM grid,
    the ortho grid and its pixels per node, :func:`~carto.ior.grids.ior_grids`; ``factor``:
    the stage's ortho-images are that many times coarser than the final ones;
    ``apply_last``: the last iteration's measurement updates the surface too, for a stage
    whose result is a start, not a product: ``surface`` is then one update ahead of
    ``dem``)."""
    stage = _stage(run, grids, s, state.heights, space, factor)
    heights, guess, search = state.heights, state.guess, state.search_px
    reports = [IterationReport(**r) for r in state.reports]
    start_refined = bool(state.facts.get("start_refined"))
    iteration = state.iteration
    while True:
        t0 = time.perf_counter()
        current = heights
        close = reports[-1].median_abs_mismatch_px < 2.0 if reports else start_refined
        # the predicted precision is a product's: not of a coarse stage, nor of an
        # iteration that cannot be the last
        may_end = not _first_here(reports, start_refined) or iteration > s.max_iterations
        precision = factor == 1 and may_end
        outcomes = _run_iteration(stage, iteration, current, guess, search, close, precision)
        measured = _measured(stage, outcomes)
        # the across-base offset stays; the along-base one the DEM removes
        if measured.matched.any():
            across_px = measured.across_px
            guess = (-across_px * stage.plan.base_rc[1], across_px * stage.plan.base_rc[0])
        done = _converged(measured, reports, s, start_refined)
        med_search = _median_search(search, measured.covered)
        last = done or iteration > s.max_iterations
        med_change = 0.0
        if not last or (apply_last and measured.matched.any()):
            heights, search, med_change = _updated(
                current, measured, search, s, stage.plan.px_per_m
            )
        seconds = time.perf_counter() - t0
        report = IterationReport(
            iteration, measured.median_abs_px, measured.matched_percent, med_change,
            measured.across_px, seconds, factor, med_search,
        )  # fmt: skip
        reports.append(report)
        if run.progress:
            run.progress(_iteration_line(report, done, last))
        if last:
            break
        iteration += 1
        del measured  # its DEM-grid arrays (100 MB of a whole scene) not held through the tiles
        space.begin(
            RunState(
                iteration,
                heights,
                guess,
                tuple(attrs.asdict(r) for r in reports),
                state.facts,
                search,
            )
        )
    return _stage_result(
        stage, state, iteration, outcomes, measured, heights,
        _Ending(tuple(reports), done, guess, search),
    )  # fmt: skip


@attrs.frozen(eq=False)
class _StagePlan:
    """What the tiles of every iteration of a stage share: the pair's base-to-height ratio
    at the grid centre and the base's direction on the north-up grid ``(d_row, d_col)``,
    the tiles (node slices) both images see with their keys, the tiles' overlap (nodes)
    and the along-base ortho pixels per metre of height."""

    b_over_h: float
    base_rc: tuple[float, float]
    tiles: list[tuple[slice, slice]]
    keys: list[str]
    overlap_n: int
    px_per_m: float


def _stage_plan(
    sensors: tuple[Sensor, Sensor],
    dem_grid: OrthoGrid,
    heights: FloatArray,
    k: int,
    s: IORSettings,
) -> _StagePlan:
    """The plan of a stage whose starting heights are ``heights``."""
    left, right = sensors
    n_r, n_c = dem_grid.shape
    c_lon, c_lat = dem_grid.lonlat(n_r / 2, n_c / 2)
    bh, base_en = base_direction(
        left, right, float(c_lon), float(c_lat), float(np.nanmedian(heights))
    )
    base_rc = np.array([-base_en[1], base_en[0]])  # (row, col) of the north-up grid
    overlap_n = max(2, -(-s.overlap_px // k))
    tile_n = max(16, s.tile_px // k)
    tiles = _tile_plan((left, right), dem_grid, heights, tile_n)
    starts = [[a for a, _ in tile_edges(n, tile_n)] for n in (n_r, n_c)]
    keys = [
        f"tile {starts[0].index(rows.start)},{starts[1].index(cols.start)}" for rows, cols in tiles
    ]
    px_per_m = bh * k / abs(dem_grid.transform.a)  # along-base pixels per metre of height
    return _StagePlan(bh, (float(base_rc[0]), float(base_rc[1])), tiles, keys, overlap_n, px_per_m)


@attrs.frozen(eq=False)
class _Stage:
    """What every iteration of :func:`iterate` shares: the run, what its tiles are refined
    with (the iteration's levels, guess, height range and variance factor left to set),
    the ortho grid, the workspace, the stage's factor and plan."""

    run: IORRun
    work: TileWork
    ortho_grid: OrthoGrid
    space: Workspace
    factor: int
    plan: _StagePlan


def _stage(
    run: IORRun,
    grids: tuple[OrthoGrid, OrthoGrid, int],
    s: IORSettings,
    heights: FloatArray,
    space: Workspace,
    factor: int,
) -> _Stage:
    """The stage of :func:`iterate` whose starting heights are ``heights``."""
    dem_grid, ortho_grid, k = grids
    plan = _stage_plan(run.sensors, dem_grid, heights, k, s)
    work = TileWork(
        run.images, run.sensors, dem_grid, k, plan.overlap_n, s,
        matcher=run.matcher, base=plan.base_rc,
    )  # fmt: skip
    return _Stage(run, work, ortho_grid, space, factor, plan)


def _run_iteration(
    stage: _Stage,
    iteration: int,
    current: FloatArray,
    guess: tuple[float, float],
    search: NDArray[np.float32] | None,
    close: bool,
    precision: bool = True,
) -> list[Any]:
    """The tiles of one iteration on the heights ``current`` (``close``: the last mismatch
    was small, the matching's pyramid is shallow; ``precision``: the tiles predict their
    heights' precision); each tile's file, or its failure."""
    s, space = stage.work.settings, stage.space
    work = attrs.evolve(
        stage.work,
        levels=s.refine_levels if close else s.levels,
        guess=guess,
        h_range=(float(np.nanmin(current)), float(np.nanmax(current))),
        variance_factor=smoothing_variance_factor(
            s.smoothing_nodes, iteration - 1, s.window, stage.work.k
        ),
        precision=precision,
    )
    job = TileJob(
        work,
        space.heights_path(iteration),
        space.iteration_dir(iteration),
        None if search is None else space.search_path(iteration),
    )
    tasks = [functools.partial(run_tile, job, rows, cols) for rows, cols in stage.plan.tiles]
    outcomes = _run_tiles(
        stage.run.engine,
        tasks,
        f"IOR {_stage_label(stage.factor)}iteration {iteration}",
        stage.plan.keys,
    )
    failed = _failures(outcomes)
    if failed and not stage.run.keep_failed_tiles:
        raise TileFailure(
            f"ior: {len(failed)} of {len(stage.plan.tiles)} tiles failed in iteration {iteration} "
            f"({failed[0]})"
        )
    return outcomes


def _failures(outcomes: list[Any]) -> list[str]:
    """The causes of the tiles that failed (``"tile R,C: cause"``)."""
    return [str(o) for o in outcomes if isinstance(o, TaskFailure)]


@attrs.frozen(eq=False)
class _Measured:
    """What an iteration's tiles measured on the DEM grid: the heights of the matched nodes
    (``new_height``), which nodes matched and which both images cover; the median
    |mismatch| along the base and the median offset across it (ortho pixels; NaN: no
    match), and the share of covered nodes matched (percent)."""

    new_height: FloatArray
    matched: NDArray[np.bool_]
    covered: NDArray[np.bool_]
    median_abs_px: float
    across_px: float
    matched_percent: float


_MEASURED_LAYERS = ("new_height", "d_row_px", "d_col_px", "covered")
"""The node layers of the tiles' files an iteration's measurement reads."""


def _measured(stage: _Stage, outcomes: list[Any]) -> _Measured:
    """The tiles' node layers assembled on the DEM grid, and their mismatch."""
    shape = stage.work.dem_grid.shape
    # the grids of the coordinator: heights in float64, offsets in float32 (what the
    # tiles measured to a hundredth of a pixel), the rest as masks
    new = np.full(shape, np.nan)
    d_row = np.full(shape, np.nan, np.float32)
    d_col = np.full(shape, np.nan, np.float32)
    covered = np.zeros(shape, bool)
    for (rows, cols), outcome in zip(stage.plan.tiles, outcomes, strict=True):
        if isinstance(outcome, TaskFailure):
            continue
        arrays = tile_arrays(outcome, _MEASURED_LAYERS)
        new[rows, cols] = arrays["new_height"]
        d_row[rows, cols] = arrays["d_row_px"]
        d_col[rows, cols] = arrays["d_col_px"]
        covered[rows, cols] = arrays["covered"]
    matched = np.isfinite(d_row) & covered
    # the mismatch a height change removes: along the base; across it, what the
    # relative orientation leaves (reported, and the next search starts from it)
    m_row, m_col = d_row[matched], d_col[matched]
    del d_row, d_col
    b_row, b_col = stage.plan.base_rc  # float32 products
    along = m_row * b_row + m_col * b_col
    across = m_col * b_row - m_row * b_col
    med = float(np.median(np.abs(along))) if along.size else float("nan")
    across_px = float(np.median(across)) if across.size else float("nan")
    del m_row, m_col, along, across
    pct = 100.0 * float(matched.sum()) / max(int(covered.sum()), 1)
    return _Measured(new, matched, covered, med, across_px, pct)


def _converged(
    measured: _Measured, reports: list[IterationReport], s: IORSettings, start_refined: bool
) -> bool:
    """Whether the iterations end here, converged."""
    med = measured.median_abs_px
    # converged: the mismatch is below the threshold, or it no longer improves (what
    # is left is the matching noise, which no height change removes)
    stalled = bool(reports) and med > (1.0 - s.min_improvement) * reports[-1].median_abs_mismatch_px
    converged = bool(measured.matched.any() and (med < s.threshold_px or stalled))
    return converged and not _first_here(reports, start_refined)


def _first_here(reports: list[IterationReport], start_refined: bool) -> bool:
    """Whether the coming iteration is the first of a stage that starts from a coarser one:
    it updates at least once at its own resolution, so that one cannot converge (a small
    median mismatch there says the coarse relief is right, not the fine one)."""
    return not reports and start_refined


def _median_search(search: NDArray[np.float32] | None, covered: NDArray[np.bool_]) -> float:
    """The median search bound of the covered nodes, ortho pixels (NaN: none)."""
    bounded = None if search is None else search[covered]
    return (
        float(np.nanmedian(bounded))
        if bounded is not None and np.isfinite(bounded).any()
        else float("nan")
    )


def _updated(
    current: FloatArray,
    measured: _Measured,
    search: NDArray[np.float32] | None,
    s: IORSettings,
    px_per_m: float,
) -> tuple[FloatArray, NDArray[np.float32], float]:
    """The regularised next heights, the next search bounds and the median |height change|
    of the covered nodes (m)."""
    heights, _ = regularise(current, measured.new_height, s)
    search = next_search_px(search, heights - current, measured.matched, px_per_m)
    change = np.abs(heights - current)[measured.covered]
    med_change = float(np.median(change)) if change.size else 0.0
    return heights, search, med_change


def _iteration_line(report: IterationReport, done: bool, last: bool) -> str:
    """The progress line of an iteration."""
    ending = (
        (" (converged)" if done else " (last)")
        if last
        else f", median DEM change {report.median_abs_dem_change_m:.2f} m"
    )
    return (
        f"{_stage_label(report.factor)}iteration {report.iteration}: median mismatch "
        f"{report.median_abs_mismatch_px:.3f} px along the base, "
        f"{report.matched_percent:.1f} % matched{ending}"
    )


@attrs.frozen(eq=False)
class _Ending:
    """How the iterations ended: their reports, whether they converged, and the last offset
    across the base and search bounds."""

    reports: tuple[IterationReport, ...]
    converged: bool
    guess: tuple[float, float]
    search: NDArray[np.float32] | None


def _stage_result(
    stage: _Stage,
    state: RunState,
    iteration: int,
    outcomes: list[Any],
    measured: _Measured,
    heights: FloatArray,
    ending: _Ending,
) -> IORResult:
    """The result of the stage's iterations: the last iteration's tiles hold the orthos made
    on the final DEM, its matching (ortho grid: k pixels per node) and the points per node
    (DEM grid)."""
    from carto.framework.sdk.dem import TiledLayer, TilePiece, piece_path

    dem_grid, ortho_grid, k = stage.work.dem_grid, stage.ortho_grid, stage.work.k
    finished = [
        (rows, cols)
        for (rows, cols), outcome in zip(stage.plan.tiles, outcomes, strict=True)
        if not isinstance(outcome, TaskFailure)
    ]

    def tiled(name: str, scale: int, shape: tuple[int, int], dtype: Any, fill: Any) -> Any:
        pieces = [
            TilePiece(
                piece_path(stage.space.iteration_dir(iteration), rows.start, cols.start),
                name,
                rows.start * scale,
                cols.start * scale,
                ((rows.stop - rows.start) * scale, (cols.stop - cols.start) * scale),
            )
            for rows, cols in finished
        ]
        return TiledLayer.of(shape, pieces, dtype, fill)

    layers = {
        name: tiled(name, k, ortho_grid.shape, np.float32, float("nan"))
        for name in ORTHO_LAYERS
        if name != "valid"
    }
    layers["valid"] = tiled("valid", k, ortho_grid.shape, bool, False)
    node_quality = {
        name: tiled(name, 1, dem_grid.shape, np.float32, 0.0 if name == "count" else np.nan)
        for name in NODE_QUALITY
    }
    # heights where the last iteration measured and in the holes it encloses; none beyond
    failed_nodes = np.zeros(dem_grid.shape, bool)
    for (rows, cols), outcome in zip(stage.plan.tiles, outcomes, strict=True):
        if isinstance(outcome, TaskFailure):
            failed_nodes[rows, cols] = True
    footprint = node_footprint(measured.matched, measured.covered, failed_nodes)
    final = np.where(footprint.has_height, heights, np.nan)
    dem = DEM.from_array(final, dem_grid.transform, dem_grid.crs.to_wkt(), vertical=ELLIPSOID)
    return IORResult(
        dem,
        dem_grid,
        ortho_grid,
        layers["ortho_left"],
        layers["ortho_right"],
        layers["score"],
        layers["valid"],
        ending.reports,
        ending.converged,
        stage.plan.b_over_h,
        init_coverage=float(state.facts.get("init_coverage", 1.0)),
        init_filled=float(state.facts.get("init_filled", 0.0)),
        failed_tiles=tuple(_failures(outcomes)),
        node_quality=node_quality,
        filled=footprint.filled,
        nodes=footprint.counts(),
        surface=heights,
        guess=ending.guess,
        search_px=ending.search,
    )
