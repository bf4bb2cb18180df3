"""The adjuster component kind and the result every adjuster returns.

An :class:`Adjuster` estimates corrections to sensor parameters from :class:`Observations`
and returns an :class:`AdjustmentResult` (adjusted sensors, residuals, sigma0, covariance,
outliers).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.observations import Observations
from carto.framework.adjustment.variance_components import VarianceComponent
from carto.framework.component import Component
from carto.framework.geometry.sensor import Sensor
from carto.framework.settings import Configurable

FloatArray = NDArray[np.float64]


@attrs.frozen(eq=False)
class AdjustmentResult:
    """The outcome of an adjustment.

    Attributes:
        sensors: the adjusted sensors (same keys as given).
        parameters: names of the estimated (free) parameters, in covariance order.
        values: their estimates; ``sigmas``: their a-posteriori standard deviations
            (``sigma0 * sqrt(diag(S^-1))``).
        covariance: a-posteriori covariance of the parameters (``sigma0^2 S^-1``).
        covariance_unit: ``S^-1`` (covariance for sigma0 = 1).
        sigma0: a-posteriori standard deviation of unit weight (1 when the a-priori sigmas
            are right).
        redundancy: number of observations minus number of unknowns.
        points: point id -> estimated (lon_deg, lat_deg, h_m).
        image_residuals: per image measurement ``(point_id, image, d_line, d_sample)``,
            measured minus computed, pixels (NaN for rejected rows).
        control_residuals: per GCP ``(id, d_east_m, d_north_m, d_up_m)``, measured minus
            computed.
        offset_residuals: per image offset ``(point_id, image_a, image_b, d_line,
            d_sample)``, measured minus computed, pixels.
        outliers: ids of points rejected (GCP blunders, wrong tie points).
        iterations: Gauss-Newton iterations of the final solution; ``converged``: whether
            the last correction was below the tolerance.
        history: per iteration: max parameter correction in sigmas, max point move (m),
            weighted RMS of normalised residuals.
        products: adjuster-specific JSON documents (name -> document), written beside the
            adjusted models as ``<name>.json`` (e.g. an in-flight camera calibration).
        variance_components: each observation group's variance factor (tie points, GCP
            image and ground coordinates, image offsets, height constraints; see
            :mod:`carto.framework.adjustment.variance_components`).
        covariance_by_group: covariance of the parameters with each group's own
            a-posteriori variance (groups too little redundant to judge themselves, and the
            a-priori parameter values, at their a-priori weights); empty when not computed.
        parameter_sensors: the sensors as estimated, carrying every parameter of
            ``parameters`` (e.g. jitter terms that ``sensors`` carry as fixed corrections),
            for propagating the covariance; empty: ``sensors`` carry them.
        prior_values, prior_sigmas: the parameters' a-priori values and sigmas, in
            ``parameters`` order (``inf``: free; empty: not known), which the corrections
            ``values - prior_values`` are judged against.
    """

    sensors: dict[str, Sensor]
    parameters: tuple[str, ...]
    values: FloatArray
    sigmas: FloatArray
    covariance: FloatArray
    covariance_unit: FloatArray
    sigma0: float
    redundancy: int
    points: dict[str, tuple[float, float, float]]
    image_residuals: dict[str, NDArray]
    control_residuals: dict[str, NDArray]
    outliers: tuple[str, ...]
    iterations: int
    converged: bool
    history: tuple[dict[str, float], ...]
    products: dict[str, Any] = attrs.field(factory=dict)
    offset_residuals: dict[str, NDArray] = attrs.field(factory=dict)
    variance_components: tuple[VarianceComponent, ...] = ()
    covariance_by_group: FloatArray = attrs.field(factory=lambda: np.zeros((0, 0)))
    parameter_sensors: dict[str, Sensor] = attrs.field(factory=dict)
    prior_values: FloatArray = attrs.field(factory=lambda: np.zeros(0))
    prior_sigmas: FloatArray = attrs.field(factory=lambda: np.zeros(0))

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary (for ``report.json``)."""
        res = self.image_residuals
        ok = np.isfinite(res["d_line"])
        rms = (
            float(np.sqrt(np.mean(res["d_line"][ok] ** 2 + res["d_sample"][ok] ** 2)))
            if (ok.any())
            else float("nan")
        )
        return {
            "sigma0": self.sigma0,
            "redundancy": self.redundancy,
            "iterations": self.iterations,
            "converged": self.converged,
            "outliers": list(self.outliers),
            "image_residual_rms_px": rms,
            "variance_components": {c.group: c.summary() for c in self.variance_components},
            "parameters": {
                n: {"value": float(v), "sigma": float(s)} | self._prior(k)
                for k, (n, v, s) in enumerate(
                    zip(self.parameters, self.values, self.sigmas, strict=True)
                )
            },
        }

    def _prior(self, k: int) -> dict[str, float]:
        """Parameter ``k``'s a-priori value and sigma, and its correction in a-priori
        sigmas (nothing when they are not known or the parameter is free)."""
        if len(self.prior_sigmas) != len(self.parameters) or not np.isfinite(self.prior_sigmas[k]):
            return {}
        value, sigma = float(self.prior_values[k]), float(self.prior_sigmas[k])
        moved = float(self.values[k]) - value
        return {
            "prior_value": value,
            "prior_sigma": sigma,
            "correction_in_prior_sigmas": moved / sigma if sigma > 0 else float("nan"),
        }


class Adjuster(Component, Configurable):
    """Estimates corrections to sensor parameters from ground control and tie points."""

    warm_start: bool = False
    """True when :meth:`adjust` also takes ``start=``: an earlier result of this adjuster on
    the same images to start from (``carto adjust`` passes it when it adjusts again with the
    tie points' measured sigma and with the GCP transfer's offsets; an adjuster built on
    :func:`adjust_bundle` hands it on). Without it every adjustment starts afresh."""

    @abc.abstractmethod
    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        """Adjust ``sensors`` (image name -> sensor) to ``observations``; ``options`` are
        adjuster specific (modes, correction orders, robust settings).

        ``observations`` may hold every kind :class:`Observations` has, image offsets
        included (``carto adjust`` adds them for its GCP transfer); an adjuster built on
        :func:`adjust_bundle` handles them all, one with its own solver must use them or
        raise :class:`~carto.framework.errors.InputError`, never ignore them."""
