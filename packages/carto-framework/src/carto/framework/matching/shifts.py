"""Global translations between two images: first guesses for the point matchers.

* :func:`global_shift`: phase correlation for a first guess of a global translation.
* :func:`coarse_shift`: a translation as large as the images between partially overlapping
  ones with NaN borders (correlation over the shared valid pixels for every shift,
  :func:`masked_ncc`, on reduced images).

Shifts are ``right - left`` in pixels, ``(d_line, d_sample)``: the content at ``p`` in the left
image is at ``p + d`` in the right one (the offsets of :mod:`~carto.framework.matching.ncc`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.matching.inputs import as_image, check_int
from carto.framework.matching.ncc import subpixel_peak


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

    a = as_image(left, "left").astype(np.float64)
    b = as_image(right, "right").astype(np.float64)
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
    first guess for :func:`~carto.framework.matching.pyramid.pyramid_match`, whose reach (77 px
    with its defaults) covers that.

    Returns:
        ``(d_line, d_sample, score)``: the shift, pixels, and its correlation coefficient
        (``(0, 0, 0)`` when the images share no valid area of the required size).

    Raises:
        InputError: malformed images or options.
    """
    a, b = as_image(left, "left"), as_image(right, "right")
    size = check_int(size, "size", 16)
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
        peak += subpixel_peak(block[None], "parabola")[0]
    d = (peak - np.array([ra.shape[0] - 1, ra.shape[1] - 1])) * factor
    # block means of f x f pixels: the centre of block k is at f k + f / 2 in both images
    return float(d[0]), float(d[1]), best
