"""Image matching: tie points and area-based matches with scores.

A :class:`Matcher` finds corresponding points between two images; matches come back as a
:class:`Matches` value. This module also holds the area-based matching functions Carto's own
matcher (:class:`NCCMatcher`, name ``"ncc"``) is built from:

* :func:`match_ncc`: normalised cross-correlation (OpenCV ``matchTemplate`` with
  ``TM_CCOEFF_NORMED``: Pearson's correlation coefficient, invariant to gain and offset) of a
  ``template x template`` window around each left point over the offsets ``-search..+search``
  (lines and samples) around an optional per-point guess in the right image. The integer peak
  is refined to sub-pixel by a parabola through the peak and its two neighbours in each
  direction, or a 2-D quadratic fitted to the 3 x 3 neighbourhood, or least-squares matching
  (``"lsm"``: Gauss-Newton on translation, gain and offset with the right image resampled by
  cubic convolution, started from the parabola; ``"lsm-affine"``: then an affine geometry,
  compiled, giving the displacement at the point itself where it varies across the
  template, e.g. with relief parallax between views). A point is dropped when its template or
  search window leaves the image or holds NaN, when its template has no texture (constant),
  when the best score is below ``min_score``, or when the peak is on the border of the search
  range (the true peak may lie beyond it).
* :func:`match_bidirectional`: left -> right, then right -> left from the positions found;
  matches that do not come back within ``tolerance`` pixels are dropped.
* :func:`pyramid_match`: coarse-to-fine over ``cv2.pyrDown`` pyramids, offsets of a level
  (cleaned by a local median) are the guesses of the next one.
* :func:`global_shift`: phase correlation for a first guess of a global translation.
* :func:`coarse_shift`: a translation as large as the images between partially overlapping
  ones with NaN borders (correlation over the shared valid pixels for every shift,
  :func:`masked_ncc`, on reduced images).
* :func:`grid_points`: regular candidate points (the matchers take any points: an interest
  operator can replace the grid).
* :func:`forstner_points`: the Forstner interest operator (weight and roundness of the
  gradients' structure tensor, non-maximum suppression, least-squares corner location,
  optional spreading over grid cells, :func:`spread_order`); :func:`forstner_measures` gives
  the measures of every pixel.

Conventions
    * Image coordinates follow the project convention: continuous ``(line, sample)``, the
      centre of the first pixel at ``(0.5, 0.5)`` (see :mod:`carto.framework.geometry.sensor`).
      Arrays of points are ``(N, 2)`` with columns ``(line, sample)``.
    * Offsets are ``right - left`` in pixels: the content at ``p`` in the left image is at
      ``p + offset`` in the right one.
    * The template is centred on the pixel that holds the point (centre ``floor(p) + 0.5``);
      the offset found there is applied to the point itself, so the point's fraction of a
      pixel is kept.
    * Scores are correlation coefficients in [-1, 1] (the integer peak's value).

Accuracy (measured, ``tests/framework/test_match.py``): the 3-point fits are biased by the
asymmetry of the correlation peak of a small template (peak locking): 0.06 px RMS for the
parabola, 0.04-0.05 px for the 2-D quadratic, on exact sub-pixel translations of a
multi-scale texture; least-squares matching brings it to 0.011 px RMS (0.022 px in a smooth
affine + sinusoidal displacement field, 0.013 px with ``"lsm-affine"``; under a 4-8 % scale
and shear 0.09 px, 0.004 px with ``"lsm-affine"``). :class:`NCCMatcher` uses ``"lsm"``.
Forstner points: corners of blurred rectangles within 0.3 px (the least-squares corner of a
rounded corner lies slightly inside it), checkerboard junctions within 0.03 px.

Speed: one ``matchTemplate`` call per point (a loop over points, everything else vectorised):
about 40 000 points/s for 15 x 15 templates and +-11 pixel searches with the parabola, 14 000
points/s with least-squares matching (one core); :class:`NCCMatcher` (pyramid, both
directions) about 5 000 points/s. The affine refinement adds 0.03-0.1 ms per point (numba,
parallel); the Forstner operator takes about 0.4 s for 8 Mpx.
"""

from __future__ import annotations

import math
from typing import Any

import attrs
import numba
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.base import Matcher, Matches

# ----------------------------------------------------------------------------- helpers
SUBPIXEL_METHODS = ("parabola", "quadratic", "lsm", "lsm-affine", "none")
"""Sub-pixel peak estimators of :func:`match_ncc`."""

_LSM_CHUNK = 1024  # points refined together by least-squares matching
_FLAT_STD = 1e-6  # templates with a standard deviation below this (relative) have no texture

# least-squares 2-D quadratic on the 3 x 3 neighbourhood of a peak: rows of the pseudo-inverse
# map the 9 scores (row-major, offsets -1, 0, 1) to (a0, a_x, a_y, a_xx, a_xy, a_yy)
_DY, _DX = np.mgrid[-1:2, -1:2]
_QUAD_PINV = np.linalg.pinv(
    np.stack(
        [
            np.ones(9),
            _DX.ravel(),
            _DY.ravel(),
            _DX.ravel() ** 2,
            (_DX * _DY).ravel(),
            _DY.ravel() ** 2,
        ],
        axis=1,
    ).astype(np.float64)
)


def _as_image(image: ArrayLike, name: str) -> NDArray[np.float32]:
    """A 2-D float32 C-contiguous image (OpenCV's input), or InputError."""
    array = np.asarray(image)
    if array.ndim != 2 or min(array.shape) < 1:
        raise InputError(f"{name} image must be a non-empty 2-D array, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
        raise InputError(f"{name} image dtype {array.dtype} is not real numeric")
    return np.ascontiguousarray(array, dtype=np.float32)


def _as_points(points: ArrayLike, name: str) -> NDArray[np.float64]:
    array = np.asarray(points, dtype=np.float64)
    if array.ndim == 1 and array.size == 2:
        array = array[None]
    if array.ndim != 2 or array.shape[1] != 2:
        raise InputError(f"{name} must be an (N, 2) array of (line, sample), got {array.shape}")
    return array


def _check_int(value: Any, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _nan_integral(image: NDArray[np.float32]) -> NDArray[np.integer] | None:
    """Summed-area table of the NaN pixels, ``(rows + 1, cols + 1)`` (``None`` when there is
    none)."""
    import cv2

    nan = np.isnan(image)
    if not nan.any():
        return None
    if image.size < 2**31:  # OpenCV's 32-bit integral image holds the count
        return cv2.integral(nan.view(np.uint8))
    table = np.zeros((image.shape[0] + 1, image.shape[1] + 1), np.int64)
    table[1:, 1:] = nan.cumsum(0).cumsum(1)
    return table


def _windows_clean(
    table: NDArray[np.integer] | None, r0: NDArray[np.intp], c0: NDArray[np.intp], size: int
) -> NDArray[np.bool_]:
    """True where the ``size x size`` windows at ``(r0, c0)`` hold no NaN."""
    if table is None:
        return np.ones(r0.shape, bool)
    r1, c1 = r0 + size, c0 + size
    count = table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0]
    return count == 0


def _subpixel(neighbourhood: NDArray[np.float64], method: str) -> NDArray[np.float64]:
    """Sub-pixel ``(d_line, d_sample)`` of peaks from their 3 x 3 score neighbourhoods."""
    n = neighbourhood
    out = np.zeros((n.shape[0], 2))
    if method == "none" or n.shape[0] == 0:
        return out
    with np.errstate(divide="ignore", invalid="ignore"):
        den_r = n[:, 0, 1] - 2.0 * n[:, 1, 1] + n[:, 2, 1]
        den_c = n[:, 1, 0] - 2.0 * n[:, 1, 1] + n[:, 1, 2]
        dr = np.where(den_r < 0.0, 0.5 * (n[:, 0, 1] - n[:, 2, 1]) / den_r, 0.0)
        dc = np.where(den_c < 0.0, 0.5 * (n[:, 1, 0] - n[:, 1, 2]) / den_c, 0.0)
        out[:, 0] = np.clip(dr, -0.5, 0.5)
        out[:, 1] = np.clip(dc, -0.5, 0.5)
        if method == "quadratic":
            a = n.reshape(-1, 9) @ _QUAD_PINV.T  # (a0, a_x, a_y, a_xx, a_xy, a_yy)
            hxx, hxy, hyy = 2.0 * a[:, 3], a[:, 4], 2.0 * a[:, 5]
            det = hxx * hyy - hxy * hxy
            ok = (hxx < 0.0) & (det > 0.0)
            dx = (-hyy * a[:, 1] + hxy * a[:, 2]) / det
            dy = (hxy * a[:, 1] - hxx * a[:, 2]) / det
            ok &= (np.abs(dx) <= 1.0) & (np.abs(dy) <= 1.0)
            out[:, 0] = np.where(ok, dy, out[:, 0])
            out[:, 1] = np.where(ok, dx, out[:, 1])
    return out


def _keys_weights(fraction: NDArray[np.float64]) -> NDArray[np.float64]:
    """Keys (a = -0.5) cubic convolution weights of the taps -1, 0, 1, 2: ``(M, 4)``."""
    f = fraction[:, None]
    return np.concatenate(
        [
            ((-0.5 * f + 1.0) * f - 0.5) * f,
            (1.5 * f - 2.5) * f * f + 1.0,
            ((-1.5 * f + 2.0) * f + 0.5) * f,
            (0.5 * f - 0.5) * f * f,
        ],
        axis=1,
    )


def _lsm_refine(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    t0: NDArray[np.intp],
    offset: NDArray[np.float64],
    template: int,
    iterations: int = 6,
) -> NDArray[np.float64]:
    """Least-squares matching (translation, gain and offset) from ``offset``.

    For each template at ``t0`` (top-left 0-based index in ``left``), Gauss-Newton on
    ``sum (g R(x + d) + o - T(x))^2`` with ``R`` resampled by Keys cubic convolution; the
    right patch is resampled one pixel wider for its central-difference gradients. Iterations
    stop for a point when its step is below 1e-4 px. Points whose window would leave the image,
    that diverge (moving more than a pixel from ``offset``) or become singular keep ``offset``.
    """
    out = offset.copy()
    for start in range(0, t0.shape[0], _LSM_CHUNK):  # chunks keep the work arrays in cache
        chunk = slice(start, start + _LSM_CHUNK)
        out[chunk] = _lsm_chunk(left, right, t0[chunk], offset[chunk], template, iterations)
    return out


def _lsm_chunk(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    t0: NDArray[np.intp],
    offset: NDArray[np.float64],
    template: int,
    iterations: int,
) -> NDArray[np.float64]:
    m = t0.shape[0]
    out = offset.copy()
    t = template
    size = t + 5
    d = offset.copy()
    gain = np.ones(m)
    bias = np.zeros(m)
    tmpl = sliding_window_view(left, (t, t))[t0[:, 0], t0[:, 1]].astype(np.float64)
    windows = sliding_window_view(right, (size, size))
    h, w = right.shape
    failed = np.zeros(m, bool)
    running = np.ones(m, bool)
    for _ in range(iterations):
        base = np.floor(d).astype(np.intp)
        start = t0 + base - 2
        inside = (start >= 0).all(axis=1) & (start[:, 0] + size <= h) & (start[:, 1] + size <= w)
        failed |= running & ~(inside & np.isfinite(d).all(axis=1))
        running &= ~failed
        idx = np.flatnonzero(running)
        if idx.size == 0:
            break
        block = windows[start[idx, 0], start[idx, 1]].astype(np.float64)
        frac = d[idx] - base[idx]
        wr, wc = _keys_weights(frac[:, 0]), _keys_weights(frac[:, 1])
        cols = wc[:, 0, None, None] * block[:, :, 0 : t + 2]
        for j in range(1, 4):
            cols += wc[:, j, None, None] * block[:, :, j : j + t + 2]
        patch = wr[:, 0, None, None] * cols[:, 0 : t + 2]
        for i in range(1, 4):
            patch += wr[:, i, None, None] * cols[:, i : i + t + 2]
        inner = patch[:, 1:-1, 1:-1].reshape(idx.size, -1)
        g = gain[idx, None]
        ga = (0.5 * (patch[:, 2:, 1:-1] - patch[:, :-2, 1:-1])).reshape(idx.size, -1) * g
        gb = (0.5 * (patch[:, 1:-1, 2:] - patch[:, 1:-1, :-2])).reshape(idx.size, -1) * g
        resid = tmpl[idx].reshape(idx.size, -1) - g * inner - bias[idx, None]
        columns = (ga, gb, inner)
        normal = np.empty((idx.size, 4, 4))
        rhs = np.empty((idx.size, 4))
        for a in range(3):
            for b in range(a, 3):
                normal[:, a, b] = normal[:, b, a] = np.einsum("nk,nk->n", columns[a], columns[b])
            normal[:, a, 3] = normal[:, 3, a] = columns[a].sum(axis=1)
            rhs[:, a] = np.einsum("nk,nk->n", columns[a], resid)
        normal[:, 3, 3] = t * t
        rhs[:, 3] = resid.sum(axis=1)
        ok = np.linalg.det(normal) > 1e-12 * np.einsum("nii->n", normal) ** 4
        step = np.zeros((idx.size, 4))
        if ok.any():
            step[ok] = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
        failed[idx[~ok]] = True
        d[idx] += step[:, :2]
        gain[idx] += step[:, 2]
        bias[idx] += step[:, 3]
        running[idx[np.hypot(step[:, 0], step[:, 1]) < 1e-4]] = False
        running &= ~failed
    good = ~failed & np.isfinite(d).all(axis=1)
    good &= (np.abs(d - offset) <= 1.0).all(axis=1) & (gain > 0.0)
    out[good] = d[good]
    return out


def _peak_method(subpixel: str) -> str:
    """The peak estimator of a sub-pixel method (least-squares matching starts from the
    parabola)."""
    return "parabola" if subpixel in ("lsm", "lsm-affine") else subpixel


def _lsm_affine_refine(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    t0: NDArray[np.intp],
    offset: NDArray[np.float64],
    template: int,
    points: NDArray[np.float64],
    iterations: int = 12,
) -> NDArray[np.float64]:
    """Least-squares matching with an affine geometry, gain and offset, from ``offset``.

    The template pixel at ``x`` from the template centre ``c`` (pixel indices) is compared
    with the right image at ``c + d + (I + A) x`` (Keys cubic convolution, 16 taps, with its
    exact derivatives): Gauss-Newton on ``d`` (2), ``A`` (4), gain and offset (a Cholesky
    solve of the Jacobi-scaled normal equations, damped by 1e-6 of their diagonal). A point
    stops when a step moves it by less than 0.001 px and the template corners by less than
    0.01 px. The result is the offset of the **point** itself, ``d + A (p - c)``: where the
    displacement varies across the template (relief parallax between views), the
    translation-only estimate is the displacement where the template's texture is, not at its
    centre. Points whose estimate fails (a window leaving the image or touching NaN, a shift
    of more than 2 pixels from ``offset``, ``|A|`` entries beyond 0.6, a singular system,
    a negative gain) keep ``offset``. Compiled (numba), parallel over the points.
    """
    n = t0.shape[0]
    if n == 0:
        return offset.copy()
    result = np.empty((n, 2))
    good = np.zeros(n, np.bool_)
    _lsm_affine_kernel(
        np.ascontiguousarray(left, np.float32),
        np.ascontiguousarray(right, np.float32),
        np.ascontiguousarray(t0, np.int64),
        np.ascontiguousarray(offset, np.float64),
        np.ascontiguousarray(points, np.float64),
        int(template),
        int(iterations),
        result,
        good,
    )
    return np.where(good[:, None], result, offset)


@numba.njit(cache=True, nogil=True, inline="always")
def _keys_kernel(f: float, out: np.ndarray, deriv: np.ndarray) -> None:  # pragma: no cover
    """Keys (a = -0.5) weights of the taps -1, 0, 1, 2 at fraction ``f`` and their
    derivatives with respect to ``f``, into ``out`` and ``deriv``."""
    out[0] = ((-0.5 * f + 1.0) * f - 0.5) * f
    out[1] = (1.5 * f - 2.5) * f * f + 1.0
    out[2] = ((-1.5 * f + 2.0) * f + 0.5) * f
    out[3] = (0.5 * f - 0.5) * f * f
    deriv[0] = (-1.5 * f + 2.0) * f - 0.5
    deriv[1] = (4.5 * f - 5.0) * f
    deriv[2] = (-4.5 * f + 4.0) * f + 0.5
    deriv[3] = (1.5 * f - 1.0) * f


@numba.njit(parallel=True, cache=True, nogil=True)
def _lsm_affine_kernel(
    left, right, t0, offset, points, t, iterations, result, good
):  # pragma: no cover
    """The Gauss-Newton iterations of :func:`_lsm_affine_refine`, one point per thread:
    ``result[k]`` the offset at point ``k``, ``good[k]`` whether it is valid."""
    h, w = right.shape
    half = t // 2
    for k in numba.prange(t0.shape[0]):
        wr = np.empty(4)
        dwr = np.empty(4)
        wc = np.empty(4)
        dwc = np.empty(4)
        jac = np.empty(8)
        normal = np.empty((8, 8))
        rhs = np.empty(8)
        chol = np.empty((8, 8))
        step = np.empty(8)
        scale = np.empty(8)
        p = np.zeros(8)  # d_r, d_c, a_rr, a_rc, a_cr, a_cc, gain, bias
        p[0], p[1], p[6] = offset[k, 0], offset[k, 1], 1.0
        c_r, c_c = float(t0[k, 0] + half), float(t0[k, 1] + half)
        rel_r, rel_c = points[k, 0] - 0.5 - c_r, points[k, 1] - 0.5 - c_c
        ok = True
        for _ in range(iterations):
            normal[:] = 0.0
            rhs[:] = 0.0
            for i in range(t):
                x_r = float(i - half)
                for j in range(t):
                    x_c = float(j - half)
                    pr = c_r + p[0] + (1.0 + p[2]) * x_r + p[3] * x_c
                    pc = c_c + p[1] + p[4] * x_r + (1.0 + p[5]) * x_c
                    if not (pr >= 1.0 and pr < h - 2.0 and pc >= 1.0 and pc < w - 2.0):
                        ok = False
                        break
                    ir, ic = int(np.floor(pr)), int(np.floor(pc))
                    _keys_kernel(pr - ir, wr, dwr)
                    _keys_kernel(pc - ic, wc, dwc)
                    val = 0.0
                    g_r = 0.0
                    g_c = 0.0
                    for u in range(4):
                        along = 0.0
                        along_d = 0.0
                        for v in range(4):
                            x = right[ir - 1 + u, ic - 1 + v]
                            along += wc[v] * x
                            along_d += dwc[v] * x
                        val += wr[u] * along
                        g_r += dwr[u] * along
                        g_c += wr[u] * along_d
                    if not np.isfinite(val):
                        ok = False
                        break
                    gain = p[6]
                    jac[0] = gain * g_r
                    jac[1] = gain * g_c
                    jac[2] = gain * g_r * x_r
                    jac[3] = gain * g_r * x_c
                    jac[4] = gain * g_c * x_r
                    jac[5] = gain * g_c * x_c
                    jac[6] = val
                    jac[7] = 1.0
                    resid = left[t0[k, 0] + i, t0[k, 1] + j] - gain * val - p[7]
                    for a in range(8):
                        rhs[a] += jac[a] * resid
                        for b in range(a, 8):
                            normal[a, b] += jac[a] * jac[b]
                if not ok:
                    break
            if not ok:
                break
            # Jacobi-scaled, damped Cholesky solve
            for a in range(8):
                if not normal[a, a] > 0.0:
                    ok = False
                else:
                    scale[a] = 1.0 / np.sqrt(normal[a, a] * (1.0 + 1e-6))
            if not ok:
                break
            for a in range(8):
                for b in range(a, 8):
                    value = normal[a, b] * scale[a] * scale[b]
                    for m in range(a):
                        value -= chol[m, a] * chol[m, b]
                    if a == b:
                        if value <= 1e-12:
                            ok = False
                            break
                        chol[a, a] = np.sqrt(value)
                    else:
                        chol[a, b] = value / chol[a, a]
                if not ok:
                    break
            if not ok:
                break
            for a in range(8):  # forward: chol^T y = scaled rhs
                value = rhs[a] * scale[a]
                for m in range(a):
                    value -= chol[m, a] * step[m]
                step[a] = value / chol[a, a]
            for a in range(7, -1, -1):  # back: chol x = y
                value = step[a]
                for m in range(a + 1, 8):
                    value -= chol[a, m] * step[m]
                step[a] = value / chol[a, a]
            for a in range(8):
                step[a] *= scale[a]
                p[a] += step[a]
            moved_r = step[0] + step[2] * rel_r + step[3] * rel_c
            moved_c = step[1] + step[4] * rel_r + step[5] * rel_c
            corner = max(abs(step[2]), abs(step[3]), abs(step[4]), abs(step[5])) * half
            if np.hypot(moved_r, moved_c) < 1e-3 and corner < 1e-2:
                break
        a_max = max(abs(p[2]), abs(p[3]), abs(p[4]), abs(p[5]))
        ok = ok and a_max <= 0.6 and p[6] > 0.0
        ok = ok and abs(p[0] - offset[k, 0]) <= 2.0 and abs(p[1] - offset[k, 1]) <= 2.0
        for a in range(8):
            ok = ok and np.isfinite(p[a])
        good[k] = ok
        result[k, 0] = p[0] + p[2] * rel_r + p[3] * rel_c
        result[k, 1] = p[1] + p[4] * rel_r + p[5] * rel_c


@attrs.frozen
class _Found:
    """Per input point: right position (NaN where no match) and score (NaN likewise)."""

    right: NDArray[np.float64]
    score: NDArray[np.float64]

    @property
    def ok(self) -> NDArray[np.bool_]:
        return np.isfinite(self.score)


def _match_points(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    points: NDArray[np.float64],
    guess: NDArray[np.float64],
    template: int,
    search: int,
    subpixel: str,
    min_score: float,
    nan_left: NDArray[np.integer] | None,
    nan_right: NDArray[np.integer] | None,
) -> _Found:
    """The correlation of :func:`match_ncc` on prepared inputs, one row per input point."""
    import cv2

    n = points.shape[0]
    right_pts = np.full((n, 2), np.nan)
    scores = np.full(n, np.nan)
    half = template // 2
    size = 2 * (half + search) + 1
    ok = np.isfinite(points).all(axis=1) & np.isfinite(guess).all(axis=1)
    pts = np.where(ok[:, None], points, 0.0)
    g = np.rint(np.where(ok[:, None], guess, 0.0))
    # the template is centred on the pixel holding the point (centre at index + 0.5)
    centre = np.floor(pts).astype(np.intp)
    t0 = centre - half
    s0 = centre + g.astype(np.intp) - half - search
    h_l, w_l = left.shape
    h_r, w_r = right.shape
    ok &= (t0[:, 0] >= 0) & (t0[:, 1] >= 0)
    ok &= (t0[:, 0] + template <= h_l) & (t0[:, 1] + template <= w_l)
    ok &= (s0[:, 0] >= 0) & (s0[:, 1] >= 0)
    ok &= (s0[:, 0] + size <= h_r) & (s0[:, 1] + size <= w_r)
    idx = np.flatnonzero(ok)
    clean = _windows_clean(nan_left, t0[idx, 0], t0[idx, 1], template)
    clean &= _windows_clean(nan_right, s0[idx, 0], s0[idx, 1], size)
    idx = idx[clean]
    if idx.size == 0:
        return _Found(right_pts, scores)
    templates = sliding_window_view(left, (template, template))[t0[idx, 0], t0[idx, 1]]
    spread = templates.reshape(idx.size, -1).std(axis=1)
    level = np.abs(templates.reshape(idx.size, -1).mean(axis=1))
    textured = spread > _FLAT_STD * np.maximum(level, 1.0)
    idx, templates = idx[textured], templates[textured]
    n_off = 2 * search + 1
    surface = np.empty((idx.size, n_off, n_off), np.float32)
    for k, (i, tmpl) in enumerate(zip(idx, templates, strict=True)):
        r, c = s0[i]
        surface[k] = cv2.matchTemplate(
            right[r : r + size, c : c + size], tmpl, cv2.TM_CCOEFF_NORMED
        )
    surface[np.isnan(surface)] = -1.0
    flat = surface.reshape(idx.size, -1)
    peak = flat.argmax(axis=1)
    best = flat[np.arange(idx.size), peak].astype(np.float64)
    pr, pc = np.divmod(peak, n_off)
    inner = (pr > 0) & (pr < n_off - 1) & (pc > 0) & (pc < n_off - 1)
    good = inner & (best >= min_score)
    idx, pr, pc, best, surface = idx[good], pr[good], pc[good], best[good], surface[good]
    rows = pr[:, None, None] + np.arange(-1, 2)[None, :, None]
    cols = pc[:, None, None] + np.arange(-1, 2)[None, None, :]
    neighbourhood = surface[np.arange(idx.size)[:, None, None], rows, cols].astype(np.float64)
    sub = _subpixel(neighbourhood, _peak_method(subpixel))
    offset = g[idx] + np.stack([pr, pc], axis=1) - search + sub
    if subpixel in ("lsm", "lsm-affine"):
        offset = _lsm_refine(left, right, t0[idx], offset, template)
    if subpixel == "lsm-affine":
        offset = _lsm_affine_refine(left, right, t0[idx], offset, template, points[idx])
    right_pts[idx] = points[idx] + offset
    scores[idx] = best
    return _Found(right_pts, scores)


def _matches(points: NDArray[np.float64], found: _Found) -> Matches:
    ok = found.ok
    return Matches(
        points[ok, 0], points[ok, 1], found.right[ok, 0], found.right[ok, 1], found.score[ok]
    )


def _check_options(template: int, search: int, subpixel: str, min_score: float) -> None:
    if _check_int(template, "template", 3) % 2 == 0:
        raise InputError(f"template must be odd (a centred window), got {template}")
    _check_int(search, "search", 1)
    if subpixel not in SUBPIXEL_METHODS:
        raise InputError(f"subpixel {subpixel!r} is not one of {', '.join(SUBPIXEL_METHODS)}")
    if not -1.0 <= float(min_score) <= 1.0:
        raise InputError(f"min_score must be within [-1, 1], got {min_score}")


def _guesses(guess_offsets: ArrayLike | None, n: int) -> NDArray[np.float64]:
    if guess_offsets is None:
        return np.zeros((n, 2))
    guess = np.asarray(guess_offsets, dtype=np.float64)
    if guess.shape == (2,):
        guess = np.broadcast_to(guess, (n, 2))
    if guess.shape != (n, 2):
        raise InputError(
            f"guess_offsets must be (N, 2) like the points ({n}, 2) or one (2,) offset, "
            f"got {guess.shape}"
        )
    return np.array(guess)


# ----------------------------------------------------------------------------- matching
def match_ncc(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    *,
    template: int = 15,
    search: int = 11,
    subpixel: str = "parabola",
    min_score: float = 0.6,
    guess_offsets: ArrayLike | None = None,
) -> Matches:
    """Match points of the left image in the right one by normalised cross-correlation.

    Args:
        left, right: single-band images (2-D, any real dtype; NaN = no data).
        points_left: ``(N, 2)`` ``(line, sample)`` in the left image.
        template: side of the square template, odd, pixels.
        search: the search reaches ``+-search`` pixels around the guess in both directions.
        subpixel: ``"parabola"`` (default; separable 3-point parabolas), ``"quadratic"``
            (2-D least-squares quadratic on the 3 x 3 neighbourhood; falls back to the
            parabolas where it has no maximum), ``"lsm"`` (least-squares matching from the
            parabola's estimate; points where it fails keep that estimate; the most accurate,
            see the module docstring), ``"lsm-affine"`` (least-squares matching with an
            affine geometry, from the ``"lsm"`` estimate: the offset of the point itself where
            the displacement varies across the template) or ``"none"`` (integer offsets).
        min_score: smallest accepted correlation score.
        guess_offsets: ``(N, 2)`` (or one ``(2,)``) expected offsets ``right - left``,
            pixels; rounded to integers to centre the search. Default zero.

    Returns:
        the matches, in the input order, of the points that pass all the tests (see the module
        docstring); scores are the integer-peak correlation coefficients.

    Raises:
        InputError: malformed images, points, guesses or options.
    """
    _check_options(template, search, subpixel, min_score)
    left_img, right_img = _as_image(left, "left"), _as_image(right, "right")
    points = _as_points(points_left, "points_left")
    guess = _guesses(guess_offsets, points.shape[0])
    found = _match_points(
        left_img,
        right_img,
        points,
        guess,
        template,
        search,
        subpixel,
        float(min_score),
        _nan_integral(left_img),
        _nan_integral(right_img),
    )
    return _matches(points, found)


def _bidirectional(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    points: NDArray[np.float64],
    guess: NDArray[np.float64],
    template: int,
    search: int,
    subpixel: str,
    min_score: float,
    tolerance: float,
    nan_left: NDArray[np.integer] | None,
    nan_right: NDArray[np.integer] | None,
) -> _Found:
    forward = _match_points(
        left, right, points, guess, template, search, subpixel, min_score, nan_left, nan_right
    )
    ok = forward.ok
    back_guess = np.where(ok[:, None], points - forward.right, 0.0)
    back_points = np.where(ok[:, None], forward.right, np.nan)
    # the check needs no more than the parabola's accuracy, except where the forward position
    # is the affine estimate at the point: a distorted template's translation peak may lie up
    # to a pixel away from it (and comparing like with like rejects the fewest good matches)
    backward = _match_points(
        right,
        left,
        back_points,
        back_guess,
        template,
        search,
        subpixel if subpixel == "lsm-affine" else _peak_method(subpixel),
        min_score,
        nan_right,
        nan_left,
    )
    closure = np.hypot(*(backward.right - points).T)
    keep = backward.ok & (closure <= tolerance)
    score = np.where(keep, np.minimum(forward.score, backward.score), np.nan)
    right_pts = np.where(keep[:, None], forward.right, np.nan)
    return _Found(right_pts, score)


def match_bidirectional(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    *,
    tolerance: float = 0.5,
    template: int = 15,
    search: int = 11,
    subpixel: str = "parabola",
    min_score: float = 0.6,
    guess_offsets: ArrayLike | None = None,
) -> Matches:
    """:func:`match_ncc` left -> right, then right -> left from the positions found.

    A match is kept when the backward match lands within ``tolerance`` pixels of the left
    point it started from: a consistency check that removes most wrong matches on nearly
    repeated patterns and occlusions (on an exactly periodic pattern both directions pick a
    period at random and a wrong pair survives as often as a right one). The backward pass uses
    the parabola when ``subpixel`` is ``"lsm"`` (the check needs no more), least-squares
    matching with an affine geometry when it is ``"lsm-affine"`` (the forward position is then
    the displacement at the point, which the translation peak of a distorted template misses
    by up to a pixel). The score is the smaller of the two directions' scores. Other arguments
    as :func:`match_ncc`.
    """
    _check_options(template, search, subpixel, min_score)
    if not float(tolerance) > 0.0:
        raise InputError(f"tolerance must be > 0 pixels, got {tolerance}")
    left_img, right_img = _as_image(left, "left"), _as_image(right, "right")
    points = _as_points(points_left, "points_left")
    guess = _guesses(guess_offsets, points.shape[0])
    found = _bidirectional(
        left_img,
        right_img,
        points,
        guess,
        template,
        search,
        subpixel,
        float(min_score),
        float(tolerance),
        _nan_integral(left_img),
        _nan_integral(right_img),
    )
    return _matches(points, found)


def _regularise(
    points: NDArray[np.float64],
    offsets: NDArray[np.float64],
    ok: NDArray[np.bool_],
    fallback: NDArray[np.float64],
    max_deviation: float,
    k: int = 9,
) -> NDArray[np.float64]:
    """Offsets for every point: the found ones, unless they differ from the median of their
    ``k`` nearest found neighbours by more than ``max_deviation`` (then that median); points
    without a match get the median of their neighbours' (or ``fallback`` when none matched)."""
    good = np.flatnonzero(ok)
    if good.size == 0:
        return fallback.copy()
    from scipy.spatial import cKDTree

    finite = np.isfinite(points).all(axis=1)
    query = np.where(finite[:, None], points, 0.0)
    tree = cKDTree(points[good])
    kk = min(k, good.size)
    _, nearest = tree.query(query, k=kk)
    nearest = np.asarray(nearest).reshape(points.shape[0], kk)
    median = np.median(offsets[good][nearest], axis=1)
    deviation = np.hypot(*(offsets - median).T)
    keep = ok & (deviation <= max_deviation)
    return np.where(keep[:, None], offsets, median)


def pyramid_match(
    left: ArrayLike,
    right: ArrayLike,
    points_left: ArrayLike,
    *,
    levels: int = 3,
    template: int = 15,
    search: int = 11,
    subpixel: str = "parabola",
    min_score: float = 0.6,
    coarse_min_score: float = 0.5,
    guess_offsets: ArrayLike | None = None,
    bidirectional: bool = True,
    tolerance: float = 0.5,
) -> Matches:
    """Coarse-to-fine matching over image pyramids (``cv2.pyrDown``, factor 2 per level).

    At the coarsest level the points are matched with the given guesses (scaled); the offsets
    found are cleaned (each compared with the median of its 9 nearest neighbours: more than
    2 pixels of that level away, or unmatched, it is replaced by the median) and passed, scaled
    by two, as the guesses of the next level. The full-resolution level is matched with
    :func:`match_bidirectional` (or :func:`match_ncc` when ``bidirectional`` is False). The
    search reach is about ``search * (2**levels - 1)`` pixels around the guesses (77 px for the
    defaults); give larger offsets as ``guess_offsets`` (e.g. from :func:`global_shift`). The
    coarse levels use the parabola when ``subpixel`` is least-squares matching (their offsets
    are only guesses).

    Args:
        levels: number of pyramid levels including the full resolution (1 = no pyramid);
            reduced where the images get smaller than two search windows.
        coarse_min_score: smallest score accepted at the coarse levels.
        template, search, subpixel, min_score, guess_offsets: as :func:`match_ncc`.
        bidirectional, tolerance: the left-right check of :func:`match_bidirectional`.

    Returns:
        the full-resolution matches, in the input order.
    """
    import cv2

    _check_options(template, search, subpixel, min_score)
    levels = _check_int(levels, "levels", 1)
    if not float(tolerance) > 0.0:
        raise InputError(f"tolerance must be > 0 pixels, got {tolerance}")
    left_img, right_img = _as_image(left, "left"), _as_image(right, "right")
    points = _as_points(points_left, "points_left")
    offsets = _guesses(guess_offsets, points.shape[0])
    pyramid = [(left_img, right_img)]
    need = template + 2 * search
    while len(pyramid) < levels:
        a, b = pyramid[-1]
        if min(*a.shape, *b.shape) < 2 * need:
            break
        pyramid.append((cv2.pyrDown(a), cv2.pyrDown(b)))
    for level in range(len(pyramid) - 1, 0, -1):
        a, b = pyramid[level]
        scale = 2.0**level
        found = _match_points(
            a,
            b,
            points / scale,
            offsets / scale,
            template,
            search,
            _peak_method(subpixel),
            float(coarse_min_score),
            _nan_integral(a),
            _nan_integral(b),
        )
        level_offsets = (found.right - points / scale) * scale
        offsets = _regularise(points, level_offsets, found.ok, offsets, 2.0 * scale)
    found = (
        _bidirectional(
            left_img,
            right_img,
            points,
            offsets,
            template,
            search,
            subpixel,
            float(min_score),
            float(tolerance),
            _nan_integral(left_img),
            _nan_integral(right_img),
        )
        if bidirectional
        else _match_points(
            left_img,
            right_img,
            points,
            offsets,
            template,
            search,
            subpixel,
            float(min_score),
            _nan_integral(left_img),
            _nan_integral(right_img),
        )
    )
    return _matches(points, found)


def _upsampled_correlation(
    spectrum: NDArray[np.complex128], centre: tuple[float, float], half: float, n: int
) -> NDArray[np.float64]:
    """Real part of the inverse DFT of ``spectrum`` on an ``n x n`` grid of shifts spanning
    ``centre +- half`` pixels (matrix-multiply DFT, after Guizar-Sicairos et al. 2008)."""
    rows, cols = spectrum.shape
    ky = np.fft.fftfreq(rows)
    kx = np.fft.fftfreq(cols)
    ys = centre[0] + np.linspace(-half, half, n)
    xs = centre[1] + np.linspace(-half, half, n)
    kernel_y = np.exp(2j * np.pi * np.outer(ys, ky))
    kernel_x = np.exp(2j * np.pi * np.outer(kx, xs))
    return (kernel_y @ spectrum @ kernel_x).real / spectrum.size


def global_shift(left: ArrayLike, right: ArrayLike) -> tuple[float, float, float]:
    """The translation ``right - left`` between two images by phase correlation.

    ``cv2.phaseCorrelate`` with a Hann window (which down-weights the borders, where content
    enters and leaves) on the common ``min(shape)`` top-left region, NaN replaced by the mean,
    gives the integer peak. Its own sub-pixel estimate (a 5 x 5 centroid) is biased by up to
    0.3 px, so the peak is refined on the normalised cross-power spectrum evaluated at
    sub-pixel shifts by matrix-multiply DFTs: a 1/8 px grid over +-1.5 px, then 1/64 and
    1/512 px grids around the maximum (the correlation of a pure translation is a sharp, symmetric
    periodic sinc there). Shifts up to about a quarter of the image size are recovered
    reliably (100 px on a 400 px ortho).

    Returns:
        ``(d_line, d_sample, score)``: content at ``(line, sample)`` in ``left`` is at
        ``(line + d_line, sample + d_sample)`` in ``right``; ``score`` is
        ``cv2.phaseCorrelate``'s peak response in [0, 1] (near 0: no reliable shift).

    Raises:
        InputError: malformed images, or fewer than 8 x 8 common pixels.
    """
    import cv2

    a = _as_image(left, "left").astype(np.float64)
    b = _as_image(right, "right").astype(np.float64)
    rows, cols = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])
    if min(rows, cols) < 8:
        raise InputError(f"global_shift: images of {rows} x {cols} common pixels are too small")
    a, b = a[:rows, :cols].copy(), b[:rows, :cols].copy()
    for img in (a, b):
        nan = np.isnan(img)
        img[nan] = float(np.mean(img[~nan])) if (~nan).any() else 0.0
        img -= img.mean()
    window = cv2.createHanningWindow((cols, rows), cv2.CV_64F)
    (d_sample, d_line), response = cv2.phaseCorrelate(a, b, window)
    # refine on the whitened cross-power spectrum (phase ramp of the shift)
    cross = np.conj(np.fft.fft2(a * window)) * np.fft.fft2(b * window)
    magnitude = np.abs(cross)
    cross = np.where(magnitude > 1e-12 * magnitude.max(), cross / np.maximum(magnitude, 1e-300), 0)
    centre = (float(np.round(d_line)), float(np.round(d_sample)))
    for half, n in ((1.5, 25), (0.125, 17), (1.0 / 64.0, 17)):
        surface = _upsampled_correlation(cross, centre, half, n)
        k_r, k_c = np.unravel_index(int(np.argmax(surface)), surface.shape)
        step = 2.0 * half / (n - 1)
        centre = (centre[0] - half + k_r * step, centre[1] - half + k_c * step)
    return float(centre[0]), float(centre[1]), float(response)


def grid_points(shape: tuple[int, int], spacing: float, margin: float = 0.0) -> NDArray[np.float64]:
    """Regular candidate points ``(N, 2)`` ``(line, sample)`` on pixel centres.

    Rows and columns every ``spacing`` pixels from ``margin`` (the distance of the first and
    last points from the image edges, pixels), centred in the image; row-major order.
    """
    rows, cols = (int(v) for v in shape)
    spacing = float(spacing)
    margin = float(margin)
    if not spacing >= 1.0:
        raise InputError(f"spacing must be >= 1 pixel, got {spacing}")
    if margin < 0.0:
        raise InputError(f"margin must be >= 0, got {margin}")

    def axis(n: int) -> NDArray[np.float64]:
        span = n - 2.0 * margin - 1.0
        if span < 0:
            return np.empty(0)
        count = int(span // spacing) + 1
        start = math.floor(margin + 0.5 * (span - (count - 1) * spacing))
        return start + 0.5 + np.round(np.arange(count) * spacing)

    lines, samples = axis(rows), axis(cols)
    grid_l, grid_s = np.meshgrid(lines, samples, indexing="ij")
    return np.stack([grid_l.ravel(), grid_s.ravel()], axis=1)


# ----------------------------------------------------------------------------- interest points
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
    if _check_int(window, "window", 3) % 2 == 0:
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
    img = _as_image(image, "image")
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
    pts = _as_points(points, "points")
    w = np.asarray(weights, np.float64)
    n_rows, n_cols = (_check_int(v, "grid_cells", 1) for v in grid_cells)
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
        keep = keep[rank < _check_int(per_cell, "per_cell", 1)]
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
    import cv2

    img = _as_image(image, "image")
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
        max_points = _check_int(max_points, "max_points", 0)
    if subpixel not in FORSTNER_SUBPIXEL:
        raise InputError(f"subpixel {subpixel!r} is not one of {', '.join(FORSTNER_SUBPIXEL)}")
    cells = None
    if grid_cells is not None:
        cells = tuple(_check_int(v, "grid_cells", 1) for v in grid_cells)
        if len(cells) != 2:
            raise InputError(f"grid_cells must be (rows, cols), got {grid_cells!r}")
        if per_cell is None:
            n_cells = cells[0] * cells[1]
            per_cell = -(-max_points // n_cells) if max_points else 1
        per_cell = _check_int(per_cell, "per_cell", 1)
    t = _structure_tensor(img, window)
    w, q = _weight_roundness(t)
    empty = np.empty((0, 2))
    if not t.valid.any():
        return empty
    threshold = max(float(np.quantile(w[t.valid], float(weight_quantile))), float(min_weight))
    candidate = t.valid & (q > float(min_roundness)) & (w > threshold)
    if not candidate.any():
        return empty
    n_rows, n_cols = w.shape
    # exact ties (plateaus of a synthetic image) broken by a fixed pseudo-random order
    flat = np.flatnonzero(candidate)
    ranked = np.zeros(w.shape, np.float32)
    ranked.ravel()[flat] = w.ravel()[flat] * (1.0 + 1e-5 * ((flat * _GOLDEN) % 1.0))
    peak = candidate & (ranked >= cv2.dilate(ranked, _disk(radius)))
    rows, cols = np.nonzero(peak)
    weight = w[rows, cols].astype(np.float64)
    if subpixel == "lsq":
        index = _lsq_corners(t, rows, cols, window)
    elif subpixel == "parabola":
        index = _parabola_peaks(w, rows, cols)
    else:
        index = np.stack([rows, cols], axis=1).astype(np.float64)
    points = index + 0.5
    if cells is not None:
        order = spread_order(points, weight, (n_rows, n_cols), cells, per_cell)
    else:
        order = np.argsort(-weight, kind="stable")
    if max_points is not None:
        order = order[:max_points]
    return points[order]


def _reduce(image: NDArray[np.float32], factor: int) -> NDArray[np.float64]:
    """Block mean over ``factor x factor`` pixels; NaN where a block holds any NaN."""
    import cv2

    if factor == 1:
        return image.astype(np.float64)
    valid = np.isfinite(image)
    shape = (max(image.shape[1] // factor, 1), max(image.shape[0] // factor, 1))
    h, w = shape[1] * factor, shape[0] * factor
    data = np.where(valid, image, 0.0).astype(np.float32)[:h, :w]
    mean = cv2.resize(data, shape, interpolation=cv2.INTER_AREA).astype(np.float64)
    frac = cv2.resize(valid[:h, :w].astype(np.float32), shape, interpolation=cv2.INTER_AREA)
    return np.where(frac > 0.999, mean / np.maximum(frac, 1e-6), np.nan)


def masked_ncc(
    left: NDArray[np.float64], right: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Normalised cross-correlation of two images with NaN (no data) for **every** shift,
    over the valid pixels the two images share at that shift (Padfield 2012, "Masked object
    registration in the Fourier domain": six FFT correlations).

    Returns:
        ``(ncc, overlap)``, both ``(H_l + H_r - 1, W_l + W_r - 1)``: element ``(i, j)`` is
        the shift ``(d_line, d_sample) = (i - H_l + 1, j - W_l + 1)`` (content at ``p`` in
        ``left`` at ``p + d`` in ``right``); ``ncc`` is NaN where fewer than 2 pixels overlap
        or either side is constant; ``overlap`` counts the shared valid pixels.
    """
    from scipy import fft

    a, b = np.asarray(left, np.float64), np.asarray(right, np.float64)
    ma, mb = np.isfinite(a), np.isfinite(b)
    a = np.where(ma, a - (a[ma].mean() if ma.any() else 0.0), 0.0)
    b = np.where(mb, b - (b[mb].mean() if mb.any() else 0.0), 0.0)
    out_shape = (a.shape[0] + b.shape[0] - 1, a.shape[1] + b.shape[1] - 1)
    size = tuple(fft.next_fast_len(n, real=True) for n in out_shape)

    def spectrum(x: NDArray[np.float64]) -> NDArray[np.complex128]:
        return fft.rfft2(x, size)

    def corr(fa: NDArray[np.complex128], fb: NDArray[np.complex128]) -> NDArray[np.float64]:
        # c(d) = sum_p A(p) B(p + d), circular over the padded size; negative shifts wrap
        full = fft.irfft2(np.conj(fa) * fb, size)
        rows = np.r_[size[0] - a.shape[0] + 1 : size[0], 0 : b.shape[0]]
        cols = np.r_[size[1] - a.shape[1] + 1 : size[1], 0 : b.shape[1]]
        return full[np.ix_(rows, cols)]

    fa, fb = spectrum(a), spectrum(b)
    fma, fmb = spectrum(ma.astype(np.float64)), spectrum(mb.astype(np.float64))
    overlap = np.rint(corr(fma, fmb))
    sum_a, sum_b = corr(fa, fmb), corr(fma, fb)
    sum_aa = corr(spectrum(a * a), fmb)
    sum_bb = corr(fma, spectrum(b * b))
    sum_ab = corr(fa, fb)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.where(overlap >= 2, overlap, np.nan)
        cov = sum_ab - sum_a * sum_b / n
        var_a = sum_aa - sum_a * sum_a / n
        var_b = sum_bb - sum_b * sum_b / n
        scale = np.sqrt(np.maximum(var_a, 0.0) * np.maximum(var_b, 0.0))
        tiny = 1e-9 * np.nanmax(np.sqrt(np.abs(sum_aa * sum_bb))) if np.any(overlap >= 2) else 0
        ncc = np.where(scale > tiny, cov / scale, np.nan)
    return np.clip(ncc, -1.0, 1.0), np.maximum(overlap, 0.0)


def coarse_shift(
    left: ArrayLike,
    right: ArrayLike,
    *,
    size: int = 256,
    min_overlap: float = 0.15,
) -> tuple[float, float, float]:
    """A large translation ``right - left`` between partially overlapping images with NaN
    borders (e.g. system-level ortho-images on one grid, hundreds of pixels apart).

    Both images are reduced by block means over ``f x f`` pixels, ``f`` the smallest power of
    two that brings the larger image to at most ``size`` pixels (a reduced pixel is valid when
    its whole block is). The correlation coefficient over the shared valid pixels is computed
    for every shift at once (:func:`masked_ncc`); shifts whose overlap is smaller than
    ``min_overlap`` times the smaller image's valid area are ignored (a small overlap can
    correlate by chance). The best shift is refined by a parabola through its neighbours in
    each direction and scaled back by ``f``. Unlike :func:`global_shift` (phase correlation,
    about a quarter of the image size) it finds shifts as large as the images themselves,
    whatever the shape of their valid areas; the accuracy is a fraction of ``f`` pixels: a
    first guess for :func:`pyramid_match`, whose reach (77 px with its defaults) covers that.

    Returns:
        ``(d_line, d_sample, score)``: the shift, pixels, and its correlation coefficient
        (``(0, 0, 0)`` when the images share no valid area of the required size).

    Raises:
        InputError: malformed images or options.
    """
    a, b = _as_image(left, "left"), _as_image(right, "right")
    size = _check_int(size, "size", 16)
    if not 0.0 < float(min_overlap) <= 1.0:
        raise InputError(f"min_overlap must be within (0, 1], got {min_overlap}")
    factor = 1
    while max(*a.shape, *b.shape) / factor > size:
        factor *= 2
    ra, rb = _reduce(a, factor), _reduce(b, factor)
    n_a, n_b = int(np.isfinite(ra).sum()), int(np.isfinite(rb).sum())
    if min(n_a, n_b) < 4:
        return 0.0, 0.0, 0.0
    ncc, overlap = masked_ncc(ra, rb)
    ncc = np.where(overlap >= max(float(min_overlap) * min(n_a, n_b), 4.0), ncc, np.nan)
    if not np.isfinite(ncc).any():
        return 0.0, 0.0, 0.0
    k_r, k_c = np.unravel_index(int(np.nanargmax(ncc)), ncc.shape)
    best = float(ncc[k_r, k_c])
    peak = np.array([k_r, k_c], np.float64)
    padded = np.pad(ncc, 1, constant_values=np.nan)
    block = padded[k_r : k_r + 3, k_c : k_c + 3]
    if np.isfinite(block[[0, 1, 1, 1, 2], [1, 0, 1, 2, 1]]).all():
        peak += _subpixel(block[None], "parabola")[0]
    d = (peak - np.array([ra.shape[0] - 1, ra.shape[1] - 1])) * factor
    # block means of f x f pixels: the centre of block k is at f k + f / 2 in both images
    return float(d[0]), float(d[1]), best


class NCCMatcher(Matcher):
    """Dense-grid NCC matcher: global phase-correlation shift, pyramid, left-right check.

    ``match(left, right)`` takes points every ``spacing`` pixels of the left image (margin
    ``template // 2 + 1``), estimates the global shift with :func:`global_shift` (used as
    the first guess when its response exceeds ``min_response``) and matches them with
    :func:`pyramid_match` (bidirectional at full resolution). The candidate points do not
    depend on the images' content: the matcher is independent of how points are chosen
    (:meth:`match_points` takes any points).
    """

    name = "ncc"
    description = (
        "normalised cross-correlation on a grid: phase-correlation first guess, "
        "3-level pyramid, least-squares sub-pixel refinement, left-right consistency check"
    )

    def __init__(
        self,
        *,
        spacing: float = 32.0,
        template: int = 15,
        search: int = 11,
        levels: int = 3,
        min_score: float = 0.6,
        tolerance: float = 0.5,
        subpixel: str = "lsm",
        use_global_shift: bool = True,
        min_response: float = 0.05,
    ) -> None:
        _check_options(template, search, subpixel, min_score)
        self.spacing = float(spacing)
        self.template = int(template)
        self.search = int(search)
        self.levels = _check_int(levels, "levels", 1)
        self.min_score = float(min_score)
        self.tolerance = float(tolerance)
        self.subpixel = subpixel
        self.use_global_shift = bool(use_global_shift)
        self.min_response = float(min_response)

    def match(self, left: NDArray, right: NDArray) -> Matches:
        left_img = _as_image(left, "left")
        points = grid_points(left_img.shape, self.spacing, self.template // 2 + 1)
        return self.match_points(left, right, points)

    def match_points(self, left: NDArray, right: NDArray, points: ArrayLike) -> Matches:
        """Match given left points (``(N, 2)`` line, sample) like :meth:`match`."""
        guess = np.zeros(2)
        left_img, right_img = _as_image(left, "left"), _as_image(right, "right")
        if self.use_global_shift and min(*left_img.shape, *right_img.shape) >= 8:
            d_line, d_sample, response = global_shift(left_img, right_img)
            if response >= self.min_response:
                guess = np.array([d_line, d_sample])
        return pyramid_match(
            left_img,
            right_img,
            points,
            levels=self.levels,
            template=self.template,
            search=self.search,
            subpixel=self.subpixel,
            min_score=self.min_score,
            guess_offsets=guess,
            tolerance=self.tolerance,
        )
