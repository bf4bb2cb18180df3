"""Relative orientation of a stereo pair inside the DEM chain: the right image corrected to
the left one from dense tie points and the starting DEM (:func:`relative_orientation`).

Why. A DEM carries its pair's relative orientation errors: a pointing error across the stereo
base leaves a parallax no height removes (the matcher then searches off its line), and one
along the base is a height error. Attitude jitter and slow attitude wander of a same-pass
pair (Cartosat-1 Fore and Aft 52 s apart) are different at the two imaging times, so a
pitch error ``p(t)`` shows as a height error proportional to ``p(t + dt) - p(t)``: bands
across the whole swath, changing every few hundred lines (``--errors full``: +-3-4 m, NMAD
1.6 m against 0.2 m with the true models, issue 30).

The observations. Tie points on a grid over the common area (every ``tie_spacing_px``
ortho pixels, :func:`~carto.framework.matching.tiepoints.automatic_tie_points`); each left
point is located on the starting DEM (:meth:`~carto.framework.geometry.sensor.Sensor.
locate_on_dem`) and projected into the right image. The right residual ``r`` (measured minus
computed) is

    ``r_i = B(l_i) c + p_i (dh_i + dH) + e_i``

with ``B(l)`` the basis of the correction (:class:`~carto.framework.geometry.line_correction.
LineBasis`: per image line, a line and a sample shift), ``p_i`` the right image's parallax
per metre of height along the left ray (pixels per metre: the stereo base's direction and
B/H), ``dh_i`` the DEM's own error at the point (sigma ``sigma_h``: random), ``dH`` a
common DEM offset and ``e_i`` the matching error (sigma ``sigma_m``). Across the base the
residual is orientation only; along it, it is orientation plus the DEM's error, which is
large for one post (an SRTM-like DEM: metres) but averages out over the hundreds of posts of
one image line: the physics that lets a pair's jitter be estimated from the pair itself.
``dh_i`` is eliminated in closed form (each point's 2 x 2 covariance ``sigma_m^2 I +
sigma_h^2 p p^T``); ``sigma_m`` and ``sigma_h`` are estimated from the residuals across and
along the base (two variance components). The fit splits every residual along and across
one base direction (the median, :func:`~carto.framework.adjustment.pair_observations.
base_axes`), and ``dH`` moves every point by one parallax vector (the median): with each
point's own (which turn and scale by a few percent over a swath), the many precise
across-base rows and that variation told the along-base constant from ``dH`` and the
starting DEM's errors set both (true models of a simulated pair, DEM datum: ``dH`` -6.3 m
and the DEM 5.4 m low, for a starting DEM 1 m high).

The correction. Line scanners (and wrappers of one) get a line-varying correction. Across
the base: a cubic B-spline of the line (knots every ``knot_lines``, spanning the lines the
points cover) plus a sine and a cosine per jitter frequency. Along the base: a constant and
the same sinusoids in the fit, then the slow shape from the DEM rows' along-base residuals
(:mod:`~carto.framework.adjustment.along_shape`). (1) Its trend, a polynomial of orders 1-2
of the line over the whole swath (a relative pitch trend of a same-pass pair: a height ramp
along the track that tie points cannot see), each coefficient shrunk by a Wiener gain
against its variance from the bin means' scatter. (2) What is left, averaged per knot
interval, where the left and right halves of the swath see the same orientation but
different parts of the starting DEM, so half their difference measures the DEM's error of a
mean and the spread of the means beyond it the orientation's; the means, shrunk by the gain
``signal / (signal + noise)`` (a Wiener filter; no shape where the DEM cannot tell it),
become the spline along the base. (3) The along-base tilt across the swath (a relative yaw:
a height tilt across the track), which
:class:`~carto.framework.geometry.line_correction.LineCorrected` carries as a line shift
proportional to the sample. The rest is refitted under them
(:func:`~carto.framework.adjustment.pair_correction.estimate_correction`). Where both
images are line scanners of one platform (same-pass stereo: Cartosat-1 Fore and Aft), the
jitter is the platform's attitude, one time series seen by each image at its own imaging
time (:func:`~carto.framework.adjustment.pair_observations.platform_of`): per frequency, a
sine and a cosine per axis (roll, pitch, yaw), moving the right image by its partials and
the left one (zero mean: it keeps its place) through the left-to-right Jacobian. The
terrain's parallax changes which left line meets a right line by tens of lines, so sinusoids
of the right image's lines alone cannot carry the left image's jitter; the images see the
platform 52 s apart, so each frequency is refined on a fine grid (the phase between the
images turns by ``2 pi df 52 s``). An axis that moves the images along the base (pitch) is
bounded by what the others found across it at that frequency (the DEM rows alone take the
starting DEM's errors for pitch jitter). Both models carry the estimate (periodic attitude
corrections of their trajectories, saved in the model files). It is an option
(:attr:`RelativeOrientationSettings.platform_jitter`), off by default: on three simulated
``--errors full`` pairs (1 GCP) the DEM error the orientation leaves (perfect
correspondences, ``benchmarks/results/orientation_limit.json``) was 0.64 / 1.13 / 1.32 m
NMAD with it against 0.68 / 0.79 / 1.30 m with the right image's sinusoids, and 1.03 / 1.16 /
1.41 m without a relative orientation: its pitch terms take the starting DEM's errors (with
the true DEM they recover the simulated amplitudes at 4.7-67 Hz). Other sensors always get
the right image's sinusoids. Jitter frequencies come from
the Lomb-Scargle periodogram of the across-base residuals binned by line
(:func:`~carto.framework.adjustment.jitter.detect_jitter_frequencies`; along the base the
DEM's correlated errors look like peaks to a white-noise test), one at a time with a re-fit
after each. Priors: ``SHAPE_SIGMA_PX``, ``JITTER_SIGMA_PX``; the DEM rows' along-base
weight carries the DEM's correlated share (:attr:`Noise.band_factor`,
:mod:`~carto.framework.adjustment.band_factor`). Other sensors (RPCs)
get a shift. The sensors come back as
:class:`~carto.framework.geometry.line_correction.LineCorrected`.

The datum (what holds the along-base constant, which a pair cannot see): GCPs when given
(rows like the ties, with the GCP's height and sigma and no DEM offset; the right image's
measurement refined by the adjustment's GCP transfer, :func:`gcps_with_offsets`), weighed
against the DEM offset ``dH`` with its a-priori sigma (the DEM's absolute accuracy,
:attr:`RelativeOrientationSettings.dem_offset_sigma_m`, and never less than its post
error, ``pair_correction.offset_sigma_m``); without GCPs the starting DEM (its own bias
remains, as when it is the only height reference), unless that sigma is worse than the
models' own (a constant start over relief); then, and for a constant
starting height, the models (``dH`` free and the along-base correction of zero mean over
the points). On the Reunion pair (constant 2344 m start, SGM, 0.5 m), the DEM went from
NMAD 0.399 m / median -0.08 m without the relative orientation to 0.386 m / -0.025 m, the
across-base parallax from 0.73 px to 0.004 px. One GCP
holds it to its own accuracy: on the simulator's ``--errors full`` pair (seed 0, hilly), the
GCP's height error put the DEM's median about 3 m off, as it did the adjusted models' (2.6 m).

Outliers: points whose normalised residual exceeds :data:`REJECT_SIGMAS` are dropped and the
fit repeated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.pair_correction import (
    MIN_POINTS,
    MODES,
    SHIFT_SPACING_PX,
    Fit,
    RelativeOrientationSettings,
    correction_px,
    estimate_correction,
)
from carto.framework.adjustment.pair_observations import (
    Observations,
    Platform,
    base_axes,
    concat,
    gcps_to_observations,
    platform_of,
    ties_to_observations,
)
from carto.framework.adjustment.platform_jitter import image_rad
from carto.framework.errors import InputError
from carto.framework.geometry.line_correction import LineBasis, LineCorrected
from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]

__all__ = [
    "MODES",
    "RelativeOrientation",
    "RelativeOrientationSettings",
    "estimate_correction",
    "relative_orientation",
]


@attrs.frozen(eq=False)
class RelativeOrientation:
    """The outcome of :func:`relative_orientation`.

    Attributes:
        right: the corrected right sensor (the given one when nothing was corrected).
        record: what ``report.json`` says of it (``relative_orientation``).
        left: the left sensor with its jitter corrected (zero mean), or None when it stays
            as given.
    """

    right: Sensor
    record: dict[str, Any]
    left: Sensor | None = None


def _kind(mode: str, right: Sensor) -> str:
    if mode != "auto":
        return mode
    from carto.framework.adjustment.attitude_terms import line_scanner_of

    inner = right
    while isinstance(inner, LineCorrected):
        inner = inner.base
    return "line" if line_scanner_of(inner) is not None else "shift"


def _stats(obs: Observations, correction: FloatArray | None = None) -> dict[str, float]:
    """Median and RMS of the across-base residual (px) and the median along it."""
    res = obs.residual if correction is None else obs.residual - correction
    u, v, _ = base_axes(obs.parallax)
    across = np.einsum("ij,ij->i", v, res)
    along = np.einsum("ij,ij->i", u, res)
    return {
        "median_across_base_px": round(float(np.median(across)), 4),
        "rms_across_base_px": round(float(np.sqrt(np.mean(across**2))), 4),
        "median_along_base_px": round(float(np.median(along)), 4),
    }


def _line_rate_hz(sensor: Sensor) -> float | None:
    """Lines per second of a line scanner (None for other sensors)."""
    from carto.framework.adjustment.attitude_terms import line_scanner_of

    inner = sensor
    while isinstance(inner, LineCorrected):
        inner = inner.base
    scanner = line_scanner_of(inner)
    if scanner is None:
        return None
    n = float(scanner.n_lines)
    t0, t1 = (float(t) for t in scanner.timing.time(np.array([0.0, n])))
    return n / (t1 - t0) if t1 != t0 else None


def with_platform_jitter(
    sensor: Sensor, platform: Platform, hz: tuple[float, ...], rad: FloatArray
) -> Sensor:
    """``sensor`` (one of ``platform``'s two) with the platform's jitter ``rad`` (``(3, 2 F)``:
    per axis, a sine and a cosine of ``2 pi f t`` per frequency ``hz``, ``t`` from the
    platform's reference) folded into its trajectory as periodic attitude corrections, which
    count time from the trajectory's middle: each pair of coefficients turned by that
    phase. The model files keep it."""
    from carto.framework.adjustment.attitude_terms import line_scanner_of, replace_line_scanner

    scanner = line_scanner_of(sensor)
    assert scanner is not None  # a platform's sensors are line scanners
    phase = 2.0 * np.pi * np.asarray(hz) * platform.phase_s(scanner)
    s, c = rad[:, 0::2], rad[:, 1::2]
    # s sin(w (tau + p)) + c cos(w (tau + p)), tau from the trajectory's middle
    out = np.empty_like(rad)
    out[:, 0::2] = s * np.cos(phase) - c * np.sin(phase)
    out[:, 1::2] = s * np.sin(phase) + c * np.cos(phase)
    trajectory = scanner.trajectory.with_attitude_periodic(hz, out)
    return replace_line_scanner(sensor, scanner.with_trajectory(trajectory))


def _platform_record(fit: Any) -> dict[str, Any] | None:
    """The platform jitter for ``report.json``: per frequency, the amplitude per axis (urad)."""
    from carto.framework.adjustment.attitude_terms import AXES

    if fit.platform_rad is None or not fit.platform_rad.size:
        return None

    def amplitudes(rad: FloatArray) -> dict[str, list[float]]:
        amplitude = np.hypot(rad[:, 0::2], rad[:, 1::2]) * 1e6
        return {axis: np.round(amplitude[k], 4).tolist() for k, axis in enumerate(AXES)}

    per_image = fit.platform_rad.ndim == 3
    return {
        "frequencies_hz": [round(f, 3) for f in fit.platform_hz],
        "amplitude_urad": amplitudes(image_rad(fit.platform_rad, 0)),
        **({"left_amplitude_urad": amplitudes(fit.platform_rad[1])} if per_image else {}),
        **({"along_wiener": fit.platform_along} if fit.platform_along else {}),
    }


TIE_TEMPLATE_PX = 15
"""The tie points' matching template, ortho pixels at the images' ground sampling (about a
line): jitter of a period near it is seen attenuated (:func:`~carto.framework.adjustment.
platform_jitter.window_gain`). On a simulated ``--errors full`` pair (hilly-0), modelling it
took the DEM error the orientation leaves from 0.73 m NMAD (measured by hand before) to
0.68 m (``benchmarks/results/orientation_limit.json``)."""


def relative_orientation(
    images: Mapping[str, Any],
    sensors: Mapping[str, Sensor],
    dem: Any,
    settings: RelativeOrientationSettings,
    *,
    gcps: Mapping[str, NDArray] | None = None,
    constant_dem: bool = False,
    engine: Any = None,
    progress: Any = None,
) -> RelativeOrientation:
    """Correct the right image of ``sensors`` (two: left first) to the left one (module
    docstring). ``images``: the prepared images (image sources); ``dem``: the starting DEM
    (ellipsoidal); ``gcps``: a control table of GCPs measured in both images (the datum);
    ``constant_dem``: the starting DEM is a constant height (the datum is then the models').
    """
    names = tuple(sensors)
    if len(names) != 2:
        raise InputError(f"relative orientation needs two images, got {len(names)}")
    left, right = (sensors[n] for n in names)
    kind = _kind(settings.mode, right)
    record: dict[str, Any] = {"mode": settings.mode, "correction": kind, "image": names[1]}
    if kind == "none":
        return RelativeOrientation(right, {**record, "applied": False})
    spacing = _tie_spacing(kind, settings, left.image_shape)
    table = _match_ties(images, sensors, dem, spacing, engine)
    platform = platform_of(left, right) if kind == "line" and settings.platform_jitter else None
    obs = ties_to_observations(table, names, left, right, dem, platform, TIE_TEMPLATE_PX)
    record["tie_points"] = int(obs.line.size)
    if obs.line.size < MIN_POINTS:
        record.update(applied=False, reason=f"{obs.line.size} tie points (< {MIN_POINTS})")
        return RelativeOrientation(right, record)
    datum = "models" if constant_dem else "dem"
    if gcps is not None:
        control = gcps_to_observations(gcps, names, left, right, platform)
        if control.line.size:
            obs = concat(obs, control)
            datum = "gcp"
            record["gcps"] = int(control.line.size)
    n_lines = int(right.image_shape[0])
    basis, fit, keep = estimate_correction(obs, n_lines, kind, datum, settings)
    left_corrected, right_jittered = left, right
    if platform is not None and fit.platform_rad is not None and fit.platform_rad.size:
        hz, rad = fit.platform_hz, fit.platform_rad
        left_corrected = with_platform_jitter(left, platform, hz, image_rad(rad, 1))
        right_jittered = with_platform_jitter(right, platform, hz, image_rad(rad, 0))
    corrected = LineCorrected(
        right_jittered, basis, fit.coefficients, fit.tilt_px, fit.tilt_centre_sample
    )
    record.update(_fit_record(obs, keep, basis, fit, _line_rate_hz(right)))
    if progress is not None:
        progress(_progress_message(names, kind, datum, int(keep.sum()), record, basis, fit))
    return RelativeOrientation(corrected, record, left_corrected)


def _tie_spacing(
    kind: str, settings: RelativeOrientationSettings, shape: tuple[int, ...]
) -> tuple[float, float]:
    """The tie-point grid's ``(rows, cols)`` spacing, ortho pixels, over an image of ``shape``:
    ``tie_spacing_px`` for a line correction (:data:`SHIFT_SPACING_PX` for a shift), the
    columns widened until about ``max_tie_points`` cover the image. The rows keep their
    spacing: they sample the correction in time (jitter of 31 lines, Cartosat-1's 97 Hz,
    needs rows closer than 15 lines), while across the swath a few hundred points a row hold
    a line's mean (the starting DEM's posts, not the points' number, bound it)."""
    if kind != "line":
        side = max(SHIFT_SPACING_PX, math.sqrt(math.prod(shape) / settings.max_tie_points))
        return side, side
    rows = settings.tie_spacing_px
    return rows, max(rows, math.prod(shape) / (rows * settings.max_tie_points))


def _match_ties(
    images: Mapping[str, Any],
    sensors: Mapping[str, Sensor],
    dem: Any,
    spacing: tuple[float, float],
    engine: Any,
) -> Any:
    """The tie points of the pair: a grid over the common area (every ``spacing`` ortho
    pixels, rows and columns: :func:`_tie_spacing`), one per cell, refined by least-squares
    matching."""
    from carto.framework.matching.tiepoints import automatic_tie_points

    names = tuple(sensors)
    return automatic_tie_points(
        {n: images[n] for n in names},
        {n: sensors[n] for n in names},
        dem,
        candidates="grid",
        spacing_px=spacing,
        per_cell=1,
        subpixel="lsm",
        template=TIE_TEMPLATE_PX,
        min_points=0,
        require_closure=False,
        engine=engine,
        prepared=True,
    )


def _fit_record(
    obs: Observations, keep: NDArray[np.bool_], basis: LineBasis, fit: Fit, rate: float | None
) -> dict[str, Any]:
    """What ``report.json`` says of an applied correction: the residuals of the points kept
    before and after it, the noise and datum found, and the correction along the base
    (pixels and what it does to heights) over every point; ``rate``: the right image's
    lines per second (jitter frequencies in Hz), None when it is no line scanner."""
    model, _ = basis.evaluate(obs.line, fit.coefficients)
    kept = obs.subset(keep)
    u, _, norm = base_axes(obs.parallax)
    along_shift = np.einsum("ij,ij->i", u, model)
    return dict(
        applied=True,
        datum=fit.datum,
        rejected=int((~keep).sum()),
        before=_stats(kept),
        after=_stats(kept, correction_px(kept, basis, fit)),
        matching_sigma_px=round(fit.noise.sigma_m, 4),
        dem_sigma_m=round(fit.noise.sigma_h, 3),
        dem_band_factor=round(fit.noise.band_factor, 2),
        dem_offset_m=round(fit.dem_offset_m, 3),
        along_shape=fit.along_shape,
        tilt=fit.tilt,
        correction_along_base_px={
            "min": round(float(along_shift.min()), 4),
            "max": round(float(along_shift.max()), 4),
            "median": round(float(np.median(along_shift)), 4),
        },
        correction_height_m={  # what the along-base correction does to heights
            "min": round(float((along_shift / norm).min()), 3),
            "max": round(float((along_shift / norm).max()), 3),
        },
        basis=basis.as_dict(),
        frequencies_hz=(
            [round(f * rate, 3) for f in basis.frequencies] if rate is not None else None
        ),
        coefficients=np.round(fit.coefficients, 5).tolist(),
        platform_jitter=_platform_record(fit),
    )


def _progress_message(
    names: tuple[str, ...],
    kind: str,
    datum: str,
    n_kept: int,
    record: dict[str, Any],
    basis: LineBasis,
    fit: Fit,
) -> str:
    """The one line :func:`relative_orientation` reports: what was corrected to what, and
    the across-base parallax and along-base correction it found."""
    return (
        f"relative orientation of {names[1]} to {names[0]} ({kind}, datum {datum}, "
        f"{n_kept} points): across-base parallax "
        f"{record['before']['median_across_base_px']:+.3f} -> "
        f"{record['after']['median_across_base_px']:+.3f} px, along-base correction "
        f"{record['correction_height_m']['min']:+.2f} .. "
        f"{record['correction_height_m']['max']:+.2f} m"
        + (
            f", {len(basis.frequencies) + len(fit.platform_hz)} jitter frequencies"
            if basis.frequencies or fit.platform_hz
            else ""
        )
    )
