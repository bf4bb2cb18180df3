"""Iterative ortho-image refinement (IOR): a DEM and ortho-images from a stereo pair with known
orientation (Radhadevi et al. 2010; design brief section 2).

With exact orientation, the ortho-images of the left and right image made on the true DEM are
identical; where the DEM height is wrong by ``e`` they are shifted against each other along
the stereo base. The loop:

1. orthorectify both images on the current DEM (:func:`carto.framework.imaging.ortho.orthorectify`);
2. match the two ortho-images densely with the chosen matcher's ``match_dense`` (the
   matcher extension point, ``carto dem --matcher``; the default ``"sgm"`` is
   :class:`carto.framework.matching.sgm_matcher.SGMMatcher`: OpenCV's semi-global matching
   along the base, left-right check, NCC confidence; ``"ncc"`` the NCC pyramid of
   :func:`carto.framework.matching.disparity.dense_offsets`), searching each node within a
   bound its last height change sets (:func:`carto.ior.iteration.next_search_px`), its
   offsets then refined by least squares along the base
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
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.sdk.common import FloatArray, InputError
from carto.framework.sdk.dem import DEM, OrthoGrid
from carto.framework.sdk.matchers import Matcher
from carto.framework.sdk.sensors import Sensor
from carto.ior.coarse_to_fine import coarse_stages, search_on
from carto.ior.grids import ior_grids as _grids
from carto.ior.iteration import (
    IORResult,
    IORRun,
    IterationReport,
    TileFailure,
    b_over_h,
    base_direction,
    iterate,
)
from carto.ior.regularise import regularise
from carto.ior.settings import IORSettings
from carto.ior.start import StartingSurface, initial_coverage, starting_surface
from carto.ior.tiles import (
    refine_tile,
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
        matcher: the dense matcher of the ortho-images (default: the framework's ``"sgm"``,
            semi-global matching along the base); any matcher with ``match_dense``.
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
    from carto.framework.sdk.common import TileEngine
    from carto.framework.sdk.dem import as_image_source

    s = settings or IORSettings()
    images = (as_image_source(left_image), as_image_source(right_image))
    dem_grid, ortho_grid, k = _grids(left, right, init_dem, s)
    s = attrs.evolve(s, smoothing_nodes=s.smoothing_for(k))  # for this grid's k
    run = IORRun(
        images,
        (left, right),
        scheduler if scheduler is not None else TileEngine(quiet=True),
        matcher,
        progress,
        keep_failed_tiles,
    )
    with _work_folder(work_dir) as (folder, kept):
        space = Workspace(folder)
        state = space.load(dem_grid.shape)
        if state is None:
            facts = _initial_facts(init_dem, dem_grid, (left, right), s, progress)
            stages = coarse_stages(run, init_dem, s, dem_grid.crs, k, folder)
            state = _first_state(stages, init_dem, dem_grid, (left, right), facts)
            space.begin(state)
        elif progress:
            progress(f"resuming at iteration {state.iteration} from {folder}")
        result = iterate(run, (dem_grid, ortho_grid, k), s, state, space)
        return _delivered(result, state, kept)


def _initial_facts(
    init_dem: DEM,
    dem_grid: OrthoGrid,
    sensors: tuple[Sensor, Sensor],
    s: IORSettings,
    progress: Callable[[str], None] | None,
) -> dict[str, Any]:
    """What the initial DEM gives on the final grid (its coverage checked, its voids
    counted), for the run's facts."""
    cover = initial_coverage(init_dem, dem_grid, sensors, s.min_init_coverage)
    if progress and cover.filled > 0.0:
        progress(
            f"initial DEM {init_dem.name}: {100.0 * cover.filled:.1f} % of the "
            "footprint filled (voids)"
        )
    return {"init_coverage": cover.coverage, "init_filled": cover.filled}


def _first_state(
    stages: tuple[DEM, tuple[float, float], list[IterationReport], DEM | None] | None,
    init_dem: DEM,
    dem_grid: OrthoGrid,
    sensors: tuple[Sensor, Sensor],
    facts: dict[str, Any],
) -> RunState:
    """The state a new run starts the final grid's iterations from: the surface, offset and
    search bounds of the coarse-to-fine ``stages`` (:func:`coarse_stages`), or without a
    stage the initial DEM."""
    if stages is None:  # no coarse stage: from the initial DEM
        start = starting_surface(init_dem, dem_grid, sensors, 0.0)
        return RunState(1, start.heights, (0.0, 0.0), (), facts)
    start_dem, guess, reports, search = stages
    start = starting_surface(start_dem, dem_grid, sensors, 0.0)
    bound = None if search is None else search_on(search, dem_grid, 1)
    facts["coarse_reports"] = [attrs.asdict(r) for r in reports]
    facts["start_refined"] = True
    return RunState(1, start.heights, guess, (), facts, bound)


def _delivered(result: IORResult, state: RunState, kept: bool) -> IORResult:
    """The final grid's result with every iteration, the coarse stages' first, numbered from
    1; its layers read into arrays unless the work folder is ``kept``."""
    coarse = [IterationReport(**r) for r in state.facts.get("coarse_reports", ())]
    every = [
        attrs.evolve(r, iteration=i + 1) for i, r in enumerate(coarse + list(result.iterations))
    ]
    result = attrs.evolve(result, iterations=tuple(every))
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
