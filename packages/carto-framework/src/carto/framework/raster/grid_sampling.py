"""Interpolation of a grid of values at fractional centre indices (0 = the first centre):
bilinear (:func:`bilinear_sample`) and Keys' cubic convolution (:func:`cubic_sample`), NaN off
the span of the centres and where a node they use is NaN."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["EDGE_TOL_PX", "bilinear_sample", "bilinear_sample_grid", "cubic_sample"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

EDGE_TOL_PX = 1e-9  # tolerance on "inside the span of pixel centres", in pixels


def _cells(
    shape: tuple[int, int], row: FloatArray, col: FloatArray
) -> tuple[BoolArray, NDArray[np.intp], NDArray[np.intp], FloatArray, FloatArray]:
    """For fractional centre indices: inside the span of the centres (1e-9 px tolerance),
    the cell's first row and column (clipped to the grid) and the fractions within it."""
    n_rows, n_cols = shape
    inside = (
        (row >= -EDGE_TOL_PX)
        & (row <= n_rows - 1 + EDGE_TOL_PX)
        & (col >= -EDGE_TOL_PX)
        & (col <= n_cols - 1 + EDGE_TOL_PX)
    )
    row = np.where(inside, row, 0.0)
    col = np.where(inside, col, 0.0)
    r0 = np.clip(np.floor(row), 0, max(n_rows - 2, 0)).astype(np.intp)
    c0 = np.clip(np.floor(col), 0, max(n_cols - 2, 0)).astype(np.intp)
    return inside, r0, c0, np.clip(row - r0, 0.0, 1.0), np.clip(col - c0, 0.0, 1.0)


def _keys_weights(t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Keys' (1981) cubic convolution weights (a = -1/2) of the nodes -1, 0, 1, 2 for a
    fraction ``t`` in [0, 1]: they sum to 1 and reproduce quadratics exactly."""
    t2, t3 = t * t, t * t * t
    return (
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    )


def cubic_sample(grid: FloatArray, row: FloatArray, col: FloatArray) -> FloatArray:
    """Cubic convolution (Keys 1981, a = -1/2: interpolating, continuous slope) of ``grid``
    at fractional centre indices (0 = first centre); the nodes beyond the edge repeat the
    edge's. NaN where :func:`bilinear_sample` is NaN or a node of the 4 x 4 is NaN."""
    n_rows, n_cols = grid.shape
    inside, r0, c0, fr, fc = _cells(grid.shape, row, col)
    w_r, w_c = _keys_weights(fr), _keys_weights(fc)
    out = np.zeros(np.shape(row))
    for i, wr in zip(range(-1, 3), w_r, strict=True):
        r = np.clip(r0 + i, 0, n_rows - 1)
        across = np.zeros(np.shape(row))
        for j, wc in zip(range(-1, 3), w_c, strict=True):
            across += wc * grid[r, np.clip(c0 + j, 0, n_cols - 1)]
        out += wr * across
    return np.where(inside, out, np.nan)


def bilinear_sample(grid: FloatArray, row: FloatArray, col: FloatArray) -> FloatArray:
    """Bilinear interpolation of ``grid`` at fractional centre indices (0 = first centre).

    NaN outside ``[0, n-1]`` (with a 1e-9 px tolerance) and where a neighbour is NaN.
    """
    n_rows, n_cols = grid.shape
    inside, r0, c0, fr, fc = _cells(grid.shape, row, col)
    dr = 1 if n_rows > 1 else 0
    dc = 1 if n_cols > 1 else 0
    flat = grid.ravel()
    index = r0 * n_cols + c0
    v00 = flat[index]
    v01 = flat[index + dc]
    v10 = flat[index + dr * n_cols]
    v11 = flat[index + dr * n_cols + dc]
    top = v00 * (1.0 - fc) + v01 * fc
    bottom = v10 * (1.0 - fc) + v11 * fc
    out = top * (1.0 - fr) + bottom * fr
    return np.where(inside, out, np.nan)


def _axis_weights(
    inside: BoolArray, first: NDArray[np.intp], frac: FloatArray, lo: int, size: int, step: int
) -> FloatArray:
    """``(len(first), size)``: the linear weights of the nodes ``lo .. lo + size - 1`` of one
    axis (cell ``first``, fraction ``frac``; ``step`` 0 on an axis of one node)."""
    w = np.zeros((first.size, size))
    n = np.flatnonzero(inside)
    np.add.at(w, (n, first[n] - lo), 1.0 - frac[n])
    np.add.at(w, (n, first[n] + step - lo), frac[n])
    return w


def bilinear_sample_grid(grid: FloatArray, row: FloatArray, col: FloatArray) -> FloatArray:
    """:func:`bilinear_sample` at every pair of the fractional indices ``row`` (1-D) and
    ``col`` (1-D): ``(len(row), len(col))``, as two small matrix products over the block of
    ``grid`` they reach (bilinear interpolation is separable), equal to rounding. NaN where
    a row or a column is outside the grid and, as there, next to a NaN node."""
    row = np.asarray(row, np.float64).ravel()
    col = np.asarray(col, np.float64).ravel()
    n_rows, n_cols = grid.shape
    in_r, r0, _, fr, _ = _cells(grid.shape, row, np.zeros_like(row))
    in_c, _, c0, _, fc = _cells(grid.shape, np.zeros_like(col), col)
    out = np.full((row.size, col.size), np.nan)
    if not (in_r.any() and in_c.any()):
        return out
    dr, dc = (1 if n_rows > 1 else 0), (1 if n_cols > 1 else 0)
    lo_r, hi_r = int(r0[in_r].min()), int(r0[in_r].max()) + dr
    lo_c, hi_c = int(c0[in_c].min()), int(c0[in_c].max()) + dc
    block = np.asarray(grid[lo_r : hi_r + 1, lo_c : hi_c + 1], np.float64)
    if not np.isfinite(block).all():  # NaN nodes: only their neighbours are NaN
        rr, cc = np.meshgrid(row, col, indexing="ij")
        return bilinear_sample(grid, rr, cc)
    wr = _axis_weights(in_r, r0, fr, lo_r, block.shape[0], dr)
    wc = _axis_weights(in_c, c0, fc, lo_c, block.shape[1], dc)
    out[np.ix_(in_r, in_c)] = (wr @ block @ wc.T)[np.ix_(in_r, in_c)]
    return out
