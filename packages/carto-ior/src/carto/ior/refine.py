"""Iterative ortho-image refinement (IOR): a DEM and ortho-images from a stereo pair with known
orientation (Radhadevi et al. 2010; design brief section 2).

With exact orientation, the ortho-images of the left and right image made on the true DEM are
identical; where the DEM height is wrong by ``e`` they are shifted against each other along
the stereo base. The loop:

1. orthorectify both images on the current DEM (:func:`carto.framework.imaging.ortho.orthorectify`);
2. match the two ortho-images densely with the chosen matcher's ``match_dense`` (the
   matcher extension point, ``carto dem --matcher``; the default ``"ncc"`` is
   :func:`carto.framework.matching.disparity.dense_offsets`: pyramid, left-right check,
   sub-pixel, score and validity), its offsets then refined by least squares along the base
   (:func:`carto.framework.matching.precision.refine_along_base`, ``subpixel_steps``);
3. turn each mismatch into a height by intersecting the two image rays at every matched
   ortho pixel (the tile's local ray model, :mod:`carto.ior.rays`), carried to the centre of
   its DEM node; a node takes the median of its points (:mod:`carto.ior.node_heights`), whose
   number and spread are kept as quality layers;
4. update the DEM with regularisation: outliers against the local median removed, holes and
   noise handled by a normalised Gaussian convolution of the height changes;
5. repeat until the median mismatch is below a threshold or a number of iterations is reached.

The delivered DEM holds the nodes the last iteration measured and the holes they enclose
(filled, flagged); nothing beyond the measured area (:mod:`carto.ior.filling`). Each node
gets a predicted height standard deviation (:mod:`carto.ior.height_precision`).

**Height from mismatch, to first order.** The left ortho pixel at ``(x, y)`` shows the terrain
where the left line of sight through ``(x, y, h_dem)`` meets it: for a height error ``e =
h_dem - h_true`` a ground detail appears ``e t_L`` away from its true place (``t``: the
horizontal displacement of a line of sight per metre of height, of length ``tan(theta)``,
``theta`` the off-nadir angle), and ``e t_R`` away in the right ortho. The two ortho-images
are therefore shifted against each other by ``dr = e |t_R - t_L| = e B/H`` along the base
(the direction of ``t_R - t_L``), so

    ``dh = -e = -dr / (B/H)``  (:func:`first_order_height_change`).

The paper prints ``dh = dr * (B/H)`` (its eq. 7): dimensionally the inverse (for Cartosat-1,
B/H = 0.62, a 1 m mismatch is a 1.6 m height error, not 0.62 m). The intersection used in step
3 needs no such approximation; the test suite checks that both agree for small mismatches.

The work of an iteration is split into tiles of DEM nodes (with overlap), each orthorectified,
matched and intersected on its own (:func:`refine_tile`), so a scheduler can distribute them;
the regularisation then runs on the assembled DEM grid.
"""

from __future__ import annotations

import contextlib
import functools
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho_grid import OrthoGrid, check_grid_size, footprint_box
from carto.framework.matching.base import Matcher
from carto.framework.parallel.engine import TaskFailure
from carto.framework.raster.dem import DEM, ELLIPSOID
from carto.ior.filling import node_footprint
from carto.ior.height_precision import smoothing_variance_factor
from carto.ior.regularise import regularise
from carto.ior.settings import IORSettings, option_label
from carto.ior.start import StartingSurface, seen_by_both, starting_surface
from carto.ior.tiles import (
    NODE_LAYERS,
    NODE_QUALITY,
    ORTHO_LAYERS,
    TileJob,
    refine_tile,
    run_tile,
    tile_arrays,
)
from carto.ior.workspace import RunState, Workspace

__all__ = [
    "IORResult",
    "IORSettings",
    "IterationReport",
    "StartingSurface",
    "TileFailure",
    "b_over_h",
    "base_direction",
    "first_order_height_change",
    "refine_dem",
    "refine_tile",
    "regularise",
    "starting_surface",
]

FloatArray = NDArray[np.float64]


def first_order_height_change(mismatch_m: Any, b_over_h: float) -> FloatArray:
    """Height change, metres, that cancels an ortho-image mismatch, to first order:
    ``dh = -dr / (B/H)``.

    ``mismatch_m`` (``dr``): position of a detail in the right ortho-image minus its position
    in the left one, metres, along the base: the unit vector of ``t_R - t_L``, where ``t`` is
    the horizontal displacement per metre of height of a line of sight (a DEM too high by
    ``e`` puts the detail ``e t`` away from its true place in each ortho-image, so ``dr = e
    B/H``). ``b_over_h`` is ``|t_R - t_L|`` (:func:`b_over_h`)."""
    if not b_over_h > 0:
        raise InputError(f"b_over_h must be > 0, got {b_over_h}")
    return -np.asarray(mismatch_m, np.float64) / float(b_over_h)


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


def _grids(
    left: Sensor, right: Sensor, init_dem: DEM, settings: IORSettings
) -> tuple[OrthoGrid, OrthoGrid, int]:
    """DEM grid (posting) and ortho grid (``k`` ortho pixels per node), aligned, covering the
    area both images see. Refuses (before allocating anything) grids too large or too small
    for the common footprint."""
    from affine import Affine

    from carto.framework.imaging.preparation import ground_sampling_m
    from carto.framework.raster.images import MIN_IMAGE_PX

    h_mid = float(np.nanmedian(init_dem.heights))
    posting = float(settings.posting_m)
    res = settings.ortho_res_m
    if res is None:
        sampling = {
            side: ground_sampling_m(s, h_mid) for side, s in (("left", left), ("right", right))
        }
        for side, value in sampling.items():
            if not (np.isfinite(value) and value > 0.0):
                raise InputError(
                    f"dem: the centre of the {side} image does not locate on the ground at "
                    f"{h_mid:.0f} m (its model gives no ground sampling there: a model outside "
                    "its validity domain, or not this image's?)"
                )
        res = max(sampling.values())
    k = max(1, round(posting / res))
    crs = settings.crs
    if crs is None:  # the UTM zone of the two footprints' centre
        crs = footprint_box([left, right], init_dem)[0]
    _, (la, ba, ra, ta) = footprint_box([left], init_dem, crs)
    _, (lb, bb, rb, tb) = footprint_box([right], init_dem, crs)
    box = (max(la, lb), max(ba, bb), min(ra, rb), min(ta, tb))
    if not (box[0] < box[2] and box[1] < box[3]):
        raise InputError("dem: the two images do not overlap on the ground")
    width, height = box[2] - box[0], box[3] - box[1]
    size = f"{width:.0f} x {height:.0f} m"
    if 2.0 * posting > min(width, height):
        raise InputError(
            f"{option_label('posting_m')} {posting:g} m is larger than the images' common "
            f"footprint ({size}) allows: a DEM needs at least 2 x 2 nodes"
        )
    check_grid_size(
        width,
        height,
        posting,
        what="ior",
        option="posting_m (--posting)",
        max_cells=settings.max_cells,
    )
    o_rows, o_cols = check_grid_size(
        width,
        height,
        posting / k,
        what="ior",
        option="ortho_res_m (--ortho-res)",
        max_cells=settings.max_cells,
    )
    if min(o_rows, o_cols) < MIN_IMAGE_PX:
        raise InputError(
            f"{option_label('ortho_res_m')} {posting / k:g} m gives {o_cols} x {o_rows} "
            f"ortho pixels "
            f"over the images' common footprint ({size}); matching needs at least "
            f"{MIN_IMAGE_PX} x {MIN_IMAGE_PX}"
        )
    dem_grid = OrthoGrid.covering(
        [], init_dem, posting, crs=crs, bounds=box, max_cells=settings.max_cells
    )
    t = dem_grid.transform
    ortho_grid = OrthoGrid(
        dem_grid.crs,
        Affine(t.a / k, 0.0, t.c, 0.0, t.e / k, t.f),
        (dem_grid.shape[0] * k, dem_grid.shape[1] * k),
    )
    return dem_grid, ortho_grid, k


def base_direction(
    left: Sensor, right: Sensor, lon: float, lat: float, h: float
) -> tuple[float, FloatArray]:
    """``(B/H, unit (east, north))`` at a ground point: ``t_R - t_L``, the horizontal
    displacement between the two lines of sight per metre of height (``t``: of length
    ``tan theta``), its length and direction. A DEM too high shifts a detail in the right
    ortho-image against the left one along this direction."""
    from carto.framework.geometry import frames

    e_n_u = frames.enu_basis(lon, lat)
    t = []
    for s in (left, right):
        line, sample = s.ground_to_image(lon, lat, h)
        lo, la = s.image_to_ground(line, sample, h + 100.0)
        d = frames.geodetic_to_ecef(lo, la, h + 100.0) - frames.geodetic_to_ecef(lon, lat, h)
        t.append((e_n_u @ np.ravel(d))[:2] / 100.0)
    base = t[1] - t[0]
    length = float(np.linalg.norm(base))
    return length, base / length


def b_over_h(left: Sensor, right: Sensor, lon: float, lat: float, h: float) -> float:
    """Base-to-height ratio at a ground point (:func:`base_direction`)."""
    return base_direction(left, right, lon, lat, h)[0]


class TileFailure(InputError):
    """Tiles of an iteration failed after their retries (the cause of the first, and how
    many)."""


def _tile_plan(
    sensors: tuple[Sensor, Sensor], grid: OrthoGrid, heights: FloatArray, tile_n: int
) -> list[tuple[slice, slice]]:
    """The tiles (node slices) that both images see: each tile's nodes sampled on an 9 x 9
    lattice (edges included) at the starting heights; tiles beyond the common footprint get
    no task."""
    n_r, n_c = grid.shape
    tiles = [
        (slice(r, min(n_r, r + tile_n)), slice(c, min(n_c, c + tile_n)))
        for r in range(0, n_r, tile_n)
        for c in range(0, n_c, tile_n)
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


@contextlib.contextmanager
def _work_folder(work_dir: str | os.PathLike[str] | None) -> Iterator[tuple[Path, bool]]:
    if work_dir is not None:
        Path(work_dir).mkdir(parents=True, exist_ok=True)
        yield Path(work_dir), True
        return
    with tempfile.TemporaryDirectory(prefix="carto-ior-") as tmp:
        yield Path(tmp), False


def refine_dem(
    left_image: Any,
    right_image: Any,
    left: Sensor,
    right: Sensor,
    init_dem: DEM,
    settings: IORSettings | None = None,
    progress: Callable[[str], None] | None = None,
    scheduler: Any = None,
    matcher: Matcher | None = None,
    *,
    work_dir: str | os.PathLike[str] | None = None,
    keep_failed_tiles: bool = False,
) -> IORResult:
    """The IOR loop (see the module docstring).

    Args:
        left_image, right_image: the prepared raw images (staggered arrays already merged):
            2-D arrays, raster paths or
            :class:`~carto.framework.raster.image_source.ImageSource` s (whole scenes: only
            the windows each tile needs are read).
        left, right: their models (adjusted, for a DEM of the adjusted accuracy).
        init_dem: the starting DEM (ellipsoidal heights; SRTM with a geoid, or
            :meth:`DEM.constant`).
        settings: :class:`IORSettings`.
        progress: called with one line per iteration.
        scheduler: runs a list of tile tasks and returns their results in order: a
            :class:`~carto.framework.parallel.engine.TileEngine` (threads, processes or a
            dask cluster, with retries and progress bars; default: this process) or any
            callable. Tasks are pure functions of files, windows and settings
            (:func:`carto.ior.tiles.run_tile`).
        matcher: the dense matcher of the ortho-images (default: the framework's ``"ncc"``,
            hierarchical NCC with a left-right check); any matcher with ``match_dense``.
        work_dir: the run's work folder (:mod:`carto.ior.workspace`): an iteration's DEM grid
            and tile files; a folder that holds the state of an interrupted run is continued
            from its finished tiles. With a work folder, the ortho-images and matching layers
            of the result stay tiles in it
            (:class:`~carto.framework.raster.tiled_layer.TiledLayer`); without one (a
            temporary folder), they are read into arrays.
        keep_failed_tiles: a tile that fails (after the engine's retries) is left unmatched
            and listed in :attr:`IORResult.failed_tiles`, instead of stopping the run.

    Raises:
        InputError: images that do not overlap, an initial DEM that covers too little of
            them (:func:`starting_surface`), a posting or ortho resolution that makes a grid
            too large or too small for the footprint, bad settings, a work folder of another
            run.
        TileFailure: tiles failed (without ``keep_failed_tiles``); the finished ones stay in
            the work folder.
    """
    from carto.framework.parallel.engine import TileEngine
    from carto.framework.raster.image_source import as_image_source

    s = settings or IORSettings()
    images = (as_image_source(left_image), as_image_source(right_image))
    dem_grid, ortho_grid, k = _grids(left, right, init_dem, s)
    s = attrs.evolve(s, smoothing_nodes=s.smoothing_for(k))  # for this grid's k
    engine = scheduler if scheduler is not None else TileEngine(quiet=True)
    with _work_folder(work_dir) as (folder, kept):
        space = Workspace(folder)
        state = space.load(dem_grid.shape)
        if state is None:
            start = starting_surface(init_dem, dem_grid, (left, right), s.min_init_coverage)
            if progress and start.filled > 0.0:
                progress(
                    f"initial DEM {init_dem.name}: {100.0 * start.filled:.1f} % of the "
                    "footprint filled (voids)"
                )
            facts = {"init_coverage": start.coverage, "init_filled": start.filled}
            state = RunState(1, start.heights, (0.0, 0.0), (), facts)
            space.begin(state)
        elif progress:
            progress(f"resuming at iteration {state.iteration} from {folder}")
        result = _iterate(
            images,
            (left, right),
            dem_grid,
            ortho_grid,
            k,
            s,
            state,
            space,
            engine,
            matcher,
            progress,
            keep_failed_tiles,
        )
        if not kept:  # the temporary folder goes: read the layers now
            result = attrs.evolve(
                result,
                ortho_left=np.asarray(result.ortho_left),
                ortho_right=np.asarray(result.ortho_right),
                score=np.asarray(result.score),
                valid=np.asarray(result.valid),
                node_quality={k: np.asarray(v) for k, v in result.node_quality.items()},
            )
        return result


def _iterate(
    images: tuple[Any, Any],
    sensors: tuple[Sensor, Sensor],
    dem_grid: OrthoGrid,
    ortho_grid: OrthoGrid,
    k: int,
    s: IORSettings,
    state: RunState,
    space: Workspace,
    engine: Any,
    matcher: Matcher | None,
    progress: Callable[[str], None] | None,
    keep_failed_tiles: bool,
) -> IORResult:
    """The iterations of :func:`refine_dem` from ``state`` on."""
    from carto.framework.raster.tiled_layer import TiledLayer, TilePiece, piece_path

    left, right = sensors
    heights = state.heights
    n_r, n_c = dem_grid.shape
    c_lon, c_lat = dem_grid.lonlat(n_r / 2, n_c / 2)
    bh, base_en = base_direction(
        left, right, float(c_lon), float(c_lat), float(np.nanmedian(heights))
    )
    base_rc = np.array([-base_en[1], base_en[0]])  # (row, col) of the north-up grid
    tile_n = max(16, s.tile_px // k)
    overlap_n = max(2, -(-s.overlap_px // k))
    plan = _tile_plan((left, right), dem_grid, heights, tile_n)
    keys = [f"tile {rows.start // tile_n},{cols.start // tile_n}" for rows, cols in plan]
    reports = [IterationReport(**r) for r in state.reports]
    converged = False
    guess = state.guess
    failed: list[str] = []
    iteration = state.iteration
    while True:
        t0 = time.perf_counter()
        current = heights
        levels = (
            s.refine_levels if reports and reports[-1].median_abs_mismatch_px < 2.0 else s.levels
        )
        job = TileJob(
            images,
            (left, right),
            space.heights_path(iteration),
            dem_grid,
            k,
            overlap_n,
            s,
            levels,
            guess,
            matcher,
            (float(np.nanmin(current)), float(np.nanmax(current))),
            space.iteration_dir(iteration),
            (float(base_rc[0]), float(base_rc[1])),
            smoothing_variance_factor(s.smoothing_nodes, iteration - 1, s.window, k),
        )
        tasks = [functools.partial(run_tile, job, rows, cols) for rows, cols in plan]
        outcomes = _run_tiles(engine, tasks, f"IOR iteration {iteration}", keys)
        failed = [str(o) for o in outcomes if isinstance(o, TaskFailure)]
        if failed and not keep_failed_tiles:
            raise TileFailure(
                f"ior: {len(failed)} of {len(plan)} tiles failed in iteration {iteration} "
                f"({failed[0]})"
            )
        # the grids of the coordinator: heights in float64, offsets in float32 (what the
        # tiles measured to a hundredth of a pixel), the rest as masks
        new = np.full(dem_grid.shape, np.nan)
        d_row = np.full(dem_grid.shape, np.nan, np.float32)
        d_col = np.full(dem_grid.shape, np.nan, np.float32)
        covered = np.zeros(dem_grid.shape, bool)
        for (rows, cols), outcome in zip(plan, outcomes, strict=True):
            if isinstance(outcome, TaskFailure):
                continue
            arrays = tile_arrays(outcome, NODE_LAYERS)
            new[rows, cols] = arrays["new_height"]
            d_row[rows, cols] = arrays["d_row_px"]
            d_col[rows, cols] = arrays["d_col_px"]
            covered[rows, cols] = arrays["covered"]
        matched = np.isfinite(d_row) & covered
        # the mismatch a height change removes: along the base; across it, what the
        # relative orientation leaves (reported, and the next search starts from it)
        m_row, m_col = d_row[matched], d_col[matched]
        del d_row, d_col
        b_row, b_col = float(base_rc[0]), float(base_rc[1])  # float32 products
        along = m_row * b_row + m_col * b_col
        across = m_col * b_row - m_row * b_col
        med = float(np.median(np.abs(along))) if along.size else float("nan")
        across_px = float(np.median(across)) if across.size else float("nan")
        del m_row, m_col, along, across
        if matched.any():  # the across-base offset stays; the along-base one the DEM removes
            guess = (-across_px * float(base_rc[1]), across_px * float(base_rc[0]))
        pct = 100.0 * float(matched.sum()) / max(int(covered.sum()), 1)
        # converged: the mismatch is below the threshold, or it no longer improves (what
        # is left is the matching noise, which no height change removes)
        stalled = (
            bool(reports) and med > (1.0 - s.min_improvement) * reports[-1].median_abs_mismatch_px
        )
        done = bool(matched.any() and (med < s.threshold_px or stalled))
        if done or iteration > s.max_iterations:
            converged = done
            reports.append(
                IterationReport(iteration, med, pct, 0.0, across_px, time.perf_counter() - t0)
            )
            if progress:
                progress(
                    f"iteration {iteration}: median mismatch {med:.3f} px along the base, "
                    f"{pct:.1f} % matched" + (" (converged)" if done else " (last)")
                )
            break
        heights, _ = regularise(current, new, s)
        change = np.abs(heights - current)[covered]
        med_change = float(np.median(change)) if change.size else 0.0
        reports.append(
            IterationReport(iteration, med, pct, med_change, across_px, time.perf_counter() - t0)
        )
        if progress:
            progress(
                f"iteration {iteration}: median mismatch {med:.3f} px along the base, "
                f"{pct:.1f} % matched, median DEM change {med_change:.2f} m"
            )
        iteration += 1
        space.begin(
            RunState(
                iteration,
                heights,
                guess,
                tuple(attrs.asdict(r) for r in reports),
                state.facts,
            )
        )
    # the last iteration's tiles hold the orthos made on the final DEM, its matching (ortho
    # grid: k pixels per node) and the points per node (DEM grid)
    finished = [
        (rows, cols)
        for (rows, cols), outcome in zip(plan, outcomes, strict=True)
        if not isinstance(outcome, TaskFailure)
    ]

    def tiled(name: str, scale: int, shape: tuple[int, int], dtype: Any, fill: Any) -> Any:
        pieces = [
            TilePiece(
                piece_path(space.iteration_dir(iteration), rows.start, cols.start),
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
    for (rows, cols), outcome in zip(plan, outcomes, strict=True):
        if isinstance(outcome, TaskFailure):
            failed_nodes[rows, cols] = True
    footprint = node_footprint(matched, covered, failed_nodes)
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
        tuple(reports),
        converged,
        bh,
        init_coverage=float(state.facts.get("init_coverage", 1.0)),
        init_filled=float(state.facts.get("init_filled", 0.0)),
        failed_tiles=tuple(failed),
        node_quality=node_quality,
        filled=footprint.filled,
        nodes=footprint.counts(),
    )
