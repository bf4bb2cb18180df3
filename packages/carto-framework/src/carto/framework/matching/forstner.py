"""Interest points by the Forstner operator.

* :func:`forstner_points`: the Forstner interest operator (weight and roundness of the
  gradients' structure tensor, non-maximum suppression, least-squares corner location,
  optional spreading over grid cells, :func:`spread_order`); :func:`forstner_measures` gives
  the measures of every pixel.

Points are ``(N, 2)`` arrays of continuous ``(line, sample)``, the centre of the first pixel at
``(0.5, 0.5)`` (see :mod:`carto.framework.geometry.sensor`).

Accuracy (measured, ``tests/framework/test_match.py``): corners of blurred rectangles within
0.3 px (the least-squares corner of a rounded corner lies slightly inside it), checkerboard
junctions within 0.03 px.

Speed: the Forstner operator takes about 0.4 s for 8 Mpx.
"""

from __future__ import annotations

import math
from typing import Any

import attrs
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.inputs import as_image, as_points, check_int

FORSTNER_SUBPIXEL = ("lsq", "parabola", "none")
"""Sub-pixel estimators of :func:`forstner_points`."""

_TRACE_EPS = 1e-12  # traces below this fraction of the largest count as no gradient
_GOLDEN = 0.6180339887498949  # tie-breaking sequence of the non-maximum suppression


@attrs.frozen(eq=False)
class _StructureTensor:
    """Gradient products per pixel (``g_r^2``, ``g_r g_c``, ``g_c^2``, rows / columns), their
    means over the integration window (float32), and where the window's gradients are all
    defined."""

    grr: NDArray[np.float32]
    grc: NDArray[np.float32]
    gcc: NDArray[np.float32]
    nrr: NDArray[np.float32]
    nrc: NDArray[np.float32]
    ncc: NDArray[np.float32]
    valid: NDArray[np.bool_]


def _check_window(window: Any) -> int:
    if check_int(window, "window", 3) % 2 == 0:
        raise InputError(f"window must be odd (a centred box), got {window}")
    return int(window)


def _structure_tensor(image: NDArray[np.float32], window: int) -> _StructureTensor:
    """Scharr gradients and their products averaged over a ``window x window`` box.

    NaN pixels are filled with the mean before the gradients; every pixel whose window holds a
    gradient that touches NaN (or the image border) is marked invalid.
    """
    import cv2

    nan = np.isnan(image)
    filled = image
    if nan.any():
        fill = float(np.mean(image[~nan])) if (~nan).any() else 0.0
        filled = np.where(nan, np.float32(fill), image)
    # Scharr 3 x 3 derivatives, normalised to grey values per pixel (float32: the measures
    # only rank and threshold pixels; the corner location sums in float64)
    g_r = cv2.Scharr(filled, cv2.CV_32F, 0, 1, scale=1.0 / 32.0)
    g_c = cv2.Scharr(filled, cv2.CV_32F, 1, 0, scale=1.0 / 32.0)
    grr, grc, gcc = g_r * g_r, g_r * g_c, g_c * g_c
    size = (window, window)
    nrr = cv2.boxFilter(grr, cv2.CV_32F, size, borderType=cv2.BORDER_REFLECT)
    nrc = cv2.boxFilter(grc, cv2.CV_32F, size, borderType=cv2.BORDER_REFLECT)
    ncc = cv2.boxFilter(gcc, cv2.CV_32F, size, borderType=cv2.BORDER_REFLECT)
    reach = window // 2 + 1  # the window's half-width plus the gradient stencil's
    invalid = np.zeros(image.shape, bool)
    if nan.any():
        kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
        invalid = cv2.dilate(nan.view(np.uint8), kernel).astype(bool)
    invalid[:reach] = invalid[-reach:] = True
    invalid[:, :reach] = invalid[:, -reach:] = True
    return _StructureTensor(grr, grc, gcc, nrr, nrc, ncc, ~invalid)


def _weight_roundness(
    t: _StructureTensor,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``w = det N / trace N`` and ``q = 4 det N / trace N^2`` (0 where there is no gradient
    or the window is invalid)."""
    det = t.nrr * t.ncc - t.nrc * t.nrc
    trace = t.nrr + t.ncc
    top = float(trace[t.valid].max()) if t.valid.any() else 0.0
    ok = t.valid & (trace > _TRACE_EPS * top) & (trace > 0.0)
    safe = np.where(ok, trace, np.float32(1.0))
    w = np.where(ok, np.maximum(det, 0.0) / safe, np.float32(0.0))
    q = np.where(ok, np.clip(4.0 * det / (safe * safe), 0.0, 1.0), np.float32(0.0))
    return w, q


def forstner_measures(
    image: ArrayLike, *, window: int = 5
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The Forstner interest measures of every pixel: weight ``w`` and roundness ``q``.

    The structure tensor ``N = mean over a window x window box of g g^T`` (``g`` the Scharr
    gradient, grey values per pixel) has eigenvalues ``l1 >= l2 >= 0``; ``N^-1`` is the
    covariance of a point located by least squares in that window. So

    * ``w = det N / trace N = l1 l2 / (l1 + l2)`` (grey values^2 per pixel^2): the precision of
      that point, large where the window holds strong gradients in two directions;
    * ``q = 4 det N / trace N^2 = 1 - ((l1 - l2) / (l1 + l2))^2`` in ``[0, 1]``: the roundness
      of its error ellipse, 0 on a straight edge, 1 where the gradients are isotropic.

    Args:
        image: 2-D single-band image, any real dtype; NaN = no data.
        window: side of the (odd) box over which the gradient products are averaged, pixels.

    Returns:
        ``(w, q)`` of the image's shape; NaN where the window (plus the gradient stencil)
        touches NaN or the image border, 0 where the window has no gradient.
    """
    img = as_image(image, "image")
    t = _structure_tensor(img, _check_window(window))
    w, q = _weight_roundness(t)
    return (
        np.where(t.valid, w, np.nan).astype(np.float64),
        np.where(t.valid, q, np.nan).astype(np.float64),
    )


def _lsq_corners(
    t: _StructureTensor, rows: NDArray[np.intp], cols: NDArray[np.intp], window: int
) -> NDArray[np.float64]:
    """Forstner's least-squares corner point near each pixel ``(rows, cols)``: the point
    closest (weighted by ``|g|^2``) to the lines through every pixel of the window along its
    edge direction (normal ``g``): ``x = N^-1 sum(g g^T x_k)`` over the window pixels ``x_k``.
    The window is re-centred once on the pixel holding the first estimate. Returns 0-based
    index coordinates; a pixel whose estimate leaves its window (or whose tensor is singular)
    keeps its centre."""
    h = window // 2
    offsets = np.arange(-h, h + 1, dtype=np.float64)
    d_r = np.broadcast_to(offsets[:, None], (window, window))
    d_c = np.broadcast_to(offsets[None, :], (window, window))
    views = [sliding_window_view(a, (window, window)) for a in (t.grr, t.grc, t.gcc)]
    centre = np.stack([rows, cols], axis=1).astype(np.intp)
    out = centre.astype(np.float64)
    active = np.ones(rows.shape, bool)
    for _ in range(2):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        r0, c0 = centre[idx, 0] - h, centre[idx, 1] - h
        grr, grc, gcc = (v[r0, c0].astype(np.float64) for v in views)
        nrr, nrc, ncc = grr.sum(axis=(1, 2)), grc.sum(axis=(1, 2)), gcc.sum(axis=(1, 2))
        br = (grr * d_r + grc * d_c).sum(axis=(1, 2))
        bc = (grc * d_r + gcc * d_c).sum(axis=(1, 2))
        det = nrr * ncc - nrc * nrc
        with np.errstate(divide="ignore", invalid="ignore"):
            x_r = (ncc * br - nrc * bc) / det
            x_c = (nrr * bc - nrc * br) / det
        good = (det > 1e-12 * (nrr + ncc) ** 2) & (np.abs(x_r) <= h) & (np.abs(x_c) <= h)
        good &= np.isfinite(x_r) & np.isfinite(x_c)
        out[idx[good], 0] = centre[idx[good], 0] + x_r[good]
        out[idx[good], 1] = centre[idx[good], 1] + x_c[good]
        # re-centre where the estimate lies in another pixel whose window is valid
        moved = np.rint(out[idx]).astype(np.intp)
        again = good & (moved != centre[idx]).any(axis=1)
        again &= t.valid[moved[:, 0], moved[:, 1]]
        centre[idx[again]] = moved[again]
        active[:] = False
        active[idx[again]] = True
    return out


def _parabola_peaks(
    w: NDArray[np.floating], rows: NDArray[np.intp], cols: NDArray[np.intp]
) -> NDArray[np.float64]:
    """Vertex of the 3-point parabolas through ``w`` at each peak, per direction (within
    +-0.5 px); 0-based index coordinates."""
    out = np.stack([rows, cols], axis=1).astype(np.float64)
    for axis, (dr, dc) in enumerate(((1, 0), (0, 1))):
        minus, centre, plus = w[rows - dr, cols - dc], w[rows, cols], w[rows + dr, cols + dc]
        den = minus - 2.0 * centre + plus
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(den < 0.0, 0.5 * (minus - plus) / den, 0.0)
        out[:, axis] += np.clip(np.nan_to_num(step), -0.5, 0.5)
    return out


def _disk(radius: float) -> NDArray[np.uint8]:
    r = math.floor(radius)
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    return (dy * dy + dx * dx <= radius * radius).astype(np.uint8)


def spread_order(
    points: ArrayLike,
    weights: ArrayLike,
    shape: tuple[int, int],
    grid_cells: tuple[int, int],
    per_cell: int | None = None,
) -> NDArray[np.intp]:
    """Indices of the points to keep so that they cover the image: the best ``per_cell``
    (highest weight) of each of ``grid_cells = (rows, cols)`` equal cells of an image of
    ``shape``, ordered round-robin (every cell's best, then every cell's second best ...,
    by decreasing weight within a round), so that any prefix is well distributed too.
    ``per_cell=None`` keeps all points (only reordering them)."""
    pts = as_points(points, "points")
    w = np.asarray(weights, np.float64)
    n_rows, n_cols = (check_int(v, "grid_cells", 1) for v in grid_cells)
    if pts.shape[0] == 0:
        return np.empty(0, np.intp)
    cell_r = np.clip((pts[:, 0] / shape[0] * n_rows).astype(np.intp), 0, n_rows - 1)
    cell_c = np.clip((pts[:, 1] / shape[1] * n_cols).astype(np.intp), 0, n_cols - 1)
    cell = cell_r * n_cols + cell_c
    order = np.lexsort((-w, cell))  # by cell, best first
    sorted_cell = cell[order]
    first = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.empty(pts.shape[0], np.intp)
    rank[order] = np.arange(pts.shape[0]) - first
    keep = np.arange(pts.shape[0])
    if per_cell is not None:
        keep = keep[rank < check_int(per_cell, "per_cell", 1)]
    return keep[np.lexsort((-w[keep], rank[keep]))]


def forstner_points(
    image: ArrayLike,
    *,
    window: int = 5,
    min_roundness: float = 0.5,
    weight_quantile: float = 0.7,
    min_weight: float = 0.0,
    nms_radius: float | None = None,
    max_points: int | None = None,
    grid_cells: tuple[int, int] | None = None,
    per_cell: int | None = None,
    subpixel: str = "lsq",
) -> NDArray[np.float64]:
    """Interest points by the Forstner operator (Forstner & Gulch 1987).

    Method: the weight ``w`` and roundness ``q`` of every pixel (:func:`forstner_measures`,
    a ``window x window`` box of Scharr gradient products); candidate pixels have
    ``q > min_roundness`` (for 0.5: eigenvalues within 5.8 : 1, an error ellipse no more
    elongated than 2.4 : 1; straight edges are rejected) and ``w`` above the threshold
    ``max(quantile(w, weight_quantile), min_weight)``, the quantile taken over the valid
    pixels of the image (0.7: only the top 30 % of the image's weights qualify, whatever its
    contrast; raise ``min_weight``, in grey values^2 per pixel^2, to reject faint texture or
    noise). Points
    are the candidates whose weight is the largest within ``nms_radius`` pixels among the
    candidates (non-maximum suppression by a grey dilation with a disk; exact ties are broken
    by a fixed pseudo-random order, so no two points' pixels are closer than the radius).

    Sub-pixel location (``subpixel``): ``"lsq"`` (default) Forstner's least-squares corner
    point, the point that best fits the lines through the window's pixels along their edge
    directions, weighted by the squared gradient (the exact corner of straight edges meeting
    in the window: an L, T, X junction; one re-centring iteration, ignored where it leaves
    the window). Measured: X junctions within 0.03 px; blurred L corners 0.1-0.3 px inside
    the corner (the blur rounds it). ``"parabola"``: the vertex of 3-point parabolas through
    ``w``; ``"none"``: the pixel centre; both locate the maximum of ``w``, which lies 1-2 px
    inside an L corner with a box window.

    Args:
        image: 2-D single-band image, any real dtype; NaN = no data (no point is found where
            the window or the gradient stencil touches NaN or the image border).
        window: side of the odd integration box, pixels.
        min_roundness: smallest roundness ``q``, in [0, 1).
        weight_quantile: quantile of the valid pixels' weights that a candidate must exceed,
            in [0, 1).
        min_weight: absolute floor of the weight threshold.
        nms_radius: suppression radius, pixels (default ``window``).
        max_points: keep at most this many points (the best; round-robin over the cells with
            ``grid_cells``).
        grid_cells: ``(rows, cols)``: divide the image into equal cells and keep the best
            ``per_cell`` points of each, so that the points cover the image.
        per_cell: points kept per cell (default ``ceil(max_points / cells)`` with
            ``max_points``, else 1).
        subpixel: ``"lsq"``, ``"parabola"`` or ``"none"``.

    Returns:
        ``(N, 2)`` ``(line, sample)`` in the project convention (first pixel centre at
        ``(0.5, 0.5)``), by decreasing weight (round-robin over the cells with
        ``grid_cells``).

    Raises:
        InputError: malformed image or options.
    """
    img = as_image(image, "image")
    options = _forstner_options(
        window,
        min_roundness,
        weight_quantile,
        min_weight,
        nms_radius,
        max_points,
        grid_cells,
        per_cell,
        subpixel,
    )
    t = _structure_tensor(img, options.window)
    w, q = _weight_roundness(t)
    rows, cols = _peak_pixels(t, w, q, options)
    if rows.size == 0:
        return np.empty((0, 2))
    points, weight = _distinct(_peak_index(t, w, rows, cols, options) + 0.5, w[rows, cols])
    return points[_kept_order(points, weight, w.shape, options)]


def _distinct(
    points: NDArray[np.float64], weight: NDArray[np.floating]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The distinct ``points`` and their weights, each the strongest (by ``weight``) of
    those at its position, in their order: two peak pixels a suppression radius apart can
    refine to one corner (each estimate moves up to half a window, then both windows
    re-centre on the same pixel)."""
    order = np.argsort(-weight, kind="stable")
    _, first = np.unique(points[order], axis=0, return_index=True)
    keep = np.sort(order[first])
    return points[keep], weight[keep].astype(np.float64)


@attrs.frozen
class _ForstnerOptions:
    """The checked options of :func:`forstner_points` (see there); ``radius_px`` is the
    non-maximum suppression's radius, ``cells`` and ``per_cell`` as :func:`_cells` gives
    them."""

    window: int
    min_roundness: float
    weight_quantile: float
    min_weight: float
    radius_px: float
    max_points: int | None
    cells: tuple[int, ...] | None
    per_cell: int | None
    subpixel: str


def _forstner_options(
    window: Any,
    min_roundness: float,
    weight_quantile: float,
    min_weight: float,
    nms_radius: float | None,
    max_points: int | None,
    grid_cells: tuple[int, int] | None,
    per_cell: int | None,
    subpixel: str,
) -> _ForstnerOptions:
    """The options of :func:`forstner_points` checked, or InputError."""
    window = _check_window(window)
    if not 0.0 <= float(min_roundness) < 1.0:
        raise InputError(f"min_roundness must be within [0, 1), got {min_roundness}")
    if not 0.0 <= float(weight_quantile) < 1.0:
        raise InputError(f"weight_quantile must be within [0, 1), got {weight_quantile}")
    if not float(min_weight) >= 0.0:
        raise InputError(f"min_weight must be >= 0, got {min_weight}")
    radius = float(window if nms_radius is None else nms_radius)
    if not radius >= 1.0:
        raise InputError(f"nms_radius must be >= 1 pixel, got {nms_radius}")
    if max_points is not None:
        max_points = check_int(max_points, "max_points", 0)
    if subpixel not in FORSTNER_SUBPIXEL:
        raise InputError(f"subpixel {subpixel!r} is not one of {', '.join(FORSTNER_SUBPIXEL)}")
    cells, per_cell = _cells(grid_cells, per_cell, max_points)
    return _ForstnerOptions(
        window,
        float(min_roundness),
        float(weight_quantile),
        float(min_weight),
        radius,
        max_points,
        cells,
        per_cell,
        subpixel,
    )


def _peak_pixels(
    t: _StructureTensor,
    w: NDArray[np.float32],
    q: NDArray[np.float32],
    options: _ForstnerOptions,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """``(rows, cols)`` of the candidate pixels (roundness and weight above the thresholds)
    whose weight is the largest within the suppression radius; none where no window is
    valid."""
    import cv2

    none = np.empty(0, np.intp)
    if not t.valid.any():
        return none, none
    quantile = float(np.quantile(w[t.valid], options.weight_quantile))
    threshold = max(quantile, options.min_weight)
    candidate = t.valid & (q > options.min_roundness) & (w > threshold)
    if not candidate.any():
        return none, none
    # exact ties (plateaus of a synthetic image) broken by a fixed pseudo-random order
    flat = np.flatnonzero(candidate)
    ranked = np.zeros(w.shape, np.float32)
    ranked.ravel()[flat] = w.ravel()[flat] * (1.0 + 1e-5 * ((flat * _GOLDEN) % 1.0))
    peak = candidate & (ranked >= cv2.dilate(ranked, _disk(options.radius_px)))
    return np.nonzero(peak)


def _peak_index(
    t: _StructureTensor,
    w: NDArray[np.float32],
    rows: NDArray[np.intp],
    cols: NDArray[np.intp],
    options: _ForstnerOptions,
) -> NDArray[np.float64]:
    """The sub-pixel location of each peak pixel by the ``subpixel`` method of
    :func:`forstner_points`, 0-based index coordinates."""
    if options.subpixel == "lsq":
        return _lsq_corners(t, rows, cols, options.window)
    if options.subpixel == "parabola":
        return _parabola_peaks(w, rows, cols)
    return np.stack([rows, cols], axis=1).astype(np.float64)


def _kept_order(
    points: NDArray[np.float64],
    weight: NDArray[np.float64],
    shape: tuple[int, int],
    options: _ForstnerOptions,
) -> NDArray[np.intp]:
    """Indices of the points :func:`forstner_points` returns, in its order: by decreasing
    weight (round-robin over the cells with ``grid_cells``, :func:`spread_order`), at most
    ``max_points``."""
    if options.cells is not None:
        order = spread_order(points, weight, shape, options.cells, options.per_cell)
    else:
        order = np.argsort(-weight, kind="stable")
    if options.max_points is not None:
        order = order[: options.max_points]
    return order


def _cells(
    grid_cells: Any, per_cell: int | None, max_points: int | None
) -> tuple[tuple[int, ...] | None, int | None]:
    """``grid_cells`` checked as ``(rows, cols)`` and the points kept per cell (default
    ``ceil(max_points / cells)``, else 1); ``(None, per_cell)`` without cells."""
    if grid_cells is None:
        return None, per_cell
    cells = tuple(check_int(v, "grid_cells", 1) for v in grid_cells)
    if len(cells) != 2:
        raise InputError(f"grid_cells must be (rows, cols), got {grid_cells!r}")
    if per_cell is None:
        n_cells = cells[0] * cells[1]
        per_cell = -(-max_points // n_cells) if max_points else 1
    return cells, check_int(per_cell, "per_cell", 1)
