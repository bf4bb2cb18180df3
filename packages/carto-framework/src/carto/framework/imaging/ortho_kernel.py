"""Coarse nodes, cells and the compiled per-pixel evaluation of the ortho mapping.

:class:`carto.framework.imaging.ortho.OrthoMapper` computes the mapping exactly on coarse
nodes (the method is in the docstring of :mod:`carto.framework.imaging.ortho`). These helpers
place the nodes of a block (:func:`node_positions`), locate every pixel between them
(:func:`cell_positions`), give the check pixels and the cells a missing node spoils
(:func:`cell_centres`, :func:`cell_any`), and evaluate the interpolated height polynomials at
every pixel in one compiled (numba) pass (:func:`evaluate_kernel`).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


def node_positions(start: int, stop: int, step: int, size: int) -> IntArray:
    """Node indices every ``step`` from ``start`` covering pixels ``[start, stop)``: the last
    node is ``stop`` (the next block's first node) or ``size - 1`` at the grid's end."""
    nodes = np.arange(start, stop, step, dtype=np.intp)
    last = stop if stop < size else size - 1
    if nodes[-1] != last:
        nodes = np.append(nodes, last)
    return nodes


def cell_positions(nodes: IntArray, positions: IntArray) -> tuple[IntArray, FloatArray]:
    """Cell index (left node) and fraction of each position between its two nodes."""
    if nodes.size == 1:
        return np.zeros(positions.size, np.intp), np.zeros(positions.size)
    i = np.clip(np.searchsorted(nodes, positions, side="right") - 1, 0, nodes.size - 2)
    span = (nodes[i + 1] - nodes[i]).astype(np.float64)
    return i, (positions - nodes[i]) / span


@functools.cache
def evaluate_kernel() -> Any:
    """The compiled per-pixel evaluation (numba is imported on first use only)."""
    import numba

    @numba.njit(parallel=True, cache=True, nogil=True)
    def evaluate(coeffs, dem_rc, ir, fr, ic, fc, heights, h_ref, line, sample):  # pragma: no cover
        """Bilinear interpolation of the node coefficients and DEM coordinates at each pixel,
        the DEM height there (bilinear, NaN outside the span of its pixel centres or next to
        nodata, as :meth:`DEM.height`), and the polynomials in ``h - h_ref`` evaluated."""
        n_r, n_c = coeffs.shape[2], coeffs.shape[3]
        h_rows, h_cols = heights.shape
        tol = 1e-9
        for a in numba.prange(ir.shape[0]):
            i0 = ir[a]
            i1 = min(i0 + 1, n_r - 1)
            wr = fr[a]
            for b in range(ic.shape[0]):
                j0 = ic[b]
                j1 = min(j0 + 1, n_c - 1)
                wc = fc[b]
                w00 = (1.0 - wr) * (1.0 - wc)
                w01 = (1.0 - wr) * wc
                w10 = wr * (1.0 - wc)
                w11 = wr * wc
                row = (
                    w00 * dem_rc[0, i0, j0]
                    + w01 * dem_rc[0, i0, j1]
                    + w10 * dem_rc[0, i1, j0]
                    + w11 * dem_rc[0, i1, j1]
                )
                col = (
                    w00 * dem_rc[1, i0, j0]
                    + w01 * dem_rc[1, i0, j1]
                    + w10 * dem_rc[1, i1, j0]
                    + w11 * dem_rc[1, i1, j1]
                )
                if not (
                    row >= -tol
                    and row <= h_rows - 1 + tol
                    and col >= -tol
                    and col <= h_cols - 1 + tol
                ):
                    line[a, b] = np.nan
                    sample[a, b] = np.nan
                    continue
                r0 = min(max(math.floor(row), 0), max(h_rows - 2, 0))
                c0 = min(max(math.floor(col), 0), max(h_cols - 2, 0))
                tr = min(max(row - r0, 0.0), 1.0)
                tc = min(max(col - c0, 0.0), 1.0)
                r1 = r0 + 1 if h_rows > 1 else r0
                c1 = c0 + 1 if h_cols > 1 else c0
                top = heights[r0, c0] * (1.0 - tc) + heights[r0, c1] * tc
                bottom = heights[r1, c0] * (1.0 - tc) + heights[r1, c1] * tc
                u = top * (1.0 - tr) + bottom * tr - h_ref
                for k in range(2):
                    p0 = (
                        w00 * coeffs[k, 0, i0, j0]
                        + w01 * coeffs[k, 0, i0, j1]
                        + w10 * coeffs[k, 0, i1, j0]
                        + w11 * coeffs[k, 0, i1, j1]
                    )
                    p1 = (
                        w00 * coeffs[k, 1, i0, j0]
                        + w01 * coeffs[k, 1, i0, j1]
                        + w10 * coeffs[k, 1, i1, j0]
                        + w11 * coeffs[k, 1, i1, j1]
                    )
                    p2 = (
                        w00 * coeffs[k, 2, i0, j0]
                        + w01 * coeffs[k, 2, i0, j1]
                        + w10 * coeffs[k, 2, i1, j0]
                        + w11 * coeffs[k, 2, i1, j1]
                    )
                    value = p0 + u * (p1 + u * p2)
                    if k == 0:
                        line[a, b] = value
                    else:
                        sample[a, b] = value

    return evaluate


def cell_any(flags: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Per cell: any of its (up to four) nodes flagged."""
    out = flags
    if out.shape[0] > 1:
        out = out[:-1] | out[1:]
    if out.shape[1] > 1:
        out = out[:, :-1] | out[:, 1:]
    return out


def cell_centres(nodes: IntArray) -> IntArray:
    return nodes if nodes.size == 1 else (nodes[:-1] + nodes[1:]) // 2
