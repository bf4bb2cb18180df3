"""The highest terrain under a bundle of rays, so that their safe steps
(:func:`~carto.framework.geometry.linescan.terrain_intersection.trace_model`) start just above
it rather than at the search's top.

:func:`block_maxima` gives, per block of :data:`BLOCK_CELLS` x :data:`BLOCK_CELLS` cells of a
DEM's bilinear surface, the highest node those cells read (the surface never rises above its
nodes). :func:`segment_top` bounds the terrain under every ray whose quadratic model is
interpolated between two exact ones (the rays between two nodes of a
:func:`~carto.framework.geometry.linescan.raycast.quadratic_table`): at each distance parameter
such a ray's longitude and latitude lie between the two models', so its path between the
search heights stays in the box of the two models' paths, and the blocks over that box bound
the terrain it can meet.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.geometry.linescan.terrain_intersection import DemGrid

BLOCK_CELLS = 8
"""Cells per side of the blocks of :func:`block_maxima`."""


def block_maxima(heights: NDArray, block: int = BLOCK_CELLS) -> NDArray[np.float64]:
    """``out[bi, bj]``: the highest node read by the bilinear cells ``(i, j)`` with ``i //
    block == bi`` and ``j // block == bj`` (nodes ``i .. i + 1``, ``j .. j + 1``); infinite
    where a node is a void. Shape: the cells' blocks, rounded up."""
    z = np.asarray(heights, np.float64)
    z = np.where(np.isfinite(z), z, np.inf)
    rows, cols = z.shape
    nb_r, nb_c = -(-rows // block), -(-cols // block)
    pad = np.full((nb_r * block + 1, nb_c * block + 1), -np.inf)
    pad[:rows, :cols] = z
    core = pad[:-1, :-1].reshape(nb_r, block, nb_c, block).max(axis=(1, 3))
    # the nodes just past a block's last cell: the first row and column of the next blocks
    next_row = pad[block::block, :-1].reshape(nb_r, nb_c, block).max(axis=2)
    next_col = pad[:-1, block::block].reshape(nb_r, block, nb_c).max(axis=1)
    return np.maximum.reduce([core, next_row, next_col, pad[block::block, block::block]])


@numba.njit(cache=True, nogil=True, inline="always")
def _quadratic_range(a0: float, a1: float, a2: float) -> tuple[float, float]:  # pragma: no cover
    """Least and greatest of ``a0 + tau (a1 + tau a2)`` for ``tau`` in [0, 1]."""
    end = a0 + a1 + a2
    lo, hi = min(a0, end), max(a0, end)
    if a2 != 0.0:
        tau = -a1 / (2.0 * a2)
        if 0.0 < tau < 1.0:
            v = a0 + tau * (a1 + tau * a2)
            lo, hi = min(lo, v), max(hi, v)
    return lo, hi


@numba.njit(cache=True, nogil=True)
def segment_top(
    a: NDArray, b: NDArray, dem: DemGrid, blocks: NDArray, block: int
) -> float:  # pragma: no cover - compiled
    """The highest terrain under the rays whose models are interpolated between the rows
    ``a`` and ``b`` of a quadratic table (the layout of
    :class:`~carto.framework.geometry.linescan.terrain_intersection.RayQuadratic`), from the
    :func:`block_maxima` ``blocks``; infinite where the box leaves the DEM, a model misses or
    a void lies under it."""
    lon_lo, lon_hi, lat_lo, lat_hi = np.inf, -np.inf, np.inf, -np.inf
    for row in (a, b):
        lo, hi = _quadratic_range(row[2], row[3], row[4])
        lon_lo, lon_hi = min(lon_lo, lo), max(lon_hi, hi)
        lo, hi = _quadratic_range(row[5], row[6], row[7])
        lat_lo, lat_hi = min(lat_lo, lo), max(lat_hi, hi)
    if not (np.isfinite(lon_lo + lon_hi + lat_lo + lat_hi)):
        return np.inf
    # the cells grid_bilinear reads over the box, one more on every side for rounding
    j0 = math.floor((lon_lo - dem.x0_deg) / dem.dx_deg - 0.5) - 1
    j1 = math.floor((lon_hi - dem.x0_deg) / dem.dx_deg - 0.5) + 1
    i0 = math.floor((lat_hi - dem.y0_deg) / dem.dy_deg - 0.5) - 1  # dy < 0: north first
    i1 = math.floor((lat_lo - dem.y0_deg) / dem.dy_deg - 0.5) + 1
    if i0 < 0 or j0 < 0 or i1 + 1 >= dem.heights.shape[0] or j1 + 1 >= dem.heights.shape[1]:
        return np.inf
    top = -np.inf
    for bi in range(i0 // block, i1 // block + 1):
        for bj in range(j0 // block, j1 // block + 1):
            top = max(top, blocks[bi, bj])
    return top


@numba.njit(cache=True, nogil=True)
def segment_tops(
    table: NDArray, n_nodes: int, dem: DemGrid, blocks: NDArray, block: int, out: NDArray
) -> None:  # pragma: no cover - compiled
    """``out[m]``: :func:`segment_top` of the rows ``m`` and ``m + 1`` of ``table``, for
    ``m < n_nodes - 1``."""
    for m in range(n_nodes - 1):
        out[m] = segment_top(table[m], table[m + 1], dem, blocks, block)
