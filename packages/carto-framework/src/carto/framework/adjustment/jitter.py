"""Periodic attitude jitter as adjustment parameters (:func:`with_jitter_terms`).

A platform's attitude jitter (reaction wheels, solar-array and antenna drives: sinusoids at a
few platform frequencies) is in the true motion but not in the attitude samples of the product
(8 Hz samples of a filtered attitude). The polynomial corrections of a trajectory cannot
represent it: over a 2000-line window of an agile view 1.7 and 4.3 Hz jitter of 2e-5 deg makes
the image points of each view wander by about 0.2 px, the same for every point imaged at the
same time. Left out of the model, this misfit is not white noise: it is common to every tie
point on a line, so its pull on weakly determined combinations of the parameters (block
deformations the tie points cannot see, held only by the priors and a few GCPs) grows with the
number of tie points while the priors and GCPs stay the same. Adjustments then get *worse* with
more tie points (``benchmarks/bba_scaling.py``, issue 18: checkpoint heights 1 -> 5 m from 1k to
100k ties, sigma0 1.3).

:func:`with_jitter_terms` wraps line scanners in :class:`JitterCorrected` sensors that add, per
attitude axis and platform frequency ``f``, a sine and a cosine coefficient ``(s, c)`` of the
attitude correction ``s sin(2 pi f t) + c cos(2 pi f t)`` (``t`` from the middle of the
trajectory), weighted by an a-priori RMS amplitude ``A`` of the jitter: each coefficient's
sigma is ``A / sqrt(2)``, so that ``E[s^2 + c^2] = A^2``. Sensors sharing a trajectory
share its jitter parameters (the names carry the trajectory's prefix). The jitter angles are a
fraction of a microradian, so their effect is applied to first order in image space: the image
point moves by the partials of ``(line, sample)`` w.r.t. the constant attitude corrections
(``c0``, analytic) times the jitter angles at the imaging time (the neglected terms are below
1e-6 px).

The delivered models stay line scanners: :func:`fold_jitter_terms` puts the estimated jitter
into their trajectories as fixed periodic attitude corrections
(:meth:`~carto.framework.geometry.trajectory.Trajectory.with_attitude_periodic`, saved in the
model files), and :func:`jitter_document` reports it (amplitude, phase, sigmas per image, axis
and frequency). Left out of the delivered models (as before issue 18's last step) a triplet's
checkpoints saw the jitter the adjustment had fitted: slow pitch jitter of the fore and aft
views is a height ramp along track, 5-9 m over a 1000-line window under ``--errors full``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.adjustment.attitude_terms import (
    AXES,
    AttitudeTermsCorrected,
    line_scanner_of,
    map_layers,
    replace_line_scanner,
)
from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.misfit import residual_lines
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Parameter, Sensor

FloatArray = NDArray[np.float64]

MAX_DETECTED_FREQUENCIES = 6
"""At most this many jitter frequencies are taken from the residuals (one per re-adjustment)."""
DETECTION_FALSE_ALARM = 1e-4
"""A periodogram peak is a jitter frequency when its false-alarm probability is below this."""
MIN_DETECTION_POINTS = 50
"""Residual series shorter than this are not searched."""
MAX_JITTER_HZ = 250.0
"""The fastest jitter searched (Hz): platform structures damp faster vibrations, and with 100k
tie points four median spacings would reach tens of kHz (a grid of 10^5 frequencies per
series)."""
MIN_CYCLES = 1.0
"""The slowest frequency searched makes this many cycles over a series: slower wander is the
trajectory's polynomial corrections' (over a 0.8 s window a 1.36-cycle jitter is not: left out,
the checkpoint heights of a 10k-tie triplet are 1.3 m instead of 0.2 m)."""


def jitter_parameter_names(prefix: str, n_frequencies: int) -> list[str]:
    """Names of the jitter coefficients, axis-major: ``<prefix>jitter.<axis>.f<k>.sin|cos``."""
    return [
        f"{prefix}jitter.{axis}.f{k}.{part}"
        for axis in AXES
        for k in range(n_frequencies)
        for part in ("sin", "cos")
    ]


@attrs.frozen(eq=False)
class JitterCorrected(AttitudeTermsCorrected):
    """A line scanner plus periodic attitude corrections (see the module docstring).

    Attributes:
        base: the line scanner (its own parameters stay as they are).
        terms: the coefficients, named by :func:`jitter_parameter_names` (radians).
        frequencies_hz: the jitter frequencies (their starting values when ``rates`` are
            given).
        rates: the frequencies as parameters (Hz, named ``jitter.f<k>.hz``: the platform's,
            shared by every image), estimated with the coefficients; empty: fixed.
    """

    frequencies_hz: tuple[float, ...] = ()
    rates: tuple[Parameter, ...] = ()

    @property
    def jitter(self) -> tuple[Parameter, ...]:
        """The jitter coefficients (:attr:`terms`)."""
        return self.terms

    @property
    def frequencies(self) -> tuple[float, ...]:
        """The current jitter frequencies (Hz)."""
        return tuple(p.value for p in self.rates) if self.rates else self.frequencies_hz

    def _extra_parameters(self) -> dict[str, tuple[Parameter, ...]]:
        return {"rates": self.rates}

    def _basis(self, t: FloatArray) -> FloatArray:
        """``(N, 2F)``: sin and cos of each frequency at times ``t`` (s since the epoch)."""
        tau = t - self.line_scanner.trajectory.t_mid_s
        cols = []
        for f in self.frequencies:
            w = 2.0 * math.pi * f * tau
            cols += [np.sin(w), np.cos(w)]
        return np.stack(cols, axis=-1)

    def _extra_partials(self, name: str, a_c0: FloatArray, tau: FloatArray) -> FloatArray:
        """d/df of ``s sin(2 pi f tau) + c cos(2 pi f tau)``, per axis, into image space."""
        j = [p.name for p in self.rates].index(name)
        coeffs = np.array([p.value for p in self.terms]).reshape(3, -1)
        w = 2.0 * math.pi * self.frequencies[j] * tau
        sin_j, cos_j = np.sin(w), np.cos(w)
        d_angle = (
            2.0
            * math.pi
            * tau[:, None]
            * (
                coeffs[None, :, 2 * j] * cos_j[:, None]
                - coeffs[None, :, 2 * j + 1] * sin_j[:, None]
            )
        )
        return np.einsum("nka,na->nk", a_c0, d_angle)

    def jitter_angles(self, t: ArrayLike) -> FloatArray:
        """The jitter corrections (roll, pitch, yaw; radians) at times ``t``, ``(..., 3)``."""
        return self.term_angles(t)

    def folded(self) -> Sensor:
        """The base with the jitter (its current values) as periodic attitude corrections of
        its line scanner's trajectory, fixed values, no parameters. The trajectory applies
        them as rotations at the imaging time of the line that sees a point; this wrapper at
        the time of the line without them: within 1e-3 px for a few tenths of a pixel of
        jitter, a few hundredths for a pixel at 100 Hz."""
        scanner = self.line_scanner
        coeffs = np.array([p.value for p in self.terms], dtype=np.float64).reshape(3, -1)
        trajectory = scanner.trajectory.with_attitude_periodic(self.frequencies, coeffs)
        return replace_line_scanner(self.base, scanner.with_trajectory(trajectory))


def _check_sampled(name: str, scanner: Any, freqs: tuple[float, ...]) -> None:
    """Refuse a frequency the image's lines cannot sample (above half its line rate):
    ``--jitter 1e308`` was taken and the adjustment failed on its GCPs instead."""
    n = float(max(int(scanner.n_lines), 1))
    t0, t1 = (float(t) for t in scanner.timing.time(np.array([0.0, n])))
    nyquist = 0.5 * n / abs(t1 - t0) if t1 != t0 else math.inf
    if max(freqs) >= nyquist:
        raise InputError(
            f"jitter frequency {max(freqs):g} Hz is above half the line rate of image {name} "
            f"({nyquist:g} Hz): its lines cannot sample it"
        )


def with_jitter_terms(
    sensors: Mapping[str, Sensor],
    frequencies_hz: Sequence[float],
    amplitude_rad: float,
    frequency_sigma_hz: float | None = None,
) -> dict[str, Sensor]:
    """``sensors`` with jitter coefficients at ``frequencies_hz`` (a-priori RMS amplitude
    ``amplitude_rad`` per axis and frequency: a sigma of ``amplitude_rad / sqrt(2)`` on each
    sine and cosine coefficient), named after each line scanner's trajectory prefix; other
    sensors and an empty ``frequencies_hz`` leave them as they are. With ``frequency_sigma_hz`` the
    frequencies are parameters too (``jitter.f<k>.hz``, shared by all images, that a-priori
    sigma about the given values)."""
    freqs = tuple(float(f) for f in frequencies_hz)
    if not freqs:
        return dict(sensors)
    if not all(math.isfinite(f) and f > 0 for f in freqs) or len(set(freqs)) != len(freqs):
        raise InputError(f"jitter frequencies must be distinct and > 0 Hz, got {list(freqs)}")
    if not (math.isfinite(amplitude_rad) and amplitude_rad > 0):
        raise InputError(f"jitter amplitude must be > 0, got {amplitude_rad}")
    sigma_rad = amplitude_rad / math.sqrt(2.0)
    rates: tuple[Parameter, ...] = ()
    if frequency_sigma_hz is not None:
        if not (math.isfinite(frequency_sigma_hz) and frequency_sigma_hz > 0):
            raise InputError(f"jitter frequency sigma must be > 0 Hz, got {frequency_sigma_hz}")
        rates = tuple(
            Parameter(
                f"jitter.f{k}.hz",
                f,
                frequency_sigma_hz,
                "Hz",
                description=f"platform jitter frequency {k} (found near {f:g} Hz)",
            )
            for k, f in enumerate(freqs)
        )
    out: dict[str, Sensor] = {}
    for name, sensor in sensors.items():
        scanner = line_scanner_of(sensor)
        if scanner is None:
            out[name] = sensor
            continue
        _check_sampled(name, scanner, freqs)
        prefix = scanner.trajectory.prefix
        params = []
        for pname in jitter_parameter_names(prefix, len(freqs)):
            axis, k, part = pname[len(prefix) :].split(".")[1:]
            params.append(
                Parameter(
                    pname,
                    0.0,
                    sigma_rad,
                    "rad",
                    description=f"{axis} jitter at {freqs[int(k[1:])]:g} Hz, {part} coefficient",
                )
            )
        wrapped = JitterCorrected(
            base=sensor, terms=tuple(params), frequencies_hz=freqs, rates=rates
        )
        wrapped._c0_names()  # refuse a model without constant attitude corrections now
        out[name] = wrapped
    return out


def fold_jitter_terms(sensors: Mapping[str, Sensor]) -> dict[str, Sensor]:
    """The sensors with their :class:`JitterCorrected` layers folded into their line
    scanners' trajectories (:meth:`JitterCorrected.folded`); others as they are."""
    return {
        n: map_layers(s, JitterCorrected, lambda layer: layer.folded()) for n, s in sensors.items()
    }


def without_jitter_terms(sensors: Mapping[str, Sensor]) -> dict[str, Sensor]:
    """The sensors without their :class:`JitterCorrected` layers (other attitude terms and
    sensors as they are)."""
    return {n: map_layers(s, JitterCorrected, lambda layer: layer.base) for n, s in sensors.items()}


def jitter_document(
    sensors: Mapping[str, Sensor], parameters: Sequence[str], sigmas: ArrayLike
) -> dict[str, Any] | None:
    """The estimated jitter per image, axis and frequency (amplitude and phase of
    ``A sin(2 pi f (t - t_mid) + phase)``, radians, with the coefficients' a-posteriori
    sigmas), or None when no sensor has jitter terms."""
    sigma = dict(zip(parameters, np.asarray(sigmas, dtype=np.float64).tolist(), strict=True))
    images: dict[str, Any] = {}
    for name, sensor in sensors.items():
        if not isinstance(sensor, JitterCorrected):
            continue
        values = {p.name: p.value for p in sensor.jitter}
        prefix = sensor.line_scanner.trajectory.prefix
        axes: dict[str, Any] = {}
        for axis in AXES:
            rows = []
            for k, f in enumerate(sensor.frequencies):
                s_name = f"{prefix}jitter.{axis}.f{k}.sin"
                c_name = f"{prefix}jitter.{axis}.f{k}.cos"
                s, c = values[s_name], values[c_name]
                rows.append(
                    {
                        "frequency_hz": f,
                        "amplitude_rad": math.hypot(s, c),
                        "phase_rad": math.atan2(c, s),
                        "sin_rad": s,
                        "cos_rad": c,
                        "sigma_sin_rad": sigma.get(s_name, math.nan),
                        "sigma_cos_rad": sigma.get(c_name, math.nan),
                    }
                )
            axes[axis] = rows
        images[name] = {"t_mid_s": sensor.line_scanner.trajectory.t_mid_s, "axes": axes}
    if not images:
        return None
    first = next(s for s in sensors.values() if isinstance(s, JitterCorrected))
    rates = [
        {"name": p.name, "hz": p.value, "sigma_hz": sigma.get(p.name, math.nan)}
        for p in first.rates
    ]
    return {
        "frequencies_hz": list(first.frequencies),
        "estimated_frequencies": rates,
        "model": "attitude correction A sin(2 pi f (t - t_mid_s) + phase) per axis and "
        "frequency, added to the trajectory's polynomial corrections (orbit frame; t in "
        "seconds since the trajectory epoch)",
        "applied_to_models": True,
        "note": "estimated with the block; the delivered line-scanner models carry it as "
        "periodic attitude corrections of their trajectories (attitude_periodic)",
        "images": images,
    }


def detect_jitter_frequencies(
    series: Sequence[tuple[FloatArray, FloatArray]],
    max_frequencies: int = 1,
    false_alarm: float = DETECTION_FALSE_ALARM,
) -> tuple[float, ...]:
    """Jitter frequencies (Hz) found in residual time series, strongest first.

    ``series``: ``(t_s, residual)`` pairs, one per image and component (residuals of an
    adjustment, against their imaging times). The platform's jitter frequencies are common to
    all of them (the phases are not), so their Lomb-Scargle periodograms (astropy, floating
    mean) are summed on one frequency grid, from :data:`MIN_CYCLES` over the longest series
    to a period of four median sample spacings (at most :data:`MAX_JITTER_HZ`). The highest
    peak is a jitter frequency when, in at least one series, its false-alarm probability
    (Baluev's bound) is below ``false_alarm``; it is then subtracted from every series and the
    search repeated, up to
    ``max_frequencies`` (one per adjustment by default: a frequency found next to a misfit
    frequency is biased, so :func:`adjust_with_jitter` re-adjusts between searches).
    """
    from astropy.timeseries import LombScargle

    kept = []
    for t_s, residual in series:
        t = np.asarray(t_s, dtype=np.float64)
        r = np.asarray(residual, dtype=np.float64)
        ok = np.isfinite(t) & np.isfinite(r)
        t, r = t[ok], r[ok]
        if t.size < MIN_DETECTION_POINTS or not np.ptp(t) > 0:
            continue
        kept.append((t, r, float(np.ptp(t)), float(np.median(np.diff(np.sort(t))))))
    if not kept:
        return ()
    low = MIN_CYCLES / max(k[2] for k in kept)
    high = min(1.0 / max(4.0 * max(k[3] for k in kept), 1e-9), MAX_JITTER_HZ)
    if not high > 4.0 * low:
        return ()
    resolution = 1.0 / max(k[2] for k in kept)
    grid = np.arange(low, high, resolution / 10.0)
    found: list[float] = []
    residuals = [r for _, r, _, _ in kept]
    for _ in range(max_frequencies):
        total = np.zeros(grid.size)
        models = []
        for (t, _, _, _), r in zip(kept, residuals, strict=True):
            ls = LombScargle(t, r)
            total += ls.power(grid, method="fast")
            models.append(ls)
        f = float(grid[int(np.argmax(total))])
        bounds = {"minimum_frequency": low, "maximum_frequency": high}
        faps = [
            float(ls.false_alarm_probability(float(ls.power(f)), method="baluev", **bounds))
            for ls in models
        ]
        if not min(faps) < false_alarm:
            break
        found.append(round(f, 4))
        residuals = [
            r - ls.model(t, f) for (t, _, _, _), r, ls in zip(kept, residuals, models, strict=True)
        ]
    return tuple(found)


def residual_series(
    result: AdjustmentResult, lines: FloatArray
) -> list[tuple[FloatArray, FloatArray]]:
    """The ``(t_s, residual)`` series of an adjustment (per line-scanner image and component;
    ``lines``: the line of each image-residual row), for :func:`detect_jitter_frequencies`."""
    res = result.image_residuals
    out = []
    for name, sensor in result.sensors.items():
        base = line_scanner_of(sensor)
        if base is None:
            continue
        m = (res["image"] == name) & np.isfinite(lines)
        if not m.any():
            continue
        t = base.timing.time(lines[m])
        out += [(t, np.asarray(res[f"d_{c}"][m], np.float64)) for c in ("line", "sample")]
    return out


def adjust_with_jitter(
    sensors: Mapping[str, Sensor],
    observations: Observations,
    frequencies_hz: Sequence[float] | str,
    amplitude_rad: float,
    start: AdjustmentResult | None = None,
    **options: Any,
) -> AdjustmentResult:
    """:func:`~carto.framework.adjustment.bundle.adjust_bundle` with jitter terms.

    ``amplitude_rad``: the a-priori RMS jitter amplitude per axis and frequency
    (:func:`with_jitter_terms`). ``frequencies_hz``: the platform's jitter frequencies when
    known (a list; empty: none), or
    ``"auto"``: adjust without jitter terms, find the strongest frequency in the residuals
    against imaging time (:func:`detect_jitter_frequencies`), adjust again with it, and repeat
    while the residuals show another (one frequency per re-adjustment, at most
    :data:`MAX_DETECTED_FREQUENCIES`). Found frequencies are parameters of the block (a-priori
    sigma: the periodogram's resolution): a frequency found beside the misfit of others is
    biased, and over a short window a 1.4-cycle jitter's fit depends on it (1.5 Hz instead of
    1.7 Hz moved a 10k-tie triplet's checkpoint heights from 0.18 to 0.37 m). The delivered
    sensors are line scanners; the
    estimated jitter and the detection are the ``jitter`` product of the result.

    ``start``: an earlier result of this function on the same images (``carto adjust`` runs
    again with the tie points' measured sigma and with the GCP transfer's offsets). The
    solution starts from it (:func:`adjust_bundle`'s ``start``) and ``"auto"`` from the
    frequencies it found, searching the residuals for more. Started afresh, the search lost
    them: with the tie points' sigma measured on the jitter-corrected fit (3 x smaller), the
    first solution without jitter rejected more than half of a triplet's tie points as outliers
    and found no frequency in the rest (two of five simulated 800-line triplets).
    """
    if isinstance(frequencies_hz, str):
        if frequencies_hz != "auto":
            raise InputError(f"jitter frequencies: a list of Hz or 'auto', got {frequencies_hz!r}")
        freqs = _found_frequencies(start)
        result = adjust_bundle(
            with_jitter_terms(sensors, freqs, amplitude_rad, _frequency_sigma(sensors)),
            observations,
            start=start,
            **options,
        )
        rounds = []
        for _ in range(MAX_DETECTED_FREQUENCIES - len(freqs)):
            found = detect_jitter_frequencies(residual_series(result, residual_lines(result)))
            new = tuple(f for f in found if all(abs(f - g) > 0.01 * g for g in freqs))
            rounds.append(list(new))
            if not new:
                break
            # the frequencies found so far are refined with the block (each was found next to
            # the misfit of the others, up to a resolution off)
            freqs = _current_frequencies(result, freqs) + new
            result = adjust_bundle(
                with_jitter_terms(sensors, freqs, amplitude_rad, _frequency_sigma(sensors)),
                observations,
                **options,
            )
        detection = {"method": "residual periodogram", "rounds": rounds}
        if start is not None:
            detection["started_from_hz"] = list(_found_frequencies(start))
    else:
        freqs = tuple(float(f) for f in frequencies_hz)
        result = adjust_bundle(
            with_jitter_terms(sensors, freqs, amplitude_rad), observations, start=start, **options
        )
        detection = {"method": "given"}
    document = jitter_document(result.sensors, result.parameters, result.sigmas)
    if document is None:
        return attrs.evolve(
            result, products={**result.products, "jitter": {"detection": detection, "images": {}}}
        )
    return attrs.evolve(
        result,
        sensors=fold_jitter_terms(result.sensors),
        parameter_sensors=result.sensors,
        products={**result.products, "jitter": {**document, "detection": detection}},
    )


def _current_frequencies(result: AdjustmentResult, freqs: tuple[float, ...]) -> tuple[float, ...]:
    """The frequencies of a result's jitter terms (estimated or given), else ``freqs``."""
    for sensor in result.sensors.values():
        if isinstance(sensor, JitterCorrected):
            return sensor.frequencies
    return freqs


def _found_frequencies(start: AdjustmentResult | None) -> tuple[float, ...]:
    """The jitter frequencies an earlier result of :func:`adjust_with_jitter` estimated (its
    ``jitter`` product; none without one)."""
    document = {} if start is None else start.products.get("jitter") or {}
    return tuple(float(f) for f in document.get("frequencies_hz", ()))


def _frequency_sigma(sensors: Mapping[str, Sensor]) -> float:
    """A-priori sigma of found frequencies: the periodogram's resolution, ``1 / span`` of the
    longest image's imaging time."""
    spans = [
        abs(float(s.timing.time(float(s.n_lines)) - s.timing.time(0.0)))
        for s in (line_scanner_of(x) for x in sensors.values())
        if s is not None
    ]
    return 1.0 / max(max(spans, default=1.0), 1e-3)
