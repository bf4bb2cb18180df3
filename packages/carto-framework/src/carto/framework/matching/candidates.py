"""Candidate points to match: a regular grid, or Forstner interest points spread over cells.

* :func:`grid_points`: regular candidate points (the matchers take any points: an interest
  operator can replace the grid).
* :func:`candidate_points`: the candidates of the tie-point pipeline (step 3 of
  :mod:`~carto.framework.matching.tiepoints`) on the reference ortho: the Forstner interest
  operator (:func:`~carto.framework.matching.forstner.forstner_points`), the best two of each
  cell of ``spacing_px`` ortho pixels (:func:`candidate_cells`; the second one is a spare: the
  final selection keeps one per cell), with the cell's centre as a fall-back where the operator
  finds nothing (or a plain grid).

Points are ``(N, 2)`` arrays of continuous ``(line, sample)``, the centre of the first pixel at
``(0.5, 0.5)`` (see :mod:`carto.framework.geometry.sensor`).
"""

from __future__ import annotations

import math
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.forstner import forstner_points, spread_order
from carto.framework.matching.inputs import as_image

CANDIDATE_METHODS = ("forstner", "grid")
"""Ways :func:`candidate_points` chooses the points to match."""


Spacing = float | tuple[float, float]
"""A cell or grid spacing, pixels: one for both axes, or ``(rows, cols)``."""


def spacing_axes(spacing: Spacing) -> tuple[float, float]:
    """``(rows, cols)`` of a :data:`Spacing`."""
    if isinstance(spacing, tuple | list | np.ndarray):
        rows, cols = (float(v) for v in spacing)
        return rows, cols
    return float(spacing), float(spacing)


def grid_points(
    shape: tuple[int, int], spacing: Spacing, margin: Spacing = 0.0
) -> NDArray[np.float64]:
    """Regular candidate points ``(N, 2)`` ``(line, sample)`` on pixel centres.

    Rows and columns every ``spacing`` pixels (one value, or ``(rows, cols)``) from
    ``margin`` (likewise: the distance of the first and last points from the image edges,
    pixels), centred in the image; row-major order.
    """
    steps, margins = spacing_axes(spacing), spacing_axes(margin)
    if not min(steps) >= 1.0:
        raise InputError(f"spacing must be >= 1 pixel, got {spacing}")
    if min(margins) < 0.0:
        raise InputError(f"margin must be >= 0, got {margin}")

    def axis(n: int, step: float, edge: float) -> NDArray[np.float64]:
        span = n - 2.0 * edge - 1.0
        if span < 0:
            return np.empty(0)
        count = int(span // step) + 1
        start = math.floor(edge + 0.5 * (span - (count - 1) * step))
        return start + 0.5 + np.round(np.arange(count) * step)

    lines, samples = (axis(int(shape[k]), steps[k], margins[k]) for k in (0, 1))
    grid_l, grid_s = np.meshgrid(lines, samples, indexing="ij")
    return np.stack([grid_l.ravel(), grid_s.ravel()], axis=1)


def candidate_cells(shape: tuple[int, int], spacing_px: Spacing) -> tuple[int, int]:
    """``(rows, cols)``: the number of cells of about ``spacing_px`` pixels (one value or
    ``(rows, cols)``; at least one cell) that divide an image of ``shape``."""
    steps = spacing_axes(spacing_px)
    return (max(1, round(shape[0] / steps[0])), max(1, round(shape[1] / steps[1])))


def _finite_at(image: NDArray[np.float32], points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """True where the pixel holding each point has data."""
    index = (points - 0.5).astype(np.intp)
    return np.isfinite(image[index[:, 0], index[:, 1]])


@attrs.frozen
class CandidateOptions:
    """How :func:`candidate_points` and :func:`window_candidates` choose their points.

    Attributes:
        method: ``"forstner"`` or ``"grid"`` (:data:`CANDIDATE_METHODS`).
        per_cell: Forstner points kept per cell.
        window, min_roundness, weight_quantile: the operator's box, smallest roundness and
            weight quantile (:func:`~carto.framework.matching.forstner.forstner_points`).
    """

    method: str = "forstner"
    per_cell: int = 2
    window: int = 5
    min_roundness: float = 0.5
    weight_quantile: float = 0.5

    def operator_points(self, image: NDArray, **cells: Any) -> NDArray[np.float64]:
        """:func:`~carto.framework.matching.forstner.forstner_points` of ``image`` with these
        options (suppression radius ``window``, least-squares corner location); ``cells``:
        its ``grid_cells`` and ``per_cell``, if any."""
        return forstner_points(
            image,
            window=self.window,
            min_roundness=self.min_roundness,
            weight_quantile=self.weight_quantile,
            **cells,
        )


def _checked(
    image: ArrayLike, method: str, spacing_px: Spacing
) -> tuple[NDArray, tuple[float, float]]:
    """The image (:func:`~carto.framework.matching.inputs.as_image`) and the spacing
    ``(rows, cols)``, refused unless the method is one of :data:`CANDIDATE_METHODS` and the
    spacing at least 4 px."""
    img = as_image(image, "image")
    if method not in CANDIDATE_METHODS:
        raise InputError(f"candidates {method!r} is not one of {', '.join(CANDIDATE_METHODS)}")
    spacing = spacing_axes(spacing_px)
    if not min(spacing) >= 4.0:
        raise InputError(f"spacing_px must be >= 4 pixels, got {spacing_px}")
    return img, spacing


def _grid_margin(spacing: tuple[float, float]) -> tuple[float, float]:
    """The grid candidates' margin: two thirds of the spacing."""
    return (2 * spacing[0] / 3, 2 * spacing[1] / 3)


def candidate_points(
    image: ArrayLike,
    spacing_px: Spacing = 40.0,
    *,
    method: str = "forstner",
    per_cell: int = 2,
    window: int = 5,
    min_roundness: float = 0.5,
    weight_quantile: float = 0.5,
) -> NDArray[np.float64]:
    """Points of ``image`` worth matching, ``(N, 2)`` ``(line, sample)`` (first pixel centre
    at 0.5), spread over cells of about ``spacing_px`` pixels (one value or ``(rows, cols)``).

    ``method="forstner"``: :func:`~carto.framework.matching.forstner.forstner_points` (box
    ``window``, ``min_roundness``, weight above the ``weight_quantile`` of the image's weights,
    suppression radius ``window``, least-squares corner location), the best ``per_cell`` of
    each cell (the quantile only removes the weakest half: the cells choose the best); a
    cell where the operator finds nothing (no texture, or only straight edges) gets its
    centre pixel instead, where that pixel holds data (the fall-back grid). ``"grid"``:
    :func:`grid_points` every ``spacing_px`` with a margin of two thirds of it, where the pixel
    holds data.
    """
    img, spacing = _checked(image, method, spacing_px)
    if method == "grid":
        points = grid_points(img.shape, spacing, margin=_grid_margin(spacing))
        return points[_finite_at(img, points)]
    cells = candidate_cells(img.shape, spacing)
    size = np.array([img.shape[0] / cells[0], img.shape[1] / cells[1]])
    options = CandidateOptions(method, per_cell, window, min_roundness, weight_quantile)
    points = options.operator_points(img, grid_cells=cells, per_cell=options.per_cell)
    occupied = np.zeros(cells, bool)
    index = np.minimum((points // size).astype(np.intp), np.array(cells) - 1)
    occupied[index[:, 0], index[:, 1]] = True
    empty_r, empty_c = np.nonzero(~occupied)
    centres = np.floor((np.stack([empty_r, empty_c], axis=1) + 0.5) * size) + 0.5
    return np.concatenate([points, centres[_finite_at(img, centres)]])


def frame_cells(
    points: NDArray[np.float64], frame_shape: tuple[int, int], cells: tuple[int, int]
) -> NDArray[np.intp]:
    """``(N, 2)`` cell ``(row, col)`` of each point of a frame of ``frame_shape`` divided into
    ``cells`` equal cells (the rule of :func:`~carto.framework.matching.forstner.spread_order`)."""
    out = np.empty(points.shape, np.intp)
    for axis in (0, 1):
        out[:, axis] = np.clip(
            (points[:, axis] / frame_shape[axis] * cells[axis]).astype(np.intp), 0, cells[axis] - 1
        )
    return out


def in_cell_range(
    points: NDArray[np.float64],
    frame_shape: tuple[int, int],
    cells: tuple[int, int],
    cell_range: tuple[tuple[int, int], tuple[int, int]],
) -> NDArray[np.bool_]:
    """True for the points (frame pixels) whose cell (:func:`frame_cells`) is in
    ``cell_range = ((row0, row1), (col0, col1))``: the points a tile owns."""
    cell = frame_cells(points, frame_shape, cells)
    (r0, r1), (c0, c1) = cell_range
    return (cell[:, 0] >= r0) & (cell[:, 0] < r1) & (cell[:, 1] >= c0) & (cell[:, 1] < c1)


def window_candidates(
    image: ArrayLike,
    spacing_px: Spacing,
    offset: tuple[int, int],
    frame_shape: tuple[int, int],
    cell_range: tuple[tuple[int, int], tuple[int, int]],
    options: CandidateOptions = CandidateOptions(),
) -> NDArray[np.float64]:
    """:func:`candidate_points` of one window of a larger frame (a tile of a whole scene's
    ortho grid), chosen as ``options`` say: ``image`` is the window at ``offset`` (row, col)
    of a frame of ``frame_shape``, divided into the frame's cells of about ``spacing_px``
    (:func:`candidate_cells`); only the cells ``cell_range = ((row0, row1), (col0, col1))``
    get candidates (the tile's own: tiles with disjoint cell ranges give disjoint candidates).
    The window must reach beyond those cells by the operator's border (``window + 2``) for
    the result to equal :func:`candidate_points` on the whole frame; the Forstner weight
    quantile is the window's. Positions in the window's pixels (first pixel centre 0.5)."""
    img, spacing = _checked(image, options.method, spacing_px)
    frame = (int(frame_shape[0]), int(frame_shape[1]))
    cells = candidate_cells(frame, spacing)
    off = np.asarray(offset, np.float64)
    (r0, r1), (c0, c1) = cell_range

    def in_window(local: NDArray[np.float64]) -> NDArray[np.bool_]:
        ok = (local >= 0.5).all(axis=1)
        ok &= (local[:, 0] < img.shape[0]) & (local[:, 1] < img.shape[1])
        return ok

    if options.method == "grid":
        points = grid_points(frame, spacing, margin=_grid_margin(spacing))
        points = points[in_cell_range(points, frame, cells, cell_range)] - off
        points = points[in_window(points)]
        return points[_finite_at(img, points)]
    glob = options.operator_points(img) + off  # all points, best first
    mine = in_cell_range(glob, frame, cells, cell_range)
    glob = glob[mine]
    weight = -np.arange(glob.shape[0], dtype=np.float64)
    order = spread_order(glob, weight, frame, cells, options.per_cell)
    points = glob[order]
    occupied = np.zeros((r1 - r0, c1 - c0), bool)
    cell = frame_cells(points, frame, cells)
    occupied[cell[:, 0] - r0, cell[:, 1] - c0] = True
    empty_r, empty_c = np.nonzero(~occupied)
    size = np.array([frame[0] / cells[0], frame[1] / cells[1]])
    centres = np.floor((np.stack([empty_r + r0, empty_c + c0], axis=1) + 0.5) * size) + 0.5
    centres = centres - off
    centres = centres[in_window(centres)]
    return np.concatenate([points - off, centres[_finite_at(img, centres)]])
