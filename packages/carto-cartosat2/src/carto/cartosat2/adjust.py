"""Adjuster ``cartosat2-bba``: bundle block adjustment of agile Cartosat-2 images.

All images of a block (a fore/nadir/aft triplet, the swaths of a paint-brush set) are adjusted
together (Radhadevi et al. 2010, eq. 5-6): the unknowns are per-image corrections to the
imaging-event parameters (attitude polynomials of order 0-3 in normalised time, optionally a
position bias, and the platform's periodic attitude jitter) and the ground coordinates of every
tie point; GCPs and the a-priori values of the parameters are weighted observations. The shared
engine (:func:`carto.framework.adjustment.bundle.adjust_bundle`) eliminates the 3 x 3 point
blocks (Schur complement), so the cost grows linearly with the number of tie points.

The default attitude order is 3 (bias, drift, quadratic and cubic terms per image): the smooth
attitude error of an agile segment (tau^2 and tau^3 over the segment, a-priori
:data:`constants.ATTITUDE_SMOOTH_SIGMA_DEG`) is not quadratic over a long window: on an
8000-line window (3.2 s of imaging, 10k tie points, 2 GCPs) order 2 leaves 2.7 m planimetric /
4.5 m height at the checkpoints and order 3 0.55 / 1.14 m (``benchmarks/bba_scaling.py``,
``long_window``; realistic errors, our simulator: a best case).

Attitude jitter (sinusoids at the platform's frequencies, in the true motion but not in the 8 Hz
attitude samples) is estimated as a sine and a cosine term per image, axis and frequency
(:mod:`carto.framework.adjustment.jitter`); the frequencies are found in the residuals
(``jitter_hz="auto"``, summed Lomb-Scargle periodograms against imaging time, one frequency per
re-adjustment, refined with the block) unless given. Without them the polynomials cannot fit
it: the misfit, common to every tie point on a line, pulls the block harder the more tie points
there are (2000 x 2000 triplet, 2 GCPs: sigma0 1.35 / 1.24 and checkpoint heights 0.97 / 2.04 m
with 1k / 10k ties; with them sigma0 0.99-1.00 and 0.37 / 0.16 / 0.20 m with 1k / 10k / 100k,
the frequencies found within 0.03 Hz of the simulator's 1.7 and 4.3 Hz). The delivered models
are line scanners with the polynomial corrections and the estimated jitter as periodic attitude
corrections of their trajectories (their RPC files are fitted to the smooth motion); the jitter
is also the ``jitter`` product of the result (``jitter.json``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs

from carto.cartosat2 import constants
from carto.framework.sdk.adjusters import (
    Adjuster,
    AdjustmentResult,
    AncillaryPrior,
    BundleSettings,
    Observations,
    adjust_with_jitter,
    line_scanner_corrections,
    self_calibration_field,
    with_self_calibration,
)
from carto.framework.sdk.common import UsageError, flag, integer, positive, positive_field
from carto.framework.sdk.sensors import LineScanner, Sensor

PRIOR = AncillaryPrior.from_degrees(
    constants.ATTITUDE_BIAS_SIGMA_DEG,
    constants.ATTITUDE_DRIFT_SIGMA_DEG_S,
    constants.ATTITUDE_SMOOTH_SIGMA_DEG,
)
"""A-priori attitude accuracy of Cartosat-2 products (bias, drift, smooth variation)."""
DEFAULT_ATTITUDE_ORDER = 3
"""Attitude correction polynomials up to tau^3, as the smooth error of an agile segment."""


def prepare_sensors(
    sensors: Mapping[str, Sensor],
    attitude_order: int = DEFAULT_ATTITUDE_ORDER,
    estimate_position: bool = False,
    prior: AncillaryPrior | None = None,
) -> dict[str, LineScanner]:
    """Independent corrections per image (parameter names prefixed by the image name),
    weighted by ``prior`` (default: the Cartosat-2 ancillary accuracy, :data:`PRIOR`)."""
    return {
        name: line_scanner_corrections(
            name,
            sensor,
            "cartosat2-bba",
            attitude_order=attitude_order,
            estimate_position=estimate_position,
            independent=True,
            prior=PRIOR if prior is None else prior,
        )
        for name, sensor in sensors.items()
    }


def _frequencies(value: Any) -> tuple[float, ...] | str:
    """``jitter_hz`` as ``"auto"`` or a tuple of floats (a single number is one frequency;
    None: none)."""
    if value is None:
        return ()
    if value == "auto":
        return "auto"
    if isinstance(value, int | float):
        return (float(value),)
    if isinstance(value, str) or not isinstance(value, Sequence):
        raise UsageError(f"option jitter_hz must be 'auto' or a list of frequencies, got {value!r}")
    return tuple(positive("jitter_hz")(v) for v in value)


@attrs.frozen
class Cartosat2Settings(BundleSettings):
    """The options of ``cartosat2-bba`` (see :meth:`Cartosat2BlockAdjuster.adjust`) and the
    bundle's."""

    attitude_order: int = attrs.field(
        default=DEFAULT_ATTITUDE_ORDER, converter=integer("attitude_order", 0, 3)
    )
    estimate_position: bool = attrs.field(default=False, converter=flag("estimate_position"))
    bias_sigma_deg: float = positive_field("bias_sigma_deg", constants.ATTITUDE_BIAS_SIGMA_DEG)
    drift_sigma_deg_s: float = positive_field(
        "drift_sigma_deg_s", constants.ATTITUDE_DRIFT_SIGMA_DEG_S
    )
    smooth_sigma_deg: float = positive_field(
        "smooth_sigma_deg", constants.ATTITUDE_SMOOTH_SIGMA_DEG
    )
    jitter_hz: Any = attrs.field(default="auto", converter=_frequencies)
    jitter_amplitude_deg: float = positive_field(
        "jitter_amplitude_deg", constants.ATTITUDE_JITTER_AMPLITUDE_DEG
    )
    self_calibration: tuple[str, ...] | Mapping[str, float] | None = self_calibration_field(
        "self_calibration"
    )


class Cartosat2BlockAdjuster(Adjuster):
    """Bundle block adjustment of agile views: per-image attitude polynomials, tie points."""

    name = "cartosat2-bba"
    description = "Cartosat-2 bundle block adjustment: per-image attitude polynomials, ties"
    Settings = Cartosat2Settings
    warm_start = True

    def settings(self, options: Mapping[str, Any]) -> Cartosat2Settings:
        if "mode" in options:  # a user's --mode must not be dropped unseen
            raise UsageError(
                f"adjuster {self.name} has no modes: option mode={options['mode']!r} does not "
                "apply (every view is adjusted on its own attitude; leave --mode out)"
            )
        return super().settings(options)

    def adjust(
        self,
        sensors: Mapping[str, Sensor],
        observations: Observations,
        *,
        start: AdjustmentResult | None = None,
        **options: Any,
    ) -> AdjustmentResult:
        """Options (:class:`Cartosat2Settings`): ``attitude_order`` (0-3, default 3),
        ``estimate_position``, the a-priori sigmas ``bias_sigma_deg``, ``drift_sigma_deg_s``,
        ``smooth_sigma_deg``, the jitter frequencies ``jitter_hz`` (``"auto"``, the default:
        found in the residuals; a list when the platform's are known; empty: no jitter
        terms) and their a-priori RMS amplitude ``jitter_amplitude_deg`` (default
        :data:`constants.ATTITUDE_JITTER_AMPLITUDE_DEG`), ``self_calibration`` (as the
        Cartosat-1 adjuster's, off by default), and those of
        :func:`~carto.framework.adjustment.bundle.adjust_bundle`. ``start``: an earlier result
        of this adjuster on these images, with the jitter frequencies it found."""
        s = self.settings(options)
        prior = AncillaryPrior.from_degrees(
            s.bias_sigma_deg, s.drift_sigma_deg_s, s.smooth_sigma_deg
        )
        prepared = prepare_sensors(sensors, s.attitude_order, s.estimate_position, prior)
        prepared = with_self_calibration(prepared, s.self_calibration, self.name)
        amplitude = math.radians(s.jitter_amplitude_deg)
        return adjust_with_jitter(
            prepared, observations, s.jitter_hz, amplitude, start=start, **s.bundle_options()
        )
