"""The reference geometry (the simulator's truth) against independent implementations, and the
models under test against the reference: with no errors, whole full-swath acquisitions of both
Cartosat presets, both staggered arrays, heights from 0 to 3000 m, to 0.01 px.

The reference shares no module with the models (an import contract), so this is the check of
every convention of the chain: orbit-frame and attitude conventions, camera mounting, stagger
direction, line time tags, GCRS -> ITRS, light time and aberration."""

from __future__ import annotations

import math

import attrs
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from carto.framework import get_registry
from carto.framework.geometry.light_path import LightPath
from carto.framework.simulation import truth_geometry as tg
from carto.framework.simulation.plan import ErrorModel, SimulationOptions
from carto.framework.simulation.reference import earth, rotations
from carto.framework.simulation.reference.pushbroom import aberrate
from carto.framework.simulation.truth_products import error_free_models

TOLERANCE_PX = 0.01


def test_quaternions_agree_with_scipy():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    ours = rotations.to_matrix(q)
    theirs = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy: scalar last
    np.testing.assert_allclose(ours, theirs, atol=1e-14)
    back = rotations.from_matrix(ours)
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-14)
    r, p, y = rng.uniform(-1, 1, (3, 50))
    # Rz(yaw) Ry(pitch) Rx(roll): scipy's extrinsic "xyz" sequence
    theirs = Rotation.from_euler("xyz", np.stack([r, p, y], 1)).as_matrix()
    np.testing.assert_allclose(rotations.to_matrix(rotations.from_rpy(r, p, y)), theirs, atol=1e-14)
    a, b = q[:10], q[10:20]
    half = rotations.slerp(a, b, 0.5)
    ra, rb, rh = (Rotation.from_quat(x[:, [1, 2, 3, 0]]) for x in (a, b, half))
    np.testing.assert_allclose((ra.inv() * rh).magnitude(), 0.5 * (ra.inv() * rb).magnitude())


def test_earth_orientation_interpolates_astropy_and_turns_at_the_sidereal_rate():
    epoch = "2026-03-01T05:18:12Z"
    eo = earth.EarthOrientation.over(epoch, (-30.0, 30.0))
    t = np.array([-29.3, -0.7, 0.0, 11.11, 29.9])
    np.testing.assert_allclose(eo.matrix(t), earth.gcrs_to_itrs_exact(epoch, t), atol=1e-13)
    omega = eo.rotation_vector_gcrs(0.0)
    assert np.linalg.norm(omega) == pytest.approx(7.2921150e-5, rel=1e-7)


def test_aberration_moves_a_source_towards_the_motion_by_v_over_c():
    beta = np.array([7500.0 / earth.SPEED_OF_LIGHT_M_S, 0.0, 0.0])
    n = np.array([0.0, 0.0, 1.0])  # seen at right angles to the motion
    seen = aberrate(n, beta)
    assert math.asin(seen[0]) == pytest.approx(beta[0], rel=1e-9)
    np.testing.assert_allclose(aberrate(seen, -beta), n, atol=1e-15)


def test_the_orbit_overflies_the_target_and_keeps_its_energy():
    plan = get_registry().get("scene-preset", "cartosat1-pair").plan(SimulationOptions())
    w = tg.world(plan)
    p, v = w.orbit.state(np.array([0.0]))
    lon, lat, _h = earth.itrs_to_geodetic(w.orientation.matrix(0.0) @ p[0])
    assert lon == pytest.approx(plan.target[0], abs=1e-9)
    assert lat == pytest.approx(plan.target[1], abs=0.2)  # geocentric radius vs normal
    t = np.linspace(*w.orbit.span_s, 7)
    p, v = w.orbit.state(t)
    r = np.linalg.norm(p, axis=1)
    energy = 0.5 * np.sum(v * v, 1) - earth.GM_M3_S2 / r
    assert np.ptp(energy) / abs(energy.mean()) < 1e-3  # J2 exchanges a little
    np.testing.assert_allclose(
        np.linalg.norm(v, axis=1), math.sqrt(earth.GM_M3_S2 / r[3]), rtol=2e-3
    )


def _imagers(preset: str):
    """Every view of a preset, whole acquisitions (all detectors, all lines), no errors."""
    plan = get_registry().get("scene-preset", preset).plan(SimulationOptions())
    w = tg.world(plan)
    out = []
    for seg in plan.segments:
        for view in seg.views:
            im = tg.full_imager(
                w,
                view,
                tg.camera_geometry(view.camera, (0.0, 0.0, 0.0)),
                seg.attitude,
                seg,
                view.target or plan.target,
                500.0,
            )
            out.append((plan, w, seg, view, im))
    return out


@pytest.mark.parametrize("preset", ["cartosat1-pair", "cartosat2-triplet"])
def test_models_reproduce_the_reference_over_whole_acquisitions(preset):
    for plan, w, seg, view, im in _imagers(preset):
        truth, anc = error_free_models(plan.platform, w, seg, view, im, tg.scene_span(plan))
        product = anc.sensors(interpolation="lagrange")[view.name]
        assert product.light_path == LightPath(True, True)
        n_l, n_s = im.image_shape
        line, sample = np.meshgrid(
            np.linspace(0.5, n_l - 0.5, 7), np.linspace(0.5, n_s - 0.5, 7), indexing="ij"
        )
        line, sample = line.ravel(), sample.ravel()
        for h0 in (0.0, 3000.0):
            lon, lat, h = im.image_to_ground(line, sample, np.full(line.size, h0))
            for model in (truth, product):
                ml, ms = model.ground_to_image(lon, lat, h)
                assert np.abs(ml - line).max() < TOLERANCE_PX, (view.name, h0)
                assert np.abs(ms - sample).max() < TOLERANCE_PX, (view.name, h0)
            # image -> ground of the models, in pixels of the reference
            mlon, mlat = product.image_to_ground(line, sample, h)
            rl, rs = im.ground_to_image(mlon, mlat, h)
            assert np.abs(rl - line).max() < TOLERANCE_PX
            assert np.abs(rs - sample).max() < TOLERANCE_PX
        # the even array (raw Cartosat data), staggered along track
        even_model = product.with_camera(attrs.evolve(product.camera, array="even"))
        lon, lat, h = im.image_to_ground(line, sample, np.full(line.size, 800.0), even=True)
        ml, ms = even_model.ground_to_image(lon, lat, h)
        assert np.abs(ml - line).max() < TOLERANCE_PX
        assert np.abs(ms - sample).max() < TOLERANCE_PX


def test_a_model_without_the_light_path_is_lines_off():
    """Aberration alone moves a Cartosat-1 ground point ~17 m (7-8 lines) along track: the
    reference must be able to disagree with a model that leaves it out."""
    plan, w, seg, view, im = _imagers("cartosat1-pair")[0]
    camera = tg.model_camera(view.camera, (0.0, 0.0, 0.0))
    truth = tg.truth_scanner(
        im, camera, tg.truth_trajectory(w, seg.attitude, tg.scene_span(plan)), 0
    )
    plain = attrs.evolve(truth, light_path=LightPath())
    lon, lat, h = im.image_to_ground(np.array([6000.0]), np.array([6000.0]), np.array([0.0]))
    ml, _ = plain.ground_to_image(lon, lat, h)
    assert abs(ml[0] - 6000.0) > 5.0


@pytest.mark.parametrize("preset", ["cartosat1-pair", "cartosat2-triplet"])
def test_the_renderers_models_follow_the_reference_under_full_errors(preset):
    """The line-scanner models the simulator renders through (truth_geometry) carry jitter up
    to 97 Hz, the interior orientation errors and the true line period of ``--errors full``:
    they stay within 0.01 px of the reference, both arrays."""
    errors = ErrorModel.full(agile=preset != "cartosat1-pair")
    rng = np.random.default_rng(3)
    interior = {
        "focal_ppm": errors.focal_length_ppm,
        "line_offset_px": -errors.detector_line_offset_px,
        "principal_point_px": errors.principal_point_px,
        "rotation_rad": math.radians(errors.ccd_rotation_deg),
    }
    plan, w, seg, view, _ = _imagers(preset)[0]
    law = tg.jittered(seg.attitude, errors.jitter_deg, errors.jitter_hz, rng)
    period = view.period_s * (1 + 1e-6 * errors.line_period_ppm)
    geo = tg.camera_geometry(view.camera, (1e-5, -2e-5, 3e-5), interior)
    full = tg.full_imager(w, view, geo, law, seg, plan.target, 500.0, period_s=period)
    im = tg.window(full, 5000, 4000, 1500, 3000)
    camera = tg.model_camera(view.camera, (1e-5, -2e-5, 3e-5), interior)
    truth = tg.truth_scanner(im, camera, tg.truth_trajectory(w, law, tg.image_span(im)), 5000)
    line, sample = np.meshgrid(np.linspace(0.5, 1499.5, 6), np.linspace(0.5, 2999.5, 6))
    line, sample = line.ravel(), sample.ravel()
    for even in (False, True):
        model = truth.with_camera(attrs.evolve(truth.camera, array="even")) if even else truth
        lon, lat, h = im.image_to_ground(line, sample, np.full(line.size, 700.0), even=even)
        ml, ms = model.ground_to_image(lon, lat, h)
        assert np.abs(ml - line).max() < TOLERANCE_PX
        assert np.abs(ms - sample).max() < TOLERANCE_PX
    # and the jitter is there: the smooth law's image of the same points moves
    smooth = attrs.evolve(im, law=seg.attitude)
    ls, ss = smooth.ground_to_image(
        *im.image_to_ground(line, sample, np.full(line.size, 700.0))[:2], 700.0
    )
    assert np.abs(ls - line).max() > 0.1 or np.abs(ss - sample).max() > 0.1
