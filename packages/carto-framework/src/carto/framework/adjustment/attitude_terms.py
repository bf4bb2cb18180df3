"""Extra attitude corrections of a line scanner as adjustment parameters, applied to first
order in image space (:class:`AttitudeTermsCorrected`).

A trajectory's corrections are polynomials of its normalised time, shared by every image on
it. Some attitude motion is not: jitter (sinusoids at platform frequencies,
:mod:`~carto.framework.adjustment.jitter`) and the short-term motion of each image's own few
seconds (:mod:`~carto.framework.adjustment.image_trends`). Both add, per attitude axis, a
linear combination of basis functions of the imaging time: ``angle_a(t) = sum_j
coeff[a, j] * basis_j(t)``, the angles a fraction of a microradian. Their effect is applied to
first order: the image point moves by the partials of ``(line, sample)`` w.r.t. the constant
attitude corrections (``c0``, analytic) times the angles at the imaging time (the neglected
terms are below 1e-6 px). A wrapper may wrap another (jitter and image trends together): the
partials are the innermost line scanner's.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Self

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.sensor import (
    Linearization,
    Parameter,
    ParameterChanges,
    Sensor,
    SensorWrapper,
)

FloatArray = NDArray[np.float64]

AXES = ("roll", "pitch", "yaw")
IMAGE_TO_GROUND_ITERATIONS = 3
"""Fixed-point steps of :meth:`AttitudeTermsCorrected.image_to_ground` (each divides the error
by the ratio of the terms' shift variation over a pixel to a pixel, < 1e-3)."""


def line_scanner_of(sensor: Sensor) -> LineScanner | None:
    """The line scanner inside ``sensor`` (itself, or inside its attitude-term wrappers)."""
    while isinstance(sensor, AttitudeTermsCorrected):
        sensor = sensor.base
    return sensor if isinstance(sensor, LineScanner) else None


def replace_line_scanner(sensor: Sensor, scanner: LineScanner) -> Sensor:
    """``sensor`` (a line scanner or attitude-term wrappers around one) with its line scanner
    replaced by ``scanner``, the wrappers kept."""
    if isinstance(sensor, AttitudeTermsCorrected):
        return attrs.evolve(sensor, base=replace_line_scanner(sensor.base, scanner))
    return scanner


def without_attitude_terms(sensors: Mapping[str, Sensor]) -> dict[str, Sensor]:
    """The line scanners inside attitude-term wrappers (other sensors as they are)."""
    out: dict[str, Sensor] = {}
    for name, sensor in sensors.items():
        while isinstance(sensor, AttitudeTermsCorrected):
            sensor = sensor.base
        out[name] = sensor
    return out


def map_layers(
    sensor: Sensor, kind: type[AttitudeTermsCorrected], transform: Callable[[Any], Sensor]
) -> Sensor:
    """``sensor`` with each of its attitude-term layers of type ``kind`` replaced by
    ``transform(layer)`` (e.g. its base: the layer removed), the other layers kept."""
    if isinstance(sensor, kind):
        return map_layers(transform(sensor), kind, transform)
    if isinstance(sensor, AttitudeTermsCorrected):
        return attrs.evolve(sensor, base=map_layers(sensor.base, kind, transform))
    return sensor


@attrs.frozen(eq=False)
class AttitudeTermsCorrected(SensorWrapper):
    """A line scanner (or another wrapper) plus attitude terms ``terms`` (radians, axis-major:
    ``3 x n_basis`` coefficients of :meth:`_basis`). Subclasses define the basis and may add
    parameters of their own (:meth:`_extra_parameters`, their partials
    :meth:`_extra_partials`)."""

    terms: tuple[Parameter, ...]

    def __attrs_post_init__(self) -> None:
        if line_scanner_of(self.base) is None:
            raise InputError(f"attitude terms need a line scanner, got {type(self.base).__name__}")

    # ------------------------------------------------------------------ to specialise
    def _basis(self, t: FloatArray) -> FloatArray:
        """``(N, n_basis)``: the basis functions at imaging times ``t`` (s since the epoch)."""
        raise NotImplementedError

    def _extra_parameters(self) -> dict[str, tuple[Parameter, ...]]:
        """Further parameter groups of the subclass: attribute name -> parameters."""
        return {}

    def _extra_partials(
        self, name: str, a_c0: FloatArray, tau: FloatArray
    ) -> FloatArray:  # pragma: no cover - only subclasses with extra parameters call it
        """``(N, 2)`` partials of ``(line, sample)`` w.r.t. the extra parameter ``name``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ Sensor data
    @property
    def line_scanner(self) -> LineScanner:
        scanner = line_scanner_of(self.base)
        assert scanner is not None  # checked at construction
        return scanner

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        extra = tuple(p for group in self._extra_parameters().values() for p in group)
        return self.base.parameters + self.terms + extra

    def with_changes(self, changes: ParameterChanges) -> Self:
        groups = {"terms": self.terms, **self._extra_parameters()}
        owned = {field: {p.name for p in params} for field, params in groups.items()}
        updated = {
            field: changes.only(owned[field]).apply(params)
            for field, params in groups.items()
            if params
        }
        mine = set().union(*owned.values())
        return attrs.evolve(self, base=changes.without(mine).applied_to(self.base), **updated)

    # ------------------------------------------------------------------ the correction
    def _c0_names(self) -> list[str]:
        prefix = self.line_scanner.trajectory.prefix
        names = [f"{prefix}attitude.{axis}.c0" for axis in AXES]
        known = {p.name for p in self.base.parameters}
        missing = [n for n in names if n not in known]
        if missing:
            raise InputError(
                f"sensor {self.name}: attitude terms need the constant attitude corrections "
                f"({', '.join(missing)} missing: attitude correction order >= 0)"
            )
        return names

    def term_angles(self, t: ArrayLike) -> FloatArray:
        """The terms' attitude corrections (roll, pitch, yaw; radians) at times ``t``,
        ``(..., 3)``."""
        t = np.asarray(t, dtype=np.float64)
        coeffs = np.array([p.value for p in self.terms]).reshape(3, -1)
        return self._basis(t.ravel()).reshape(*t.shape, -1) @ coeffs.T

    def _linearize(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> Linearization:
        own = [p.name for p in self.terms]
        extra = {p.name for group in self._extra_parameters().values() for p in group}
        base_names = [n for n in names if n not in own and n not in extra]
        line, sample, a_ground, a_base, a_c0, basis, tau = self._linearize_base(
            lon, lat, h, base_names
        )
        shift = self._shift(a_c0, basis)
        a_param = np.empty((line.size, 2, len(names)))
        per_axis = basis.shape[1]
        for k, name in enumerate(names):
            if name in extra:
                a_param[:, :, k] = self._extra_partials(name, a_c0, tau)
            elif name in own:
                axis, j = divmod(own.index(name), per_axis)
                a_param[:, :, k] = a_c0[:, :, axis] * basis[:, j, None]
            else:
                a_param[:, :, k] = a_base[:, :, base_names.index(name)]
        return line + shift[:, 0], sample + shift[:, 1], a_ground, a_param

    def _linearize_base(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike, names: list[str]
    ) -> tuple[FloatArray, ...]:
        """The base's ``linearize`` for ``names``, its partials w.r.t. the constant attitude
        corrections ``(N, 2, 3)``, the basis at the imaging times and those times from the
        trajectory's middle."""
        c0 = self._c0_names()
        asked = names + [n for n in c0 if n not in names]
        line, sample, a_ground, a_all = self.base.linearize(lon_deg, lat_deg, h_m, asked)
        a_c0 = a_all[:, :, [asked.index(n) for n in c0]]
        scanner = self.line_scanner
        li = np.where(np.isfinite(line), line, 0.5 * scanner.n_lines)
        t = scanner.timing.time(li)
        basis = self._basis(t)
        tau = t - scanner.trajectory.t_mid_s
        return line, sample, a_ground, a_all[:, :, : len(names)], a_c0, basis, tau

    def _shift(self, a_c0: FloatArray, basis: FloatArray) -> FloatArray:
        """Image shift ``(N, 2)`` (line, sample) of the terms, first order."""
        coeffs = np.array([p.value for p in self.terms]).reshape(3, -1)
        return np.einsum("nka,na->nk", a_c0, basis @ coeffs.T)

    @property
    def _still(self) -> bool:
        """No term (all coefficients zero, as an adjustment starts): the base model."""
        return not any(p.value for p in self.terms)

    # ------------------------------------------------------------------ Sensor interface
    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        if self._still:
            return self.base.project(lon_deg, lat_deg, h_m)
        lon, lat, h = as_float_arrays(lon_deg, lat_deg, h_m)
        shape = lon.shape
        line, sample, _, _ = self.linearize(lon, lat, h, [])
        inside = self.in_image(line, sample)
        return line.reshape(shape), sample.reshape(shape), inside.reshape(shape)

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        return self._projection_in_image(lon_deg, lat_deg, h_m)

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
