"""An image-space correction that varies with the image line: :class:`LineCorrected`.

A pushbroom image is recorded line by line, so whatever moves its lines of sight over time
(attitude jitter, slow attitude wander, a clock error) moves its image points by amounts that
are functions of the line: to first order a shift along the lines (pitch), across them (roll)
and, far smaller, a rotation (yaw; 0.006 px at the edge of a 12 000-pixel line for 6e-5 deg,
left out). :class:`LineCorrected` adds to any sensor's image coordinates

    ``line'   = line   + sum_j B_j(line) * a_j``
    ``sample' = sample + sum_j B_j(line) * b_j``

with the basis :class:`LineBasis`: a constant, a cubic B-spline of the line with knots every
``knot_lines`` lines (slow motion), and a sine and a cosine per frequency in cycles per line
(jitter); plus, optionally, a tilt across the swath: shifts proportional to the sample's
distance from a centre sample (``tilt``: line and sample shifts per 1000 samples), what a
static relative yaw (a line shift growing across the swath: a height tilt across the track)
or a relative scale leaves. It works on every sensor kind (line scanners, RPCs, a plugin's)
because it only needs the wrapped sensor's projections; its own coefficients are fixed
values, estimated by :mod:`carto.framework.adjustment.relative_orientation`. The wrapped
sensor's parameters stay adjustable through it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Linearization, Sensor, SensorWrapper

FloatArray = NDArray[np.float64]

__all__ = ["LineBasis", "LineCorrected"]

INVERSE_ITERATIONS = 6
"""Fixed-point steps of :meth:`LineCorrected.image_to_ground` (each divides the error by the
slope of the correction along the lines, a few hundredths of a pixel per pixel)."""


def _as_frequencies(values: Sequence[float]) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _as_span(value: Sequence[float] | None) -> tuple[float, float] | None:
    return None if value is None else (float(value[0]), float(value[1]))


@attrs.frozen
class LineBasis:
    """The basis functions of a line correction.

    Attributes:
        n_lines: the image's lines.
        knot_lines: spacing of the cubic B-spline's knots, lines; 0: no spline (a constant
            only).
        frequencies: jitter frequencies, cycles per line (a sine and a cosine each).
        span_lines: the lines the spline spans (default ``(0, n_lines)``); beyond them it
            keeps its end values (a spline is not extrapolated where nothing measured it).
    """

    n_lines: int = attrs.field(converter=int)
    knot_lines: float = attrs.field(default=0.0, converter=float)
    frequencies: tuple[float, ...] = attrs.field(default=(), converter=_as_frequencies)
    span_lines: tuple[float, float] | None = attrs.field(default=None, converter=_as_span)

    def __attrs_post_init__(self) -> None:
        if self.n_lines < 1:
            raise InputError(f"line correction: n_lines must be >= 1, got {self.n_lines}")
        if not (math.isfinite(self.knot_lines) and self.knot_lines >= 0):
            raise InputError(f"line correction: knot_lines must be >= 0, got {self.knot_lines}")
        bad = [f for f in self.frequencies if not (math.isfinite(f) and 0 < f <= 0.5)]
        if bad:
            raise InputError(
                f"line correction: frequencies must be in (0, 0.5] cycles per line, got {bad}"
            )
        first, last = self.span
        if not (math.isfinite(first) and math.isfinite(last) and first < last):
            raise InputError(f"line correction: span_lines must be increasing, got {self.span}")

    @property
    def span(self) -> tuple[float, float]:
        """The spline's first and last line."""
        return self.span_lines if self.span_lines is not None else (0.0, float(self.n_lines))

    @property
    def knots(self) -> FloatArray:
        """The spline's full knot vector (clamped: end knots repeated), or empty."""
        if self.knot_lines <= 0:
            return np.zeros(0)
        first, last = self.span
        n_spans = max(1, round((last - first) / self.knot_lines))
        inner = np.linspace(first, last, n_spans + 1)
        return np.r_[[inner[0]] * 3, inner, [inner[-1]] * 3]

    @property
    def n_spline(self) -> int:
        """Spline functions (0 without a spline)."""
        return max(0, self.knots.size - 4)

    @property
    def size(self) -> int:
        """Basis functions: the spline's (it sums to one: it holds the constant), else one
        constant, plus two per frequency."""
        return (self.n_spline or 1) + 2 * len(self.frequencies)

    def labels(self) -> list[str]:
        """One name per basis function (``spline.k``, ``const``, ``sin.f``, ``cos.f``)."""
        names = [f"spline.{k}" for k in range(self.n_spline)] or ["const"]
        for k in range(len(self.frequencies)):
            names += [f"sin.{k}", f"cos.{k}"]
        return names

    def design(self, lines: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(B, dB/dline)``, each ``(N, size)``: the basis functions and their derivatives
        at ``lines`` (NaN lines give zero rows)."""
        return self.evaluate(lines, np.eye(self.size))

    def evaluate(self, lines: ArrayLike, coefficients: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``(value, slope)``, each ``(N, m)``: the functions with ``coefficients``
        ``(m, size)`` and their derivatives along the lines, at ``lines`` (for a whole
        image's pixels at once: the design matrix is not formed)."""
        x = np.asarray(lines, dtype=np.float64).ravel()
        ok = np.isfinite(x)
        x0 = np.where(ok, x, 0.0)
        c = np.asarray(coefficients, dtype=np.float64)
        n0 = self.n_spline or 1
        if self.n_spline:
            from scipy.interpolate import BSpline

            first, last = self.span
            inside = (x0 >= first) & (x0 <= last)
            xc = np.clip(x0, first, last - 1e-9 * max(1.0, abs(last)))
            spline = BSpline(self.knots, c[:, :n0].T, 3, extrapolate=False)
            value = np.nan_to_num(spline(xc))
            slope = np.where(inside[:, None], np.nan_to_num(spline.derivative()(xc)), 0.0)
        else:
            value = np.repeat(c[None, :, 0], x.size, axis=0)
            slope = np.zeros_like(value)
        for k, f in enumerate(self.frequencies):
            w = 2.0 * math.pi * f
            s_k, c_k = c[:, n0 + 2 * k], c[:, n0 + 2 * k + 1]
            sin, cos = np.sin(w * x0)[:, None], np.cos(w * x0)[:, None]
            value = value + sin * s_k + cos * c_k
            slope = slope + w * (cos * s_k - sin * c_k)
        value[~ok] = 0.0
        slope[~ok] = 0.0
        return value, slope

    def as_dict(self) -> dict[str, object]:
        return {
            "n_lines": self.n_lines,
            "knot_lines": self.knot_lines,
            "span_lines": list(self.span),
            "frequencies_cycles_per_line": list(self.frequencies),
        }


def _pair(value: ArrayLike) -> tuple[float, float]:
    a, b = (float(v) for v in np.asarray(value, np.float64).ravel())
    if not (math.isfinite(a) and math.isfinite(b)):
        raise InputError(f"line correction: tilt must be finite, got {(a, b)}")
    return a, b


def _coefficients(value: ArrayLike) -> FloatArray:
    out = np.array(value, dtype=np.float64)
    if out.ndim != 2 or out.shape[0] != 2:
        raise InputError(f"line correction: coefficients must be (2, n), got shape {out.shape}")
    out.flags.writeable = False
    return out


@attrs.frozen(eq=False)
class LineCorrected(SensorWrapper):
    """``base`` with an image-space correction varying with the line (module docstring).

    Attributes:
        base: the corrected sensor.
        basis: the correction's basis functions.
        coefficients: ``(2, basis.size)``: row 0 the line shifts' coefficients, row 1 the
            sample shifts', pixels.
        tilt: ``(d_line, d_sample)`` per 1000 samples from ``tilt_centre_sample``, pixels.
        tilt_centre_sample: the base-model sample where the tilt is zero.
    """

    basis: LineBasis
    coefficients: FloatArray = attrs.field(converter=_coefficients)
    tilt: tuple[float, float] = attrs.field(default=(0.0, 0.0), converter=_pair)
    tilt_centre_sample: float = attrs.field(default=0.0, converter=float)

    def __attrs_post_init__(self) -> None:
        if self.coefficients.shape[1] != self.basis.size:
            raise InputError(
                f"line correction: {self.coefficients.shape[1]} coefficients per axis for "
                f"{self.basis.size} basis functions"
            )

    # ------------------------------------------------------------------ the correction
    def shift(
        self, line: ArrayLike, sample: ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """``(d_line, d_sample)`` added at base-model points ``(line, sample)``, pixels (the
        tilt needs the samples; without them, the line-varying part only)."""
        line = np.asarray(line, dtype=np.float64)
        d, _ = self.basis.evaluate(line, self.coefficients)
        d_line, d_sample = d[:, 0].reshape(line.shape), d[:, 1].reshape(line.shape)
        if sample is None:
            return d_line, d_sample
        return self._tilted(d_line, d_sample, sample)

    def _tilted(
        self, d_line: FloatArray, d_sample: FloatArray, sample: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """The shifts ``(d_line, d_sample)`` of the lines plus the tilt at ``sample``."""
        if not any(self.tilt):
            return d_line, d_sample
        x = (np.asarray(sample, np.float64) - self.tilt_centre_sample) / 1000.0
        return d_line + self.tilt[0] * x, d_sample + self.tilt[1] * x

    # ------------------------------------------------------------------ Sensor data
    @property
    def ray_heights_m(self) -> tuple[float, float]:
        return self.base.ray_heights_m

    def for_raster(self, raster: object) -> Sensor:  # type: ignore[override]
        return self

    @property
    def raw_needs_preparation(self) -> bool:
        return self.base.raw_needs_preparation

    def prepare_raw(self, raw: ArrayLike, dem: object) -> NDArray[np.float32]:
        return self.base.prepare_raw(raw, dem)

    def prepare_rows(self, raw: object, dem: object, rows: slice) -> NDArray[np.float32]:
        return self.base.prepare_rows(raw, dem, rows)

    # ------------------------------------------------------------------ Sensor interface
    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        line, sample, _ = self.base.project(lon_deg, lat_deg, h_m)
        line, sample = np.asarray(line, np.float64), np.asarray(sample, np.float64)
        d_line, d_sample = self.shift(line, sample)
        line, sample = line + d_line, sample + d_sample
        return line, sample, self.in_image(line, sample)

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line0, sample0 = self.base.ground_to_image(lon_deg, lat_deg, h_m)
        line0, sample0 = np.asarray(line0, np.float64), np.asarray(sample0, np.float64)
        d_line, d_sample = self.shift(line0, sample0)
        line, sample = line0 + d_line, sample0 + d_sample
        _n_l, _n_s = self.image_shape
        seen = np.isfinite(line0) & np.isfinite(sample0)
        # the base's own clipping (its margin beyond the image) on the base's coordinates
        return np.where(seen, line, np.nan), np.where(seen, sample, np.nan)

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        line, sample, h = as_float_arrays(line, sample, h_m)
        base_line, base_sample = line.copy(), sample.copy()
        for _ in range(INVERSE_ITERATIONS):  # the base point whose corrected one is given
            d_line, d_sample = self.shift(base_line, base_sample)
            base_line, base_sample = line - d_line, sample - d_sample
        d_line, d_sample = self.shift(base_line, base_sample)
        return self.base.image_to_ground(line - d_line, sample - d_sample, h)

    def _linearize(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> Linearization:
        line, sample, a_ground, a_param = self.base.linearize(lon, lat, h, names)
        shift, slope = self.basis.evaluate(line, self.coefficients)
        d_line, d_sample = self._tilted(shift[:, 0], shift[:, 1], sample)
        t_line, t_sample = (t / 1000.0 for t in self.tilt)
        # d(line + s(line) + t x) = (1 + s'(line)) d line + t d sample; the sample likewise
        chain = np.stack(
            [
                np.stack([1.0 + slope[:, 0], np.full_like(line, t_line)], axis=1),
                np.stack([slope[:, 1], np.full_like(line, 1.0 + t_sample)], axis=1),
            ],
            axis=1,
        )  # (N, 2, 2): rows (line', sample'), columns (line, sample)
        a_ground = np.einsum("nij,njk->nik", chain, a_ground)
        a_param = np.einsum("nij,njk->nik", chain, a_param)
        return line + d_line, sample + d_sample, a_ground, a_param
