"""Each image's own short-term attitude motion as adjustment parameters
(:func:`with_image_trends`), and its delivery in the adjusted models
(:func:`fold_image_trends`).

Images on one trajectory share its polynomial corrections: one body attitude (bias and drift)
for the Fore and Aft images of a Cartosat-1 pair, taken about 52 s apart. Attitude motion of
periods shorter than that interval (the slowest jitter, which a 1000-line window sees as a
trend, not a cycle; attitude-control limit cycles) is not common to the images: each image
sees its own. Left out, it is not white noise but common to every tie point on a line, and
with thousands of tie points it pulls whatever the block lets it: over a 12000 x 1000 px
Cartosat-1 window an across-track trend of a few tenths of a pixel in the Fore image drove the
shared yaw drift 19 a-priori sigmas away (the Fore footprint is 336 km ahead of nadir, so a
yaw rate moves it across track), which rotated the Aft image and tilted the heights by 20 m
across the swath (``benchmarks/cartosat1_accuracy.py --errors full``, issue 18).

:class:`ImageTrendCorrected` adds per image and attitude axis the Legendre polynomials
``P_1 .. P_order`` of the image's own normalised time ``u`` (-1 at its first line, +1 past its
last), weighted by an a-priori sigma: zero-mean over the image, so the constant stays the
trajectory's and the camera's. Parameter names carry the image: ``<image>.trend.<axis>.p<k>``.

A trend common to all images moves every image the same way, which tie points do not see;
only its differences between images are observable (and along track not even those: a pitch
trend difference is a height trend, held by GCPs or DEM height constraints only). So adjusters
give trends to the images of all cameras but a reference one (relative trends, as a residual
camera alignment is relative).

The adjusted models carry the trends: :func:`fold_image_trends` adds each image's trend,
re-expressed in its trajectory's normalised time, to that image's attitude correction
polynomials (order raised to the trend's) under image-own parameter names
(``<image>.trajectory.``), since the image's corrections are no longer the shared ones.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping

import attrs
import numpy as np
from numpy.polynomial import legendre as npleg
from numpy.polynomial import polynomial as npoly

from carto.framework.adjustment.attitude_terms import (
    AXES,
    AttitudeTermsCorrected,
    FloatArray,
    line_scanner_of,
    map_layers,
    replace_line_scanner,
)
from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.sensor import Parameter, Sensor

MAX_TREND_ORDER = 2
"""Highest Legendre order of an image trend (linear and quadratic over the image; a cubic,
re-expressed in a trajectory's normalised time of +-45 s around a 0.3 s image, would need
coefficients of 1e7 times its size)."""


def trend_parameter_names(image: str, order: int) -> list[str]:
    """Names of an image's trend coefficients, axis-major: ``<image>.trend.<axis>.p<k>``."""
    return [f"{image}.trend.{axis}.p{k}" for axis in AXES for k in range(1, order + 1)]


def _image_span(scanner: LineScanner) -> tuple[float, float]:
    """Middle time and half duration (s) of an image's lines."""
    t0, t1 = (float(t) for t in scanner.timing.time(np.array([0.0, float(scanner.n_lines)])))
    half = 0.5 * (t1 - t0)
    if not (math.isfinite(half) and half != 0.0):
        raise InputError(f"image {scanner.name}: its lines span no time; no attitude trend")
    return 0.5 * (t0 + t1), half


@attrs.frozen(eq=False)
class ImageTrendCorrected(AttitudeTermsCorrected):
    """A line scanner plus its image's own attitude trend (see the module docstring).

    Attributes:
        base: the line scanner (or a wrapper of it).
        terms: the Legendre coefficients, named by :func:`trend_parameter_names` (radians).
        order: the highest Legendre order.
    """

    order: int = 1

    def _basis(self, t: FloatArray) -> FloatArray:
        t_mid, half = _image_span(self.line_scanner)
        u = (np.asarray(t, dtype=np.float64) - t_mid) / half
        return npleg.legvander(u, self.order)[..., 1:]

    def folded(self) -> Sensor:
        """The base with the trend added to its line scanner's attitude correction
        polynomials (the trend's angles to rounding; image-own parameter names)."""
        scanner = self.line_scanner
        traj = scanner.trajectory
        t_mid, half = _image_span(scanner)
        # u = alpha + beta * tau, with tau the trajectory's normalised time
        beta = traj.t_half_s / half
        alpha = (traj.t_mid_s - t_mid) / half
        coeffs = np.array([p.value for p in self.terms]).reshape(3, self.order)
        order = max(traj.attitude_correction_order, self.order)
        prefix = f"{self.name}.trajectory."
        folded = traj.with_correction_orders(attitude=order)
        if traj.prefix != prefix:
            folded = folded.with_prefix(prefix)
        current = {p.name: p.value for p in folded.parameters}
        values = {}
        for a, axis in enumerate(AXES):
            in_u = npleg.leg2poly(np.concatenate([[0.0], coeffs[a]]))
            in_tau = npoly.polyval(npoly.Polynomial([alpha, beta]), in_u)
            for k, c in enumerate(np.atleast_1d(in_tau.coef)):
                name = f"{prefix}attitude.{axis}.c{k}"
                values[name] = current[name] + float(c)
        folded = folded.with_parameters(values=values)
        return replace_line_scanner(self.base, scanner.with_trajectory(folded))


def with_image_trends(
    sensors: Mapping[str, Sensor],
    order: int,
    sigma_rad: float,
    images: Collection[str] | None = None,
) -> dict[str, Sensor]:
    """``sensors`` with the attitude trends of ``images`` (default: every line scanner) up to
    Legendre ``order``, a-priori sigma ``sigma_rad`` per coefficient; ``order`` 0 leaves them
    as they are."""
    if not 0 <= order <= MAX_TREND_ORDER:
        raise InputError(f"image trend order must be 0..{MAX_TREND_ORDER}, got {order}")
    if order == 0:
        return dict(sensors)
    if not (math.isfinite(sigma_rad) and sigma_rad > 0):
        raise InputError(f"image trend sigma must be > 0, got {sigma_rad}")
    chosen = set(sensors) if images is None else set(images)
    unknown = chosen - set(sensors)
    if unknown:
        raise InputError(f"image trends: no image {', '.join(sorted(unknown))}")
    out: dict[str, Sensor] = {}
    for name, sensor in sensors.items():
        if name not in chosen or line_scanner_of(sensor) is None:
            out[name] = sensor
            continue
        params = tuple(
            Parameter(
                pname,
                0.0,
                sigma_rad,
                "rad",
                description=f"image {name}: {pname.split('.')[-2]} trend, Legendre "
                f"P{pname[-1]} of the image's normalised time",
            )
            for pname in trend_parameter_names(name, order)
        )
        wrapped = ImageTrendCorrected(base=sensor, terms=params, order=order)
        wrapped._c0_names()  # refuse a model without constant attitude corrections now
        _image_span(wrapped.line_scanner)
        out[name] = wrapped
    return out


def fold_image_trends(sensors: Mapping[str, Sensor]) -> dict[str, Sensor]:
    """The sensors with their :class:`ImageTrendCorrected` layers folded into their line
    scanners (:meth:`ImageTrendCorrected.folded`); others as they are."""
    return {
        n: map_layers(s, ImageTrendCorrected, lambda layer: layer.folded())
        for n, s in sensors.items()
    }


def trend_document(
    sensors: Mapping[str, Sensor], parameters: list[str], sigmas: FloatArray
) -> dict[str, object] | None:
    """The estimated trends per image and axis (coefficients and a-posteriori sigmas,
    radians; the angle's range over the image), or None when no sensor has trends."""
    sigma = dict(zip(parameters, np.asarray(sigmas, dtype=np.float64).tolist(), strict=True))
    images: dict[str, object] = {}
    for name, sensor in sensors.items():
        layer = sensor
        while isinstance(layer, AttitudeTermsCorrected) and not isinstance(
            layer, ImageTrendCorrected
        ):
            layer = layer.base
        if not isinstance(layer, ImageTrendCorrected):
            continue
        u = np.linspace(-1.0, 1.0, 201)
        coeffs = np.array([p.value for p in layer.terms]).reshape(3, layer.order)
        angles = npleg.legvander(u, layer.order)[:, 1:] @ coeffs.T
        images[name] = {
            axis: {
                "coefficients_rad": coeffs[a].tolist(),
                "sigmas_rad": [
                    sigma.get(p, math.nan)
                    for p in trend_parameter_names(name, layer.order)[
                        a * layer.order : (a + 1) * layer.order
                    ]
                ],
                "peak_to_peak_rad": float(np.ptp(angles[:, a])),
            }
            for a, axis in enumerate(AXES)
        }
    if not images:
        return None
    return {
        "model": "attitude correction sum_k p_k P_k(u) per image and axis (Legendre, u the "
        "image's normalised time, -1 at its first line, +1 past its last; orbit frame)",
        "applied_to_models": True,
        "images": images,
    }
