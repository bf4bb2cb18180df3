"""The slow shape of a pair's along-base correction, from the starting DEM: its trend, a
low-order polynomial of the image line (:func:`along_trend`), and what is left of it per knot
interval, Wiener-filtered (:func:`knot_shape`); the method is
:func:`carto.framework.adjustment.pair_correction.estimate_correction`'s (see
:mod:`carto.framework.adjustment.relative_orientation`).

The trend.

Why. A relative pitch trend of a same-pass pair (one image's attitude drifting against the
other's over the seconds of a scene) moves the right image along the base by an amount that
grows with the line: a height ramp along the track that tie points cannot see (heights absorb
it) and that one GCP cannot hold. The tied Cartosat-1 adjustment's image trends (a-priori
1e-4 deg) leave such ramps: on a simulated full-swath pair (12 000 x 1500 px, realistic
errors, 1 GCP) 0.82 m per 1000 lines, which made most of the DEM's NMAD (0.47 m, 0.23 m once a
plane is removed). The starting DEM sees it: averaged over the whole swath, an SRTM-like DEM
knows the mean height of a band of lines to centimetres, and the along-base residuals of the
tie points against it showed 0.85 m per 1000 lines.

The estimate. The DEM rows' along-base residuals are averaged over bins of
:data:`TREND_BIN_LINES` lines; a polynomial of order :data:`TREND_ORDER` (Legendre, without the
constant: the datum stays where the fit put it) is fitted to the bin means. The noise of a bin
mean is the larger of what the swath's halves say (half the spread of the differences of the
left and right halves' means: the DEM's error of a mean, where its errors are independent
across the swath) and the scatter of the bin means about the polynomial (everything the trend
does not explain: the DEM's errors correlated over the whole swath, jitter, wander),
inflated by the bin means' correlation along the track. Each coefficient ``a`` is shrunk by
the Wiener gain ``s^2 / (s^2 + var)`` with the signal power ``s^2 = a^2 - 4 var`` (at least
0, at most the square of its a-priori sigma :data:`TREND_SIGMA_PX`): a trend the DEM cannot
tell from its own errors (a narrow swath, a coarse DEM over ridges) stays near zero (with
the true models of a simulated 1000 x 4000 px pair, a gain of the prior alone took 0.05 px
of the DEM's errors for a trend: band 0.05 -> 0.36 m).
"""

from __future__ import annotations

import math

import attrs
import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray

from carto.framework.geometry.line_correction import LineBasis

FloatArray = NDArray[np.float64]

__all__ = ["AlongTrend", "along_tilt", "along_trend", "half_means", "knot_shape"]

TREND_ORDER = 2
"""Order of the trend's polynomial of the line (the Cartosat-1 adjuster's image trends have
orders 1 and 2)."""
TREND_BIN_LINES = 64.0
"""Lines per bin of the along-base residuals' means (at least: sparse points widen them)."""
TREND_SIGMA_PX = 0.5
"""A-priori sigma of each Legendre coefficient of the trend, px (a relative attitude trend of
1e-4 deg over a scene moves a Cartosat-1 point by about half a pixel)."""
MIN_HALF_POINTS = 10
"""A bin needs this many DEM rows each side of the swath (:func:`half_means`)."""
SHAPE_ACROSS_RATIO = 1.5
"""The knot shape's signal is at most this times the spread of the slow across-base
correction (attitude errors of a similar size about the pitch and roll axes, whose image
motions differ by the views' tilts): with the true models of five simulated pairs the
unbounded shape copied the starting DEM's swath-wide errors (NMAD 0.2 -> 0.4-1.2 m)."""
MIN_BINS = 8
"""Fewer full bins than this: no trend (no tilt)."""
TILT_BINS = 24
"""Bins across the swath of :func:`along_tilt`."""
TILT_SIGMA_PX = 0.05
"""A-priori sigma of the tilt across the swath, px per 1000 samples (a relative yaw of 0.002
deg, the Cartosat-1 cameras' residual alignment, turns the line by 0.035 px per 1000
samples)."""


def half_means(
    k: NDArray[np.int64], position: FloatArray, value: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int64]]:
    """Per bin ``k``: the mean of ``value`` over the bin, over its points below and above
    the bin's median ``position`` (for bins of lines, the left and right halves of the
    swath: the sample; for bins of samples, the early and late lines), and the count (bins
    with fewer than :data:`MIN_HALF_POINTS` points a side are NaN)."""
    n = int(k.max()) + 1
    order = np.lexsort((position, k))
    k_s, v_s = k[order], value[order]
    count = np.bincount(k_s, minlength=n)
    rank = np.arange(k_s.size) - np.r_[0, np.cumsum(count)[:-1]][k_s]
    left = rank < count[k_s] / 2.0
    c_l = np.bincount(k_s[left], minlength=n)
    c_r = count - c_l
    m_l = np.bincount(k_s[left], weights=v_s[left], minlength=n) / np.maximum(c_l, 1)
    m_r = np.bincount(k_s[~left], weights=v_s[~left], minlength=n) / np.maximum(c_r, 1)
    full = np.bincount(k_s, weights=v_s, minlength=n) / np.maximum(count, 1)
    ok = (c_l >= MIN_HALF_POINTS) & (c_r >= MIN_HALF_POINTS)
    nan = np.full(n, np.nan)
    return np.where(ok, full, nan), np.where(ok, m_l, nan), np.where(ok, m_r, nan), count


def _mad(x: FloatArray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def _bin_noise(halves_diff: FloatArray, residual: FloatArray, n_params: int) -> float:
    """The variance of a bin mean: the larger of what the halves say (a quarter of the
    spread of their differences) and the scatter of the bin means about the fit
    (``residual``, ``n_params`` fitted), inflated for neighbouring bins' correlation (an
    AR(1) process of the residuals' lag-one correlation ``rho``: ``(1 + rho) / (1 - rho)``;
    the starting DEM's errors and the attitude's motion span several bins)."""
    n = residual.size
    scatter = _mad(residual) ** 2 * (n - 1) / max(1, n - n_params)
    r = residual - residual.mean()
    rho = float(r[1:] @ r[:-1] / (r @ r)) if n > 2 and r @ r > 0 else 0.0
    rho = min(max(rho, 0.0), 0.9)
    return max(_mad(halves_diff) ** 2 / 4.0, scatter, 1e-12) * (1.0 + rho) / (1.0 - rho)


TREND_SIGNIFICANCE = 2.0
"""A trend coefficient's signal is what its square holds beyond this many sigmas squared: a
trend within two sigmas of zero is none (with the true models of a simulated 1000 x 4000 px
pair, one sigma let a bow of 1.2 sigmas through: orientation-limited NMAD 0.087 -> 0.128 m)."""
TILT_SIGNIFICANCE = 1.0
"""The same for the tilt, one coefficient under a tight prior (:data:`TILT_SIGMA_PX`): on
four narrow simulated pairs its estimates were within 0.4 sigma of zero; on a full-swath
pair the real relative yaw (0.07 m of height per 1000 samples) stood at 1.9 sigmas."""


def _gain(
    estimate: FloatArray, sigma: FloatArray, prior_px: float, significance: float
) -> FloatArray:
    """The Wiener gain of each coefficient: its signal power (what its square holds beyond
    ``significance`` squared times its variance, at most the prior's square) over signal
    plus variance; none for a coefficient within its noise."""
    excess = estimate**2 - (significance * sigma) ** 2
    signal = np.minimum(np.maximum(excess, 0.0), prior_px**2)
    return signal / (signal + sigma**2)


@attrs.frozen(eq=False)
class AlongTrend:
    """A trend of the along-base correction (:func:`along_trend`).

    Attributes:
        span: the lines the polynomial's ``[-1, 1]`` maps to.
        coefficients: the shrunk Legendre coefficients of orders 1.. (px).
        centre: the polynomial's weighted mean over the points (px), taken off its values.
        estimate: the coefficients before the shrinking (px).
        sigma: their standard errors (px).
        gain: the shrinking of each.
        bin_noise_px: the noise of a bin mean used.
    """

    span: tuple[float, float]
    coefficients: FloatArray
    centre: float
    estimate: FloatArray
    sigma: FloatArray
    gain: FloatArray
    bin_noise_px: float

    def _x(self, lines: FloatArray) -> FloatArray:
        first, last = self.span
        return np.clip(2.0 * (np.asarray(lines, np.float64) - first) / (last - first) - 1.0, -1, 1)

    def values(self, lines: FloatArray) -> FloatArray:
        """The trend at ``lines`` (px along the base; constant beyond the span)."""
        c = np.r_[0.0, self.coefficients]
        return legendre.legval(self._x(lines), c) - self.centre

    def spline_coefficients(self, basis: LineBasis) -> FloatArray | None:
        """The coefficients of ``basis``'s spline that hold the trend (a cubic spline holds a
        quadratic exactly), or None for a zero trend."""
        if not np.any(self.coefficients):
            return None
        first, last = basis.span
        lines = np.linspace(first, last, 8 * basis.n_spline + 8)
        spline = basis.design(lines)[0][:, : basis.n_spline]
        return np.linalg.lstsq(spline, self.values(lines), rcond=None)[0]

    def record(self) -> dict[str, object]:
        """What ``report.json`` says of it."""
        return {
            "order": int(self.coefficients.size),
            "coefficients_px": np.round(self.coefficients, 4).tolist(),
            "estimate_px": np.round(self.estimate, 4).tolist(),
            "sigma_px": np.round(self.sigma, 4).tolist(),
            "gain": np.round(self.gain, 3).tolist(),
            "bin_noise_px": round(self.bin_noise_px, 4),
        }


def along_trend(
    line: FloatArray, sample: FloatArray, along_px: FloatArray, span: tuple[float, float]
) -> AlongTrend | None:
    """The trend of the along-base residuals ``along_px`` of the DEM rows at ``(line,
    sample)`` over the lines ``span`` (module docstring), or None where too few bins measure
    it."""
    first, last = float(span[0]), float(span[1])
    if not last > first:
        return None
    # bins of TREND_BIN_LINES, wider where the points are sparse (about 4 halves' worth each)
    width = max(TREND_BIN_LINES, 4 * MIN_HALF_POINTS * (last - first) / max(line.size, 1))
    k = np.clip(np.floor((line - first) / width), 0, None).astype(np.int64)
    full, m_l, m_r, count = half_means(k, sample, along_px)
    ok = np.isfinite(full)
    if ok.sum() < MIN_BINS:
        return None
    centres = first + (np.flatnonzero(ok) + 0.5) * width
    x = np.clip(2.0 * (centres - first) / (last - first) - 1.0, -1.0, 1.0)
    w = count[ok].astype(np.float64)
    p = legendre.legvander(x, TREND_ORDER)[:, 1:]
    p = p - np.average(p, axis=0, weights=w)
    y = full[ok] - np.average(full[ok], weights=w)
    normal = p.T @ p
    estimate = np.linalg.solve(normal, p.T @ y)
    noise = _bin_noise((m_l - m_r)[ok], y - p @ estimate, TREND_ORDER + 1)
    sigma = np.sqrt(np.diag(np.linalg.inv(normal)) * noise)
    gain = _gain(estimate, sigma, TREND_SIGMA_PX, TREND_SIGNIFICANCE)
    coefficients = gain * estimate
    poly = legendre.legvander(x, TREND_ORDER)[:, 1:] @ coefficients
    centre = float(np.average(poly, weights=w))
    return AlongTrend((first, last), coefficients, centre, estimate, sigma, gain, math.sqrt(noise))


def knot_shape(
    line: FloatArray,
    sample: FloatArray,
    along_px: FloatArray,
    basis: LineBasis,
    across_coefficients: FloatArray,
) -> tuple[FloatArray | None, dict[str, float] | None]:
    """The along-base residuals ``along_px`` of the DEM rows at ``(line, sample)`` averaged
    per knot interval of ``basis``; their left and right halves of the swath see the same
    orientation but different parts of the DEM, so half their difference measures the DEM's
    (and matching's) error of a mean, and the spread of the means beyond it the
    orientation's. The means, shrunk by the gain ``signal / (signal + noise)`` (a Wiener
    filter) and of zero mean (the datum stays), become spline coefficients along the base
    (returned, or None where there is none, with the record). The signal is bounded by the
    slow motion the fit found across the base (``across_coefficients``, its spline's
    coefficients; :data:`SHAPE_ACROSS_RATIO`): a DEM's errors correlated over the whole
    swath (a coarse DEM smooths ridges that cross it) pass the halves' test as orientation,
    but they have no counterpart across the base."""
    first, last = basis.span
    width = (last - first) / max(1, round((last - first) / basis.knot_lines))
    k = np.clip(np.floor((line - first) / width), 0, None).astype(np.int64)
    full, m_l, m_r, count = half_means(k, sample, along_px)
    ok = np.isfinite(full)
    if ok.sum() < 4:
        return None, None
    noise = _mad((m_l - m_r)[ok]) ** 2 / 4.0
    centred = full[ok] - np.average(full[ok], weights=count[ok])
    spread = _mad(centred) ** 2
    centres = first + (np.flatnonzero(ok) + 0.5) * width
    b, _ = basis.design(centres)
    spline = b[:, : basis.n_spline]
    across = spline @ across_coefficients
    bound = (SHAPE_ACROSS_RATIO * float(np.std(across))) ** 2
    signal = min(max(spread - noise, 0.0), bound)
    gain = signal / (signal + noise) if signal + noise > 0 else 0.0
    record = {
        "signal_px": round(math.sqrt(signal), 4),
        "noise_px": round(math.sqrt(noise), 4),
        "across_px": round(float(np.std(across)), 4),
        "gain": round(gain, 3),
        "bins": int(ok.sum()),
    }
    if gain <= 0.0:
        return None, record
    normal = spline.T @ spline + 1e-6 * np.eye(basis.n_spline)
    return np.linalg.solve(normal, spline.T @ (gain * centred)), record


def along_tilt(
    line: FloatArray, sample: FloatArray, along_px: FloatArray, centre: float
) -> tuple[float, dict[str, float] | None]:
    """The along-base tilt across the swath of the DEM rows' along-base residuals
    ``along_px`` at ``(line, sample)``: px per 1000 samples from the sample ``centre``, and
    its record (0 and None where too few bins measure it). A relative yaw of the pair turns
    the right image's lines, a height tilt across the track that tie points cannot see; the
    whole scene's DEM rows measure it. The residuals are averaged over :data:`TILT_BINS`
    bins of the sample; the noise of a bin mean is the larger of what its early and late
    lines say (half the spread of their means' differences) and the bin means' scatter about
    the line (inflated for neighbouring bins' correlation); the slope is shrunk as the
    trend's coefficients are (prior :data:`TILT_SIGMA_PX`)."""
    lo, hi = float(np.min(sample)), float(np.max(sample))
    if not hi > lo:
        return 0.0, None
    width = (hi - lo) / TILT_BINS * (1 + 1e-9)
    k = np.floor((sample - lo) / width).astype(np.int64)
    full, m_a, m_b, count = half_means(k, line, along_px)
    ok = np.isfinite(full)
    if ok.sum() < MIN_BINS:
        return 0.0, None
    x = (lo + (np.flatnonzero(ok) + 0.5) * width - centre) / 1000.0
    w = count[ok].astype(np.float64)
    xc = x - np.average(x, weights=w)
    y = full[ok] - np.average(full[ok], weights=w)
    estimate = float(xc @ y / (xc @ xc))
    variance = _bin_noise((m_a - m_b)[ok], y - xc * estimate, 2) / float(xc @ xc)
    sigma = np.array([math.sqrt(variance)])
    gain = float(_gain(np.array([estimate]), sigma, TILT_SIGMA_PX, TILT_SIGNIFICANCE)[0])
    record = {
        "px_per_1000_samples": round(gain * estimate, 5),
        "estimate": round(estimate, 5),
        "sigma": round(math.sqrt(variance), 5),
        "gain": round(gain, 3),
    }
    return gain * estimate, record
