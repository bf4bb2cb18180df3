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
trajectory), weighted by an a-priori sigma of the jitter amplitude. Sensors sharing a trajectory
share its jitter parameters (the names carry the trajectory's prefix). The jitter angles are a
fraction of a microradian, so their effect is applied to first order in image space: the image
point moves by the partials of ``(line, sample)`` w.r.t. the constant attitude corrections
(``c0``, analytic) times the jitter angles at the imaging time (the neglected terms are below
1e-6 px).

The delivered models stay line scanners: :func:`without_jitter_terms` unwraps them and
:func:`jitter_document` reports the estimated jitter (amplitude, phase, sigmas per image, axis
and frequency), which the models cannot yet carry (their trajectory corrections are
polynomials).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.misfit import residual_lines
from carto.framework.adjustment.observations import Observations
from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry.linescan import LineScanner
from carto.framework.geometry.sensor import Parameter, Sensor, replace_parameters

FloatArray = NDArray[np.float64]

AXES = ("roll", "pitch", "yaw")
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
IMAGE_TO_GROUND_ITERATIONS = 3
"""Fixed-point steps of :meth:`JitterCorrected.image_to_ground` (each divides the error by
the ratio of the jitter shift's variation over a pixel to a pixel, < 1e-3)."""


def jitter_parameter_names(prefix: str, n_frequencies: int) -> list[str]:
    """Names of the jitter coefficients, axis-major: ``<prefix>jitter.<axis>.f<k>.sin|cos``."""
    return [
        f"{prefix}jitter.{axis}.f{k}.{part}"
        for axis in AXES
        for k in range(n_frequencies)
        for part in ("sin", "cos")
    ]


@attrs.frozen(eq=False)
class JitterCorrected(Sensor):
    """A line scanner plus periodic attitude corrections (see the module docstring).

    Attributes:
        base: the line scanner (its own parameters stay as they are).
        frequencies_hz: the jitter frequencies (their starting values when ``rates`` are
            given).
        jitter: the coefficients, named by :func:`jitter_parameter_names` (radians).
        rates: the frequencies as parameters (Hz, named ``jitter.f<k>.hz``: the platform's,
            shared by every image), estimated with the coefficients; empty: fixed.
    """

    base: LineScanner
    frequencies_hz: tuple[float, ...]
    jitter: tuple[Parameter, ...]
    rates: tuple[Parameter, ...] = ()

    @property
    def name(self) -> str:
        return self.base.name

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.base.image_shape

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        return self.base.parameters + self.jitter + self.rates

    @property
    def frequencies(self) -> tuple[float, ...]:
        """The current jitter frequencies (Hz)."""
        return tuple(p.value for p in self.rates) if self.rates else self.frequencies_hz

    def with_parameters(
        self,
        values: Mapping[str, float] | None = None,
        free: Mapping[str, bool] | None = None,
        sigmas: Mapping[str, float] | None = None,
    ) -> JitterCorrected:
        groups = {"jitter": {p.name for p in self.jitter}, "rates": {p.name for p in self.rates}}

        def part(mapping: Mapping[str, Any] | None, group: str) -> dict[str, Any] | None:
            if mapping is None:
                return None
            if group == "base":
                return {
                    k: v for k, v in mapping.items() if not any(k in g for g in groups.values())
                }
            return {k: v for k, v in mapping.items() if k in groups[group]}

        def update(params: tuple[Parameter, ...], group: str) -> tuple[Parameter, ...]:
            return replace_parameters(
                params, part(values, group), part(free, group), part(sigmas, group)
            )

        return attrs.evolve(
            self,
            base=self.base.with_parameters(
                part(values, "base"), part(free, "base"), part(sigmas, "base")
            ),
            jitter=update(self.jitter, "jitter"),
            rates=update(self.rates, "rates") if self.rates else (),
        )

    # ------------------------------------------------------------------ the correction
    def _c0_names(self) -> list[str]:
        prefix = self.base.trajectory.prefix
        names = [f"{prefix}attitude.{axis}.c0" for axis in AXES]
        known = {p.name for p in self.base.parameters}
        missing = [n for n in names if n not in known]
        if missing:
            raise InputError(
                f"sensor {self.base.name}: jitter terms need the constant attitude corrections "
                f"({', '.join(missing)} missing: attitude correction order >= 0)"
            )
        return names

    def _basis(self, t: FloatArray) -> FloatArray:
        """``(N, 2F)``: sin and cos of each frequency at times ``t`` (s since the epoch)."""
        tau = t - self.base.trajectory.t_mid_s
        cols = []
        for f in self.frequencies:
            w = 2.0 * math.pi * f * tau
            cols += [np.sin(w), np.cos(w)]
        return np.stack(cols, axis=-1)

    def jitter_angles(self, t: ArrayLike) -> FloatArray:
        """The jitter corrections (roll, pitch, yaw; radians) at times ``t``, ``(..., 3)``."""
        t = np.asarray(t, dtype=np.float64)
        coeffs = np.array([p.value for p in self.jitter]).reshape(3, -1)
        return self._basis(t) @ coeffs.T

    def linearize(
        self,
        lon_deg: ArrayLike,
        lat_deg: ArrayLike,
        h_m: ArrayLike,
        names: Sequence[str] | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        if names is None:
            names = [p.name for p in self.parameters if p.free]
        names = list(names)
        own = [p.name for p in self.jitter]
        rates = [p.name for p in self.rates]
        base_names = [n for n in names if n not in own and n not in rates]
        line, sample, a_ground, a_base, a_c0, basis, tau = self._linearize_base(
            lon_deg, lat_deg, h_m, base_names
        )
        shift = self._shift(a_c0, basis)
        a_param = np.empty((line.size, 2, len(names)))
        per_axis = basis.shape[1]
        if rates:
            coeffs = np.array([p.value for p in self.jitter]).reshape(3, -1)
        for k, name in enumerate(names):
            if name in own:
                axis, j = divmod(own.index(name), per_axis)
                a_param[:, :, k] = a_c0[:, :, axis] * basis[:, j, None]
            elif name in rates:
                # d/df of s sin(2 pi f tau) + c cos(2 pi f tau), per axis
                j = rates.index(name)
                sin_j, cos_j = basis[:, 2 * j], basis[:, 2 * j + 1]
                d_angle = (
                    2.0
                    * math.pi
                    * tau[:, None]
                    * (
                        coeffs[None, :, 2 * j] * cos_j[:, None]
                        - coeffs[None, :, 2 * j + 1] * sin_j[:, None]
                    )
                )
                a_param[:, :, k] = np.einsum("nka,na->nk", a_c0, d_angle)
            else:
                a_param[:, :, k] = a_base[:, :, base_names.index(name)]
        return line + shift[:, 0], sample + shift[:, 1], a_ground, a_param

    def _linearize_base(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike, names: list[str]
    ) -> tuple[FloatArray, ...]:
        """The base model's ``linearize`` for ``names``, its partials w.r.t. the constant
        attitude corrections ``(N, 2, 3)``, the jitter basis at the imaging times and those
        times from the trajectory's middle."""
        c0 = self._c0_names()
        asked = names + [n for n in c0 if n not in names]
        line, sample, a_ground, a_all = self.base.linearize(lon_deg, lat_deg, h_m, asked)
        a_c0 = a_all[:, :, [asked.index(n) for n in c0]]
        li = np.where(np.isfinite(line), line, 0.5 * self.base.n_lines)
        t = self.base.timing.time(li)
        basis = self._basis(t)
        tau = t - self.base.trajectory.t_mid_s
        return line, sample, a_ground, a_all[:, :, : len(names)], a_c0, basis, tau

    def _shift(self, a_c0: FloatArray, basis: FloatArray) -> FloatArray:
        """Image shift ``(N, 2)`` (line, sample) of the jitter corrections, first order."""
        coeffs = np.array([p.value for p in self.jitter]).reshape(3, -1)
        return np.einsum("nka,na->nk", a_c0, basis @ coeffs.T)

    @property
    def _still(self) -> bool:
        """No jitter (all coefficients zero, as an adjustment starts): the base model."""
        return not any(p.value for p in self.jitter)

    # ------------------------------------------------------------------ Sensor interface
    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        if self._still:
            return self.base.project(lon_deg, lat_deg, h_m)
        lon, lat, h = as_float_arrays(lon_deg, lat_deg, h_m)
        shape = lon.shape
        line, sample, _, _ = self.linearize(lon.ravel(), lat.ravel(), h.ravel(), [])
        n_l, n_s = self.image_shape
        inside = (line >= 0) & (line <= n_l) & (sample >= 0) & (sample <= n_s)
        return line.reshape(shape), sample.reshape(shape), inside.reshape(shape)

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line, sample, inside = self.project(lon_deg, lat_deg, h_m)
        return np.where(inside, line, np.nan), np.where(inside, sample, np.nan)

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        if self._still:
            return self.base.image_to_ground(line, sample, h_m)
        line, sample, h = as_float_arrays(line, sample, h_m)
        shape = line.shape
        line, sample, h = line.ravel(), sample.ravel(), h.ravel()
        lon, lat = self.base.image_to_ground(line, sample, h)
        for _ in range(IMAGE_TO_GROUND_ITERATIONS):
            # where the base model sees the point the corrected model sees at (line, sample)
            _, _, _, _, a_c0, basis, _ = self._linearize_base(lon, lat, h, [])
            shift = self._shift(a_c0, basis)
            lon, lat = self.base.image_to_ground(line - shift[:, 0], sample - shift[:, 1], h)
        return lon.reshape(shape), lat.reshape(shape)


def with_jitter_terms(
    sensors: Mapping[str, Sensor],
    frequencies_hz: Sequence[float],
    sigma_rad: float,
    frequency_sigma_hz: float | None = None,
) -> dict[str, Sensor]:
    """``sensors`` with jitter coefficients at ``frequencies_hz`` (a-priori sigma
    ``sigma_rad`` each), named after each line scanner's trajectory prefix; other sensors and
    an empty ``frequencies_hz`` leave them as they are. With ``frequency_sigma_hz`` the
    frequencies are parameters too (``jitter.f<k>.hz``, shared by all images, that a-priori
    sigma about the given values)."""
    freqs = tuple(float(f) for f in frequencies_hz)
    if not freqs:
        return dict(sensors)
    if not all(math.isfinite(f) and f > 0 for f in freqs) or len(set(freqs)) != len(freqs):
        raise InputError(f"jitter frequencies must be distinct and > 0 Hz, got {list(freqs)}")
    if not (math.isfinite(sigma_rad) and sigma_rad > 0):
        raise InputError(f"jitter sigma must be > 0, got {sigma_rad}")
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
        if not isinstance(sensor, LineScanner):
            out[name] = sensor
            continue
        prefix = sensor.trajectory.prefix
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
        wrapped = JitterCorrected(sensor, freqs, tuple(params), rates)
        wrapped._c0_names()  # refuse a model without constant attitude corrections now
        out[name] = wrapped
    return out


def without_jitter_terms(sensors: Mapping[str, Sensor]) -> dict[str, Sensor]:
    """The line scanners inside :class:`JitterCorrected` sensors (others as they are)."""
    return {n: s.base if isinstance(s, JitterCorrected) else s for n, s in sensors.items()}


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
        prefix = sensor.base.trajectory.prefix
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
        images[name] = {"t_mid_s": sensor.base.trajectory.t_mid_s, "axes": axes}
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
        "applied_to_models": False,
        "note": "estimated with the block and used to keep the jitter out of the polynomial "
        "corrections; the delivered line-scanner models carry the polynomial corrections only",
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
        base = sensor.base if isinstance(sensor, JitterCorrected) else sensor
        if not isinstance(base, LineScanner):
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
    sigma_rad: float,
    **options: Any,
) -> AdjustmentResult:
    """:func:`~carto.framework.adjustment.bundle.adjust_bundle` with jitter terms.

    ``frequencies_hz``: the platform's jitter frequencies when known (a list; empty: none), or
    ``"auto"``: adjust without jitter terms, find the strongest frequency in the residuals
    against imaging time (:func:`detect_jitter_frequencies`), adjust again with it, and repeat
    while the residuals show another (one frequency per re-adjustment, at most
    :data:`MAX_DETECTED_FREQUENCIES`). Found frequencies are parameters of the block (a-priori
    sigma: the periodogram's resolution): a frequency found beside the misfit of others is
    biased, and over a short window a 1.4-cycle jitter's fit depends on it (1.5 Hz instead of
    1.7 Hz moved a 10k-tie triplet's checkpoint heights from 0.18 to 0.37 m). The delivered
    sensors are line scanners; the
    estimated jitter and the detection are the ``jitter`` product of the result.
    """
    if isinstance(frequencies_hz, str):
        if frequencies_hz != "auto":
            raise InputError(f"jitter frequencies: a list of Hz or 'auto', got {frequencies_hz!r}")
        result = adjust_bundle(sensors, observations, **options)
        freqs: tuple[float, ...] = ()
        rounds = []
        for _ in range(MAX_DETECTED_FREQUENCIES):
            found = detect_jitter_frequencies(residual_series(result, residual_lines(result)))
            new = tuple(f for f in found if all(abs(f - g) > 0.01 * g for g in freqs))
            rounds.append(list(new))
            if not new:
                break
            # the frequencies found so far are refined with the block (each was found next to
            # the misfit of the others, up to a resolution off)
            freqs = _current_frequencies(result, freqs) + new
            result = adjust_bundle(
                with_jitter_terms(sensors, freqs, sigma_rad, _frequency_sigma(result, freqs)),
                observations,
                **options,
            )
        detection = {"method": "residual periodogram", "rounds": rounds}
    else:
        freqs = tuple(float(f) for f in frequencies_hz)
        result = adjust_bundle(
            with_jitter_terms(sensors, freqs, sigma_rad), observations, **options
        )
        detection = {"method": "given"}
    document = jitter_document(result.sensors, result.parameters, result.sigmas)
    if document is None:
        return attrs.evolve(
            result, products={**result.products, "jitter": {"detection": detection, "images": {}}}
        )
    return attrs.evolve(
        result,
        sensors=without_jitter_terms(result.sensors),
        products={**result.products, "jitter": {**document, "detection": detection}},
    )


def _current_frequencies(result: AdjustmentResult, freqs: tuple[float, ...]) -> tuple[float, ...]:
    """The frequencies of a result's jitter terms (estimated or given), else ``freqs``."""
    for sensor in result.sensors.values():
        if isinstance(sensor, JitterCorrected):
            return sensor.frequencies
    return freqs


def _frequency_sigma(result: AdjustmentResult, freqs: tuple[float, ...]) -> float:
    """A-priori sigma of found frequencies: the periodogram's resolution, ``1 / span`` of the
    longest image's imaging time."""
    spans = [
        abs(float(s.timing.time(float(s.n_lines)) - s.timing.time(0.0)))
        for s in (x.base if isinstance(x, JitterCorrected) else x for x in result.sensors.values())
        if isinstance(s, LineScanner)
    ]
    return 1.0 / max(max(spans, default=1.0), 1e-3)
