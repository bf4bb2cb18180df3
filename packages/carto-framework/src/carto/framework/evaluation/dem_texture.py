"""How much relief detail a DEM holds, how much of it is noise, and whether it has stripes:
the measures that compare a DEM with a coarser one when no reference is finer than both
(e.g. a 1 m DEM against SRTM).

The heights are split into bands by Gaussian filters (normalised over the nodes that have a
height, :func:`smooth`):

* **detail** band: ``G(fine) - G(coarse)`` (``fine``, ``coarse``: the Gaussians' sigmas in
  metres), the relief between a few postings and the scale a coarse DEM resolves. A DEM
  resampled from SRTM (3", about 90 m) has almost none there.
* **finest** band: ``h - G(one node)``, from node to node. Natural relief has a steep
  spectrum (power falling as a power of the wavenumber), so almost nothing of it is left at
  one node, while independent per-node noise keeps its full variance there. All of the
  finest band is counted as noise: :attr:`DEMTexture.noise_m` is an **upper bound** of the
  per-node noise (steep breaks add to it), and the detail band's relief with that noise's
  share removed (:attr:`DEMTexture.relief_m`) a **lower bound**. The noise's share of each
  band is the sum of the squared taps of the band's filter (what white noise of unit
  variance becomes, :func:`white_noise_gain`).
* **stripes**: the median of the finest band along each grid row (and each column).
  Without a pattern aligned with the grid, row and column medians are alike; stripes along
  the rows make the row medians larger (a feature that crosses part of a row moves its
  median little). :attr:`DEMTexture.stripe_ratio` is the ratio of the two RMS (rows over
  columns), each median scaled by the square root of its count so that lines of any length
  weigh alike.

Independent checks (``tests/framework/evaluation/test_dem_texture.py``): the band of a
sinusoid against the Gaussians' analytic transfer ``exp(-2 pi^2 sigma^2 / lambda^2)``, the
noise of white noise of known variance, a sinusoid plus noise separated into both, and
stripes of known size.
"""

from __future__ import annotations

import math
import warnings

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError

__all__ = ["DEMTexture", "dem_texture", "smooth", "white_noise_gain"]

FloatArray = NDArray[np.float64]

MIN_NODES = 256
"""Fewest nodes with a height for figures worth reporting."""


def smooth(heights: ArrayLike, sigma_nodes: float) -> FloatArray:
    """Gaussian of ``sigma_nodes`` normalised over the finite nodes (NaN stays NaN); the
    edges reflect."""
    from scipy.ndimage import gaussian_filter

    h = np.asarray(heights, np.float64)
    ok = np.isfinite(h)
    if sigma_nodes <= 0.0:
        return h.copy()
    num = gaussian_filter(np.where(ok, h, 0.0), sigma_nodes, mode="reflect", truncate=4.0)
    den = gaussian_filter(ok.astype(np.float64), sigma_nodes, mode="reflect", truncate=4.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok & (den > 1e-6), num / den, np.nan)


def white_noise_gain(fine_nodes: float, coarse_nodes: float | None) -> float:
    """Variance that unit white noise keeps in the band ``G(fine) - G(coarse)``
    (``coarse=None``: ``identity - G(fine)``): the sum of the squared taps of the band's
    2-D filter."""
    n = 2 * math.ceil(4.0 * max(fine_nodes, coarse_nodes or 0.0)) + 3
    impulse = np.zeros((n, n))
    impulse[n // 2, n // 2] = 1.0
    lo = smooth(impulse, fine_nodes)
    taps = impulse - lo if coarse_nodes is None else lo - smooth(impulse, coarse_nodes)
    return float(np.sum(taps**2))


@attrs.frozen
class DEMTexture:
    """Relief detail, noise and stripes of a DEM (see the module docstring).

    Attributes:
        detail_m: RMS of the detail band (relief and noise), metres.
        noise_m: upper bound of the per-node noise, metres (all of the finest band).
        relief_m: the detail band without the noise's share (``sqrt(detail^2 - gain
            noise^2)``, at least 0): a lower bound of the relief detail, metres.
        stripe_ratio: RMS of the finest band's row medians over that of its column medians
            (about 1 without stripes; above 1: stripes along rows; below 1: along columns).
        band_m: the detail band's Gaussian sigmas ``(fine, coarse)``, metres.
        nodes: nodes with a height.
    """

    detail_m: float
    noise_m: float
    relief_m: float
    stripe_ratio: float
    band_m: tuple[float, float]
    nodes: int

    def as_dict(self) -> dict[str, float | int | list[float]]:
        return {
            "detail_m": round(self.detail_m, 4),
            "noise_m": round(self.noise_m, 4),
            "relief_m": round(self.relief_m, 4),
            "stripe_ratio": round(self.stripe_ratio, 3),
            "band_m": list(self.band_m),
            "nodes": self.nodes,
        }


def _rms(values: FloatArray) -> float:
    v = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _line_rms(values: FloatArray, use: NDArray[np.bool_], axis: int) -> float:
    """RMS over the lines (rows for ``axis=1``) of each line's median times the square root
    of its count: white noise gives the same figure whatever the line lengths, and a
    feature that crosses part of a line moves its median little (a stripe moves all of it)."""
    v = np.where(use, values, np.nan)
    n = use.sum(axis=axis)
    keep = n >= 8
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(v, axis=axis)
    z = med[keep] * np.sqrt(n[keep])
    return float(np.sqrt(np.mean(z**2))) if z.size else float("nan")


def dem_texture(
    heights: ArrayLike, posting_m: float, *, band_m: tuple[float, float] = (2.0, 10.0)
) -> DEMTexture:
    """The texture of a DEM grid of ``posting_m`` (square nodes). ``band_m``: the detail
    band's sigmas, metres (each at least one node; the coarse one above the fine one).

    Raises:
        InputError: not a 2-D grid of at least 8 x 8 nodes with a height at :data:`MIN_NODES`, a
            posting that is not a positive number, a band that is not ``fine < coarse``.
    """
    h = np.asarray(heights, np.float64)
    if not (isinstance(posting_m, int | float) and math.isfinite(posting_m) and posting_m > 0):
        raise InputError(
            f"dem texture: posting must be a positive number of metres, got {posting_m!r}"
        )
    fine_m, coarse_m = (float(b) for b in band_m)
    if not 0.0 < fine_m < coarse_m:
        raise InputError(
            f"dem texture: band must be (fine, coarse) with 0 < fine < coarse, got {band_m}"
        )
    if h.ndim != 2 or min(h.shape) < 8:
        raise InputError(
            f"dem texture: a 2-D grid of at least 8 x 8 nodes is needed, got {h.shape}"
        )
    ok = np.isfinite(h)
    if ok.sum() < MIN_NODES:
        raise InputError(
            f"dem texture: only {ok.sum()} of {h.size} nodes have a height (at least "
            f"{MIN_NODES} needed)"
        )
    fine, coarse = max(fine_m / posting_m, 1.0), max(coarse_m / posting_m, 2.0)
    if coarse <= fine:
        coarse = 2.0 * fine
    finest = h - smooth(h, 1.0)
    detail = smooth(h, fine) - smooth(h, coarse)
    # away from the edges of the data, where the normalised filters see one side only
    from scipy.ndimage import binary_erosion

    inner = binary_erosion(ok, iterations=math.ceil(2.0 * coarse), border_value=0)
    if inner.sum() < 64:
        inner = ok
    # the finest band's Gaussian reaches 4 nodes: nearer the edge of the data it sees one
    # side only (a bias along a straight edge would look like a stripe)
    near = binary_erosion(ok, iterations=4, border_value=0)
    noise = _rms(finest[near]) / math.sqrt(white_noise_gain(1.0, None))
    detail_rms = _rms(detail[inner])
    relief = math.sqrt(max(0.0, detail_rms**2 - white_noise_gain(fine, coarse) * noise**2))
    stripe = _line_rms(finest, near, 1) / max(_line_rms(finest, near, 0), 1e-12)
    return DEMTexture(
        detail_rms, noise, relief, stripe, (fine * posting_m, coarse * posting_m), int(ok.sum())
    )
