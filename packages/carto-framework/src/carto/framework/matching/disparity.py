"""Dense offsets between two nearly co-registered images (e.g. two ortho-images of a stereo
pair on the same grid and DEM): hierarchical area-based correlation.

:func:`dense_offsets` returns, for every pixel of the left image, the offset ``(d_row, d_col)``
to the matching position in the right image (``right[row + d_row, col + d_col]`` shows what
``left[row, col]`` shows), with the correlation score and a validity mask.

Method
    * Image pyramids (``cv2.pyrDown``, factor 2 per level), coarse to fine. At each level the
      right image is warped by the current offset field (``cv2.remap``, bilinear), and the
      normalised cross-correlation of a ``window x window`` neighbourhood is computed for every
      integer residual shift within ``radius`` pixels, for all pixels at once (box filters of
      the products: the cost is ``(2 radius + 1)^2`` image-sized filter passes, whatever the
      number of pixels). The best shift per pixel is refined to sub-pixel by a parabola through
      its neighbours along each axis. The field is cleaned (a 3 x 3 median of the valid
      offsets replaces offsets more than 1 pixel of that level from it), holes are filled
      from their neighbours, and it is upsampled to the next level. The reach of the search is
      about ``radius * (2**levels - 1)`` pixels at full resolution (62 px with the defaults),
      plus a given first guess.
    * Validity at full resolution: a score of at least ``min_score``, texture (the window's
      standard deviation above ``min_std`` of the image's robust range), and the
      **left-right check**: the offsets are computed in both directions and a pixel is kept
      when ``d_lr(p) + d_rl(p + d_lr(p))`` is shorter than ``consistency_px``.
    * Memory stays flat: the full-resolution searches run over bands of rows.

NaN marks no data in the inputs; windows touching it get no match.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.base import OffsetField
from carto.framework.matching.precision import box_mean, window_moments

FloatArray = NDArray[np.float32]

_BAND_ROWS = 512  # rows per band of the full-resolution search (memory stays flat)


def _as_image(image: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(image, dtype=np.float32)
    if a.ndim != 2 or min(a.shape) < 8:
        raise InputError(f"dense offsets: {name} image must be 2-D, at least 8 x 8 (got {a.shape})")
    return a


def _filled(image: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The image with NaN replaced by its mean (for filtering), and the validity mask."""
    valid = np.isfinite(image)
    fill = float(np.mean(image[valid])) if valid.any() else 0.0
    return np.where(valid, image, fill).astype(np.float32), valid


def _pyramid(image: FloatArray, levels: int) -> list[tuple[FloatArray, NDArray[np.bool_]]]:
    import cv2

    out = [_filled(image)]
    for _ in range(levels - 1):
        img, valid = out[-1]
        small = cv2.pyrDown(img)
        # a reduced pixel is valid when its whole 2 x 2 block is
        v = valid[: small.shape[0] * 2, : small.shape[1] * 2]
        v = np.pad(v, ((0, small.shape[0] * 2 - v.shape[0]), (0, small.shape[1] * 2 - v.shape[1])))
        v = v.reshape(small.shape[0], 2, small.shape[1], 2).all(axis=(1, 3))
        out.append((small, v))
    return out


def _warp(image: FloatArray, d_row: FloatArray, d_col: FloatArray) -> FloatArray:
    """``image[row + d_row, col + d_col]`` (bilinear), NaN outside."""
    import cv2

    rows, cols = d_row.shape
    grid_r, grid_c = np.mgrid[0:rows, 0:cols].astype(np.float32)
    return cv2.remap(
        image,
        (grid_c + d_col).astype(np.float32),
        (grid_r + d_row).astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=float("nan"),
    )


@numba.njit(parallel=True, cache=True, nogil=True)
def _score_shift(  # pragma: no cover (compiled)
    cov: NDArray,
    mean_l: NDArray,
    var_l: NDArray,
    hole_l: NDArray,
    mean_r: NDArray,
    var_r: NDArray,
    hole_r: NDArray,
    dr: int,
    dc: int,
    index: int,
    scores: NDArray,
    best: NDArray,
    best_index: NDArray,
) -> None:
    """The NCC of every pixel's window with the right image's window shifted by ``(dr, dc)``
    (``cov``: the box mean of ``left * right[row + dr, col + dc]``; the right image's window
    statistics are read at the shifted pixel), -2 where either window has no data or
    reaches beyond an image; the running best score and its shift index."""
    n_r, n_c = cov.shape
    for r in numba.prange(n_r):
        rr = r + dr
        for c in range(n_c):
            cc = c + dc
            s = -2.0
            if 0 <= rr < n_r and 0 <= cc < n_c and not hole_l[r, c] and not hole_r[rr, cc]:
                v = var_l[r, c] * var_r[rr, cc]
                if v > 0.0:
                    s = (cov[r, c] - mean_l[r, c] * mean_r[rr, cc]) / np.sqrt(v)
            scores[r, c] = s
            if s > best[r, c]:
                best[r, c] = s
                best_index[r, c] = index


def _window_stats(image: FloatArray, window: int) -> tuple[FloatArray, FloatArray, NDArray]:
    """``(zero-filled image, box mean, box variance, windows with no data or beyond the
    image)``."""
    bad = ~np.isfinite(image)
    filled = np.where(bad, 0.0, image).astype(np.float32)
    mean, var = window_moments(filled, window)
    hole = box_mean(bad.astype(np.float32), window) > 0
    # windows that reach beyond the image (the box filter reflects the border)
    half = window // 2
    hole[:half] = hole[-half:] = True
    hole[:, :half] = hole[:, -half:] = True
    return filled, mean, var, hole


def _search(
    left: FloatArray, right: FloatArray, radius: int, window: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Best integer shift within ``radius`` (sub-pixel by parabolas) of ``right`` against
    ``left`` at every pixel: ``(d_row, d_col, score)``; NaN where no full window. One box
    filter per shift (the right image's window statistics are computed once and read at the
    shifted pixel) and one compiled pass that scores it and keeps the best."""
    lf, mean_l, var_l, hole_l = _window_stats(left, window)
    rf, mean_r, var_r, hole_r = _window_stats(right, window)
    n = 2 * radius + 1
    scores = np.empty((n * n, *left.shape), np.float32)
    best = np.full(left.shape, -np.inf, np.float32)
    best_index = np.zeros(left.shape, np.int64)
    shifted = np.zeros_like(rf)
    rows, cols = left.shape
    for i, dr in enumerate(range(-radius, radius + 1)):
        for j, dc in enumerate(range(-radius, radius + 1)):
            # right[row + dr, col + dc], zero beyond the image (those windows are holes)
            shifted.fill(0.0)
            r0, r1 = max(0, -dr), min(rows, rows - dr)
            c0, c1 = max(0, -dc), min(cols, cols - dc)
            if r0 < r1 and c0 < c1:
                shifted[r0:r1, c0:c1] = rf[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
            cov = box_mean(lf * shifted, window)
            _score_shift(
                cov, mean_l, var_l, hole_l, mean_r, var_r, hole_r, dr, dc, i * n + j,
                scores[i * n + j], best, best_index,
            )  # fmt: skip
    score = best
    bi, bj = np.divmod(best_index, n)

    def parabola(lo: FloatArray, mid: FloatArray, hi: FloatArray) -> FloatArray:
        den = lo - 2.0 * mid + hi
        with np.errstate(invalid="ignore", divide="ignore"):
            off = np.where(den < 0, 0.5 * (lo - hi) / den, 0.0)
        return np.clip(np.nan_to_num(off), -0.5, 0.5)

    def at(ii: NDArray, jj: NDArray) -> FloatArray:
        ii, jj = np.clip(ii, 0, n - 1), np.clip(jj, 0, n - 1)
        return np.take_along_axis(scores, (ii * n + jj)[None], axis=0)[0]

    inner_r = (bi > 0) & (bi < n - 1)
    inner_c = (bj > 0) & (bj < n - 1)
    sub_r = np.where(inner_r, parabola(at(bi - 1, bj), score, at(bi + 1, bj)), 0.0)
    sub_c = np.where(inner_c, parabola(at(bi, bj - 1), score, at(bi, bj + 1)), 0.0)
    # a best shift on the edge of the search is no peak: the match lies farther
    found = (score > -1.5) & inner_r & inner_c
    d_row = np.where(found, bi - radius + sub_r, np.nan).astype(np.float32)
    d_col = np.where(found, bj - radius + sub_c, np.nan).astype(np.float32)
    return d_row, d_col, np.where(found, score, np.nan).astype(np.float32)


def _search_bands(
    left: FloatArray, right: FloatArray, radius: int, window: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`_search` over bands of rows (overlapping by the window and the radius)."""
    rows = left.shape[0]
    if rows <= 2 * _BAND_ROWS:
        return _search(left, right, radius, window)
    pad = window // 2 + radius + 1
    out = [np.empty(left.shape, np.float32) for _ in range(3)]
    for r0 in range(0, rows, _BAND_ROWS):
        r1 = min(rows, r0 + _BAND_ROWS)
        a, b = max(0, r0 - pad), min(rows, r1 + pad)
        part = _search(left[a:b], right[a:b], radius, window)
        for o, p in zip(out, part, strict=True):
            o[r0:r1] = p[r0 - a : r1 - a]
    return out[0], out[1], out[2]


NEAR_FILL_SIGMAS = (1.0, 3.0, 9.0)
"""Widths (px) of the normalised Gaussian convolutions that fill holes near valid offsets;
what they leave is filled by a push-pull pyramid, whose cost does not grow with the hole."""


def fill_holes(d: FloatArray) -> FloatArray:
    """Holes (NaN) filled from their valid neighbours: normalised Gaussian convolutions of
    growing width (:data:`NEAR_FILL_SIGMAS`) near valid offsets, then a push-pull pyramid
    (:func:`_push_pull`) for what lies farther: the cost is proportional to the pixels, not
    to the size of the holes (a tile mostly outside the footprint of a long strip)."""
    import cv2

    valid = np.isfinite(d)
    if valid.all():
        return d.astype(np.float32)
    if not valid.any():
        return np.zeros_like(d, dtype=np.float32)
    out = np.where(valid, d, 0.0).astype(np.float32)
    w = valid.astype(np.float32)
    filled = out.copy()
    missing = ~valid
    for sigma in NEAR_FILL_SIGMAS:
        if not missing.any():
            break
        num = cv2.GaussianBlur(out, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        den = cv2.GaussianBlur(w, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        ok = missing & (den > 1e-3)
        filled[ok] = num[ok] / den[ok]
        missing &= ~ok
    if missing.any():
        far = _push_pull(out, w)
        filled[missing] = far[missing]
    return filled


def _push_pull(values: FloatArray, weights: FloatArray) -> FloatArray:
    """Weighted averages of growing extent (Gortler et al. 1996): push the weighted sums down
    a 2 x 2 pyramid until every pixel of the coarsest level has weight, then pull the averages
    back up, each level keeping its own where it has weight and taking the coarser level's
    elsewhere. About 4/3 of the pixels' work, whatever the holes."""
    import cv2

    levels = [(values * weights, weights)]
    while levels[-1][1].min() <= 1e-6 and min(levels[-1][1].shape) > 1:
        num, den = levels[-1]
        size = (max(1, (num.shape[1] + 1) // 2), max(1, (num.shape[0] + 1) // 2))
        levels.append(
            (
                cv2.resize(num, size, interpolation=cv2.INTER_AREA),
                cv2.resize(den, size, interpolation=cv2.INTER_AREA),
            )
        )
    num, den = levels[-1]
    total = float(den.sum())
    mean = float(num.sum()) / total if total > 0 else 0.0
    estimate = np.where(den > 1e-6, num / np.maximum(den, 1e-12), mean).astype(np.float32)
    for num, den in reversed(levels[:-1]):
        coarse = cv2.resize(estimate, (num.shape[1], num.shape[0]), interpolation=cv2.INTER_LINEAR)
        own = num / np.maximum(den, 1e-12)
        blend = np.clip(den, 0.0, 1.0)  # full weight: its own average; none: the coarser one
        estimate = (blend * own + (1.0 - blend) * coarse).astype(np.float32)
    return estimate


def _clean(d: FloatArray, tolerance: float) -> FloatArray:
    """Holes filled from valid neighbours, then offsets more than ``tolerance`` from the
    3 x 3 median replaced by it."""
    import cv2

    filled = fill_holes(d)
    med = cv2.medianBlur(filled, 3)
    return np.where(np.abs(filled - med) <= tolerance, filled, med).astype(np.float32)


def _upsample(d: FloatArray, shape: tuple[int, int]) -> FloatArray:
    import cv2

    return (2.0 * cv2.resize(d, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)).astype(
        np.float32
    )


def _flow(
    left: FloatArray,
    right: FloatArray,
    levels: int,
    window: int,
    radius: int,
    guess: tuple[float, float],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Coarse-to-fine offsets left -> right (full resolution, not yet validated)."""
    pl, pr = _pyramid(left, levels), _pyramid(right, levels)
    top = len(pl) - 1
    shape = pl[top][0].shape
    scale = 2.0**top
    d_row = np.full(shape, guess[0] / scale, np.float32)
    d_col = np.full(shape, guess[1] / scale, np.float32)
    score = np.full(shape, np.nan, np.float32)
    for level in range(top, -1, -1):
        img_l, val_l = pl[level]
        img_r, val_r = pr[level]
        if d_row.shape != img_l.shape:
            d_row, d_col = _upsample(d_row, img_l.shape), _upsample(d_col, img_l.shape)
        a = np.where(val_l, img_l, np.nan).astype(np.float32)
        b = np.where(val_r, img_r, np.nan).astype(np.float32)
        warped = _warp(b, d_row, d_col)
        r_row, r_col, score = _search_bands(a, warped, radius, window)
        d_row = d_row + r_row
        d_col = d_col + r_col
        if level > 0:
            d_row, d_col = _clean(d_row, 1.0), _clean(d_col, 1.0)
    return d_row, d_col, score


def dense_offsets(
    left: ArrayLike,
    right: ArrayLike,
    *,
    levels: int = 5,
    window: int = 9,
    radius: int = 2,
    min_score: float = 0.5,
    min_std: float = 0.005,
    consistency_px: float = 1.0,
    guess: tuple[float, float] = (0.0, 0.0),
) -> OffsetField:
    """Dense offsets from ``left`` to ``right`` (see the module docstring).

    Args:
        left, right: 2-D images of the same area (NaN = no data); need not be the same size.
        levels: pyramid levels including the full resolution (fewer when the images are
            small).
        window: correlation window side, pixels (odd, >= 3).
        radius: integer search radius at every level, pixels.
        min_score: smallest correlation coefficient of a valid match.
        min_std: smallest window standard deviation, as a fraction of the left image's
            2-98 percentile range (flat windows match anything).
        consistency_px: tolerance of the left-right check, pixels.
        guess: a constant first-guess offset ``(d_row, d_col)``, pixels.

    Raises:
        InputError: malformed images or options.
    """
    a, b = _as_image(left, "left"), _as_image(right, "right")
    if isinstance(window, bool) or int(window) != window or window < 3 or window % 2 == 0:
        raise InputError(f"dense offsets: window must be an odd integer >= 3, got {window}")
    if isinstance(radius, bool) or int(radius) != radius or not 1 <= radius <= 8:
        raise InputError(f"dense offsets: radius must be an integer in 1..8, got {radius}")
    if isinstance(levels, bool) or int(levels) != levels or levels < 1:
        raise InputError(f"dense offsets: levels must be an integer >= 1, got {levels}")
    if not -1.0 <= float(min_score) <= 1.0:
        raise InputError(f"dense offsets: min_score must be within [-1, 1], got {min_score}")
    if not float(consistency_px) > 0:
        raise InputError(f"dense offsets: consistency_px must be > 0, got {consistency_px}")
    small = min(*a.shape, *b.shape)
    levels = max(1, min(int(levels), int(np.log2(max(small / (4 * window), 1))) + 1))
    d_row, d_col, score = _flow(a, b, levels, int(window), int(radius), guess)
    back_row, back_col, _ = _flow(b, a, levels, int(window), int(radius), (-guess[0], -guess[1]))
    # left-right check: the offset back from where the match lands returns to the start
    back_r = _warp(np.nan_to_num(back_row), d_row, d_col)
    back_c = _warp(np.nan_to_num(back_col), d_row, d_col)
    lr = np.hypot(d_row + back_r, d_col + back_c).astype(np.float32)
    lo, hi = np.nanpercentile(a, [2, 98]) if np.isfinite(a).any() else (0.0, 1.0)
    af, _ = _filled(a)
    std = np.sqrt(window_moments(af, window)[1])
    valid = (
        np.isfinite(d_row)
        & np.isfinite(score)
        & (score >= float(min_score))
        & (lr <= float(consistency_px))
        & (std > float(min_std) * max(float(hi - lo), 1e-12))
    )
    nan = np.float32(np.nan)
    return OffsetField(
        np.where(valid, d_row, nan),
        np.where(valid, d_col, nan),
        score,
        valid,
        lr,
    )
