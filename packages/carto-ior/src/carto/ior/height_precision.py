"""The predicted standard deviation of each DEM node's height: the matching precision of its
ortho pixels (:func:`carto.framework.matching.precision.offset_sigma_px`) turned into metres by
the local base-to-height ratio, and carried through the regularised updates that made the DEM.

**A node's measurement.** A pixel's offset along the base, ``sigma_d`` pixels, is a height
error of ``sigma_d res / (B/H)`` metres (``res``: ortho pixel size; ``B/H``: the length of
``t_L - t_R``, :mod:`carto.ior.rays`). The ``k x k`` pixels of a node match overlapping
``w x w`` windows, so their errors are nearly one error: together they are a match of the
``(w + k - 1)``-pixel window that spans them, whose bound is the pixels' (median) bound times
``w / (w + k - 1)``.

**The DEM.** The DEM a run delivers went through ``m`` regularised updates
(:func:`carto.ior.regularise.regularise`): ``H_{i+1} = H_i + G * (N - H_i)`` with ``G`` the
normalised Gaussian of ``smoothing_nodes`` and ``N`` the measured heights. With the same
measurement error ``e`` in every iteration (the images do not change), the DEM's error is
``K_m * e`` with ``K_m = 1 - (1 - G)^m``: ``m = 1`` smooths by ``G``, many updates pass ``e``
through. Neighbouring nodes' errors correlate as their windows overlap (``1 - d k / (w + k -
1)`` per axis at a distance of ``d`` nodes), so the variance shrinks by
``F = sum_ij K_i K_j corr(i - j)`` (:func:`smoothing_variance_factor`).

Not included: the orientation's error (one offset for the whole DEM, in the adjustment's
report), the DEM's interpolation of relief finer than the posting, and a matcher's bias.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from carto.framework.sdk.matchers import OffsetField

__all__ = [
    "matching_efficiency",
    "node_sigma_m",
    "smoothing_variance_factor",
    "window_span_factor",
]


def window_span_factor(window: int, k: int) -> float:
    """``w / (w + k - 1)``: the bound of a node's ``k x k`` overlapping window matches
    against one pixel's."""
    return float(window) / float(window + k - 1)


def smoothing_variance_factor(smoothing_nodes: float, updates: int, window: int, k: int) -> float:
    """``F`` of the module docstring: the share of a node's measurement variance that ``updates``
    regularised updates with a Gaussian of ``smoothing_nodes`` leave in the DEM, for node
    errors correlated over windows of ``window`` ortho pixels (``k`` per node). 0 for no
    update (the DEM is the starting surface: its error is not the matching's).

    Computed on a periodic grid in the frequency domain: ``K^ = 1 - (1 - G^)^m`` and
    ``F = mean(|K^|^2 corr^)``, the grid wide enough for the kernel and the correlation."""
    if updates <= 0:
        return 0.0
    sigma = float(smoothing_nodes)
    span = (window + k - 1) / float(k)  # correlation length, nodes
    reach = 4.0 * sigma * np.sqrt(float(updates)) + 4.0 * sigma + span
    n = int(2 ** np.ceil(np.log2(max(64.0, 4.0 * reach))))
    impulse = np.zeros((n, n))
    impulse[0, 0] = 1.0
    g_hat = np.fft.fft2(ndimage.gaussian_filter(impulse, sigma, mode="wrap"))
    k_hat = 1.0 - (1.0 - g_hat) ** int(updates)
    d = np.minimum(np.arange(n), n - np.arange(n))  # periodic distance, nodes
    corr_1d = np.clip(1.0 - d / span, 0.0, None)
    corr_hat = np.fft.fft2(np.outer(corr_1d, corr_1d)).real
    return float(np.mean(np.abs(k_hat) ** 2 * corr_hat))


def node_sigma_m(
    left: NDArray,
    right: NDArray,
    field: OffsetField,
    window: int,
    base: tuple[float, float],
    k: int,
    res_m: float,
    b_over_h: NDArray,
    variance_factor: float,
) -> tuple[NDArray[np.float32], float]:
    """Per node of a tile (``k x k`` ortho pixels; rows and columns multiples of ``k``): the
    predicted height standard deviation of the DEM, metres (module docstring), and the
    tile's matching efficiency (NaN: too few nodes to measure it; the bound is used as it
    is). ``left``, ``right``: the ortho-images; ``field``: the offsets;
    ``base``: the unit base ``(d_row, d_col)``; ``b_over_h``: per node."""
    from carto.framework.sdk.matchers import offset_sigma_px, refine_along_base
    from carto.ior.node_heights import block_quantiles

    span = window_span_factor(window, k)
    pixel_px = offset_sigma_px(left, right, field, window, base)
    _, (bound_px,) = block_quantiles(np.asarray(pixel_px, np.float64), k, (0.5,))
    bound_px = bound_px * span
    # the in-situ check: offsets across the base hold no height, only matching noise
    across = (-float(base[1]), float(base[0]))
    moved = refine_along_base(left, right, field, window, across, iterations=1)
    noise = np.where(field.valid, moved.d_row * across[0] + moved.d_col * across[1], np.nan)
    _, (node_noise,) = block_quantiles(np.asarray(noise, np.float64), k, (0.5,))
    efficiency = matching_efficiency(node_noise, bound_px)
    scale = efficiency if np.isfinite(efficiency) else 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        height_m = (
            scale
            * bound_px
            * float(res_m)
            / np.asarray(b_over_h, np.float64)
            * np.sqrt(variance_factor)
        )
    return height_m.astype(np.float32), efficiency


MIN_EFFICIENCY_NODES = 50
"""Fewest nodes with an across-base offset and a bound to measure a tile's efficiency."""


def matching_efficiency(across_px: NDArray, bound_px: NDArray) -> float:
    """How far the matching is from its bound, measured where no height can hide it: the
    NMAD of the nodes' offsets across the base (about their median: a relative orientation
    error is one offset) over the median of the nodes' bounds. NaN with fewer than
    :data:`MIN_EFFICIENCY_NODES` nodes."""
    ok = np.isfinite(across_px) & np.isfinite(bound_px) & (bound_px > 0)
    if int(ok.sum()) < MIN_EFFICIENCY_NODES:
        return float("nan")
    x = across_px[ok]
    nmad = 1.4826 * float(np.median(np.abs(x - np.median(x))))
    return nmad / float(np.median(bound_px[ok]))
