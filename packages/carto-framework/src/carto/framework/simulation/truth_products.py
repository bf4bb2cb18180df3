"""The platform's record of a reference acquisition (:mod:`.truth_geometry`), in the product
formats users get: the ancillary file a user's tools read.

Ephemeris every 125 ms in the ITRS (``"ecef"``, Earth-relative velocity, as GNSS receivers
give it), attitude as body -> GCRS quaternions (``"eci"``, as star trackers give it), the
nominal camera constants, line timing as ``(line, time)`` nodes, and ``light_path`` (the
timing and attitude describe the physical light path: models correct light time and
aberration). The samples carry the measurement errors of the
:class:`~carto.framework.simulation.plan.ErrorModel` drawn for the segment; the attitude
sensors see the smooth motion (no jitter).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples
from carto.framework.products.ancillary import Ancillary, CameraSpec, ImageSpec
from carto.framework.simulation import truth_geometry as tg
from carto.framework.simulation.reference import attitude as ref_attitude
from carto.framework.simulation.reference import rotations
from carto.framework.simulation.truth_geometry import PHYSICAL_LIGHT_PATH, World

ANCILLARY_STEP_S = 0.125
ERRORS_NOTE = (
    "attitude errors: measured R_body_to_orbit = rpy(e)^T @ true (orbit frame of the true "
    "inertial position and velocity), with e = bias + drift * dt_s + tau2 * tau^2 + tau3 * "
    "tau^3 (tau over the ancillary samples of the segment), delivered as body -> GCRS "
    "quaternions; plus, under --errors full, attitude wander (sinusoids per axis, "
    "attitude_wander_*) in e, white ephemeris noise, and the interior orientation and line "
    "timing errors of camera_interior and line_timing (the product states the nominal "
    "values); ephemeris: measured = true - R_orbit_to_gcrs @ (along, across, -radial), "
    "delivered in the ITRS"
)


def _span(seg_span: tuple[float, float], images: Sequence[ImageSpec]) -> tuple[float, float]:
    lo, hi = seg_span
    for image in images:  # windows of many lines may reach beyond the planned span
        t_first = float(image.timing.time(0.0))
        t_last = float(image.timing.time(float(image.n_lines)))
        if t_first < lo + 0.5:  # keep four samples before the first line
            lo = min(lo, t_first - 1.0)
        if t_last > hi - 0.5:
            hi = max(hi, t_last + 1.0)
    return lo, hi


def measured_ancillary(
    platform: str,
    w: World,
    seg_span: tuple[float, float],
    law: ref_attitude.AttitudeLaw,
    drawn: Mapping[str, Sequence[float]],
    cameras: Mapping[str, CameraSpec],
    images: Sequence[ImageSpec],
    ephemeris_noise_m: float = 0.0,
) -> Ancillary:
    """The ancillary product of one trajectory segment as the platform measures it
    (``drawn``: the segment's errors, :data:`ERRORS_NOTE`; ``ephemeris_noise_m``: white noise
    per axis of each position sample, seeded by ``drawn["ephemeris_noise_seed"]``)."""
    lo, hi = _span(seg_span, images)
    step = ANCILLARY_STEP_S
    dt = np.arange(math.floor(lo / step), math.ceil(hi / step) + 1) * step
    p, v = w.orbit.state(dt)
    q_true = law.body_to_gcrs(dt, w.orbit, w.orientation)
    r_o2g = ref_attitude.orbital_frame(p, v)
    # attitude error in the orbit frame: measured R_b2o = rpy(e)^T R_b2o_true
    t_mid, t_half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    tau = (dt - t_mid) / t_half
    e = (
        np.asarray(drawn["attitude_bias_rad"])[:, None]
        + np.asarray(drawn["attitude_drift_rad_s"])[:, None] * dt[None, :]
        + np.asarray(drawn["attitude_tau2_rad"])[:, None] * tau[None, :] ** 2
        + np.asarray(drawn["attitude_tau3_rad"])[:, None] * tau[None, :] ** 3
    )
    if "attitude_wander_amplitude_rad" in drawn:  # low-frequency wander, sinusoids per axis
        amp = np.asarray(drawn["attitude_wander_amplitude_rad"], float)
        periods = np.asarray(drawn["attitude_wander_period_s"], float)
        phase = np.asarray(drawn["attitude_wander_phase_rad"], float)
        for k, period in enumerate(periods):
            e += amp[:, k, None] * np.sin(2.0 * np.pi * dt[None, :] / period + phase[:, k, None])
    q_o2g = rotations.from_matrix(r_o2g)
    q_err = rotations.conjugate(rotations.from_rpy(e[0], e[1], e[2]))
    q_meas = rotations.multiply(
        q_o2g, rotations.multiply(q_err, rotations.multiply(rotations.conjugate(q_o2g), q_true))
    )
    b = np.asarray(drawn["ephemeris_bias_m"], float)
    p_meas = p - np.einsum("nij,j->ni", r_o2g, np.array([b[0], b[1], -b[2]]))
    r = w.orientation.matrix(dt)
    omega = w.orientation.rotation_vector_gcrs(dt)
    p_itrs = np.einsum("nij,nj->ni", r, p_meas)
    if ephemeris_noise_m > 0:
        noise = np.random.default_rng(int(drawn["ephemeris_noise_seed"]))
        p_itrs = p_itrs + noise.normal(0.0, ephemeris_noise_m, p_itrs.shape)
    v_itrs = np.einsum("nij,nj->ni", r, v - np.cross(omega, p_meas))
    # one continuous sign (q and -q are one rotation)
    flips = np.cumsum(np.sum(q_meas[1:] * q_meas[:-1], axis=1) < 0) % 2
    q_meas[1:] *= np.where(flips[:, None] == 1, -1.0, 1.0)
    return Ancillary(
        platform,
        w.epoch_utc,
        EphemerisSamples(dt, p_itrs, v_itrs, "ecef"),
        AttitudeSamples(dt, q_meas, "eci"),
        dict(cameras),
        {i.name: i for i in images},
        light_path=PHYSICAL_LIGHT_PATH,
    )


NO_ORIENTATION_ERRORS = {
    "attitude_bias_rad": [0.0] * 3,
    "attitude_drift_rad_s": [0.0] * 3,
    "attitude_tau2_rad": [0.0] * 3,
    "attitude_tau3_rad": [0.0] * 3,
    "ephemeris_bias_m": [0.0] * 3,
}
"""The ``drawn`` errors of :func:`measured_ancillary` for an error-free product."""


def error_free_models(
    platform: str, w: World, seg: Any, view: Any, imager: Any, span_s: tuple[float, float]
) -> tuple[Any, Ancillary]:
    """The true line-scanner model of one reference ``imager`` (trajectory sampled over
    ``span_s``) and the error-free ancillary product of its view: the pair the models are
    held to the reference with (tests and ``benchmarks/reference_agreement.py``)."""
    camera = tg.model_camera(view.camera, (0.0, 0.0, 0.0))
    truth = tg.truth_scanner(imager, camera, tg.truth_trajectory(w, seg.attitude, span_s), 0)
    n_l, n_s = imager.image_shape
    spec = ImageSpec(view.name, view.camera.name, "x.tif", n_l, n_s, 0, 0, truth.timing)
    product = measured_ancillary(
        platform,
        w,
        seg.span_s,
        seg.attitude,
        NO_ORIENTATION_ERRORS,
        {view.camera.name: view.camera},
        [spec],
    )
    return truth, product
