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

from carto.framework.adjustment.along_shape import (
    MIN_HALF_POINTS,
    along_tilt,
    along_trend,
    knot_shape,
)
from carto.framework.adjustment.band_factor import band_factor
from carto.framework.adjustment.pair_observations import Noise, Observations, axes, base_axes
from carto.framework.adjustment.platform_jitter import (
    JITTER_SIGMA_PX,
    AlongWiener,
    along_axes,
    along_wiener,
    has_platform,
    platform_design,
    platform_px,
    platform_sigmas,
    px_per_rad,
    refined_hz,
    seconds_per_line,
    window_gain,
)
from carto.framework.errors import InputError
from carto.framework.geometry.line_correction import LineBasis
from carto.framework.settings import flag, positive_attribute

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


def _check_mode(_self: Any, _attr: attrs.Attribute, value: str) -> None:
    if value not in MODES:
        raise InputError(f"--relative-orientation must be one of {', '.join(MODES)}, got {value!r}")


_check_positive = positive_attribute("relative orientation")

BAND_FACTORS = ("binned", "spectral")
"""How :class:`RelativeOrientationSettings` measures the DEM rows' correlated share
(:mod:`carto.framework.adjustment.band_factor`)."""


def _check_band_factor(_self: Any, _attr: attrs.Attribute, value: str) -> None:
    if value not in BAND_FACTORS:
        raise InputError(
            f"relative orientation: band_factor must be one of {', '.join(BAND_FACTORS)}, "
            f"got {value!r}"
        )


PLATFORM_ALONG = ("bound", "wiener")
"""How :class:`RelativeOrientationSettings` weighs the platform's along-base axis (pitch)."""


def _check_platform_along(_self: Any, _attr: attrs.Attribute, value: str) -> None:
    if value not in PLATFORM_ALONG:
        raise InputError(
            f"relative orientation: platform_along must be one of {', '.join(PLATFORM_ALONG)}, "
            f"got {value!r}"
        )


@attrs.frozen
class RelativeOrientationSettings:
    """Settings of :func:`relative_orientation` (checked on construction).

    Attributes:
        mode: one of :data:`MODES`.
        tie_spacing_px: grid spacing of the tie points, ortho pixels at the images' ground
            sampling (line-varying corrections; a shift takes :data:`SHIFT_SPACING_PX`).
        max_tie_points: the grid's columns are widened beyond ``tie_spacing_px`` to about
            this many points over the left image (a 12000 x 12000 pair at 8 px: 1.9 M
            points, 170 s to match; the rows keep their spacing: jitter's time sampling).
        knot_lines: knot spacing of the line-varying correction's spline, lines (slow
            wander; a spline as fine as the DEM's own band errors would copy them).
        max_frequencies: most jitter frequencies taken from the residuals.
        dem_offset_sigma_m: a-priori sigma of the starting DEM's offset (absolute accuracy;
            SRTM: about 4 m).
        platform_jitter: where both images are line scanners of one platform
            (:func:`~carto.framework.adjustment.pair_observations.platform_of`), take their
            jitter as one attitude time series of the platform, seen by each image at its
            own imaging time, instead of sinusoids of the right image's lines. On by
            default: on three simulated ``--errors full`` Cartosat-1 pairs (1 GCP: 12000 x
            2000, 1000 x 4000 and 12000 x 400 px) the height error the orientation leaves
            where the merged images show the points was 0.54 / 0.63 / 0.33 m NMAD with it,
            0.60 / 0.71 / 0.49 m without
            (``benchmarks/results/orientation_limit_issue30_s48.json``, issue 30).
        band_factor: how a line-varying correction measures the DEM rows' correlated share
            (:data:`BAND_FACTORS`): over 64-line bins (``binned``, the default) or in the
            jitter band (``spectral``). With ``platform_jitter`` on simulated ``--errors
            full`` pairs (1 GCP), the spectral measure took the orientation-limited DEM error
            (the height at the true point) from 0.62 to 0.48 m NMAD on a 12 000 x 2000 px
            full swath, but from 0.69 to 1.03 m on a 1000 x 4000 px one, whose DEM errors
            grow toward the lowest jitter frequencies more than the band's median says
            (``benchmarks/results/orientation_limit_issue30_s47.json``).
        platform_along: how the platform jitter's along-base axis (pitch, for along-track
            stereo) is weighed (:data:`PLATFORM_ALONG`): bounded by the amplitude the other
            axes found across the base (``bound``, the default), or estimated per frequency
            from the DEM rows against the DEM's own error at neighbouring frequencies
            (``wiener``, :func:`~carto.framework.adjustment.platform_jitter.along_wiener`).
        jitter_per_image: with ``platform_jitter``, each image's jitter its own sinusoids at
            the platform's frequencies, seen at its own imaging times, instead of one series
            of the platform: the phase between views tens of seconds apart needs a frequency
            known to a thousandth of a hertz, which a few seconds of tie points do not give.
    """

    mode: str = attrs.field(default="auto", validator=_check_mode)
    tie_spacing_px: float = attrs.field(default=8.0, validator=_check_positive)
    max_tie_points: int = attrs.field(default=250_000, converter=int, validator=_check_positive)
    knot_lines: float = attrs.field(default=256.0, validator=_check_positive)
    max_frequencies: int = attrs.field(default=8, converter=int)
    dem_offset_sigma_m: float = attrs.field(default=4.0, validator=_check_positive)
    platform_jitter: bool = attrs.field(default=True, converter=flag("platform_jitter"))
    band_factor: str = attrs.field(default="binned", validator=_check_band_factor)
    platform_along: str = attrs.field(default="bound", validator=_check_platform_along)
    jitter_per_image: bool = attrs.field(default=False, converter=flag("jitter_per_image"))


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
    along_shape: Mapping[str, Any] | None = None
    platform_rad: FloatArray | None = None
    platform_hz: tuple[float, ...] = ()
    offset_parallax: FloatArray = attrs.field(factory=lambda: np.zeros(2))
    tilt_px: FloatArray = attrs.field(factory=lambda: np.zeros(2))
    tilt_centre_sample: float = 0.0
    tilt: Mapping[str, float] | None = None
    platform_along: Mapping[str, Any] | None = None


SHAPE_SIGMA_PX = 0.25
"""A-priori sigma of the change of the spline between neighbouring coefficients, px: slow
attitude wander (0.0002 deg of 15-90 s periods moves a Cartosat-1 point by about a pixel)
changes by a fraction of a pixel over a knot spacing of 0.6 s."""
SHAPE_ACROSS_RATIO = 1.5
"""An along-base jitter term's sigma is this times the amplitude found across the base at its
frequency (:func:`_along_bound_px`; the along-base shape's signal has the same bound,
:data:`~carto.framework.adjustment.along_shape.SHAPE_ACROSS_RATIO`)."""
JITTER_FLOOR_PX = 0.02
"""Least sigma of an along-base jitter term (:func:`_along_jitter_sigmas`)."""
JITTER_MIN_ACROSS_PX = 0.05
"""A frequency whose across-base amplitude is below this keeps its along-base terms at
:data:`JITTER_FLOOR_PX` (the true models of simulated pairs show at most 0.033 px across at
the frequencies found; adjusted models under ``--errors full`` 0.05-0.14 px)."""
COEFFICIENT_SIGMA_PX = 10.0
"""A weak prior on every coefficient (knots without points stay determined)."""


def _expansion(basis: LineBasis, u0: FloatArray, n_l: int) -> FloatArray:
    """``T``: full coefficients ``[line (size), sample (size), dH, platform (n_l)]`` from the
    estimated ``[along (1 + 2 F), across (size), dH, platform (n_l)]`` (the platform's
    jitter, :func:`platform_design`, as such). Along the base
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
    t = np.zeros((2 * n_b + 1 + n_l, n_a + n_b + 1 + n_l))
    for axis in range(2):
        rows = slice(axis * n_b, (axis + 1) * n_b)
        t[rows, :n_a] = u0[axis] * expand
        t[rows, n_a : n_a + n_b] = v0[axis] * np.eye(n_b)
    t[2 * n_b, n_a + n_b] = 1.0
    t[2 * n_b + 1 :, n_a + n_b + 1 :] = np.eye(n_l)
    return t


def _priors(
    basis: LineBasis, platform_sigma: FloatArray, along_jitter: FloatArray | None = None
) -> FloatArray:
    """The normal-matrix share of the priors on the estimated parameters ``[along, across,
    dH, platform]`` (:func:`_expansion`; the DEM offset's is the caller's);
    ``platform_sigma``: the platform jitter coefficients' sigmas, radians; ``along_jitter``:
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
    n_x = n_a + n_b + 1 + platform_sigma.size
    prior = np.zeros((n_x, n_x))
    prior[np.arange(sigma.size), np.arange(sigma.size)] = 1.0 / sigma**2
    extra = np.arange(n_a + n_b + 1, n_x)
    prior[extra, extra] = 1.0 / platform_sigma**2
    for k in range(n_a, n_a + n_s - 1):  # neighbouring spline coefficients across the base
        d = np.zeros(n_x)
        d[k], d[k + 1] = -1.0, 1.0
        prior += np.outer(d, d) / SHAPE_SIGMA_PX**2
    return prior


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
    platform_hz: tuple[float, ...] = (),
    platform_sigma: FloatArray | None = None,
) -> Fit:
    """Weighted least squares of :class:`Observations` (module docstring), whitened along and
    across the base, with the priors of :func:`_priors`; ``platform_hz``: the platform's
    jitter frequencies (:func:`platform_design`). Returns the variance components of its
    residuals too."""
    n_b = basis.size
    i_h = 2 * n_b  # the DEM offset, then the platform's jitter
    images = 2 if settings.jitter_per_image else 1
    n_l = 6 * len(platform_hz) * images
    u, v, norm = base_axes(obs.parallax)
    expand = _expansion(basis, u[0].copy(), n_l)
    p_offset = offset_parallax(obs)
    axes_uv = (u[0].copy(), v[0].copy())
    normal, rhs, cond = _normal_equations(
        obs, basis, noise, (platform_hz, p_offset, images == 2), axes_uv, expand
    )
    if datum == "models":  # the along-base correction has zero mean over the points
        normal += np.outer(cond, cond) / DATUM_SIGMA_PX**2
    # the DEM offset's prior is the DEM's absolute accuracy (free when the models hold the
    # datum)
    if platform_sigma is None:
        platform_sigma = platform_sigmas(obs, len(platform_hz), images, JITTER_SIGMA_PX)
    normal += _priors(basis, platform_sigma, along_jitter)
    i_x = normal.shape[0] - 1 - n_l  # the DEM offset among the estimated parameters
    normal[i_x, i_x] += (
        0.0 if datum == "models" else 1.0 / offset_sigma_m(noise, settings.dem_offset_sigma_m) ** 2
    )
    x = expand @ np.linalg.solve(normal, rhs)
    fit = Fit(
        x[: 2 * n_b].reshape(2, n_b),
        float(x[i_h]),
        noise,
        datum,
        platform_rad=x[i_h + 1 :].reshape((images, 3, -1)[2 - images :]) if n_l else None,
        platform_hz=tuple(platform_hz),
        offset_parallax=p_offset,
    )
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
    spectral = settings.band_factor == "spectral" and basis.n_spline > 0
    new = attrs.evolve(new, band_factor=band_factor(obs, along, new, spectral))
    return attrs.evolve(fit, noise=new)


FIT_CHUNK_ROWS = 65536
"""Tie points whose design rows :func:`_normal_equations` holds at once: the normal
equations are summed chunk by chunk, so a fit's memory does not grow with the points (a
whole 12000 x 12000 pair, 1.9 M points, took 9 GB in one piece)."""


def _normal_equations(
    obs: Observations,
    basis: LineBasis,
    noise: Noise,
    terms: tuple[tuple[float, ...], FloatArray],
    axes_uv: tuple[FloatArray, FloatArray],
    expand: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(normal, rhs, cond)`` of :func:`_fit`'s rows, whitened along and across the base
    (``axes_uv``: its two directions, :func:`~carto.framework.adjustment.pair_observations.
    base_axes`), in the estimated parameters (``expand``: :func:`_expansion`), summed over
    chunks of :data:`FIT_CHUNK_ROWS` points; ``terms``: the platform's jitter frequencies
    and the DEM offset's parallax (:func:`offset_parallax`); ``cond``: the mean along-base
    correction's row (the models' datum)."""
    platform_hz, p_offset, per_image = terms
    n_b = basis.size
    n_p = expand.shape[0]
    normal = np.zeros((expand.shape[1],) * 2)
    rhs = np.zeros(expand.shape[1])
    cond = np.zeros(n_p)
    spl = seconds_per_line(obs) if platform_hz else None
    for start in range(0, obs.line.size, FIT_CHUNK_ROWS):
        part = obs.subset(slice(start, start + FIT_CHUNK_ROWS))
        u, v = (np.broadcast_to(d, part.parallax.shape) for d in axes_uv)
        s_along, s_across = part.sigmas(noise)
        b = _seen_design(basis, part)
        s_p = platform_design(part, platform_hz, spl, per_image)  # (n, 2, n_l)
        for axis, scale in ((u, s_along), (v, s_across)):
            a = np.empty((part.line.size, n_p))
            a[:, :n_b] = b * axis[:, 0:1]
            a[:, n_b : 2 * n_b] = b * axis[:, 1:2]
            a[:, 2 * n_b] = np.where(part.on_dem, axis @ p_offset, 0.0)
            a[:, 2 * n_b + 1 :] = np.einsum("im,imk->ik", axis, s_p)
            y = np.einsum("ij,ij->i", axis, part.residual) / scale
            design = (a / scale[:, None]) @ expand
            normal += design.T @ design
            rhs += design.T @ y
        cond[:n_b] += (b * u[:, 0:1]).sum(axis=0)
        cond[n_b : 2 * n_b] += (b * u[:, 1:2]).sum(axis=0)
    return normal, rhs, (cond / max(obs.line.size, 1)) @ expand


def offset_parallax(obs: Observations) -> FloatArray:
    """The parallax of the DEM offset, px/m, ``(2,)``: the median over the DEM rows, one
    vector for all of them. An offset moves every point by its own parallax, which varies
    by a few percent over a swath; with that variation in the model the along-base constant
    and the offset were told apart by it, and the starting DEM's errors correlated with
    position set the offset (true models of a simulated pair, DEM datum: offset -6.3 m,
    DEM median -5.4 m for a starting DEM 1 m off). With one vector, the constant and the
    offset are one unknown along the base and their priors (or the GCPs) share it."""
    rows = obs.on_dem
    if not rows.any():
        return np.zeros(2)
    return np.median(obs.parallax[rows], axis=0)


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
    hz: tuple[float, ...] = ()
    if kind == "line" and settings.max_frequencies > 0:
        platform = settings.platform_jitter and has_platform(obs)
        found: list[float] = []
        for _ in range(settings.max_frequencies):
            new = _next_frequency(obs.subset(keep), basis, fit, found)
            if new is None:
                break
            found.append(new)
            if platform:
                hz = (*hz, new / seconds_per_line(obs))
                fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings, platform_hz=hz)
                part = obs.subset(keep)
                rest = part.residual - correction_px(part, basis, fit)
                hz = refined_hz(part, rest, fit.noise, (hz, fit.platform_rad), len(hz) - 1)
            else:
                basis = attrs.evolve(basis, frequencies=tuple(found))
            fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings, platform_hz=hz)
        keep = _inliers(obs, basis, fit)
        fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings, platform_hz=hz)
    bound = _along_jitter_sigmas(obs.subset(keep), basis, fit) if basis.frequencies else None
    wiener = bool(hz) and settings.platform_along == "wiener"
    p_bound = _platform_bound(obs.subset(keep), fit) if hz and not wiener else None
    if bound is not None or p_bound is not None:
        fit = _fit(obs.subset(keep), basis, fit.noise, datum, settings, bound, hz, p_bound)
    held, record = np.zeros(0), None
    if wiener:
        again = (datum, settings, bound)
        obs, fit, pitch, p_bound = _with_along_wiener(obs, keep, basis, fit, again)
        held, record = pitch.rad.ravel(), pitch.record()
        fit = _less_platform(fit, held)
    if kind == "line" and basis.n_spline > 1:
        fit = _with_slow_shape(obs, keep, basis, fit, (datum, settings, bound, hz, p_bound))
    return basis, attrs.evolve(_less_platform(fit, -held), platform_along=record), keep


def _less_platform(fit: Fit, rad: FloatArray) -> Fit:
    """``fit`` with ``rad`` taken from its platform terms."""
    if not rad.size:
        return fit
    shape = fit.platform_rad.shape
    return attrs.evolve(fit, platform_rad=(fit.platform_rad.ravel() - rad).reshape(shape))


def _with_slow_shape(
    obs: Observations, keep: NDArray[np.bool_], basis: LineBasis, fit: Fit, again: tuple
) -> Fit:
    """``fit`` with the along-base shape (:func:`_along_shape`) and the tilt across the swath
    (:func:`_tilt`) the DEM rows measure, the rest refitted under them (``again``: the rest
    of :func:`_fit`'s arguments)."""
    delta, record = _along_shape(obs.subset(keep), basis, fit)
    delta = np.zeros_like(fit.coefficients) if delta is None else delta
    shaped = attrs.evolve(fit, coefficients=fit.coefficients + delta)
    tilt, centre, tilt_record = _tilt(obs.subset(keep), basis, shaped)
    if delta.any() or tilt.any():  # the rest refitted under them
        x = (obs.sample - centre) / 1000.0
        model = basis.evaluate(obs.line, delta)[0] + x[:, None] * tilt[None, :]
        less = attrs.evolve(obs, residual=obs.residual - model)
        fit = _fit(less.subset(keep), basis, fit.noise, *again)
        fit = attrs.evolve(fit, coefficients=fit.coefficients + delta)
    return attrs.evolve(
        fit, along_shape=record, tilt_px=tilt, tilt_centre_sample=centre, tilt=tilt_record
    )


def _tilt(
    obs: Observations, basis: LineBasis, fit: Fit
) -> tuple[FloatArray, float, dict[str, float] | None]:
    """The along-base tilt across the swath of the DEM rows' residuals under ``fit``
    (:func:`~carto.framework.adjustment.along_shape.along_tilt`) as ``(d_line, d_sample)``
    per 1000 samples, its centre (the samples' median) and its record."""
    rows = obs.dem_rows
    if rows.sum() < 4 * MIN_HALF_POINTS:
        return np.zeros(2), 0.0, None
    along, _ = residuals_px(obs, basis, fit)
    centre = float(np.median(obs.sample[rows]))
    slope, record = along_tilt(obs.line[rows], obs.sample[rows], along[rows], centre)
    return _base_direction(obs) * slope, centre, record


def _base_direction(obs: Observations) -> FloatArray:
    """The stereo base's median direction in the right image, a unit ``(2,)`` vector."""
    return base_axes(obs.parallax)[0][0].copy()


def _along_jitter_sigmas(obs: Observations, basis: LineBasis, fit: Fit) -> FloatArray:
    """Sigmas of the along-base sines and cosines: :data:`SHAPE_ACROSS_RATIO` times the
    amplitude the fit found across the base at the same frequency, plus
    :data:`JITTER_FLOOR_PX`, and the floor alone below :data:`JITTER_MIN_ACROSS_PX` (the
    DEM rows alone let the starting DEM's errors at a frequency pass as jitter: with the true
    models of a simulated pair, NMAD 0.2 -> 0.45 m)."""
    n0 = basis.n_spline or 1
    u0 = _base_direction(obs)
    across = np.array([-u0[1], u0[0]]) @ fit.coefficients[:, n0:]  # (2 F,): sin, cos, ...
    return np.repeat(_along_bound_px(np.hypot(across[0::2], across[1::2])), 2)


def _along_bound_px(across_px: FloatArray) -> FloatArray:
    """The sigma of an along-base jitter term, px, from the amplitude found across the base
    at its frequency: :data:`SHAPE_ACROSS_RATIO` times it plus :data:`JITTER_FLOOR_PX`, and
    the floor alone below :data:`JITTER_MIN_ACROSS_PX`."""
    return np.where(
        across_px >= JITTER_MIN_ACROSS_PX, SHAPE_ACROSS_RATIO * across_px + JITTER_FLOOR_PX,
        JITTER_FLOOR_PX,
    )  # fmt: skip


def _along_shape(
    obs: Observations, basis: LineBasis, fit: Fit
) -> tuple[FloatArray | None, dict[str, Any] | None]:
    """The slow shape of the along-base correction, as coefficients to add to ``fit``'s
    (None where there is none), and its record (module docstring), from the along-base
    residuals of the DEM rows (:mod:`carto.framework.adjustment.along_shape`): first their
    trend over the whole swath (:func:`~carto.framework.adjustment.along_shape.along_trend`),
    then what is left of them per knot interval, Wiener-filtered
    (:func:`~carto.framework.adjustment.along_shape.knot_shape`)."""
    rows = obs.dem_rows
    if rows.sum() < 4 * MIN_HALF_POINTS:
        return None, None
    along, _ = residuals_px(obs, basis, fit)
    sub = obs.subset(rows)
    trend = along_trend(sub.line, sub.sample, along[rows], basis.span)
    rest = along[rows] - (trend.values(sub.line) if trend is not None else 0.0)
    u0 = _base_direction(obs)
    across = np.array([-u0[1], u0[0]]) @ fit.coefficients[:, : basis.n_spline]
    shape, record = knot_shape(sub.line, sub.sample, rest, basis, across)
    if trend is not None:
        record = {**(record or {}), "trend": trend.record()}
    c = trend.spline_coefficients(basis) if trend is not None else None
    if shape is not None:
        c = shape if c is None else c + shape
    if c is None:
        return None, record
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


def _seen_design(basis: LineBasis, obs: Observations) -> FloatArray:
    """``basis``'s design at the rows' lines as the tie points see it: the sinusoids
    attenuated by their matching window (:func:`window_gain`)."""
    b, _ = basis.design(obs.line)
    if basis.frequencies and obs.window_lines > 0:
        n0 = basis.n_spline or 1
        gain = window_gain(np.asarray(basis.frequencies), obs.window_lines)
        b = b.copy()
        b[:, n0:] *= np.repeat(gain, 2)[None, :]
    return b


def _platform_bound(obs: Observations, fit: Fit) -> FloatArray:
    """Sigmas of the platform jitter coefficients after a first fit: an axis that moves the
    images mostly along the base (pitch, for along-track stereo) is told from the starting
    DEM's errors only by the DEM rows, whose errors at a frequency pass for jitter; it gets
    the sigma :func:`_along_jitter_sigmas` gives from the amplitude the other axes found
    across the base at that frequency (the true models of a simulated pair took 0.1-0.5
    urad of pitch jitter from the DEM without it: NMAD 0.19 -> 0.44 m)."""
    rad = np.asarray(fit.platform_rad).reshape(-1, 3, len(fit.platform_hz), 2)
    sigma = platform_sigmas(obs, len(fit.platform_hz), rad.shape[0], JITTER_SIGMA_PX).reshape(
        -1, 3, rad.shape[2], 2
    )
    per_rad = px_per_rad(obs)
    along_like = along_axes(obs)
    amplitude_px = np.hypot(rad[..., 0], rad[..., 1]) * per_rad[None, :, None]  # (images, 3, F)
    across = amplitude_px[:, ~along_like]
    bound_px = _along_bound_px(np.sqrt(np.sum(across**2, axis=(0, 1)) / rad.shape[0]))
    for a in np.flatnonzero(along_like):
        sigma[:, a] = (bound_px / max(per_rad[a], 1e-3))[None, :, None]
    return sigma.ravel()


FIXED_SIGMA_PX = 1e-6
"""Sigma, px, that holds the along-base axes' platform terms where :func:`along_wiener` set
them (the fit refits the rest under them)."""


def _with_along_wiener(
    obs: Observations, keep: NDArray[np.bool_], basis: LineBasis, fit: Fit, again: tuple
) -> tuple[Observations, Fit, AlongWiener, FloatArray]:
    """The along-base axes' platform jitter estimated per frequency (:func:`along_wiener`,
    ``RelativeOrientationSettings.platform_along="wiener"``), the rest refitted under it
    (``again``: :func:`_fit`'s ``datum, settings, along_jitter``). Returns the observations
    less those terms (what the later steps fit), the fit (its ``platform_rad`` with them),
    the terms (:class:`AlongWiener`) and the platform sigmas that hold them."""
    hz = fit.platform_hz
    shape = fit.platform_rad.shape
    rad = np.asarray(fit.platform_rad).reshape(-1, 3, len(hz), 2)
    held = np.zeros_like(rad)
    on = along_axes(obs)
    held[:, on] = rad[:, on]
    along, _ = residuals_px(obs, basis, fit)
    u, _, _ = base_axes(obs.parallax)
    along = along + np.einsum(
        "ij,ij->i", u, platform_px(obs, hz, held.reshape(shape), FIT_CHUNK_ROWS)
    )
    found = along_wiener(obs.subset(keep), hz, along[keep], rad.shape[0])
    found_px = platform_px(obs, hz, found.rad.reshape(shape), FIT_CHUNK_ROWS)
    less = attrs.evolve(obs, residual=obs.residual - found_px)
    sigma = platform_sigmas(obs, len(hz), rad.shape[0], JITTER_SIGMA_PX).reshape(
        rad.shape[0], 3, -1
    )
    sigma[:, on] = FIXED_SIGMA_PX / np.maximum(px_per_rad(obs)[on], 1e-3)[None, :, None]
    fit = _fit(less.subset(keep), basis, fit.noise, *again, hz, sigma.ravel())
    rad_all = np.asarray(fit.platform_rad).ravel() + found.rad.ravel()
    return less, attrs.evolve(fit, platform_rad=rad_all.reshape(shape)), found, sigma.ravel()


def correction_px(obs: Observations, basis: LineBasis, fit: Fit) -> FloatArray:
    """``(N, 2)``: what ``fit`` explains of each row's right residual, pixels: the right
    correction, the DEM offset's parallax and the platform's jitter, as the tie points see
    them (:func:`_seen_design`, :func:`platform_design`; neither is formed for all rows)."""
    coefficients = np.array(fit.coefficients, np.float64)
    if basis.frequencies and obs.window_lines > 0:  # the sinusoids as the windows see them
        gain = window_gain(np.asarray(basis.frequencies), obs.window_lines)
        coefficients[:, (basis.n_spline or 1) :] *= np.repeat(gain, 2)[None, :]
    model, _ = basis.evaluate(obs.line, coefficients)
    model = model + np.where(obs.on_dem, fit.dem_offset_m, 0.0)[:, None] * fit.offset_parallax
    if fit.tilt_px.any():
        x = (obs.sample - fit.tilt_centre_sample) / 1000.0
        model = model + x[:, None] * fit.tilt_px[None, :]
    return model + platform_px(obs, fit.platform_hz, fit.platform_rad, FIT_CHUNK_ROWS)


def residuals_px(obs: Observations, basis: LineBasis, fit: Fit) -> tuple[FloatArray, FloatArray]:
    """Residuals of every row under ``fit``, along and across the base, pixels."""
    u, v, _ = base_axes(obs.parallax)
    res = obs.residual - correction_px(obs, basis, fit)
    return np.einsum("ij,ij->i", u, res), np.einsum("ij,ij->i", v, res)


def _inliers(obs: Observations, basis: LineBasis, fit: Fit) -> NDArray[np.bool_]:
    """Rows within :data:`REJECT_SIGMAS` of ``fit`` on both axes (each row's own sigma)."""
    along, across = residuals_px(obs, basis, fit)
    s_along, s_across = obs.sigmas(fit.noise, banded=False)
    return (np.abs(along / s_along) < REJECT_SIGMAS) & (np.abs(across / s_across) < REJECT_SIGMAS)
