"""RPC bias compensation in image space (Grodecki & Dial 2003): the ``rpc-bias`` adjuster."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

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

    A block without GCPs gets minimal constraints: unless ``fixed`` names images, the first
    image stays as it is (as ``carto dem``'s relative orientation keeps the left one) and
    the others are corrected relative to it, their a-priori sigmas both products' put
    together (:func:`relative_priors`). Tie points fix the relative pointing across the
    base; along the base an offset is a height. Without height constraints it is held at
    zero: the priors alone had spread the datum between the images (on the Reunion pair the
    DEM 0.8 m up and 0.05 m worse in NMAD against the products' own; with the first image
    fixed, the other's smallest correction still had an along-base part: 0.27 px, the DEM
    0.48 m up). With DEM heights the DEM holds it, and nothing else
    (:func:`relative_datum`): the block's place on the ground then stays the first
    product's. Left to the priors of all images, the block moved with a relative error (half
    of it), and the DEM's slope under the moved tie points turned that into an along-base
    error: the Ventoux pair's +60-line bias was found 61.78 lines, 59.67 with the first
    image fixed but the prior along the base, 59.83 with neither (benchmarks/results,
    session 59).
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
        constraints: tuple[ParameterConstraint, ...] = ()
        if not observations.control_id.size:
            prepared = relative_priors(prepared, fixed)
        if relative and not settings.fixed:
            prepared, constraints = relative_datum(prepared, observations, relative)
        return adjust_bundle(
            prepared, observations, constraints=constraints, **settings.bundle_options()
        )


def relative_fixed(sensors: Mapping[str, Sensor], observations: Observations) -> set[str]:
    """The image a block without GCPs keeps as it is (see :class:`RPCBiasAdjuster`): the
    first; none when GCPs hold the datum, or for a single image."""
    if observations.control_id.size or len(sensors) < 2:
        return set()
    return {next(iter(sensors))}


def relative_priors(sensors: Mapping[str, Sensor], fixed: set[str]) -> dict[str, Sensor]:
    """Without GCPs, the free images' corrections are relative to the ``fixed`` images, whose
    own errors stay in them: each free parameter's a-priori sigma is its product's and the
    fixed products' largest of the same term put together (``hypot``)."""
    held: dict[str, float] = {}
    for name in fixed:
        for p in sensors[name].parameters:
            term = p.name[len(name) + 1 :]
            held[term] = max(held.get(term, 0.0), p.sigma)
    return {
        name: s
        if name in fixed
        else s.with_parameters(
            sigmas={
                p.name: math.hypot(p.sigma, held.get(p.name[len(name) + 1 :], 0.0))
                for p in s.parameters
                if p.free
            }
        )
        for name, s in sensors.items()
    }


ALONG_BASE_SIGMA_PX = 1e-4
"""A-priori sigma of the condition that an image's offset has no part along the stereo base
(a datum condition: as good as exact)."""


def relative_datum(
    sensors: Mapping[str, Sensor], observations: Observations, fixed: set[str]
) -> tuple[dict[str, Sensor], tuple[ParameterConstraint, ...]]:
    """The datum of a block without GCPs whose first image is ``fixed``, as conditions on the
    other images' offsets, split along and across the stereo base (:func:`base_directions`).
    Across the base, tie points measure the offset; its a-priori sigma stays. Along the base
    the offset is a height: without height constraints it is held at zero
    (:data:`ALONG_BASE_SIGMA_PX`); with DEM heights the DEM is the datum there and the
    product's prior is not applied (a second, weaker height datum that would pull the DEM
    towards the products' own heights: on the Ventoux pair it kept 0.17 line of the +60-line
    bias of ``right_image_bias.geom``)."""
    held = bool(observations.height_id.size)
    out, constraints = dict(sensors), []
    for name, d in base_directions(sensors, observations, fixed).items():
        line, sample = f"{name}.rpc.line.c0", f"{name}.rpc.sample.c0"
        if not held:
            constraints.append(ParameterConstraint({line: d[0], sample: d[1]}, ALONG_BASE_SIGMA_PX))
            continue
        sigma = next(p.sigma for p in sensors[name].parameters if p.name == line)
        out[name] = sensors[name].with_parameters(sigmas={line: math.inf, sample: math.inf})
        constraints.append(ParameterConstraint({line: -d[1], sample: d[0]}, sigma))
    return out, tuple(constraints)


def base_directions(
    sensors: Mapping[str, Sensor], observations: Observations, fixed: set[str]
) -> dict[str, NDArray[np.float64]]:
    """For each image but the ``fixed`` one: the unit direction ``(line, sample)`` in which a
    point of the fixed image moves in it when the point's height changes (the epipolar
    direction at the tie points' centre, at their DEM heights' median or the middle of the
    rays' heights); images where it is not defined are left out."""
    (reference,) = fixed
    ref = sensors[reference]
    rows = observations.image == reference
    line = float(np.mean(observations.line[rows])) if rows.any() else ref.image_shape[0] / 2
    sample = float(np.mean(observations.sample[rows])) if rows.any() else ref.image_shape[1] / 2
    low, high = ref.ray_heights_m
    held = observations.height_m
    middle = float(np.median(held)) if held.size else 0.5 * (low + high)
    h = np.array([middle - 50.0, middle + 50.0])
    lon, lat = ref.image_to_ground(np.full(2, line), np.full(2, sample), h)
    out = {}
    for name, sensor in sensors.items():
        if name == reference:
            continue
        lines, samples = sensor.ground_to_image(lon, lat, h)
        d = np.array([lines[1] - lines[0], samples[1] - samples[0]])
        if np.all(np.isfinite(d)) and np.any(d):
            out[name] = d / np.linalg.norm(d)
    return out
