"""The errors of a simulated product, drawn: what
:func:`~carto.framework.simulation.simulate.simulate_scene` puts into the measured ancillary
data and the cameras, and records in ``truth/errors.json``.

The errors the adjusters model (ephemeris and attitude biases, drifts, smooth attitude terms,
camera misalignment) come from one random stream, those outside their parameters (``--errors
full``: camera interior, line timing, attitude wander) from another; every draw is made
whatever the sizes (scaled by them), so switching one source off leaves the others' draws
unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from carto.framework.simulation.plan import ErrorModel, ScenePlan


def _draw_unmodelled(
    errors: ErrorModel,
    rng: np.random.Generator,
    n_segments: int,
    cameras: Sequence[str],
    views: Sequence[str],
) -> dict[str, Any]:
    """The draws of the errors outside the adjusters' parameters (``--errors full``). Every
    draw is made whatever the sizes (scaled by them), so switching one source off leaves the
    others unchanged."""
    deg = math.radians

    def normal(sigma: float, n: int | None = None) -> Any:
        z = rng.standard_normal(n)
        return (np.asarray(z) * sigma).tolist()

    interior = {
        c: {
            "focal_ppm": normal(errors.focal_length_ppm),
            "line_offset_px": normal(errors.detector_line_offset_px),
            "principal_point_px": normal(errors.principal_point_px),
            "rotation_rad": normal(deg(errors.ccd_rotation_deg)),
        }
        for c in cameras
    }
    timing = {
        v: {
            "offset_s": normal(errors.line_time_offset_s),
            "period_ppm": normal(errors.line_period_ppm),
        }
        for v in views
    }
    wander = [
        {
            "amplitude_rad": (
                deg(errors.attitude_wander_deg) * rng.uniform(0.5, 1.0, (3, 3))
            ).tolist(),
            "period_s": rng.uniform(15.0, 90.0, 3).tolist(),
            "phase_rad": rng.uniform(0.0, 2.0 * math.pi, (3, 3)).tolist(),
            "ephemeris_noise_seed": int(rng.integers(2**31)),
        }
        for _ in range(n_segments)
    ]
    return {"camera_interior": interior, "line_timing": timing, "segments": wander}


def _draw_errors(
    errors: ErrorModel, rng: np.random.Generator, n_segments: int, cameras: Sequence[str]
) -> dict[str, Any]:
    """The draws of the errors the adjusters model: the ephemeris bias (one, every segment
    carries it), per segment the attitude bias, drift and smooth terms, per camera its
    misalignment."""

    def draw(sigma: float) -> list[float]:
        """Three normal draws of ``sigma`` (none when the source is switched off)."""
        return (rng.normal(0.0, sigma, 3) if sigma else np.zeros(3)).tolist()

    deg = np.radians
    eph = draw(errors.ephemeris_bias_m)
    seg = [
        {
            "ephemeris_bias_m": eph,
            "attitude_bias_rad": draw(deg(errors.attitude_bias_deg)),
            "attitude_drift_rad_s": draw(deg(errors.attitude_drift_deg_s)),
            "attitude_tau2_rad": draw(deg(errors.attitude_smooth_deg)),
            "attitude_tau3_rad": draw(deg(errors.attitude_smooth_deg)),
        }
        for _ in range(n_segments)
    ]
    mis = {c: draw(deg(errors.misalignment_deg)) for c in cameras}
    return {"segments": seg, "camera_misalignment_rad": mis}


def draw_product_errors(
    plan: ScenePlan,
    errors: ErrorModel,
    rng_err: np.random.Generator,
    rng_full: np.random.Generator,
    platform_seed: int | None = None,
) -> dict[str, Any]:
    """Every error a simulated product carries (``truth/errors.json``'s ``drawn``): the
    adjustable ones drawn from ``rng_err``, the unmodelled ones (``rng_full``) merged in, the
    platform's camera misalignment from ``platform_seed`` when given."""
    cameras = sorted({v.camera.name for s in plan.segments for v in s.views})
    drawn = _draw_errors(errors, rng_err, len(plan.segments), cameras)
    view_names = [v.name for seg in plan.segments for v in seg.views]
    unmodelled = _draw_unmodelled(errors, rng_full, len(plan.segments), cameras, view_names)
    drawn["camera_interior"] = unmodelled["camera_interior"]
    drawn["line_timing"] = unmodelled["line_timing"]
    for seg_draw, extra in zip(drawn["segments"], unmodelled["segments"], strict=True):
        seg_draw.update(
            {
                f"attitude_wander_{k}" if k != "ephemeris_noise_seed" else k: v
                for k, v in extra.items()
            }
        )
    if platform_seed is not None:
        platform_rng = np.random.default_rng(int(platform_seed))
        drawn["camera_misalignment_rad"] = {
            c: (platform_rng.normal(0.0, math.radians(errors.misalignment_deg), 3)).tolist()
            for c in cameras
        }
    return drawn
