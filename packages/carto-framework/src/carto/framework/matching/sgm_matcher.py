"""Semi-global dense matching along the stereo base: :class:`SGMMatcher` (name ``"sgm"``).

Two ortho-images of a stereo pair on the current DEM differ by a parallax along the stereo
base (what a height error makes) and a nearly constant offset across it (what the relative
orientation leaves, the caller's ``guess``). The matcher

1. shifts the right image by the guess and rotates both so that the base runs along rows
   (``cv2.warpAffine``, cubic; the bounding box of the rotated image, no more);
2. stretches each to 8 bits between its 0.5 and 99.5 percentiles (OpenCV's SGM takes 8-bit
   images) and runs OpenCV's ``StereoSGBM`` (Hirschmuller 2008, with Birchfield-Tomasi costs
   over ``block`` x ``block`` windows) aggregated over 5 paths in one pass over the rows
   (``MODE_SGBM``; 3, 4 or 8 on request), with its left-right check (``disp12MaxDiff``);
   sub-pixel disparities from the parabola through the NCC of the windows at the integer
   disparity and its two neighbours (``subpixel="ncc"``), or OpenCV's own (``"sgbm"``);
3. rotates the disparity back (nearest) and scores every match by the normalised
   cross-correlation of the two ``window`` x ``window`` neighbourhoods at the match, the
   confidence a DEM generator reports; flat windows, low scores and matches outside either
   image are invalid.

An offset across the base that the caller's guess lacks is measured first, as the median of
sparse NCC matches (least-squares sub-pixel) on a grid of the image.

The search range is the caller's reach, ``radius * (2**levels - 1)`` pixels each way along the
base (:class:`~carto.framework.matching.base.DenseSettings`), or the largest of the caller's
per-pixel bounds (``search_px``) when smaller, rounded up to OpenCV's multiples of 16
disparities. Sparse points (:meth:`SGMMatcher.match_points`) are read from the dense field
of the two images, so they suit nearly co-registered images only (ortho-images of one grid).
"""

from __future__ import annotations

import math

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.base import (
    DenseSettings,
    Matcher,
    Matches,
    MatchSettings,
    OffsetField,
)
from carto.framework.matching.precision import window_moments, window_ncc

__all__ = ["SGMMatcher"]

_MODES = {
    3: "STEREO_SGBM_MODE_SGBM_3WAY",
    5: "STEREO_SGBM_MODE_SGBM",
    4: "STEREO_SGBM_MODE_HH4",
    8: "STEREO_SGBM_MODE_HH",
}
"""OpenCV's modes by aggregation paths. 3 and 5 work row by row (memory of a few rows of
costs: about 0.1 GB for a 2304 x 2304 tile and 128 disparities); 4 and 8 hold the whole cost
volume (2.5 GB for that tile)."""

FloatArray = NDArray[np.float32]


def _rotation(shape: tuple[int, int], base: tuple[float, float]) -> tuple[NDArray, int, int]:
    """The affine map (2 x 3, OpenCV's ``(x, y)`` order) that turns the image so that the base
    direction ``(d_row, d_col)`` points along +x, and the size of the turned image."""
    import cv2

    rows, cols = shape
    angle = math.degrees(math.atan2(base[0], base[1]))
    m = cv2.getRotationMatrix2D((cols / 2.0, rows / 2.0), angle, 1.0)
    corners = np.array([[0, 0, 1], [cols, 0, 1], [0, rows, 1], [cols, rows, 1]], float)
    turned = corners @ m.T
    lo = np.floor(turned.min(axis=0))
    hi = np.ceil(turned.max(axis=0))
    m[:, 2] -= lo
    width, height = (hi - lo).astype(int)
    return m, int(width), int(height)


def _to_8bit(image: FloatArray, valid: NDArray[np.bool_]) -> FloatArray:
    """The image stretched to 0..255 between its 0.5 and 99.5 percentiles (float32)."""
    values = image[valid]
    if values.size == 0:
        return np.zeros(image.shape, np.float32)
    lo, hi = np.percentile(values, [0.5, 99.5])
    scale = 255.0 / max(float(hi - lo), 1e-12)
    return np.clip((np.where(valid, image, lo) - lo) * scale, 0.0, 255.0).astype(np.float32)


def _refine_along_rows(
    left: FloatArray, right: FloatArray, disparity: FloatArray, found: NDArray, window: int
) -> FloatArray:
    """Sub-pixel disparities: the right image resampled at the integer disparities
    (``right[x - d]``), the NCC of the windows at -1, 0 and +1 pixel along the rows, and the
    vertex of the parabola through them."""
    import cv2

    rows, cols = left.shape
    d0 = np.where(found, np.round(disparity), 0.0).astype(np.float32)
    x_at = np.arange(cols, dtype=np.float32)[None, :] - d0
    yy = np.repeat(np.arange(rows, dtype=np.float32)[:, None], cols, axis=1)
    moments = window_moments(left, window)
    scores = []
    for step in (-1.0, 0.0, 1.0):
        shifted = cv2.remap(right, x_at - step, yy, cv2.INTER_NEAREST, borderValue=0.0)
        scores.append(window_ncc(left, shifted, window, moments)[0])
    lo, mid, hi = scores
    with np.errstate(invalid="ignore", divide="ignore"):
        den = lo - 2.0 * mid + hi
        vertex = np.where(den < 0.0, 0.5 * (lo - hi) / den, 0.0)
        peak = (mid >= lo) & (mid >= hi)
    # NCC's -1..+1 step: a peak at d0 + step where the disparity is d0 + step (sign of x - d)
    return np.where(found & peak, d0 + np.clip(np.nan_to_num(vertex), -0.5, 0.5), disparity)


def _guess_across(
    left: FloatArray, right: FloatArray, settings: DenseSettings, base: tuple[float, float]
) -> tuple[float, float]:
    """The guess with its component across the base measured: the median across-base offset
    of NCC matches (least-squares sub-pixel, left-right check) on a grid of about 16 x 16
    points; the guess as given when fewer than 10 points match. SGM searches along the base
    only, so an offset across it that the caller does not know yet (what a relative
    orientation leaves) is found here."""
    from carto.framework.matching.candidates import grid_points
    from carto.framework.matching.ncc_matcher import NCCMatcher

    g = np.asarray(settings.guess, np.float64)
    along_dir = np.asarray(base, np.float64)
    across_dir = np.array([-along_dir[1], along_dir[0]])
    spacing = max(16.0, min(left.shape) / 16.0)
    points = grid_points(left.shape, spacing, 16)
    if len(points) == 0:
        return settings.guess
    found = NCCMatcher(use_global_shift=False).match_points(
        left,
        right,
        points,
        guess_offsets=g,
        settings=MatchSettings(template_px=15, search_px=3, levels=max(1, settings.levels)),
    )
    if len(found) < 10:
        return settings.guess
    offsets = np.stack(
        [found.right_line - found.left_line, found.right_sample - found.left_sample], axis=1
    )
    across = float(np.median(offsets @ across_dir))
    new = float(g @ along_dir) * along_dir + across * across_dir
    return float(new[0]), float(new[1])


def _checked_pair(left: NDArray, right: NDArray) -> tuple[FloatArray, FloatArray]:
    """The two images as float32, refused unless 2-D, of one shape and at least 8 x 8."""
    a = np.asarray(left, np.float32)
    b = np.asarray(right, np.float32)
    if a.ndim != 2 or a.shape != b.shape or min(a.shape) < 8:
        raise InputError(
            f"matcher sgm: two 2-D images of one shape (at least 8 x 8) are needed, got "
            f"{a.shape} and {b.shape}"
        )
    return a, b


def _disparity_count(left: FloatArray, settings: DenseSettings) -> int:
    """OpenCV's number of disparities (a multiple of 16) covering the search each way along
    the base: the caller's reach ``radius * (2**levels - 1)`` pixels, or the largest of its
    per-pixel bounds ``search_px`` over the left image's data when smaller."""
    s = settings
    reach = s.radius * (2**s.levels - 1)
    if s.search_px is not None:  # the caller's per-pixel bound: no wider than needed
        bound = np.asarray(s.search_px, np.float32)[np.isfinite(left)]
        if bound.size and np.isfinite(bound).all():
            reach = min(reach, max(2, math.ceil(float(bound.max()))))
    return 16 * max(1, math.ceil(2 * reach / 16))


@attrs.frozen
class _TurnedPair:
    """The two images turned so that the base runs along rows (:func:`_turned_pair`).

    Attributes:
        rotation: the affine map (2 x 3, OpenCV's ``(x, y)``) from the image to the turned
            frame (:func:`_rotation`).
        left, right: the turned images (float32, zeros where no data; ``right`` sampled at
            ``p + guess`` before turning).
        left_8bit, right_8bit: the same stretched to 8 bits (:func:`_to_8bit`), SGM's input.
        left_inside, right_inside: pixels whose whole SGM block lies on each image's data.
    """

    rotation: NDArray
    left: FloatArray
    right: FloatArray
    left_8bit: NDArray[np.uint8]
    right_8bit: NDArray[np.uint8]
    left_inside: NDArray[np.bool_]
    right_inside: NDArray[np.bool_]

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the turned frame."""
        rows, cols = self.left.shape
        return rows, cols


def _turned_pair(
    a: FloatArray, b: FloatArray, base: tuple[float, float], guess: tuple[float, float], block: int
) -> _TurnedPair:
    """The right image shifted by ``guess`` (``(d_row, d_col)``, cubic), then both turned
    so that ``base`` runs along rows (cubic; validity masks nearest), stretched to 8 bits and
    their masks eroded by the SGM ``block``."""
    import cv2

    rows, cols = a.shape
    m, width, height = _rotation(a.shape, base)
    g_row, g_col = guess
    # the right image sampled at p + guess, then both turned
    shift = np.array([[1.0, 0.0, -g_col], [0.0, 1.0, -g_row]])
    valid_a, valid_b = np.isfinite(a), np.isfinite(b)
    flags = cv2.INTER_CUBIC
    b_shifted = cv2.warpAffine(np.where(valid_b, b, 0.0), shift, (cols, rows), flags=flags)
    vb_shifted = cv2.warpAffine(
        valid_b.astype(np.uint8), shift, (cols, rows), flags=cv2.INTER_NEAREST
    ).astype(bool)
    turned = [
        cv2.warpAffine(img, m, (width, height), flags=flags)
        for img in (np.where(valid_a, a, 0.0).astype(np.float32), b_shifted)
    ]
    masks = [
        cv2.warpAffine(v.astype(np.uint8), m, (width, height), flags=cv2.INTER_NEAREST) > 0
        for v in (valid_a, vb_shifted)
    ]
    pairs = zip(turned, masks, strict=True)
    eight = [_to_8bit(img, mask).astype(np.uint8) for img, mask in pairs]
    # a block that reaches beyond either image's data (zeros there) matches the edge of
    # the data, not the ground: only blocks wholly inside count
    kernel = np.ones((block, block), np.uint8)
    masks = [cv2.erode(mask.astype(np.uint8), kernel).astype(bool) for mask in masks]
    return _TurnedPair(m, turned[0], turned[1], eight[0], eight[1], masks[0], masks[1])


def _along_on_grid(along: FloatArray, pair: _TurnedPair, shape: tuple[int, int]) -> FloatArray:
    """The offsets along the base (turned frame, NaN where none) kept where the match falls
    inside the right image's data, turned back onto the images' grid of ``shape`` (nearest,
    NaN outside)."""
    import cv2

    height, width = pair.shape
    rows, cols = shape
    # the match must fall inside the right image
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    x_r = xx + np.nan_to_num(along)
    inside = cv2.remap(
        pair.right_inside.astype(np.uint8), x_r, yy, cv2.INTER_NEAREST, borderValue=0
    ).astype(bool)
    along = np.where(inside, along, np.nan)
    back = cv2.invertAffineTransform(pair.rotation)
    return cv2.warpAffine(
        along, back, (cols, rows), flags=cv2.INTER_NEAREST, borderValue=float("nan")
    )


def _scored_field(
    a: FloatArray,
    b: FloatArray,
    t: FloatArray,
    d_row: FloatArray,
    d_col: FloatArray,
    s: DenseSettings,
) -> OffsetField:
    """The offset field of the matches ``(d_row, d_col)`` (``t``: the offset along the base,
    NaN where none), scored by the NCC of the windows at the match, the confidence; flat
    windows, low scores and matches off either image are invalid."""
    import cv2

    rows, cols = a.shape
    valid_a, valid_b = np.isfinite(a), np.isfinite(b)
    # confidence: NCC of the windows at the match
    gy, gx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    warped = cv2.remap(
        np.where(valid_b, b, 0.0).astype(np.float32),
        gx + np.nan_to_num(d_col),
        gy + np.nan_to_num(d_row),
        cv2.INTER_CUBIC,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )
    a_filled = np.where(valid_a, a, float(np.mean(a[valid_a])) if valid_a.any() else 0.0)
    score, std = window_ncc(a_filled.astype(np.float32), warped, s.window)
    lo, hi = np.percentile(a[valid_a], [2, 98]) if valid_a.any() else (0.0, 1.0)
    valid = (
        np.isfinite(t)
        & valid_a
        & np.isfinite(score)
        & (score >= s.min_score)
        & (std > s.min_std * max(float(hi - lo), 1e-12))
    )
    nan = np.float32(np.nan)
    return OffsetField(
        np.where(valid, d_row, nan),
        np.where(valid, d_col, nan),
        np.where(np.isfinite(t), score, nan).astype(np.float32),
        valid,
        np.full(a.shape, nan, np.float32),
    )


class SGMMatcher(Matcher):
    """Semi-global matching along the stereo base (see the module docstring).

    Args:
        block: side of the matching block of OpenCV's SGM, pixels (odd, 3..11).
        paths: aggregation paths: 5 (default) or 3, row by row; 4 or 8 hold the whole
            cost volume in memory (:data:`_MODES`).
        p1, p2: SGM's penalties for a disparity change of one pixel and of more, per pixel
            of the block (multiplied by ``block**2``, as OpenCV's documentation advises).
        uniqueness: OpenCV's uniqueness ratio, percent.
        subpixel: ``"ncc"`` (default) or ``"sgbm"`` (see the module docstring). In one-off
            IOR runs of session 9 without the least-squares steps (#17 notes), ``"ncc"``
            halved the DEM's NMAD on simulated pairs and matched ``"sgbm"`` on Reunion;
            ``carto dem`` refines either by least squares along the base afterwards.
    """

    name = "sgm"
    description = (
        "semi-global matching (OpenCV StereoSGBM) along the stereo base of two ortho-images, "
        "left-right check, NCC confidence; dense (sparse points read from the dense field)"
    )

    def __init__(
        self,
        *,
        block: int = 7,
        paths: int = 5,
        p1: int = 8,
        p2: int = 32,
        uniqueness: int = 5,
        subpixel: str = "ncc",
    ) -> None:
        if isinstance(block, bool) or int(block) != block or not 3 <= block <= 11 or block % 2 == 0:
            raise InputError(f"matcher sgm: block must be an odd integer in 3..11, got {block!r}")
        if paths not in _MODES:
            raise InputError(
                f"matcher sgm: paths must be one of {', '.join(map(str, _MODES))}, got {paths!r}"
            )
        if not 0 < p1 < p2:
            raise InputError(f"matcher sgm: penalties must satisfy 0 < p1 < p2, got {p1}, {p2}")
        self.block, self.paths = int(block), int(paths)
        self.p1, self.p2, self.uniqueness = int(p1), int(p2), int(uniqueness)
        if subpixel not in ("ncc", "sgbm"):
            raise InputError(f"matcher sgm: subpixel must be 'ncc' or 'sgbm', got {subpixel!r}")
        self.subpixel = subpixel

    def match_dense(
        self, left: NDArray, right: NDArray, *, settings: DenseSettings | None = None
    ) -> OffsetField:
        """Offsets along ``settings.base`` (default: along rows) around ``settings.guess``
        for every pixel of ``left``; ``right`` must have the shape of ``left`` (two
        ortho-images of one grid)."""
        s = settings or DenseSettings()
        a, b = _checked_pair(left, right)
        base = s.base if s.base is not None else (0.0, 1.0)
        n_disp = _disparity_count(a, s)
        guess = _guess_across(a, b, s, base)
        pair = _turned_pair(a, b, base, guess, self.block)
        disparity = self._disparity(pair, n_disp, s.consistency_px)
        found = (disparity >= -n_disp // 2) & pair.left_inside
        if self.subpixel == "ncc":
            disparity = _refine_along_rows(pair.left, pair.right, disparity, found, s.window)
        # OpenCV: left x matches right x - d; our offset right - left along the base is -d
        along = np.where(found, -disparity, np.nan).astype(np.float32)
        t = _along_on_grid(along, pair, a.shape)
        d_row = (t * base[0] + guess[0]).astype(np.float32)
        d_col = (t * base[1] + guess[1]).astype(np.float32)
        return _scored_field(a, b, t, d_row, d_col, s)

    def _disparity(self, pair: _TurnedPair, n_disp: int, consistency_px: float) -> FloatArray:
        """OpenCV's SGM disparities (pixels, float32) of the turned pair, with this matcher's
        block, penalties, paths and uniqueness and the caller's left-right tolerance."""
        import cv2

        sgbm = cv2.StereoSGBM_create(
            minDisparity=-n_disp // 2,
            numDisparities=n_disp,
            blockSize=self.block,
            P1=self.p1 * self.block**2,
            P2=self.p2 * self.block**2,
            disp12MaxDiff=max(1, round(consistency_px)),
            uniquenessRatio=self.uniqueness,
            speckleWindowSize=0,
            mode=getattr(cv2, _MODES[self.paths]),
        )
        return sgbm.compute(pair.left_8bit, pair.right_8bit).astype(np.float32) / 16.0

    def match_points(
        self,
        left: NDArray,
        right: NDArray,
        points: ArrayLike,
        *,
        guess_offsets: ArrayLike | None = None,
        settings: MatchSettings | None = None,
    ) -> Matches:
        """Points read from the dense field of the two images (nearest pixel), for nearly
        co-registered images of one shape; a constant ``guess_offsets`` is the search
        centre."""
        s = settings or MatchSettings()
        pts = np.asarray(points, np.float64).reshape(-1, 2)
        guess = (0.0, 0.0)
        if guess_offsets is not None:
            g = np.asarray(guess_offsets, np.float64).reshape(-1, 2)
            guess = (float(np.median(g[:, 0])), float(np.median(g[:, 1])))
        field = self.match_dense(
            left,
            right,
            settings=DenseSettings(
                levels=s.levels,
                window=s.template_px,
                radius=max(1, math.ceil(s.search_px / max(2**s.levels - 1, 1))),
                min_score=s.min_score,
                guess=guess,
            ),
        )
        r = np.clip(np.floor(pts[:, 0]).astype(int), 0, field.valid.shape[0] - 1)
        c = np.clip(np.floor(pts[:, 1]).astype(int), 0, field.valid.shape[1] - 1)
        ok = field.valid[r, c]
        return Matches(
            pts[ok, 0],
            pts[ok, 1],
            pts[ok, 0] + field.d_row[r[ok], c[ok]],
            pts[ok, 1] + field.d_col[r[ok], c[ok]],
            field.score[r[ok], c[ok]],
        )
