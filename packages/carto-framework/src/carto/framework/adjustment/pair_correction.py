"""The least-squares estimation of a pair's line correction
(:func:`estimate_correction`): the method of
:mod:`carto.framework.adjustment.relative_orientation` (its module docstring), on the
observations of :mod:`carto.framework.adjustment.pair_observations`, with its settings
(:class:`RelativeOrientationSettings`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.pair_observations import Noise, Observations, axes
from carto.framework.errors import InputError
from carto.framework.geometry.line_correction import LineBasis

FloatArray = NDArray[np.float64]

__all__ = [
    "MODES",
    "Fit",
    "RelativeOrientationSettings",
    "estimate_correction",
    "residuals_px",
]

MODES = ("auto", "none", "shift", "line")
"""``--relative-orientation``: ``auto`` (line-varying for line scanners, a shift otherwise),
``none``, ``shift`` (a constant line and sample shift of the right image), ``line`` (the
line-varying correction for any sensor)."""
REJECT_SIGMAS = 4.0
"""Points whose residual exceeds this many sigmas (either axis, normalised) are dropped."""
DATUM_SIGMA_PX = 1e-3
"""Sigma of the zero-mean condition of the along-base correction (datum from the models)."""
MIN_POINTS = 30
"""Fewer tie points than this: no relative orientation (the pair is reported as is)."""
MIN_HALF_POINTS = 10
"""A knot interval needs this many DEM rows each side of the swath to measure the along-base
shape (:func:`_along_shape`)."""


def _check_mode(_self: Any, _attr: attrs.Attribute, value: str) -> None:
    if value not in MODES:
        raise InputError(f"--relative-orientation must be one of {', '.join(MODES)}, got {value!r}")


def _check_positive(_self: Any, attr: attrs.Attribute, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"relative orientation: {attr.name} must be > 0, got {value!r}")


@attrs.frozen
class RelativeOrientationSettings:
    """Settings of :func:`relative_orientation` (checked on construction).

    Attributes:
        mode: one of :data:`MODES`.
        tie_spacing_px: grid spacing of the tie points, ortho pixels at the images' ground
            sampling (line-varying corrections; a shift takes :data:`SHIFT_SPACING_PX`).
        knot_lines: knot spacing of the line-varying correction's spline, lines (slow
            wander; a spline as fine as the DEM's own band errors would copy them).
        max_frequencies: most jitter frequencies taken from the residuals.
        dem_offset_sigma_m: a-priori sigma of the starting DEM's offset (absolute accuracy;
            SRTM: about 4 m).
        left_jitter: estimate the left image's jitter at the same frequencies too (off by
            default: on five simulated ``--errors full`` pairs it fitted the ties better,
            matching sigma 0.058 against 0.07 px, but left the DEM's bands no smaller,
            median NMAD 0.96 against 0.86 m; issue 30).
    """

    mode: str = attrs.field(default="auto", validator=_check_mode)
    tie_spacing_px: float = attrs.field(default=8.0, validator=_check_positive)
    knot_lines: float = attrs.field(default=256.0, validator=_check_positive)
    max_frequencies: int = attrs.field(default=8, converter=int)
    dem_offset_sigma_m: float = attrs.field(default=4.0, validator=_check_positive)
    left_jitter: bool = False


SHIFT_SPACING_PX = 32.0
"""Tie-point spacing of a shift (a constant needs a few thousand points, not a grid)."""


@attrs.frozen(eq=False)
class Fit:
    """One least-squares fit: coefficients ``(2, basis.size)``, the DEM offset (m) and the
    variance components its residuals give."""

    coefficients: FloatArray
    dem_offset_m: float
    noise: Noise
    datum: str = "dem"
    along_shape: Mapping[str, float] | None = None
    left_coefficients: FloatArray | None = None


BAND_LINES = 64.0
"""Bins of this many lines measure the DEM's correlated share (:attr:`Noise.band_factor`)."""
BAND_NEIGHBOURS = 5
"""Each bin's mean is compared with the mean of this many bins around it."""
SHAPE_SIGMA_PX = 0.25
"""A-priori sigma of the change of the spline between neighbouring coefficients, px: slow
attitude wander (0.0002 deg of 15-90 s periods moves a Cartosat-1 point by about a pixel)
changes by a fraction of a pixel over a knot spacing of 0.6 s."""
JITTER_SIGMA_PX = 0.3
"""A-priori sigma of each jitter sine and cosine coefficient, px (jitter of a few tenths of a
pixel; the prior keeps a frequency the DEM's errors alone pretend to see small)."""
SHAPE_ACROSS_RATIO = 1.5
"""The along-base shape's signal is at most this times the spread of the slow across-base
correction (attitude errors of a similar size about the pitch and roll axes, whose image
motions differ by the views' tilts): with the true models of five simulated pairs the
unbounded shape copied the starting DEM's swath-wide errors (NMAD 0.2 -> 0.4-1.2 m)."""
JITTER_FLOOR_PX = 0.02
"""Least sigma of an along-base jitter term (:func:`_along_jitter_sigmas`)."""
JITTER_MIN_ACROSS_PX = 0.05
"""A frequency whose across-base amplitude is below this keeps its along-base terms at
:data:`JITTER_FLOOR_PX` (the true models of simulated pairs show at most 0.033 px across at
the frequencies found; adjusted models under ``--errors full`` 0.05-0.14 px)."""
COEFFICIENT_SIGMA_PX = 10.0
"""A weak prior on every coefficient (knots without points stay determined)."""


def _expansion(basis: LineBasis, u0: FloatArray, left: bool) -> FloatArray:
    """``T``: full coefficients ``[line (size), sample (size), dH, left (4 F)]`` from the
    estimated ``[along (1 + 2 F), across (size), dH, left (4 F)]`` (``left``: the left
    image's jitter sines and cosines, line then sample, :func:`left_design`). Along the base
    the fit has a constant and the jitter sinusoids only; its slow shape comes after it,
    filtered against the starting DEM's error (:func:`_along_shape`). Across the base
    the spline follows it too."""
    n_b, n_f = basis.size, len(basis.frequencies)
    n0 = basis.n_spline or 1
    n_a = 1 + 2 * n_f
    expand = np.zeros((n_b, n_a))  # along parameters -> coefficients of the basis
    expand[:n0, 0] = 1.0  # the spline sums to one: equal coefficients are a constant
    expand[n0:, 1:] = np.eye(2 * n_f)
    v0 = np.array([-u0[1], u0[0]])
    n_l = 4 * n_f if left else 0  # the left image's jitter (line, sample), as such
    t = np.zeros((2 * n_b + 1 + n_l, n_a + n_b + 1 + n_l))
    for axis in range(2):
        rows = slice(axis * n_b, (axis + 1) * n_b)
        t[rows, :n_a] = u0[axis] * expand
        t[rows, n_a : n_a + n_b] = v0[axis] * np.eye(n_b)
    t[2 * n_b, n_a + n_b] = 1.0
    t[2 * n_b + 1 :, n_a + n_b + 1 :] = np.eye(n_l)
    return t


def _priors(basis: LineBasis, left: bool, along_jitter: FloatArray | None = None) -> FloatArray:
    """The normal-matrix share of the priors on the estimated parameters ``[along, across,
    dH, left]`` (:func:`_expansion`; the DEM offset's is the caller's); ``along_jitter``:
    the sigmas of the along-base sines and cosines (default :data:`JITTER_SIGMA_PX`)."""
    n_b, n_f = basis.size, len(basis.frequencies)
    n0, n_s = basis.n_spline or 1, basis.n_spline
    n_a = 1 + 2 * n_f
    sigma = np.r_[
        COEFFICIENT_SIGMA_PX,
        np.full(2 * n_f, JITTER_SIGMA_PX) if along_jitter is None else along_jitter,
        np.full(n0, COEFFICIENT_SIGMA_PX),
        np.full(2 * n_f, JITTER_SIGMA_PX),
    ]
    n_x = n_a + n_b + 1 + (4 * n_f if left else 0)
    prior = np.zeros((n_x, n_x))
    prior[np.arange(sigma.size), np.arange(sigma.size)] = 1.0 / sigma**2
    left = np.arange(n_a + n_b + 1, n_x)
    prior[left, left] = 1.0 / JITTER_SIGMA_PX**2
    for k in range(n_a, n_a + n_s - 1):  # neighbouring spline coefficients across the base
        d = np.zeros(n_x)
        d[k], d[k + 1] = -1.0, 1.0
        prior += np.outer(d, d) / SHAPE_SIGMA_PX**2
    return prior


def _band_factor(obs: Observations, along_px: FloatArray, noise: Noise) -> float:
    """:attr:`Noise.band_factor` from the along-base residuals of the DEM rows: the spread of
    their means over :data:`BAND_LINES` lines, each less the mean of its
    :data:`BAND_NEIGHBOURS` neighbours (slow motion the model leaves along the base is not
    the DEM's), against what independent rows would give."""
    rows = obs.dem_rows
    if rows.sum() < 10:
        return 1.0
    s_along, _ = obs.subset(rows).sigmas(noise, banded=False)
    k = np.floor(obs.line[rows] / BAND_LINES).astype(np.int64)
    k -= k.min()
    count = np.bincount(k)
    full = count >= 5
    if full.sum() < 2 * BAND_NEIGHBOURS:
        return 1.0
    mean = (np.bincount(k, weights=along_px[rows]) / np.maximum(count, 1))[full]
    predicted = (np.bincount(k, weights=s_along**2) / np.maximum(count, 1) ** 2)[full]
    window = np.ones(BAND_NEIGHBOURS) / BAND_NEIGHBOURS
    detail = (mean - np.convolve(mean, window, mode="same"))[BAND_NEIGHBOURS:-BAND_NEIGHBOURS]
    if detail.size < 4:
        return 1.0
    # a point less its window's mean keeps (1 - 1/n) of an independent variance
    spread = 1.4826 * np.median(np.abs(detail - np.median(detail)))
    independent = (1.0 - 1.0 / BAND_NEIGHBOURS) * np.median(predicted)
    return max(1.0, float(spread**2 / independent))


def offset_sigma_m(noise: Noise, dem_offset_sigma_m: float) -> float:
    """A-priori sigma of the starting DEM's offset: its stated absolute accuracy, and never
    less than its own post error (``noise.sigma_h``, measured along the base). A DEM whose
    posts are tens of metres off the terrain (a constant height over relief) does not know
    its mean to better than that either: on the Reunion pair a constant 2344 m start (posts
    46 m off) taken at its stated 4 m put the DEM 22 m high (NMAD 0.40 -> 1.08 m)."""
    return math.hypot(dem_offset_sigma_m, noise.sigma_h)


def _fit(
    obs: Observations,
    basis: LineBasis,
    noise: Noise,
    datum: str,
    settings: RelativeOrientationSettings,
    along_jitter: FloatArray | None = None,
) -> Fit:
    """Weighted least squares of :class:`Observations` (module docstring), whitened along and
    across the base, with the priors of :func:`_priors`; returns the variance components of
    its residuals too."""
    left_jitter, dem_offset_sigma_m = settings.left_jitter, settings.dem_offset_sigma_m
    u, v, norm = axes(obs.parallax)
    s_along, s_across = obs.sigmas(noise)
    b, _ = basis.design(obs.line)
    n_b = basis.size
    i_h = 2 * n_b  # the DEM offset, then the left image's jitter
    s_l = left_design(basis, obs.left_line) if left_jitter else np.zeros((obs.line.size, 0))
    n_l = s_l.shape[1]
    n_p = 2 * n_b + 1 + 2 * n_l
    expand = _expansion(basis, _base_direction(obs), left_jitter)

    def rows(axis: FloatArray, scale: FloatArray) -> tuple[FloatArray, FloatArray]:
        a = np.zeros((obs.line.size, n_p))
        a[:, :n_b] = b * axis[:, 0:1]
        a[:, n_b : 2 * n_b] = b * axis[:, 1:2]
        a[:, i_h] = np.where(obs.on_dem, np.einsum("ij,ij->i", axis, obs.parallax), 0.0)
        # a left correction d moves the right residual by -J d
        through = np.einsum("im,imk->ik", axis, obs.left_jacobian)
        a[:, i_h + 1 : i_h + 1 + n_l] = -s_l * through[:, 0:1]
        a[:, i_h + 1 + n_l :] = -s_l * through[:, 1:2]
        y = np.einsum("ij,ij->i", axis, obs.residual)
        return a / scale[:, None], y / scale

    a_al, y_al = rows(u, s_along)
    a_ac, y_ac = rows(v, s_across)
    design = np.vstack([a_al, a_ac]) @ expand
    target = np.concatenate([y_al, y_ac])
    normal = design.T @ design
    rhs = design.T @ target
    if datum == "models":  # the along-base correction has zero mean over the points
        cond = np.zeros(n_p)
        cond[:n_b] = (b * u[:, 0:1]).mean(axis=0)
        cond[n_b : 2 * n_b] = (b * u[:, 1:2]).mean(axis=0)
        cond = cond @ expand
        normal += np.outer(cond, cond) / DATUM_SIGMA_PX**2
    # the DEM offset's prior is the DEM's absolute accuracy (free when the models hold the
    # datum)
    normal += _priors(basis, left_jitter, along_jitter)
    i_x = normal.shape[0] - 1 - 2 * n_l  # the DEM offset among the estimated parameters
    normal[i_x, i_x] += (
        0.0 if datum == "models" else 1.0 / offset_sigma_m(noise, dem_offset_sigma_m) ** 2
    )
    x = expand @ np.linalg.solve(normal, rhs)
    coefficients = x[: 2 * n_b].reshape(2, n_b)
    offset = float(x[i_h])
    left = x[i_h + 1 :].reshape(2, n_l) if n_l else None
    fit = Fit(coefficients, offset, noise, datum, left_coefficients=left)
    res = obs.residual - correction_px(obs, basis, fit)
    along = np.einsum("ij,ij->i", u, res)
    across = np.einsum("ij,ij->i", v, res)
    # variance components: matching from across the base, DEM from along it
    mad = 1.4826
    dem_rows = obs.dem_rows
    a_ties = across[dem_rows] if dem_rows.any() else across
    s_m = max(float(mad * np.median(np.abs(a_ties - np.median(a_ties)))), 1e-3)
    s_h = noise.sigma_h
    if dem_rows.any():
        s_al = float(mad * np.median(np.abs(along[dem_rows] - np.median(along[dem_rows]))))
        s_h = math.sqrt(max(s_al**2 - s_m**2, 1e-6)) / float(np.median(norm[dem_rows]))
    new = Noise(s_m, max(s_h, 0.05))
    new = attrs.evolve(new, band_factor=_band_factor(obs, along, new))
    return attrs.evolve(fit, noise=new)


def _binned(line: FloatArray, value: FloatArray, width: float) -> tuple[FloatArray, FloatArray]:
    """Means of ``value`` in bins of ``width`` lines (bins with a point)."""
    k = np.floor(line / width).astype(np.int64)
    k -= k.min()
    count = np.bincount(k)
    total = np.bincount(k, weights=value)
    ok = count > 0
    centres = (np.arange(count.size) + 0.5) * width + np.floor(line.min() / width) * width
    return centres[ok], total[ok] / count[ok]


def estimate_correction(
    obs: Observations,
    n_lines: int,
    kind: str,
    datum: str,
    settings: RelativeOrientationSettings,
) -> tuple[LineBasis, Fit, NDArray[np.bool_]]:
    """The right image's correction from ``obs``: ``kind`` ``"shift"`` or ``"line"``,
    ``datum`` ``"gcp"``, ``"dem"`` or ``"models"`` (module docstring). The spline spans the
    lines the tie points cover. Returns the basis, the fit and the rows kept."""
    if kind == "shift":
        basis = LineBasis(n_lines)
    else:
        lines = obs.line[obs.dem_rows] if obs.dem_rows.any() else obs.line
        first, last = float(lines.min()), float(lines.max())
        if not last > first:
            last = first + 1.0
        basis = LineBasis(n_lines, min(settings.knot_lines, last - first), (), (first, last))
    keep = np.ones(obs.line.size, bool)
    fit = Fit(np.zeros((2, basis.size)), 0.0, Noise())
    for _ in range(3):  # variance components and outliers settle in a few rounds
        fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings)
        keep = _inliers(obs, basis, fit)
    if datum == "dem" and _dem_coarser_than_models(obs.subset(keep), fit.noise, settings):
        datum = "models"
        for _ in range(2):
            fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings)
            keep = _inliers(obs, basis, fit)
    if kind == "line" and settings.max_frequencies > 0:
        found: list[float] = []
        for _ in range(settings.max_frequencies):
            new = _next_frequency(obs.subset(keep), basis, fit, found)
            if new is None:
                break
            found.append(new)
            basis = attrs.evolve(basis, frequencies=tuple(found))
            fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings)
        keep = _inliers(obs, basis, fit)
        fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings)
    bound = _along_jitter_sigmas(obs.subset(keep), basis, fit) if basis.frequencies else None
    if bound is not None:
        fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings, bound)
    if kind == "line" and basis.n_spline > 1:
        delta, record = _along_shape(obs.subset(keep), basis, fit)
        if delta is not None:  # the rest refitted under the shape
            b, _ = basis.design(obs.line)
            less = attrs.evolve(obs, residual=obs.residual - b @ delta.T)
            fit = _fit(less.subset(keep), basis, fit.noise, datum, settings, bound)
            fit = attrs.evolve(fit, coefficients=fit.coefficients + delta)
        fit = attrs.evolve(fit, along_shape=record)
    return basis, fit, keep


def _base_direction(obs: Observations) -> FloatArray:
    """The stereo base's median direction in the right image, a unit ``(2,)`` vector."""
    u0 = np.median(axes(obs.parallax)[0], axis=0)
    return u0 / np.linalg.norm(u0)


def _along_jitter_sigmas(obs: Observations, basis: LineBasis, fit: Fit) -> FloatArray:
    """Sigmas of the along-base sines and cosines: :data:`SHAPE_ACROSS_RATIO` times the
    amplitude the fit found across the base at the same frequency, plus
    :data:`JITTER_FLOOR_PX`, and the floor alone below :data:`JITTER_MIN_ACROSS_PX` (the
    DEM rows alone let the starting DEM's errors at a frequency pass as jitter: with the true
    models of a simulated pair, NMAD 0.2 -> 0.45 m)."""
    n0 = basis.n_spline or 1
    u0 = _base_direction(obs)
    across = np.array([-u0[1], u0[0]]) @ fit.coefficients[:, n0:]  # (2 F,): sin, cos, ...
    amplitude = np.hypot(across[0::2], across[1::2])
    sigma = np.where(
        amplitude >= JITTER_MIN_ACROSS_PX, SHAPE_ACROSS_RATIO * amplitude + JITTER_FLOOR_PX,
        JITTER_FLOOR_PX,
    )  # fmt: skip
    return np.repeat(sigma, 2)


def _half_means(
    k: NDArray[np.int64], sample: FloatArray, value: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int64]]:
    """Per line bin ``k``: the mean of ``value`` over the bin, over its points left and right
    of the bin's median sample, and the count (bins with fewer than
    :data:`MIN_HALF_POINTS` points a side are NaN)."""
    n = int(k.max()) + 1
    order = np.lexsort((sample, k))
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


def _along_shape(
    obs: Observations, basis: LineBasis, fit: Fit
) -> tuple[FloatArray | None, dict[str, float] | None]:
    """The slow shape of the along-base correction, as coefficients to add to ``fit``'s
    (None where there is none), and its record (module docstring): the
    along-base residuals of the DEM rows averaged per knot interval; their left and right
    halves of the swath see the same orientation but different parts of the DEM, so half
    their difference measures the DEM's (and matching's) error of a mean, and the spread of
    the means beyond it the orientation's. The means, shrunk by the gain
    ``signal / (signal + noise)`` (a Wiener filter) and of zero mean (the datum stays),
    become spline coefficients along the base. The signal is bounded by the slow motion the
    fit found across the base (:data:`SHAPE_ACROSS_RATIO`): a DEM's errors correlated over
    the whole swath (a coarse DEM smooths ridges that cross it) pass the halves' test as
    orientation, but they have no counterpart across the base."""
    rows = obs.dem_rows
    if rows.sum() < 4 * MIN_HALF_POINTS:
        return None, None
    along, _ = residuals_px(obs, basis, fit)
    sub = obs.subset(rows)
    first, last = basis.span
    width = (last - first) / max(1, round((last - first) / basis.knot_lines))
    k = np.clip(np.floor((sub.line - first) / width), 0, None).astype(np.int64)
    full, m_l, m_r, count = _half_means(k, sub.sample, along[rows])
    ok = np.isfinite(full)
    if ok.sum() < 4:
        return None, None
    mad = 1.4826
    diff = (m_l - m_r)[ok]
    noise = (mad * float(np.median(np.abs(diff - np.median(diff))))) ** 2 / 4.0
    centred = full[ok] - np.average(full[ok], weights=count[ok])
    spread = (mad * float(np.median(np.abs(centred - np.median(centred))))) ** 2
    centres = first + (np.flatnonzero(ok) + 0.5) * width
    b, _ = basis.design(centres)
    spline = b[:, : basis.n_spline]
    u0 = _base_direction(obs)
    across = spline @ fit.coefficients[:, : basis.n_spline].T @ np.array([-u0[1], u0[0]])
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
    c = np.linalg.solve(normal, spline.T @ (gain * centred))
    delta = np.zeros_like(fit.coefficients)
    delta[:, : basis.n_spline] = u0[:, None] * c[None, :]
    return delta, record


def _dem_coarser_than_models(
    obs: Observations, noise: Noise, settings: RelativeOrientationSettings
) -> bool:
    """Whether the starting DEM knows the along-base constant worse than the models do: its
    offset's sigma (:func:`offset_sigma_m`) in pixels of parallax beyond
    :data:`COEFFICIENT_SIGMA_PX`, the models' a-priori sigma. The models then hold the datum
    (a constant start over relief: the Reunion pair's 2344 m, whose posts are 46 m off,
    moved the DEM 2.5 m even weighed against the models, against -0.08 m without)."""
    _, _, norm = axes(obs.parallax)
    rows = obs.dem_rows
    if not rows.any():
        return False
    px_per_m = float(np.median(norm[rows]))
    return offset_sigma_m(noise, settings.dem_offset_sigma_m) * px_per_m > COEFFICIENT_SIGMA_PX


def _next_frequency(
    obs: Observations, basis: LineBasis, fit: Fit, found: list[float]
) -> float | None:
    """The strongest jitter frequency (cycles per line) left in the across-base residuals,
    or None. Across the base only: along it, the starting DEM's own errors, correlated over
    hundreds of metres, make peaks a white-noise test takes for jitter. The series is given
    in kilolines (the detector rounds frequencies to 1e-4 of its unit)."""
    from carto.framework.adjustment.jitter import detect_jitter_frequencies

    _, across = residuals_px(obs, basis, fit)
    width = max(1.0, float(basis.n_lines) / 4096.0)
    t, r = _binned(obs.line, across, width)
    for f in detect_jitter_frequencies([(t / 1000.0, r)], max_frequencies=1):
        f = f / 1000.0
        if f <= 0.5 and all(abs(f - g) > 0.5 / basis.n_lines for g in found):
            return f
    return None


def left_design(basis: LineBasis, left_line: FloatArray) -> FloatArray:
    """The left image's jitter terms at its lines: a sine and a cosine per frequency of
    ``basis`` (no constant: the left image keeps its place), ``(N, 2 F)``."""
    if not basis.frequencies:
        return np.zeros((left_line.size, 0))
    design, _ = LineBasis(basis.n_lines, 0.0, basis.frequencies).design(left_line)
    return design[:, 1:]


def left_basis(basis: LineBasis, n_lines: int) -> LineBasis:
    """The basis of the left image's correction (:class:`LineCorrected`, coefficients
    ``[0, sines and cosines]`` per axis)."""
    return LineBasis(n_lines, 0.0, basis.frequencies)


def correction_px(obs: Observations, basis: LineBasis, fit: Fit) -> FloatArray:
    """``(N, 2)``: what ``fit`` explains of each row's right residual, pixels: the right
    correction, the DEM offset's parallax and the left correction seen through the
    left-to-right Jacobian."""
    b, _ = basis.design(obs.line)
    model = b @ fit.coefficients.T
    model = model + np.where(obs.on_dem, fit.dem_offset_m, 0.0)[:, None] * obs.parallax
    if fit.left_coefficients is not None and fit.left_coefficients.size:
        d_left = left_design(basis, obs.left_line) @ fit.left_coefficients.T
        model = model - np.einsum("imk,ik->im", obs.left_jacobian, d_left)
    return model


def residuals_px(obs: Observations, basis: LineBasis, fit: Fit) -> tuple[FloatArray, FloatArray]:
    """Residuals of every row under ``fit``, along and across the base, pixels."""
    u, v, _ = axes(obs.parallax)
    res = obs.residual - correction_px(obs, basis, fit)
    return np.einsum("ij,ij->i", u, res), np.einsum("ij,ij->i", v, res)


def _inliers(obs: Observations, basis: LineBasis, fit: Fit) -> NDArray[np.bool_]:
    """Rows within :data:`REJECT_SIGMAS` of ``fit`` on both axes (each row's own sigma)."""
    along, across = residuals_px(obs, basis, fit)
    s_along, s_across = obs.sigmas(fit.noise, banded=False)
    return (np.abs(along / s_along) < REJECT_SIGMAS) & (np.abs(across / s_across) < REJECT_SIGMAS)
