"""How much more the starting DEM's errors move a line's mean of the tie points along the
base than independent errors would: :attr:`~carto.framework.adjustment.pair_observations.
Noise.band_factor`, which weighs the DEM rows of a pair's relative orientation
(:mod:`carto.framework.adjustment.pair_correction`).

An SRTM-like DEM's errors are correlated over hundreds of metres (its 90 m posts and their
interpolation), so averaging a line's points removes less of them than their number says.
Two measures, each against what the rows' own sigmas predict for independent errors
(:attr:`~carto.framework.adjustment.pair_correction.RelativeOrientationSettings.band_factor`
chooses):

* :func:`binned_band_factor` (the default, and always for a shift): the spread of the
  residuals' means over :data:`BAND_LINES` lines, each less the mean of its
  :data:`BAND_NEIGHBOURS` neighbours;
* :func:`spectral_band_factor`, for a line-varying correction, whose along-base terms in the
  least squares are jitter sinusoids: the power of the residuals' line means at the jitter
  band's frequencies. The binned measure takes the jitter and slow wander that the fit does
  not model (yet) for the DEM's correlated error, and the DEM rows then weigh too little to
  find them: on a simulated full-swath Cartosat-1 pair (12 000 x 2000 px, ``--errors
  full``, 1 GCP) it gave 40 where the spectral one gave 8.7. But one factor for the whole
  band is the median of its probes, mostly its upper part, where an SRTM-like DEM's
  interpolated errors are weakest: on a 1000 px swath it gave 1 (binned: 33) and the
  platform jitter's pitch took the DEM's errors at 7 Hz (0.73 urad against 0.21).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.pair_observations import Noise, Observations

FloatArray = NDArray[np.float64]

__all__ = ["band_factor", "binned_band_factor", "spectral_band_factor"]

BAND_LINES = 64.0
"""Bins of this many lines measure the DEM's correlated share (:func:`binned_band_factor`)."""
BAND_NEIGHBOURS = 5
"""Each bin's mean is compared with the mean of this many bins around it."""
SPECTRAL_BIN_LINES = 2.0
"""Lines per bin of :func:`spectral_band_factor`'s line means."""
PROBE_CYCLES_PER_LINE = (0.002, 0.04)
"""The jitter band the probes cover, cycles per line (Cartosat-1's 2976 lines per second:
6-120 Hz, where simulated and reported jitter lies; slower motion is the spline's)."""
MIN_PROBES = 8
"""Fewer independent probe frequencies than this (a short image): the binned measure."""
MIN_BIN_POINTS = 5
"""A bin's mean needs this many DEM rows."""


def band_factor(obs: Observations, along_px: FloatArray, noise: Noise, spectral: bool) -> float:
    """:attr:`Noise.band_factor` of ``obs``'s DEM rows from their along-base residuals
    ``along_px`` (all rows'): :func:`spectral_band_factor` for a line-varying correction
    (``spectral``) where the image is long enough, else :func:`binned_band_factor`."""
    rows = obs.dem_rows
    if rows.sum() < 10:
        return 1.0
    s_along, _ = obs.subset(rows).sigmas(noise, banded=False)
    if spectral:
        value = spectral_band_factor(obs.line[rows], along_px[rows], s_along)
        if value is not None:
            return value
    return binned_band_factor(obs.line[rows], along_px[rows], s_along)


def binned_band_factor(line: FloatArray, along_px: FloatArray, sigma_px: FloatArray) -> float:
    """The spread of the means of ``along_px`` over :data:`BAND_LINES` lines, each less the
    mean of its :data:`BAND_NEIGHBOURS` neighbours (slow motion the model leaves along the
    base is not the DEM's), against what independent rows of sigmas ``sigma_px`` would
    give (at least 1)."""
    k = np.floor(line / BAND_LINES).astype(np.int64)
    k -= k.min()
    count = np.bincount(k)
    full = count >= MIN_BIN_POINTS
    if full.sum() < 2 * BAND_NEIGHBOURS:
        return 1.0
    mean = (np.bincount(k, weights=along_px) / np.maximum(count, 1))[full]
    predicted = (np.bincount(k, weights=sigma_px**2) / np.maximum(count, 1) ** 2)[full]
    window = np.ones(BAND_NEIGHBOURS) / BAND_NEIGHBOURS
    detail = (mean - np.convolve(mean, window, mode="same"))[BAND_NEIGHBOURS:-BAND_NEIGHBOURS]
    if detail.size < 4:
        return 1.0
    # a point less its window's mean keeps (1 - 1/n) of an independent variance
    spread = 1.4826 * np.median(np.abs(detail - np.median(detail)))
    independent = (1.0 - 1.0 / BAND_NEIGHBOURS) * np.median(predicted)
    return max(1.0, float(spread**2 / independent))


def spectral_band_factor(
    line: FloatArray, along_px: FloatArray, sigma_px: FloatArray
) -> float | None:
    """The DEM rows' correlated share in the jitter band (at least 1), or None where the
    image is too short for :data:`MIN_PROBES` probes.

    ``along_px`` is averaged over bins of :data:`SPECTRAL_BIN_LINES` lines, each with the
    sigma independent rows of sigmas ``sigma_px`` would give it. At each probe frequency
    (every ``1 / span`` cycles per line over :data:`PROBE_CYCLES_PER_LINE`: independent
    frequencies), the weighted Lomb-Scargle power of the bin means (astropy, ``psd``
    normalisation: half the chi-square a sinusoid takes out) is, where only noise is, the
    factor times a chi-square of two degrees of freedom over two, whose median is ``ln 2``.
    The median over the probes is taken: a few frequencies where jitter the fit does not
    model stands out do not move it. Slower motion (wander the along-base shape takes after
    the fit) is taken out first (:func:`_less_slow`): its leakage would pass for noise at the
    lowest probes."""
    from astropy.timeseries import LombScargle  # here: not at every command's start

    k = np.floor((line - line.min()) / SPECTRAL_BIN_LINES).astype(np.int64)
    count = np.bincount(k)
    full = count >= MIN_BIN_POINTS
    centres = (np.flatnonzero(full) + 0.5) * SPECTRAL_BIN_LINES
    span = float(np.ptp(centres)) if centres.size else 0.0
    if not span > 0:
        return None
    low, high = PROBE_CYCLES_PER_LINE
    probes = np.arange(max(low, 2.0 / span), high, 1.0 / span)
    if probes.size < MIN_PROBES:
        return None
    mean = (np.bincount(k, weights=along_px) / np.maximum(count, 1))[full]
    variance = (np.bincount(k, weights=sigma_px**2) / np.maximum(count, 1) ** 2)[full]
    mean = _less_slow(centres, mean, 1.0 / low)
    power = LombScargle(centres, mean, np.sqrt(variance)).power(probes, normalization="psd")
    return max(1.0, float(np.median(power) / math.log(2.0)))


def _less_slow(centres: FloatArray, mean: FloatArray, window_lines: float) -> FloatArray:
    """``mean`` less its means over windows of ``window_lines`` lines, interpolated
    linearly between the windows' centres: a high-pass that keeps the periods shorter than
    the window (a window's mean of such a sinusoid is at most a fifth of it)."""
    k = np.floor((centres - centres.min()) / window_lines).astype(np.int64)
    count = np.bincount(k)
    ok = count > 0
    slow = (np.bincount(k, weights=mean) / np.maximum(count, 1))[ok]
    where = (np.bincount(k, weights=centres) / np.maximum(count, 1))[ok]
    return mean - np.interp(centres, where, slow)
