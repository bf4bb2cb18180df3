"""The platform's attitude jitter in a pair's relative orientation
(:mod:`carto.framework.adjustment.pair_correction`): how a sinusoid of the platform's roll,
pitch or yaw moves each tie point's right residual through both images at their own imaging
times (:func:`platform_design`), as a matching window sees it (:func:`window_gain`), and the
along-base axis's amplitudes estimated per frequency from the DEM rows against the DEM's own
error at that frequency (:func:`along_wiener`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.pair_observations import Noise, Observations, base_axes
from carto.framework.geometry.line_correction import LineBasis

FloatArray = NDArray[np.float64]

NOISE_OFFSETS = (-8, -7, -6, -5, -4, -3, 3, 4, 5, 6, 7, 8)
"""Where :func:`along_wiener` measures the DEM rows' noise at a jitter frequency: at these
multiples of the tie points' resolution (one cycle over their lines) either side of it, so
that the jitter's own sidelobes (1/(pi m) of its amplitude) stay small."""
JITTER_SIGMA_PX = 0.3
"""A-priori sigma of each jitter sine and cosine coefficient, px (jitter of a few tenths of a
pixel; the prior keeps a frequency the DEM's errors alone pretend to see small)."""
DESIGN_CHUNK_ROWS = 65536
"""Rows whose :func:`platform_design` is formed at once (:func:`platform_px`)."""
NUISANCE_PERIODS = 2.0
""":func:`along_wiener`'s nuisance spline has knots this many of the slowest jitter period
apart (the slow wander and the DEM's long-wave error, kept out of the jitter's estimate)."""


def seconds_per_line(obs: Observations) -> float:
    """The right image's line period, from its rows' imaging times."""
    slope = abs(float(np.polyfit(obs.line, obs.time_s[:, 0], 1)[0]))
    return slope if slope > 0 else 1.0


def platform_design(
    obs: Observations,
    hz: tuple[float, ...],
    period_s: float | None = None,
    per_image: bool = False,
) -> FloatArray:
    """``(N, 2, 6 F)``: how each platform jitter coefficient (axis-major: roll, pitch, yaw;
    then frequency; then sine and cosine of ``2 pi f t``, radians) moves each row's right
    residual (line, sample), through both images at their own imaging times
    (:attr:`Observations.attitude_px`), as the tie points see it (attenuated by their
    matching window, :func:`window_gain`; ``period_s``: the right image's line period,
    :func:`seconds_per_line` when not given). ``per_image``: ``(N, 2, 12 F)``, the right
    image's coefficients then the left image's, each image's jitter its own (no phase tie
    across the tens of seconds between the views, :func:`image_rad`)."""
    n = obs.line.size
    if not hz:
        return np.zeros((n, 2, 0))
    if period_s is None:
        period_s = seconds_per_line(obs)
    w = 2.0 * math.pi * np.asarray(hz)[None, None, :] * obs.time_s[:, :, None]  # (N, 2, F)
    gain = window_gain(np.asarray(hz) * period_s, obs.window_lines)
    waves = np.stack([np.sin(w) * gain, np.cos(w) * gain], axis=-1).reshape(n, 2, -1)
    # (N, image, axis_img, axis_att) x (N, image, 2F) -> (N, axis_img, [image,] axis_att, 2F)
    spec = "nika,nif->nkiaf" if per_image else "nika,nif->nkaf"
    return np.einsum(spec, obs.attitude_px, waves).reshape(n, 2, -1)


def platform_px(
    obs: Observations,
    hz: Sequence[float],
    rad: FloatArray | None,
    chunk_rows: int = DESIGN_CHUNK_ROWS,
) -> FloatArray:
    """``(N, 2)``: how the jitter ``rad`` (a fit's ``platform_rad``, :func:`image_rad`) at
    ``hz`` moves each row's right residual, its design formed ``chunk_rows`` rows at a time
    (a whole pair's 1.9 M points at 8 frequencies per image would take 2.9 GB at once)."""
    out = np.zeros((obs.line.size, 2))
    if not hz or rad is None or not rad.size:
        return out
    period, per_image = seconds_per_line(obs), rad.ndim == 3
    for start in range(0, obs.line.size, chunk_rows):
        part = slice(start, start + chunk_rows)
        out[part] = platform_design(obs.subset(part), tuple(hz), period, per_image) @ rad.ravel()
    return out


def image_rad(rad: FloatArray, image: int) -> FloatArray:
    """``(3, 2 F)``: the jitter coefficients of the right (``image`` 0) or the left image
    (1) from a fit's ``platform_rad``: ``(3, 2 F)`` tied to the platform (both images'), or
    ``(2, 3, 2 F)`` per image (:func:`platform_design`'s ``per_image``)."""
    return rad[image] if rad.ndim == 3 else rad


def window_gain(cycles_per_line: FloatArray, window_lines: float) -> FloatArray:
    """What a matching window of ``window_lines`` (a box: the template's mean) leaves of a
    sinusoid's amplitude, ``sinc(f W)``: at Cartosat-1's 97 Hz (31 lines) a 15-line template
    sees 0.66 of it (the platform jitter estimated on a simulated pair's true DEM came out at
    0.53-0.73 of the simulated amplitude at 67-97 Hz without this)."""
    return np.sinc(np.asarray(cycles_per_line, np.float64) * float(window_lines))


def px_per_rad(obs: Observations) -> FloatArray:
    """``(3,)``: the right image's median motion per radian of roll, pitch and yaw."""
    return np.median(np.linalg.norm(obs.attitude_px[:, 0], axis=1), axis=0)


def along_axes(obs: Observations) -> NDArray[np.bool_]:
    """``(3,)``: the attitude axes that move the right image mostly along the stereo base
    (pitch, for along-track stereo): only the DEM rows tell them from the starting DEM's
    errors."""
    u0 = base_axes(obs.parallax)[0][0]
    along = np.median(np.abs(np.einsum("j,njk->nk", u0, obs.attitude_px[:, 0])), axis=0)
    return along > 0.5 * px_per_rad(obs)


def has_platform(obs: Observations) -> bool:
    """Whether ``obs`` carry a platform's attitude partials."""
    return bool(obs.attitude_px.size and np.any(obs.attitude_px[:, 0]))


def platform_sigmas(obs: Observations, n_f: int, images: int, sigma_px: float) -> FloatArray:
    """A-priori sigmas of the platform jitter coefficients, radians: ``sigma_px`` through
    the right image's median motion per radian of each axis (``images``: 2, each image's
    coefficients, :func:`platform_design`'s ``per_image``)."""
    if not n_f:
        return np.zeros(0)
    return np.tile(np.repeat(sigma_px / np.maximum(px_per_rad(obs), 1e-3), 2 * n_f), images)


REFINE_HALF_WIDTH_HZ = 0.03
"""The platform frequency is searched this far either side of the periodogram's peak."""
REFINE_STEP_HZ = 0.0005
"""The search step: a phase step of 0.16 rad over the 52 s between Cartosat-1's views."""


def refined_hz(
    obs: Observations,
    rest_px: FloatArray,
    noise: Noise,
    jitter: tuple[tuple[float, ...], FloatArray],
    k: int,
) -> tuple[float, ...]:
    """The platform frequencies ``jitter[0]`` with the ``k``-th refined (``jitter[1]``: a
    fit's ``platform_rad``; ``rest_px``: the ``(N, 2)`` residuals that fit leaves). The
    right and left images see the platform's jitter at times tens of seconds apart
    (Cartosat-1: 52 s), so the phase between them turns by ``2 pi df 52 s``; a periodogram
    of one image's few seconds does not know a frequency to the thousandth of a hertz this
    needs. The frequency is searched on a grid (:data:`REFINE_HALF_WIDTH_HZ`,
    :data:`REFINE_STEP_HZ`), fitting that frequency's coefficients alone to the residuals
    less the rest of the fit; a whole number of cycles over the gap more or less changes
    little, the phase between the images is what counts. Each image's own jitter
    (``per_image``) needs the frequency to a fraction of a cycle over the tie points' lines
    only: the search spans one cycle over them either side, in 40 steps."""
    hz = list(jitter[0])
    per_image = jitter[1].ndim == 3
    rad = np.asarray(jitter[1]).reshape(-1, 3, len(hz), 2)
    u, v, _ = base_axes(obs.parallax)
    s_along, s_across = obs.sigmas(noise)
    own = np.zeros_like(rad)
    own[:, :, k] = rad[:, :, k]
    rest = rest_px + platform_px(obs, hz, own.reshape(jitter[1].shape))
    y = np.r_[np.einsum("ij,ij->i", u, rest) / s_along, np.einsum("ij,ij->i", v, rest) / s_across]
    prior = np.diag(1.0 / platform_sigmas(obs, 1, rad.shape[0], JITTER_SIGMA_PX) ** 2)
    period = seconds_per_line(obs)  # once, not per candidate
    half, step = REFINE_HALF_WIDTH_HZ, REFINE_STEP_HZ
    if per_image:
        half = 1.0 / max(float(np.ptp(obs.line)) * period, 1e-9)
        step = half / 20.0
    best, best_cost = hz[k], np.inf
    for f in hz[k] + np.arange(-half, half + 1e-9 * half, step):
        d = platform_design(obs, (float(f),), period, per_image)
        a = np.vstack(
            [
                np.einsum("ij,ijk->ik", u, d) / s_along[:, None],
                np.einsum("ij,ijk->ik", v, d) / s_across[:, None],
            ]
        )
        rhs = a.T @ y
        x = np.linalg.solve(a.T @ a + prior, rhs)
        cost = float(y @ y - rhs @ x)
        if cost < best_cost:
            best, best_cost = float(f), cost
    hz[k] = best
    return tuple(hz)


@attrs.frozen
class AlongWiener:
    """:func:`along_wiener`'s result: ``rad`` ``(images, 3, F, 2)`` (zero on the other axes), and
    per frequency the least-squares amplitude, the noise amplitude the neighbouring
    frequencies give and the gain, radians (``gain``: 0 to 1)."""

    rad: FloatArray
    amplitude_rad: tuple[float, ...]
    noise_rad: tuple[float, ...]
    gain: tuple[float, ...]

    def record(self) -> dict[str, list[float]]:
        return {
            "amplitude_urad": [round(a * 1e6, 4) for a in self.amplitude_rad],
            "noise_urad": [round(a * 1e6, 4) for a in self.noise_rad],
            "gain": [round(g, 3) for g in self.gain],
        }


def along_wiener(
    obs: Observations, hz: Sequence[float], along_px: FloatArray, images: int = 1
) -> AlongWiener:
    """The along-base axes' jitter (:func:`along_axes`) at the platform's frequencies ``hz``,
    from the DEM rows' along-base residuals ``along_px`` (those axes' terms not removed),
    each frequency's least-squares amplitude shrunk by a Wiener gain ``1 - N / P``: ``P``
    its power, ``N`` the power the same fit finds at neighbouring frequencies
    (:data:`NOISE_OFFSETS`; their median, as that of Gaussian terms). The starting
    DEM's error is red: one weight for all the DEM rows (its 64-line band factor) either
    drowned the pitch on a full swath or let the DEM's errors at 7 Hz pass for it on a
    1000 px window. A nuisance spline (:data:`NUISANCE_PERIODS`) takes the slow wander.
    ``images``: 1 (the platform's coefficients) or 2 (each image's, ``per_image``)."""
    n_f = len(hz)
    rad = np.zeros((images, 3, n_f, 2))
    rows = obs.dem_rows
    axes_on = along_axes(obs) if rows.sum() >= 20 * n_f * images else np.zeros(3, bool)
    if not n_f or not axes_on.any():
        return AlongWiener(rad, (0.0,) * n_f, (0.0,) * n_f, (0.0,) * n_f)
    sub = obs.subset(rows)
    period_s = seconds_per_line(sub)
    u0 = base_axes(sub.parallax)[0][0]
    first, last = float(sub.line.min()), float(sub.line.max())
    span = max(last - first, 1.0)
    knot = NUISANCE_PERIODS / max(min(hz) * period_s, 1e-9)
    nuisance, _ = LineBasis(1, min(knot, span), (), (first, max(last, first + 1.0))).design(
        sub.line
    )
    q, _ = np.linalg.qr(nuisance)

    def columns(f: float) -> FloatArray:  # the along axes' along-base columns at f, spline out
        d = platform_design(sub, (float(f),), period_s, images == 2)
        d = np.einsum("j,njk->nk", u0, d).reshape(-1, images, 3, 2)[:, :, axes_on]
        d = d.reshape(sub.line.size, -1)
        return d - q @ (q.T @ d)

    y = along_px[rows] - q @ (q.T @ along_px[rows])
    a = np.hstack([columns(f) for f in hz])
    n_c = a.shape[1] // n_f
    normal, rhs = a.T @ a, a.T @ y
    x = np.linalg.lstsq(normal, rhs, rcond=None)[0].reshape(n_f, n_c)
    df_hz = 1.0 / (span * period_s)
    amplitude, noise, gains = [], [], []
    for k, f in enumerate(hz):
        power = []
        block = slice(k * n_c, (k + 1) * n_c)
        for m in NOISE_OFFSETS:
            g = f + m * df_hz
            if g <= 0 or any(abs(g - h) < 1.5 * df_hz for j, h in enumerate(hz) if j != k):
                continue
            c = columns(g)  # frequency k's columns moved to g, the normal equations updated
            trial, trial_rhs = normal.copy(), rhs.copy()
            trial[block] = c.T @ a
            trial[:, block] = trial[block].T
            trial[block, block] = c.T @ c
            trial_rhs[block] = c.T @ y
            x_m = np.linalg.lstsq(trial, trial_rhs, rcond=None)[0].reshape(n_f, n_c)
            power.append(float(np.sum(x_m[k] ** 2)))
        p = float(np.sum(x[k] ** 2))
        # the median of a chi-square of n_c terms is about n_c (1 - 2 / (9 n_c))^3 sigma^2
        n = float(np.median(power)) / (1.0 - 2.0 / (9.0 * n_c)) ** 3 if power else p
        gain = max(0.0, 1.0 - n / p) if p > 0 else 0.0
        gains.append(gain)
        amplitude.append(math.sqrt(2.0 * p / n_c))
        noise.append(math.sqrt(2.0 * n / n_c))
        rad[:, axes_on, k] = (gain * x[k]).reshape(images, -1, 2)
    return AlongWiener(rad, tuple(amplitude), tuple(noise), tuple(gains))
