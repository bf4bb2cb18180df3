"""How precise a dense match is, and the least-squares step that makes it as precise as it can
be, from the two images themselves, whatever matcher found the offsets.

**The bound.** A window of the left image ``f = s + n_1`` and its match in the right image
``g = s + n_2`` (the same signal ``s``, independent noise of variance ``sigma_n^2`` each)
correlate with ``rho = var(s) / (var(s) + sigma_n^2)``, so ``sigma_n^2 = var(f) (1 - rho)``.
A least-squares shift of the window along a direction ``u`` is then known to (Förstner 1982;
the Cramér-Rao bound of image registration)

    ``sigma_d^2 = 2 sigma_n^2 / sum_window (grad s . u - mean)^2``

pixels squared (the signal's gradient: the left image's, less the noise's expected share;
about its window mean, since a match free in brightness learns nothing from the mean slope):
little texture along the base or a poor correlation, a loose match (:func:`offset_sigma_px`).

**The step.** :func:`refine_along_base` takes that least-squares step (Gauss-Newton, with a
brightness offset and gain) from any matcher's offsets. Each window is resampled at one
offset, its pixels' mean (:func:`window_offsets`): warping each pixel by its own offset
would mix the neighbours' noise into every window. Resampling is Lanczos (8 x 8): OpenCV's
cubic kernel alone moves a fine texture by hundredths of a pixel.

Real matches fall short of the bound (resampling, image differences that are not white
noise); :mod:`carto.ior.height_precision` measures by how much, across the base.
"""

from __future__ import annotations

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.matching.base import OffsetField

__all__ = [
    "box_mean",
    "levels_for_reach",
    "limit_along_base",
    "offset_sigma_px",
    "refine_along_base",
    "resample_at_offsets",
    "window_moments",
    "window_ncc",
    "window_offsets",
]

FloatArray = NDArray[np.float32]


def box_mean(image: NDArray, window: int, normalize: bool = True) -> FloatArray:
    """The mean (or with ``normalize`` False the sum) of each pixel's ``window`` x ``window``
    neighbourhood, float32, the edges reflected: OpenCV's separable filter, a third faster
    than its box filter."""
    import cv2

    weight = 1.0 / window if normalize else 1.0
    kernel = np.full(window, weight, np.float32)
    return cv2.sepFilter2D(image, cv2.CV_32F, kernel, kernel)


def window_moments(image: FloatArray, window: int) -> tuple[FloatArray, FloatArray]:
    """The mean and the variance (never below 0) of each pixel's ``window`` x ``window``
    neighbourhood (no NaN)."""
    mean = box_mean(image, window)
    return mean, np.maximum(box_mean(image * image, window) - mean * mean, 0.0)


def window_ncc(
    left: FloatArray,
    right_at_match: FloatArray,
    window: int,
    left_moments: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The normalised cross-correlation of each pixel's ``window`` x ``window`` neighbourhood in
    ``left`` and in ``right_at_match`` (the right image already resampled at the matches; no
    NaN), and the left window's standard deviation. ``left_moments``: the left's
    :func:`window_moments`, when several right images are scored against one left."""
    mean_l, var_l = left_moments if left_moments is not None else window_moments(left, window)
    mean_r, var_r = window_moments(right_at_match, window)
    with np.errstate(invalid="ignore", divide="ignore"):
        ncc = (box_mean(left * right_at_match, window) - mean_l * mean_r) / np.sqrt(var_l * var_r)
    return ncc.astype(np.float32), np.sqrt(var_l).astype(np.float32)


def resample_at_offsets(image: NDArray, d_row: NDArray, d_col: NDArray) -> FloatArray:
    """``image[row + d_row, col + d_col]`` (Lanczos; NaN outside the image, at a NaN of the
    image or where the offset is NaN)."""
    import cv2

    rows, cols = np.asarray(d_row).shape
    src = np.asarray(image, np.float32)
    hole = ~np.isfinite(src)
    map_c = np.add(np.asarray(d_col, np.float32), np.arange(cols, dtype=np.float32)[None, :])
    map_r = np.add(np.asarray(d_row, np.float32), np.arange(rows, dtype=np.float32)[:, None])
    with np.errstate(invalid="ignore"):
        outside = ~((map_c >= 0) & (map_c <= cols - 1) & (map_r >= 0) & (map_r <= rows - 1))
    map_c[outside] = 0.0
    map_r[outside] = 0.0
    any_hole = bool(hole.any())
    out = cv2.remap(
        np.where(hole, np.float32(0.0), src) if any_hole else src,
        map_c,
        map_r,
        cv2.INTER_LANCZOS4,
        borderMode=cv2.BORDER_REPLICATE,
    )
    out[outside] = np.nan
    if any_hole:
        reach = cv2.remap(
            hole.astype(np.float32),
            map_c,
            map_r,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        out[reach > 0] = np.nan
    return out


def offset_sigma_px(
    left: NDArray, right: NDArray, field: OffsetField, window: int, base: tuple[float, float]
) -> FloatArray:
    """The predicted standard deviation, pixels, of each valid match's offset along ``base``
    (a unit ``(d_row, d_col)``): see the module docstring. ``left``, ``right``: the two
    images (NaN: no data); ``field``: each left pixel's offset to its match in ``right``.
    NaN where the match is not valid, the window has no data or no texture along the
    base."""
    f = np.asarray(left, np.float32)
    ok = _usable(field)
    g = resample_at_offsets(right, *window_offsets(field.d_row, field.d_col, ok, window))
    hole = ~(np.isfinite(f) & np.isfinite(g))
    f0 = np.where(hole, 0.0, f).astype(np.float32)
    g0 = np.where(hole, 0.0, g).astype(np.float32)
    rho, std = window_ncc(f0, g0, window)
    grad_r, grad_c = np.gradient(f0)
    along = (grad_r * np.float32(base[0]) + grad_c * np.float32(base[1])).astype(np.float32)
    # the window's gradient energy about its mean: a match that is free in brightness
    # learns nothing from the mean slope
    mean_along = box_mean(along, window)
    energy = (box_mean(along * along, window) - mean_along * mean_along) * np.float32(
        window * window
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        noise = std * std * np.clip(1.0 - rho, 0.0, 1.0)
        # the noise's own share of the gradient energy (a central difference passes half
        # its variance) is no texture
        energy = energy - np.float32(0.5 * window * window) * noise
        sigma = np.sqrt(2.0 * noise / energy).astype(np.float32)
    touched = box_mean(hole.astype(np.float32), window) > 0  # a window with no data
    sigma[touched | ~ok | ~(energy > 0)] = np.nan
    return sigma


def window_offsets(
    d_row: NDArray, d_col: NDArray, ok: NDArray[np.bool_], window: int
) -> tuple[FloatArray, FloatArray]:
    """The offsets at which each pixel's window is resampled: the mean offset of the valid
    (``ok``) pixels of its ``window`` x ``window`` neighbourhood (warping every pixel by its own
    offset would mix the neighbours' noise into the window; NaN where no pixel is valid)."""
    ok = np.asarray(ok, bool)
    support = box_mean(ok.astype(np.float32), window)
    zero = np.float32(0.0)
    has = support > 0
    out = []
    for d in (d_row, d_col):
        total = box_mean(np.where(ok, np.asarray(d, np.float32), zero), window)
        mean = np.full(total.shape, np.nan, np.float32)
        np.divide(total, support, out=mean, where=has)
        out.append(mean)
    return out[0], out[1]


def refine_along_base(
    left: NDArray,
    right: NDArray,
    field: OffsetField,
    window: int,
    base: tuple[float, float],
    iterations: int = 2,
    max_step_px: float = 0.5,
) -> OffsetField:
    """Least-squares sub-pixel refinement of dense offsets along ``base``: each valid
    pixel's offset moves by the Gauss-Newton step of its ``window`` x ``window`` match,
    ``sum (g - mean g)(e - mean e) / sum (g - mean g)^2`` with ``e`` the left window less the
    right one resampled at the match (brought to the left's mean and contrast) and ``g`` the
    gradient of the resampled right window along the base; ``iterations`` steps, each at most
    ``max_step_px``. This is the estimator whose precision :func:`offset_sigma_px` bounds;
    a parabola through three correlation scores is far from it. Returns ``field`` with the
    new offsets (invalid pixels keep theirs)."""
    f = np.asarray(left, np.float32)
    u_r, u_c = np.float32(base[0]), np.float32(base[1])
    out_r = np.array(field.d_row, np.float32)
    out_c = np.array(field.d_col, np.float32)
    ok = _usable(field)
    f_hole = ~np.isfinite(f)
    zero = np.float32(0.0)
    f0 = np.where(f_hole, zero, f)
    mean_f = box_mean(f0, window)
    std_f = np.sqrt(np.maximum(box_mean(f0 * f0, window) - mean_f * mean_f, zero))
    for _ in range(max(0, int(iterations))):
        # each window is resampled at one offset along the base: its valid pixels' mean
        # (warping by every pixel's own offset would mix the neighbours' noise in)
        mean_r, mean_c = window_offsets(out_r, out_c, ok, window)
        shift = np.where(ok, (mean_r - out_r) * u_r + (mean_c - out_c) * u_c, zero)
        at_r, at_c = out_r + shift * u_r, out_c + shift * u_c
        g = resample_at_offsets(right, at_r, at_c)
        hole = f_hole | ~np.isfinite(g)
        g0 = np.where(hole, zero, g)
        mean_g = box_mean(g0, window)
        std_g = np.sqrt(np.maximum(box_mean(g0 * g0, window) - mean_g * mean_g, zero))
        gain = np.zeros(std_g.shape, np.float32)
        np.divide(std_f, std_g, out=gain, where=std_g > 0)
        grad_r, grad_c = np.gradient(g0)
        slope = grad_r * u_r + grad_c * u_c
        # window means of the centred products
        mean_s = box_mean(slope, window)
        cov = box_mean(slope * g0, window) - mean_s * mean_g
        cov_f = box_mean(slope * f0, window) - mean_s * mean_f
        var_s = box_mean(slope * slope, window) - mean_s * mean_s
        with np.errstate(invalid="ignore", divide="ignore"):
            # f ~ a + gain g(p + step u): step = cov(s, f - gain g) / (gain var(s))
            step = (cov_f - gain * cov) / (gain * var_s)
        touched = box_mean(hole.astype(np.float32), window) > 0
        move = ok & ~touched & np.isfinite(step) & (var_s > 0)
        step = np.clip(np.where(move, step, zero), -max_step_px, max_step_px)
        out_r = np.where(move, at_r + step * u_r, out_r)
        out_c = np.where(move, at_c + step * u_c, out_c)
    return attrs.evolve(field, d_row=out_r, d_col=out_c)


def _usable(field: OffsetField) -> NDArray[np.bool_]:
    return np.asarray(field.valid, bool) & np.isfinite(field.d_row) & np.isfinite(field.d_col)


def levels_for_reach(reach_px: float, radius: int = 2) -> int:
    """The fewest pyramid levels whose reach ``radius * (2**levels - 1)`` is at least
    ``reach_px`` (at least 1)."""
    if not np.isfinite(reach_px) or reach_px <= radius:
        return 1 if np.isfinite(reach_px) else 12
    return int(np.ceil(np.log2(reach_px / radius + 1.0)))


def limit_along_base(
    field: OffsetField,
    search_px: NDArray,
    guess: tuple[float, float],
    direction: tuple[float, float],
) -> OffsetField:
    """``field`` without the matches whose offset along ``direction`` (unit ``(d_row,
    d_col)``) from ``guess`` exceeds the pixel's bound ``search_px`` (inf: no bound): a
    per-pixel search range enforced for any matcher, whatever its own search."""
    along = (field.d_row - np.float32(guess[0])) * np.float32(direction[0])
    along = along + (field.d_col - np.float32(guess[1])) * np.float32(direction[1])
    with np.errstate(invalid="ignore"):
        beyond = np.abs(along) > np.asarray(search_px, np.float32)
    if not beyond.any():
        return field
    nan = np.float32(np.nan)
    return attrs.evolve(
        field,
        d_row=np.where(beyond, nan, field.d_row),
        d_col=np.where(beyond, nan, field.d_col),
        valid=field.valid & ~beyond,
    )
