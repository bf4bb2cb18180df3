"""Coarse-to-fine stages of IOR (:func:`coarse_stages`): iterations on the images reduced
``2**c`` times before the final grid, each stage starting from the one before, so that the
final iterations start close and search a few pixels around each node."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import InputError
from carto.framework.sdk.dem import DEM, ELLIPSOID, OrthoGrid
from carto.ior.grids import ior_grids
from carto.ior.iteration import IORRun, IterationReport, iterate
from carto.ior.settings import IORSettings
from carto.ior.start import starting_surface, values_on_grid
from carto.ior.workspace import RunState, Workspace


def coarse_stages(
    run: IORRun,
    init_dem: DEM,
    s: IORSettings,
    crs: Any,
    k: int,
    folder: Path,
) -> tuple[DEM, tuple[float, float], list[IterationReport], DEM | None] | None:
    """The coarse-to-fine stages before the final grid (``s.coarse_stages``) of ``run``: IOR
    on the images reduced ``f = 2**c`` times (:class:`~carto.framework.raster.image_source.
    DecimatedImage`, block means: no aliasing) with their models
    (:class:`~carto.framework.geometry.decimated.DecimatedSensor`), on a grid ``f`` times
    coarser with ortho-images ``f`` times coarser, from ``c = s.coarse_stages`` down to 1,
    each with ``s.coarse_iterations`` updates plus one from its last measurement, starting
    from the one before; a stage the
    footprint is too small for is skipped. Each stage keeps its work in ``folder /
    "stage_1_F"`` (resumable). Returns the last stage's surface (a DEM for the final grid to
    start from), its offset across the base in final ortho pixels, the stages' reports and
    its search bounds along the base (a
    DEM of final ortho pixels: the bound of a node of a stage ``f`` times coarser, times
    ``f``; None when unbounded), or None without a stage."""
    from carto.framework.sdk.dem import DecimatedImage
    from carto.framework.sdk.sensors import DecimatedSensor

    start_dem, guess, ran = init_dem, (0.0, 0.0), False
    search: DEM | None = None  # the last stage's search bounds, final ortho pixels
    reports: list[IterationReport] = []
    res = s.posting_m / k  # final ortho pixel, metres
    for c in range(s.coarse_stages, 0, -1):
        f = 2**c
        cs = attrs.evolve(
            s,
            posting_m=s.posting_m * f,
            ortho_res_m=res * f,
            crs=crs,
            max_iterations=s.coarse_iterations,
            levels=max(s.refine_levels, s.levels - c),
            smoothing_nodes=None,
        )
        coarse = attrs.evolve(
            run,
            images=(DecimatedImage(run.images[0], f), DecimatedImage(run.images[1], f)),
            sensors=(DecimatedSensor(run.sensors[0], f), DecimatedSensor(run.sensors[1], f)),
        )
        try:
            grid, o_grid, k_f = ior_grids(*coarse.sensors, start_dem, cs)
        except InputError:
            continue  # a footprint too small for this stage
        cs = attrs.evolve(cs, smoothing_nodes=cs.smoothing_for(k_f))
        space = Workspace(folder / f"stage_1_{f}")
        state = space.load(grid.shape)
        if state is None:
            start = starting_surface(start_dem, grid, coarse.sensors, 0.0)
            g = (guess[0] / f, guess[1] / f)
            bound = None if search is None else search_on(search, grid, f)
            state = RunState(1, start.heights, g, (), {"start_refined": ran}, bound)
            space.begin(state)
        stage = iterate(coarse, (grid, o_grid, k_f), cs, state, space, factor=f, apply_last=True)
        ran = True
        start_dem = DEM.from_array(
            np.asarray(stage.surface), grid.transform, grid.crs.to_wkt(), vertical=ELLIPSOID
        )
        guess = (stage.guess[0] * f, stage.guess[1] * f)
        if stage.search_px is not None:  # in final ortho pixels
            search = DEM.from_array(
                np.asarray(stage.search_px, np.float64) * f,
                grid.transform,
                grid.crs.to_wkt(),
                vertical=ELLIPSOID,
            )
        reports += stage.iterations
    if not ran:
        return None
    return start_dem, guess, reports, search


def search_on(search: DEM, grid: OrthoGrid, factor: int) -> NDArray[np.float32]:
    """Search bounds in final ortho pixels (a DEM of a coarser stage's grid) on ``grid``,
    in pixels ``factor`` times the final ones (bilinear; NaN: none)."""
    return (values_on_grid(search, grid, smooth=False) / factor).astype(np.float32)
