"""Tie points of whole scenes by tiles: bounded memory, tasks of a tile engine.

The tie-point pipeline (:mod:`~carto.framework.matching.tiepoints`) matches system-level
ortho-images of the whole block grid. A 12000 x 12000 Cartosat-1 pair makes orthos of 0.6 GB
each, and the matching arrays several times that; so the grid is split into tiles:

1. the tiles are ranges of the candidate cells of the whole grid
   (:func:`~carto.framework.matching.candidates.candidate_cells`), about ``tile_px`` ortho
   pixels a side (:func:`plan_tiles`); a tile owns the candidates of its cells, so the tiles'
   points are disjoint (no duplicates in the overlaps) and the per-cell selection, cell by
   cell, is that of the whole grid;
2. which images see which part of the grid is found on a coarse lattice of grid nodes
   projected into every image (:func:`coverage_lattice`); tiles that no two images see
   are skipped;
3. the first guess of the shift between the reference ortho and each other one (step 4 of
   the pipeline: :func:`~carto.framework.matching.shifts.coarse_shift`, on the whole orthos
   for a small scene) comes from a probe window of ``PROBE_PX`` ortho pixels at the centre
   of the area both images see (:func:`probe_guesses`);
4. each tile task orthorectifies the window it needs (its cells plus a margin of the
   matching's reach and the guessed shift) from every image, read by windows
   (:class:`~carto.framework.raster.image_source.ImageSource`; staggered images prepared once,
   :func:`~carto.framework.imaging.preparation.prepare_image`), finds its candidates
   (:func:`~carto.framework.matching.candidates.window_candidates`), matches them
   (:func:`~carto.framework.matching.tiepoints.tie_points_on_orthos`) and returns only its
   tie-point table; the tables are concatenated (ids prefixed by the tile).

A grid that fits in one tile is one task on the whole grid: the pipeline as it always was.
What differs between tiles and one piece: the Forstner weight quantile (the window's), the
first guess (the probe's), and the gross-error test's median limit (the tile's points); on
a simulated hilly pair, tiles of 256 px give the same points to 0.05 px.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.matching.candidates import (
    CandidateOptions,
    Spacing,
    candidate_cells,
    candidate_points,
    in_cell_range,
    window_candidates,
)
from carto.framework.matching.forstner import spread_order
from carto.framework.matching.multiview import match_views, ortho_parallax

TILE_PX = 2048
"""Side of a tie-point tile (its own cells), ortho pixels."""

PROBE_PX = 3072
"""Side of the probe window of :func:`probe_guesses`, ortho pixels."""

HALO_CELLS = 3
"""Cells around a tile whose candidates it matches too, as context only: the matching's
neighbourhood steps (the pyramid's median guesses, the gross-error test's neighbours) see
the points they would see in one piece."""

LATTICE_PX = 64
"""Spacing of the nodes of :func:`coverage_lattice`, ortho pixels."""

Range = tuple[tuple[int, int], tuple[int, int]]

TABLE_COLUMNS = ("id", "image", "line", "sample", "score", "sigma_px")
"""Columns of the tie-point table (long format: one row per point and image)."""


def _empty_table() -> dict[str, NDArray]:
    return {k: np.empty(0, object if k in ("id", "image") else float) for k in TABLE_COLUMNS}


def tie_points_on_orthos(
    grid: Any,
    orthos: Mapping[str, NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    ref: str,
    spacing_px: Spacing,
    points: NDArray | None,
    candidates: str,
    forstner: Mapping[str, Any] | None,
    matching: Mapping[str, Any],
    per_cell: int,
    min_views: int,
    sigma_px: float,
    *,
    guesses: Mapping[str, tuple[float, float]] | None = None,
    offset: tuple[int, int] = (0, 0),
    frame_shape: tuple[int, int] | None = None,
    id_prefix: str = "A",
    returned: NDArray[np.bool_] | None = None,
) -> dict[str, NDArray]:
    """Candidates, multi-view matching and selection on orthos already made on ``grid``
    (steps 3-6 of the module docstring; arguments as :func:`automatic_tie_points`'s, with
    ``matching`` the options of :func:`match_views`): the tie-point table, raw coordinates
    computed with the very models that made the orthos. Also used on small ortho chips
    (:mod:`~carto.framework.matching.gcp_transfer`) and on the tiles of a whole scene
    (:mod:`~carto.framework.matching.tiled_ties`): ``grid`` is then a window at ``offset``
    (row, col) of a larger frame of ``frame_shape`` whose cells of ``spacing_px`` the
    selection uses, ``guesses`` the first guesses of :func:`match_views`, ``id_prefix``
    starts the point ids and ``returned`` marks the candidates whose points are returned (the
    others, the tile's neighbours', are matched only as the context of the matching's
    neighbourhood tests)."""
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
        guesses=guesses,
    )
    raw = _raw_positions(mv, grid, sensors, dem)
    seen = np.isfinite(raw).all(axis=2)
    n_seen = seen.sum(axis=0)
    good = seen[0] & (n_seen >= max(int(min_views), 2))
    if returned is not None:
        good &= np.asarray(returned, bool)
    keep = np.flatnonzero(good)
    if keep.size == 0:
        return _empty_table()
    if per_cell:
        frame = tuple(grid.shape) if frame_shape is None else tuple(frame_shape)
        spread = _Spread(frame, spacing_px, per_cell, offset)
        keep = _spread_subset(keep, points, n_seen, mv.scores[0], spread)
    return _long_table(mv, raw, seen, keep, id_prefix, sigma_px)


def _raw_positions(mv: Any, grid: Any, sensors: Mapping[str, Sensor], dem: Any) -> NDArray:
    """``(views, points, 2)`` raw image ``(line, sample)`` of the matches ``mv`` (ortho
    positions on ``grid``), each computed with the model that made that view's ortho; NaN
    where a view has no match."""
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
    return raw


@attrs.frozen
class _Spread:
    """How the kept points are spread: ``per_cell`` per cell of ``spacing_px`` pixels of a
    frame of ``frame_shape`` in which the matched window lies at ``offset`` (row, col)."""

    frame_shape: tuple[int, ...]
    spacing_px: Spacing
    per_cell: int
    offset: tuple[int, int]


def _spread_subset(
    keep: NDArray[np.intp],
    points: NDArray[np.float64],
    n_seen: NDArray[np.intp],
    ref_scores: NDArray,
    spread: _Spread,
) -> NDArray[np.intp]:
    """The candidates of ``keep`` (indices of ``points``) that
    :func:`~carto.framework.matching.forstner.spread_order` keeps per cell (those seen in
    most views, best reference score first), in index order."""
    weight = n_seen[keep] + 0.5 * np.nan_to_num(ref_scores[keep], nan=-1.0)
    frame = spread.frame_shape
    order = spread_order(
        points[keep] + np.asarray(spread.offset, np.float64),
        weight,
        frame,
        candidate_cells(frame, spread.spacing_px),
        spread.per_cell,
    )
    return np.sort(keep[order])


def _long_table(
    mv: Any,
    raw: NDArray,
    seen: NDArray[np.bool_],
    keep: NDArray[np.intp],
    id_prefix: str,
    sigma_px: float,
) -> dict[str, NDArray]:
    """The tie-point table (one row per kept point and view that sees it, by point, then
    view) of the matches ``mv`` at raw positions ``raw``; ids ``id_prefix`` and the
    candidate's index."""
    point_pos, view_idx = np.nonzero(seen[:, keep].T)  # row-major: by point, then view
    point_idx = keep[point_pos]
    ids = np.array([f"{id_prefix}{i:05d}" for i in keep], object)
    return {
        "id": ids[point_pos],
        "image": np.array(mv.views, object)[view_idx],
        "line": raw[view_idx, point_idx, 0],
        "sample": raw[view_idx, point_idx, 1],
        "score": mv.scores[view_idx, point_idx],
        "sigma_px": np.full(point_idx.size, float(sigma_px)),
    }


def plan_tiles(grid_shape: tuple[int, int], spacing_px: Spacing, tile_px: int) -> list[Range]:
    """The tiles of a grid: ranges ``((row0, row1), (col0, col1))`` of its candidate cells
    (:func:`~carto.framework.matching.candidates.candidate_cells`), about ``tile_px`` pixels
    a side, row-major."""
    cells = candidate_cells(grid_shape, spacing_px)
    axes = []
    for n, size in zip(cells, grid_shape, strict=True):
        per = max(1, round(float(tile_px) / (size / n)))
        count = math.ceil(n / per)
        per = math.ceil(n / count)  # even tiles
        axes.append([(k, min(n, k + per)) for k in range(0, n, per)])
    return [(r, c) for r in axes[0] for c in axes[1]]


def cell_bounds(cell_range: Range, grid_shape: tuple[int, int], cells: tuple[int, int]) -> NDArray:
    """``[[row0, row1], [col0, col1]]``: the pixels the cells cover (outwards)."""
    out = np.empty((2, 2), np.int64)
    for axis in (0, 1):
        size = grid_shape[axis] / cells[axis]
        lo, hi = cell_range[axis]
        out[axis] = [math.floor(lo * size), min(grid_shape[axis], math.ceil(hi * size))]
    return out


def coverage_lattice(
    grid: Any, sensors: Mapping[str, Sensor], dem: Any, step: int = LATTICE_PX
) -> tuple[NDArray[np.float64], dict[str, NDArray[np.bool_]]]:
    """Nodes every ``step`` pixels of ``grid`` (``(R, C, 2)`` pixel rows and cols) and, per
    image, whether the image sees each node on the DEM (``(R, C)``)."""
    rows = np.arange(step / 2, grid.shape[0], step)
    cols = np.arange(step / 2, grid.shape[1], step)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    lon, lat = grid.lonlat(rr.ravel() - 0.5, cc.ravel() - 0.5)
    h = dem.height(lon, lat)
    seen = {}
    for name, sensor in sensors.items():
        _, _, inside = sensor.project(lon, lat, np.nan_to_num(h, nan=0.0))
        seen[name] = (np.asarray(inside, bool) & np.isfinite(h)).reshape(rr.shape)
    return np.stack([rr, cc], axis=2), seen


@attrs.frozen(eq=False)
class _Scene:
    """What every task orthorectifies from: image name -> prepared image (an ImageSource or
    array), image name -> model, the DEM and the block grid."""

    images: Mapping[str, Any]
    sensors: Mapping[str, Sensor]
    dem: Any
    grid: Any

    def ortho(self, name: str, sub: Any) -> NDArray:
        """Image ``name`` orthorectified on ``sub``, a window of the grid."""
        from carto.framework.imaging.ortho import orthorectify

        return orthorectify(self.images[name], self.sensors[name], sub, self.dem)


def _probe_task(
    scene: _Scene, window: tuple[int, int, int, int], ref: str, other: str
) -> tuple[float, float, float]:
    """:func:`~carto.framework.matching.shifts.coarse_shift` of ``other``'s ortho against
    ``ref``'s on one window of the scene's grid."""
    from carto.framework.matching.shifts import coarse_shift

    sub = scene.grid.window(*window)
    return coarse_shift(scene.ortho(ref, sub), scene.ortho(other, sub))


def probe_guesses(
    scene: _Scene,
    ref: str,
    lattice: tuple[NDArray, Mapping[str, NDArray]],
    engine: Any,
    probe_px: int = PROBE_PX,
) -> dict[str, tuple[float, float]]:
    """First guesses ``(d_line, d_sample)`` of every other image's ortho against the
    reference's: :func:`~carto.framework.matching.shifts.coarse_shift` on a window of
    ``probe_px`` pixels of the scene's grid (the whole grid when it is smaller: the shift of
    one piece) centred between the two images' footprints by their models (which may not even
    overlap: the system-level models of an agile triplet are hundreds of metres apart); one
    task of ``engine`` per image, ``(0, 0)`` for an image that sees none of the grid."""
    from carto.framework.parallel.engine import TaskFailure

    nodes, seen = lattice
    grid = scene.grid
    others = [n for n in scene.sensors if n != ref]
    tasks, keys, names = [], [], []
    guesses = {n: (0.0, 0.0) for n in others}
    for name in others:
        if not (seen[ref].any() and seen[name].any()):
            continue
        centre = 0.5 * (nodes[seen[ref]].mean(axis=0) + nodes[seen[name]].mean(axis=0))
        size = [min(probe_px, n) for n in grid.shape]
        start = [
            int(np.clip(round(centre[k] - size[k] / 2), 0, grid.shape[k] - size[k])) for k in (0, 1)
        ]
        window = (start[0], start[1], size[0], size[1])
        tasks.append(functools.partial(_probe_task, scene, window, ref, name))
        keys.append(f"probe {name}")
        names.append(name)
    for name, found in zip(
        names, engine.run(tasks, desc="tie-point shifts", keys=keys), strict=True
    ):
        if isinstance(found, TaskFailure):
            raise InputError(f"tie points: the shift of {name} could not be found ({found})")
        guesses[name] = (float(found[0]), float(found[1]))
    return guesses


def _shifted(mask: NDArray[np.bool_], shift: NDArray[np.float64]) -> NDArray[np.bool_]:
    """``mask`` moved by ``shift`` nodes (rounded both ways: a node is kept when it or its
    neighbour towards the shift is set), False where it comes from outside."""
    out = np.zeros(mask.shape, bool)
    for dr in {math.floor(shift[0]), math.ceil(shift[0])}:
        for dc in {math.floor(shift[1]), math.ceil(shift[1])}:
            src = mask[
                max(0, -dr) : mask.shape[0] - max(0, dr), max(0, -dc) : mask.shape[1] - max(0, dc)
            ]
            if src.size:
                out[
                    max(0, dr) : max(0, dr) + src.shape[0], max(0, dc) : max(0, dc) + src.shape[1]
                ] |= src
    return out


def tile_margin(template: int, search: int, levels: int, shift_px: float) -> int:
    """Pixels a tile's window reaches beyond its cells: the matching pyramid's reach (the
    template and the search at the coarsest level), the guessed shift and a little for the
    least-squares refinement and the candidate operator."""
    reach = (int(template) // 2 + int(search) + 2) * 2 ** (max(int(levels), 1) - 1)
    return math.ceil(reach + float(shift_px)) + 16


@attrs.frozen
class _Tile:
    """One task of :func:`tiled_tie_points`: the ``window`` ``(row0, col0, rows, cols)`` of
    the grid it orthorectifies, the range of the grid's cells whose candidates it owns (None:
    the whole grid, with the pipeline's own candidates) and the prefix of its point ids."""

    window: tuple[int, int, int, int]
    cell_range: Range | None
    id_prefix: str


def _tile_task(
    scene: _Scene,
    tile: _Tile,
    ref: str,
    spacing_px: Spacing,
    settings: Mapping[str, Any],
    guesses: Mapping[str, tuple[float, float]] | None,
) -> dict[str, NDArray]:
    """One tile: its window orthorectified from every image, its candidates matched; the
    tie-point table (``tile.cell_range`` None: the whole grid, with the pipeline's own
    candidates)."""
    s = dict(settings)
    window, frame = tile.window, tuple(scene.grid.shape)
    sub = scene.grid.window(*window)
    orthos = {n: scene.ortho(n, sub) for n in scene.sensors}
    points = s.pop("points")
    returned = None
    if tile.cell_range is not None:
        points, returned = _tile_candidates(orthos[ref], tile, frame, spacing_px, s)
    return tie_points_on_orthos(
        sub,
        orthos,
        scene.sensors,
        scene.dem,
        ref,
        spacing_px,
        points,
        s["candidates"],
        s["forstner"],
        s["matching"],
        s["per_cell"],
        s["min_views"],
        s["sigma_px"],
        guesses=guesses,
        offset=(window[0], window[1]),
        frame_shape=frame,
        id_prefix=tile.id_prefix,
        returned=returned,
    )


def _tile_candidates(
    ortho: NDArray,
    tile: _Tile,
    frame: tuple[int, ...],
    spacing_px: Spacing,
    settings: Mapping[str, Any],
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The candidates of a tile's reference ``ortho`` in its cells and the halo around them
    (window pixels), and which of them are its own (in its ``cell_range``: returned)."""
    cells = candidate_cells(frame, spacing_px)
    wide = _widened(tile.cell_range, cells, HALO_CELLS)
    window = tile.window
    options = CandidateOptions(settings["candidates"], **dict(settings["forstner"] or {}))
    points = window_candidates(ortho, spacing_px, (window[0], window[1]), frame, wide, options)
    returned = in_cell_range(
        points + np.array(window[:2], np.float64), frame, cells, tile.cell_range
    )
    return points, returned


def _widened(cell_range: Range, cells: tuple[int, int], halo: int) -> Range:
    """A range of cells widened by ``halo`` cells (within the frame's ``cells``)."""
    (r0, r1), (c0, c1) = cell_range
    return (
        (max(0, r0 - halo), min(cells[0], r1 + halo)),
        (max(0, c0 - halo), min(cells[1], c1 + halo)),
    )


def tiled_tie_points(
    images: Mapping[str, Any],
    sensors: Mapping[str, Sensor],
    dem: Any,
    grid: Any,
    ref: str,
    spacing_px: Spacing,
    settings: Mapping[str, Any],
    *,
    engine: Any = None,
    tile_px: int = TILE_PX,
) -> dict[str, NDArray]:
    """The tie-point table of prepared ``images`` on ``grid``, tile by tile (see the module
    docstring), the tiles tasks of ``engine`` (default: this process).

    Args:
        images: image name -> prepared image (an ImageSource or array).
        sensors, dem, ref, spacing_px: as :func:`~carto.framework.matching.tiepoints.
            tie_points_on_orthos`.
        grid: the block grid.
        settings: ``points`` (None, or candidates on the whole grid: then one tile),
            ``candidates``, ``forstner``, ``matching`` (options of
            :func:`~carto.framework.matching.multiview.match_views`), ``per_cell``,
            ``min_views``, ``sigma_px``.
        tile_px: side of a tile, ortho pixels.

    Raises:
        InputError: a tile that failed (the first cause).
    """
    from carto.framework.parallel.engine import TaskFailure, TileEngine

    engine = engine if engine is not None else TileEngine(quiet=True)
    scene = _Scene(images, sensors, dem, grid)
    shape = (int(grid.shape[0]), int(grid.shape[1]))
    if settings.get("points") is not None or max(shape) <= int(tile_px):
        whole = _Tile((0, 0, shape[0], shape[1]), None, "A")
        task = functools.partial(_tile_task, scene, whole, ref, spacing_px, settings, None)
        found = engine.run([task], desc="tie points", keys=["tile 0"])[0]
        if isinstance(found, TaskFailure):
            raise InputError(f"tie points: {found}")
        return found
    lattice = coverage_lattice(grid, sensors, dem)
    guesses = probe_guesses(scene, ref, lattice, engine)
    m = settings["matching"]
    shift = max((math.hypot(*g) for g in guesses.values()), default=0.0)
    margin = tile_margin(m.get("template", 15), m.get("search", 11), m.get("levels", 4), shift)
    tiles = _seen_tiles(shape, spacing_px, tile_px, margin, _useful_nodes(lattice, ref, guesses))
    tasks = [
        functools.partial(_tile_task, scene, tile, ref, spacing_px, settings, guesses)
        for tile in tiles
    ]
    keys = [f"tile {tile.cell_range[0][0]},{tile.cell_range[1][0]}" for tile in tiles]
    tables = engine.run(tasks, desc="tie points", keys=keys)
    failed = [t for t in tables if isinstance(t, TaskFailure)]
    if failed:
        raise InputError(f"tie points: {len(failed)} of {len(tasks)} tiles failed ({failed[0]})")
    if not tables:
        return _empty_table()
    return {k: np.concatenate([t[k] for t in tables]) for k in tables[0]}


def _useful_nodes(
    lattice: tuple[NDArray, Mapping[str, NDArray]],
    ref: str,
    guesses: Mapping[str, tuple[float, float]],
) -> tuple[NDArray, NDArray[np.bool_]]:
    """The lattice's nodes and whether each is useful: the reference sees it and so does
    another image's ortho, moved by its guessed shift."""
    nodes, seen = lattice
    others = np.zeros(nodes.shape[:2], bool)
    for name, guess in guesses.items():  # where the other image's ortho shows ref's ground
        others |= _shifted(seen[name], -np.asarray(guess) / LATTICE_PX)
    return nodes, seen[ref] & others


def _seen_tiles(
    shape: tuple[int, int],
    spacing_px: Spacing,
    tile_px: int,
    margin: int,
    useful_nodes: tuple[NDArray, NDArray[np.bool_]],
) -> list[_Tile]:
    """The tiles of the grid (:func:`plan_tiles`) that two images see (a useful node within
    ``margin`` pixels of the tile's cells and halo), each with its window: those cells and
    halo widened by ``margin`` (within the grid), ids ``A<k>.`` by the tile's plan index."""
    nodes, useful = useful_nodes
    cells = candidate_cells(shape, spacing_px)
    tiles = []
    for k, cell_range in enumerate(plan_tiles(shape, spacing_px, tile_px)):
        (r0, r1), (c0, c1) = cell_bounds(_widened(cell_range, cells, HALO_CELLS), shape, cells)
        near = (
            (nodes[..., 0] >= r0 - margin)
            & (nodes[..., 0] < r1 + margin)
            & (nodes[..., 1] >= c0 - margin)
            & (nodes[..., 1] < c1 + margin)
        )
        if not (useful & near).any():
            continue  # no two images see this tile
        w0, v0 = max(0, r0 - margin), max(0, c0 - margin)
        window = (w0, v0, min(shape[0], r1 + margin) - w0, min(shape[1], c1 + margin) - v0)
        tiles.append(_Tile(window, cell_range, f"A{k}."))
    return tiles
