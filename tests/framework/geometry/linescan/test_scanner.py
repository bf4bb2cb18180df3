"""The rigorous line scanner: round trips, geometry against independent figures, model files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner, LineScannerModelType
from carto.framework.geometry.linescan.timing import LineTiming

HEIGHTS = (-100.0, 9000.0)


def _swath_points(sensor: LineScanner, n: int = 20000, seed: int = 0):
    rng = np.random.default_rng(seed)
    lines, samples = sensor.image_shape
    line = rng.uniform(0.0, lines, n)
    sample = rng.uniform(0.0, samples, n)
    h = rng.uniform(*HEIGHTS, n)
    # include the corners and edges at both extreme heights
    cl, cs = np.meshgrid([0.0, lines / 2, lines], [0.0, samples / 2, samples], indexing="ij")
    for hh in HEIGHTS:
        line = np.concatenate([line, cl.ravel()])
        sample = np.concatenate([sample, cs.ravel()])
        h = np.concatenate([h, np.full(cl.size, hh)])
    return line, sample, h


@pytest.mark.parametrize("which", ["fore", "aft", "agile"])
def test_round_trip_ground_image_ground(which, cartosat1_pair, cartosat2_agile):
    sensor = cartosat2_agile if which == "agile" else cartosat1_pair[which]
    line, sample, h = _swath_points(sensor)
    lon, lat = sensor.image_to_ground(line, sample, h)
    assert np.all(np.isfinite(lon))
    line2, sample2 = sensor.ground_to_image(lon, lat, h)
    assert np.all(np.isfinite(line2))
    err = np.hypot(line2 - line, sample2 - sample)
    assert err.max() <= 1e-4, err.max()
    # and back to the ground
    lon3, lat3 = sensor.image_to_ground(line2, sample2, h)
    xyz = frames.geodetic_to_ecef(lon, lat, h)
    xyz3 = frames.geodetic_to_ecef(lon3, lat3, h)
    assert np.linalg.norm(xyz - xyz3, axis=1).max() < 1e-3  # metres


def test_located_point_is_on_the_ray_at_the_height(cartosat1_pair):
    sensor = cartosat1_pair["fore"]
    line, sample, h = _swath_points(sensor, n=2000)
    lon, lat = sensor.image_to_ground(line, sample, h)
    x = frames.geodetic_to_ecef(lon, lat, h)
    p, u = sensor.ray(line, sample)
    d = x - p
    off_ray = np.linalg.norm(np.cross(d, u), axis=1)  # distance from the ray, metres
    assert off_ray.max() < 1e-5
    assert np.all(np.sum(d * u, axis=1) > 0)  # in front of the camera
    _, _, h_back = frames.ecef_to_geodetic(x)
    np.testing.assert_allclose(h_back, h, atol=1e-5)


def test_ground_to_image_solves_collinearity_exactly(cartosat2_agile):
    """The fast interpolated-table solver against the exact rotation chain."""
    sensor = cartosat2_agile
    line, sample, h = _swath_points(sensor, n=3000, seed=3)
    lon, lat = sensor.image_to_ground(line, sample, h)
    l2, s2, inside = sensor.project(lon, lat, h)
    assert inside.all()
    x = frames.geodetic_to_ecef(lon, lat, h)
    p, r_c2e = sensor.camera_to_ecef(l2)  # exact chain at the solved line
    v = np.einsum("nji,nj->ni", r_c2e, x - p)
    tan_x, tan_y = sensor.camera.tan_psi(s2)
    px_per_tan = 5.6 / 7e-6
    assert np.abs(v[:, 0] / v[:, 2] - tan_x).max() * px_per_tan < 1e-6
    assert np.abs(v[:, 1] / v[:, 2] - tan_y).max() * px_per_tan < 1e-6


def test_cartosat1_ground_sampling_from_the_constants(cartosat1_pair):
    # nadir-ish across-track GSD = H * pitch / f / cos^2(tilt) ... measured by locating pixels
    for name, low, high in (("aft", 2.1, 2.35), ("fore", 2.4, 2.75)):
        s = cartosat1_pair[name]
        lon, lat = s.image_to_ground([6000.5, 6000.5, 6001.5], [6000.0, 6001.0, 6000.0], 0.0)
        xyz = frames.geodetic_to_ecef(lon, lat, 0.0)
        across = np.linalg.norm(xyz[1] - xyz[0])
        along = np.linalg.norm(xyz[2] - xyz[0])
        assert low < across < high, (name, across)
        assert 2.0 < along < 2.6, (name, along)


def test_points_outside_the_image_are_nan_with_a_mask(cartosat1_pair):
    s = cartosat1_pair["aft"]
    lon, lat = s.image_to_ground([100.0, 100.0], [-50.0, 500.0], 0.0)
    _, sample, inside = s.project(lon, lat, 0.0)
    np.testing.assert_allclose(sample, [-50.0, 500.0], atol=1e-6)
    assert inside.tolist() == [False, True]
    l2, s2 = s.ground_to_image(lon, lat, 0.0)
    assert np.isnan(l2[0])
    assert np.isnan(s2[0])
    assert np.isfinite(l2[1])
    # far away on the other side of the Earth: NaN, no exception
    l3, s3 = s.ground_to_image([lon[0] + 180.0], [-lat[0]], [0.0])
    assert np.isnan(l3[0])
    assert np.isnan(s3[0])


def test_roll_correction_moves_the_image_across_track(cartosat1_pair):
    s = cartosat1_pair["aft"]
    lon, lat = s.image_to_ground([6000.0], [6000.0], 0.0)
    d = s.parameter_partials(
        lon, lat, 0.0, ["trajectory.attitude.roll.c0", "trajectory.attitude.pitch.c0"]
    )
    # a small rotation moves the image by f / pitch pixels per radian (tilt-corrected)
    f_px = 1.945 / 7e-6
    assert abs(d[0, 1, 0]) == pytest.approx(f_px, rel=0.03)  # roll -> sample
    assert abs(d[0, 0, 0]) < 0.02 * f_px  # roll barely moves the line
    # pitch moves the line by f/pitch / cos^2(5 deg) px per radian (line period = 1 px)
    assert abs(d[0, 0, 1]) == pytest.approx(f_px / np.cos(np.radians(5)) ** 2, rel=0.05)


def test_ground_partials(cartosat1_pair):
    s = cartosat1_pair["aft"]
    lon, lat = s.image_to_ground([6000.0], [6000.0], 500.0)
    g = s.ground_partials(lon, lat, 500.0)[0]
    # 1 m on the ground is ~1/2.2 px across and ~1/2.3 px along; height parallax of Aft (5 deg)
    assert 0.3 < np.hypot(*g[:, 0]) < 0.6
    assert 0.3 < np.hypot(*g[:, 1]) < 0.6
    assert 0.0 < abs(g[0, 2]) < 0.1  # along-track parallax per metre of height (tan 5 deg/2.3)


def test_model_file_round_trip(tmp_path, cartosat1_pair):
    s = cartosat1_pair["fore"].with_parameters(
        {"trajectory.attitude.roll.c0": 1e-4, "camera.fore.align.yaw": 2e-5}
    )
    path = s.save(tmp_path / "fore.model.json")
    assert LineScannerModelType().identify(path)
    again = LineScannerModelType().open(path)
    line, sample, h = _swath_points(s, n=100)
    np.testing.assert_array_equal(
        s.image_to_ground(line, sample, h), again.image_to_ground(line, sample, h)
    )
    assert again.parameters == s.parameters
    assert not list(tmp_path.glob("*.tmp"))


def test_model_file_errors_are_one_line(tmp_path, cartosat1_pair):
    doc = cartosat1_pair["fore"].to_dict()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**doc, "version": 99}))
    with pytest.raises(InputError, match=r"bad.json: model file version 99 is not supported"):
        LineScanner.load(bad)
    del doc["camera"]
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"bad.json: missing field 'camera'"):
        LineScanner.load(bad)
    bad.write_text("{not json")
    with pytest.raises(InputError, match="not a JSON model file"):
        LineScanner.load(bad)
    with pytest.raises(InputError, match="cannot read model file"):
        LineScanner.load(tmp_path / "missing.json")
    with pytest.raises(InputError, match="unknown parameter"):
        cartosat1_pair["fore"].with_parameters({"nope": 1.0})


def test_line_timing():
    t = LineTiming.constant(10.0, 0.5e-3)
    np.testing.assert_allclose(t.time([0.5, 1.5, 100.5]), [10.0, 10.0005, 10.05])
    np.testing.assert_allclose(t.line(t.time([-3.0, 7.25])), [-3.0, 7.25])
    v = LineTiming([0.5, 10.5, 20.5], [0.0, 1.0, 3.0])
    np.testing.assert_allclose(v.period([5.0, 15.0]), [0.1, 0.2])
    with pytest.raises(InputError):
        LineTiming([0.5, 0.5], [0.0, 1.0])


def test_camera_look_angles_and_stagger():
    cam = Camera.linear_array("c", 12000, 1.945, 7e-6, stagger_m=35e-6, array="odd")
    tx, ty = cam.tan_psi([0.0, 6000.0, 12000.0])
    np.testing.assert_allclose(ty, [6000 * 7e-6 / 1.945, 0.0, -6000 * 7e-6 / 1.945])
    np.testing.assert_allclose(tx, 0.0)
    tx_even, _ = cam.with_array("even").tan_psi([10.0])
    np.testing.assert_allclose(tx_even, 35e-6 / 1.945)  # 5 lines of 7 um
    np.testing.assert_allclose(cam.sample_from_tan_psi_y(ty), [0.0, 6000.0, 12000.0])
    # a tabulated (curved) camera inverts too
    s = np.linspace(0, 12000, 50)
    curved = Camera.from_look_angles(
        "k", s, 1e-3 + 1e-9 * (s - 6000) ** 2, -(s - 6000) * 3.6e-6 + 1e-15 * (s - 6000) ** 3, 12000
    )
    _, ty = curved.tan_psi(s)
    np.testing.assert_allclose(curved.sample_from_tan_psi_y(ty), s, atol=1e-6)


def test_locate_on_a_dem_lands_on_the_terrain_and_projects_back(cartosat1_pair):
    from affine import Affine

    from carto.framework.raster.dem import DEM

    s = cartosat1_pair["fore"]
    lon0, lat0 = s.image_to_ground([6000.0], [6000.0], 0.0)
    # a tilted plane rising 1 m per 10 m eastwards over 0.2 x 0.2 degrees
    n = 400
    x = lon0[0] - 0.1 + 0.0005 * (np.arange(n) + 0.5)
    heights = np.tile(800.0 + (x - lon0[0]) * 111e3 * np.cos(np.radians(lat0[0])) * 0.1, (n, 1))
    dem = DEM.from_array(
        heights, Affine(0.0005, 0.0, lon0[0] - 0.1, 0.0, -0.0005, lat0[0] + 0.1), "EPSG:4326"
    )
    line = np.array([5000.0, 6000.0, 7000.0])
    sample = np.array([5500.0, 6000.0, 6600.0])
    lon, lat, h = s.locate_on_dem(line, sample, dem)
    np.testing.assert_allclose(h, dem.height(lon, lat), atol=1e-2)
    l2, s2 = s.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(l2, line, atol=1e-3)
    np.testing.assert_allclose(s2, sample, atol=1e-3)


def test_a_window_is_the_full_image_shifted(cartosat1_pair, tmp_path):
    full = cartosat1_pair["aft"]
    t = full.timing
    crop_timing = LineTiming.constant(float(t.time(4000.5)), float(t.period(4000.5)))
    crop = LineScanner(
        "aft-crop",
        2000,
        crop_timing,
        full.camera,
        full.trajectory,
        first_sample=3000,
        width=2500,
        first_line=4000,
    )
    assert crop.image_shape == (2000, 2500)
    line = np.array([0.5, 1000.0, 1999.5])
    sample = np.array([0.5, 1250.0, 2499.5])
    lon, lat = crop.image_to_ground(line, sample, 300.0)
    lon_f, lat_f = full.image_to_ground(line + 4000, sample + 3000, 300.0)
    np.testing.assert_allclose(lon, lon_f, atol=1e-12)
    np.testing.assert_allclose(lat, lat_f, atol=1e-12)
    l2, s2 = crop.ground_to_image(lon, lat, 300.0)
    np.testing.assert_allclose(l2, line, atol=1e-6)
    np.testing.assert_allclose(s2, sample, atol=1e-6)
    # outside the window but inside the full image: NaN for the crop
    lon_o, lat_o = full.image_to_ground([100.0], [100.0], 0.0)
    assert np.isnan(crop.ground_to_image(lon_o, lat_o, 0.0)[0][0])
    again = LineScanner.load(crop.save(tmp_path / "crop.model.json"))
    assert again.image_shape == (2000, 2500)
    assert again.first_sample == 3000
    assert again.first_line == 4000
    with pytest.raises(InputError, match="first_sample 12000 is outside"):
        LineScanner("x", 10, crop_timing, full.camera, full.trajectory, first_sample=12000)


def test_polynomial_partials_match_numeric_differences(cartosat1_pair):
    from carto.framework.geometry.sensor import Sensor

    s = cartosat1_pair["fore"]
    s = s.with_trajectory(s.trajectory.with_correction_orders(attitude=2, position=1))
    lon, lat = s.image_to_ground([100.0, 6000.0, 11000.0], [300.0, 6000.0, 9000.0], 400.0)
    names = [p.name for p in s.parameters if p.free]
    fast = s.parameter_partials(lon, lat, 400.0, names)
    slow = Sensor.parameter_partials(s, lon, lat, 400.0, names)  # all numeric
    # the all-numeric reference is the less precise one for tiny tau^2 steps
    np.testing.assert_allclose(fast, slow, rtol=1e-3, atol=0.05)
