"""RPC bias compensation in image space (Grodecki & Dial 2003): the ``rpc-bias`` adjuster."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np

from carto.framework.adjustment.adjuster_settings import BundleSettings
from carto.framework.adjustment.base import Adjuster, AdjustmentResult
from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.observations import Observations
from carto.framework.adjustment.parameter_constraints import ParameterConstraint
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.settings import choice, names


@attrs.frozen
class RPCBiasSettings(BundleSettings):
    """``mode``: ``"shift"`` (offsets only) or ``"affine"`` (six terms per image); ``fixed``:
    images whose RPC stays as it is; and the bundle's options."""

    mode: str = attrs.field(default="shift", converter=choice("mode", ("shift", "affine")))
    fixed: tuple[str, ...] = attrs.field(default=(), converter=names("fixed"))


class RPCBiasAdjuster(Adjuster):
    """Bias compensation of RPC models in image space (Grodecki & Dial 2003).

    Each image gets its own correction ``line' = line + a0 + a1 line + a2 sample`` (and the same
    for samples): ``mode="shift"`` estimates the offsets ``a0, b0`` only, ``mode="affine"`` all
    six terms. GCPs fix the absolute position; tie points between images (with optional height
    constraints, e.g. from a DEM, that fix what tie points alone cannot: a common shift along
    the stereo base looks like a height change) tie the images together. ``fixed`` images keep
    their RPC as it is (the reference of a relative adjustment).

    A purely relative block (no GCP, no height constraint) gets minimal constraints: unless
    ``fixed`` names images, the first image stays as it is (as ``carto dem``'s relative
    orientation keeps the left one) and the others' offsets do not move along the stereo
    base. Tie points fix only the relative pointing across the base; the rest (a common
    shift, and a shift along the base, which is a height) is the datum, and the priors alone
    spread it between the images: on the Reunion pair that moved the DEM 0.8 m up and
    0.05 m worse in NMAD against the products' own; with the first image fixed, the other's
    smallest correction still had an along-base part (0.27 px, the DEM 0.48 m up)
    (:func:`relative_fixed`, :func:`along_base_held`).
    """

    name = "rpc-bias"
    description = "RPC bias compensation in image space (shift or affine per image)"
    Settings = RPCBiasSettings

    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        from carto.framework.geometry.rpc.sensor import RPCSensor

        settings = self.settings(options)
        relative = relative_fixed(sensors, observations)
        mode, fixed = settings.mode, set(settings.fixed) or relative
        prepared: dict[str, Sensor] = {}
        for name, sensor in sensors.items():
            if not isinstance(sensor, RPCSensor):
                raise InputError(
                    f"rpc-bias adjusts RPC sensors; image {name!r} is {type(sensor).__name__}"
                )
            s = sensor.with_prefix(f"{name}.")
            free = {
                p.name: (name not in fixed) and (mode == "affine" or p.name.endswith("c0"))
                for p in s.parameters
            }
            prepared[name] = s.with_parameters(free=free)
        constraints = ()
        if relative and not settings.fixed:
            constraints = along_base_held(prepared, observations, relative)
        return adjust_bundle(
            prepared, observations, constraints=constraints, **settings.bundle_options()
        )


def relative_fixed(sensors: Mapping[str, Sensor], observations: Observations) -> set[str]:
    """The image a purely relative block keeps as it is (see :class:`RPCBiasAdjuster`): the
    first; none when GCPs or height constraints hold the datum, or for a single image."""
    if observations.control_id.size or observations.height_id.size or len(sensors) < 2:
        return set()
    return {next(iter(sensors))}


ALONG_BASE_SIGMA_PX = 1e-4
"""A-priori sigma of the condition that an image's offset has no part along the stereo base
(a datum condition: as good as exact)."""


def along_base_held(
    sensors: Mapping[str, Sensor], observations: Observations, fixed: set[str]
) -> tuple[ParameterConstraint, ...]:
    """For each image but the ``fixed`` one of a relative block: its offset ``(line, sample)``
    has no part along the direction in which a point of the fixed image moves in it when
    the point's height changes (the epipolar direction at the tie points' centre)."""
    (reference,) = fixed
    ref = sensors[reference]
    rows = observations.image == reference
    line = float(np.mean(observations.line[rows])) if rows.any() else ref.image_shape[0] / 2
    sample = float(np.mean(observations.sample[rows])) if rows.any() else ref.image_shape[1] / 2
    low, high = ref.ray_heights_m
    h = np.array([0.5 * (low + high) - 50.0, 0.5 * (low + high) + 50.0])
    lon, lat = ref.image_to_ground(np.full(2, line), np.full(2, sample), h)
    out = []
    for name, sensor in sensors.items():
        if name == reference:
            continue
        lines, samples = sensor.ground_to_image(lon, lat, h)
        d = np.array([lines[1] - lines[0], samples[1] - samples[0]])
        if not np.all(np.isfinite(d)) or not np.any(d):
            continue
        d /= np.linalg.norm(d)
        coefficients = {f"{name}.rpc.line.c0": float(d[0]), f"{name}.rpc.sample.c0": float(d[1])}
        out.append(ParameterConstraint(coefficients, ALONG_BASE_SIGMA_PX))
    return tuple(out)
