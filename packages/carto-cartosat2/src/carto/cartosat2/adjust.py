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

from carto.cartosat2 import constants
from carto.framework.sdk.adjusters import (
    Adjuster,
    AdjustmentResult,
    AncillaryPrior,
    Observations,
    adjust_with_jitter,
    line_scanner_corrections,
    with_self_calibration,
)
from carto.framework.sdk.common import InputError
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


class Cartosat2BlockAdjuster(Adjuster):
    """Bundle block adjustment of agile views: per-image attitude polynomials, tie points."""

    name = "cartosat2-bba"
    description = "Cartosat-2 bundle block adjustment: per-image attitude polynomials, ties"

    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        """Options: ``attitude_order`` (0-3, default 3), ``estimate_position``, the a-priori
        sigmas ``bias_sigma_deg``, ``drift_sigma_deg_s``, ``smooth_sigma_deg``, the jitter
        frequencies ``jitter_hz`` (``"auto"``, the default: found in the residuals; a list
        when the platform's are known; empty: no jitter terms) and their a-priori RMS
        amplitude ``jitter_amplitude_deg`` (default
        :data:`constants.ATTITUDE_JITTER_AMPLITUDE_DEG`),
        ``self_calibration`` (as the Cartosat-1 adjuster's, off by default), and those of
        :func:`~carto.framework.adjustment.bundle.adjust_bundle`."""
        prior = AncillaryPrior.from_degrees(
            float(options.pop("bias_sigma_deg", constants.ATTITUDE_BIAS_SIGMA_DEG)),
            float(options.pop("drift_sigma_deg_s", constants.ATTITUDE_DRIFT_SIGMA_DEG_S)),
            float(options.pop("smooth_sigma_deg", constants.ATTITUDE_SMOOTH_SIGMA_DEG)),
        )
        jitter_hz = _frequencies(options.pop("jitter_hz", "auto"))
        jitter_amplitude = math.radians(
            float(options.pop("jitter_amplitude_deg", constants.ATTITUDE_JITTER_AMPLITUDE_DEG))
        )
        prepared = prepare_sensors(
            sensors,
            int(options.pop("attitude_order", DEFAULT_ATTITUDE_ORDER)),
            bool(options.pop("estimate_position", False)),
            prior,
        )
        prepared = with_self_calibration(prepared, options.pop("self_calibration", None), self.name)
        if "mode" in options:  # a user's --mode must not be dropped unseen
            raise InputError(
                f"adjuster {self.name} has no modes: option mode={options['mode']!r} does not "
                "apply (every view is adjusted on its own attitude; leave --mode out)"
            )
        return adjust_with_jitter(prepared, observations, jitter_hz, jitter_amplitude, **options)


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
        raise InputError(
            f"cartosat2-bba: jitter_hz must be 'auto' or a list of frequencies, got {value!r}"
        )
    return tuple(float(v) for v in value)
