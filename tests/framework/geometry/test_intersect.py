"""Forward intersection of rays and of image points seen by several sensors.

Truth is independent of the code under test: rays built through known points, perpendicular
distances by cross products, an independent minimiser (scipy ``least_squares``), and two
analytic sensors written here: a frame camera in ECEF (straight lines of sight) and an
RPC-like sensor whose lines of sight are curved (a quadratic height term).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import GeometryError, InputError
from carto.framework.geometry.frames import (
    WGS84_A_M,
    WGS84_B_M,
    ecef_to_geodetic,
    ellipsoid_normal,
    geodetic_to_ecef,
)
from carto.framework.geometry.intersection import (
    IntersectionResult,
    intersect_rays,
    intersect_sensors,
    sensor_rays,
)
from carto.framework.geometry.sensor import Sensor


def _ground_points(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    lon = rng.uniform(5.15, 5.25, n)
    lat = rng.uniform(44.18, 44.24, n)
    h = rng.uniform(200.0, 1500.0, n)
    return lon, lat, h


def _satellites(k: int) -> np.ndarray:
    """``(K, 3)`` ECEF positions about 700 km above the area, spread along and across track."""
    lon = [5.2, 5.2, 7.0, 3.5][:k]
    lat = [41.0, 47.5, 44.0, 44.5][:k]
    return geodetic_to_ecef(lon, lat, np.full(k, 695e3))


def _hand_distances(point: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    u = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    return np.linalg.norm(np.cross(point[None] - origins, u), axis=-1)


# ----------------------------------------------------------------------------- rays
def test_exact_rays_meet_at_the_known_points():
    rng = np.random.default_rng(0)
    lon, lat, h = _ground_points(rng, 500)
    points = geodetic_to_ecef(lon, lat, h)
    origins = np.broadcast_to(_satellites(3)[:, None, :], (3, 500, 3)).copy()
    directions = (points[None] - origins) * rng.uniform(0.5, 3.0, (3, 500, 1))  # any length
    result = intersect_rays(origins, directions)
    assert isinstance(result, IntersectionResult)
    assert result.valid.all()
    assert result.n_degenerate == 0
    np.testing.assert_allclose(result.xyz_ecef, points, rtol=0, atol=1e-6)
    np.testing.assert_allclose(result.lon_deg, lon, rtol=0, atol=1e-11)
    np.testing.assert_allclose(result.lat_deg, lat, rtol=0, atol=1e-11)
    np.testing.assert_allclose(result.h_m, h, rtol=0, atol=1e-6)
    assert result.residuals_m.shape == (3, 500)
    assert result.rms_m.shape == (500,)
    assert np.max(result.residuals_m) < 1e-6


def test_noisy_rays_least_squares_point_and_residuals():
    rng = np.random.default_rng(1)
    n, k = 200, 3
    lon, lat, h = _ground_points(rng, n)
    points = geodetic_to_ecef(lon, lat, h)
    origins = np.broadcast_to(_satellites(k)[:, None, :], (k, n, 3)).copy()
    directions = points[None] - origins
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    directions += rng.normal(0.0, 5e-6, directions.shape)  # ~3.5 m at 700 km
    weights = np.array([1.0, 2.0, 0.5])
    result = intersect_rays(origins, directions, weights)

    for j in range(0, n, 20):  # independent minimiser, about the true point for precision
        rel = origins[:, j] - points[j]
        u = directions[:, j] / np.linalg.norm(directions[:, j], axis=-1, keepdims=True)

        def perpendiculars(x, rel=rel, u=u):
            return (np.sqrt(weights)[:, None] * np.cross(x[None] - rel, u)).ravel()

        def jacobian(x, u=u):  # d(x cross u)/dx = -[u]_x, exact
            skew = np.zeros((len(u), 3, 3))
            skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
            skew -= skew.transpose(0, 2, 1)
            return (-np.sqrt(weights)[:, None, None] * skew).reshape(-1, 3)

        best = least_squares(perpendiculars, np.zeros(3), jac=jacobian, xtol=1e-15).x
        np.testing.assert_allclose(result.xyz_ecef[j] - points[j], best, rtol=0, atol=1e-6)
    hand = np.stack(
        [_hand_distances(result.xyz_ecef[j], origins[:, j], directions[:, j]) for j in range(n)],
        axis=1,
    )
    np.testing.assert_allclose(result.residuals_m, hand, rtol=1e-9, atol=1e-9)
    rms = np.sqrt((weights[:, None] * hand**2).sum(0) / weights.sum())
    np.testing.assert_allclose(result.rms_m, rms, rtol=1e-9)
    assert 0.1 < np.median(result.rms_m) < 10.0  # the noise is really there
    error = np.linalg.norm(result.xyz_ecef - points, axis=-1)
    assert np.median(error) < 10.0


def test_zero_weight_and_missing_rays_are_left_out():
    rng = np.random.default_rng(2)
    lon, lat, h = _ground_points(rng, 50)
    points = geodetic_to_ecef(lon, lat, h)
    origins = np.broadcast_to(_satellites(3)[:, None, :], (3, 50, 3)).copy()
    directions = points[None] - origins + rng.normal(0, 2.0, (3, 50, 3))
    two = intersect_rays(origins[:2], directions[:2])
    zero = intersect_rays(origins, directions, weights=[1.0, 1.0, 0.0])
    np.testing.assert_allclose(zero.xyz_ecef, two.xyz_ecef, rtol=0, atol=1e-6)
    assert np.isnan(zero.residuals_m[2]).all()
    missing = directions.copy()
    missing[2] = np.nan
    np.testing.assert_allclose(
        intersect_rays(origins, missing).xyz_ecef, two.xyz_ecef, rtol=0, atol=1e-6
    )


def test_degenerate_rays():
    origins = np.zeros((2, 4, 3))
    origins[1, :, 0] = 1000.0
    directions = np.zeros((2, 4, 3))
    directions[:, :, 2] = 1.0  # parallel rays 1 km apart ...
    directions[0, 1] = [0.1, 0.0, 1.0]  # ... except point 1 (meets at x = 1000 m / 0.1)
    directions[0, 2] = [1e-7, 0.0, 1.0]  # 1e-7 rad: below the 1e-5 rad default -> degenerate
    directions[1, 3] = np.nan  # a single usable ray
    result = intersect_rays(origins, directions)
    np.testing.assert_array_equal(result.valid, [False, True, False, False])
    assert result.n_degenerate == 3
    assert np.isnan(result.xyz_ecef[~result.valid]).all()
    assert np.isnan(result.rms_m[~result.valid]).all()
    np.testing.assert_allclose(result.xyz_ecef[1], [1000.0, 0.0, 10_000.0], atol=1e-6)
    ok = intersect_rays(origins, directions, min_angle_rad=1e-8)
    np.testing.assert_array_equal(ok.valid, [False, True, True, False])
    with pytest.raises(GeometryError, match="3 of 4 points"):
        intersect_rays(origins, directions, on_degenerate="raise")
    with pytest.raises(GeometryError, match="2 of 2"):
        intersect_rays(origins[:, [0, 3]], directions[:, [0, 3]])


def test_ray_input_errors():
    with pytest.raises(InputError, match="at least 2"):
        intersect_rays(np.zeros((1, 3, 3)), np.ones((1, 3, 3)))
    with pytest.raises(InputError, match=r"\(K, N, 3\)"):
        intersect_rays(np.zeros((2, 3, 3)), np.ones((2, 4, 3)))
    with pytest.raises(InputError, match="weights"):
        intersect_rays(np.zeros((2, 3, 3)), np.ones((2, 3, 3)), weights=[1.0, -1.0])
    with pytest.raises(InputError, match="on_degenerate"):
        intersect_rays(np.zeros((2, 1, 3)), np.ones((2, 1, 3)), on_degenerate="ignore")


# ----------------------------------------------------------------------------- sensors
class FrameCamera(Sensor):
    """Pinhole camera in ECEF: centre ``C``, looking at ``target``, focal ``f`` pixels.

    ``image_to_ground`` intersects the line of sight with the surface at geodetic height h
    (ellipsoid a+h, b+h to start, then Newton on the ray parameter).
    """

    def __init__(self, centre: np.ndarray, target: np.ndarray, focal_px: float = 1.4e6):
        self.centre = np.asarray(centre, float)
        z = target - self.centre
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        self.axes = np.stack([x, np.cross(z, x), z], axis=1)  # columns: camera axes in ECEF
        self.f = focal_px
        self.c = 5000.0

    @property
    def image_shape(self) -> tuple[int, int]:
        return (10_000, 10_000)

    def ground_to_image(self, lon_deg, lat_deg, h_m):
        v = (geodetic_to_ecef(lon_deg, lat_deg, h_m) - self.centre) @ self.axes
        return self.c + self.f * v[..., 1] / v[..., 2], self.c + self.f * v[..., 0] / v[..., 2]

    def image_to_ground(self, line, sample, h_m):
        line, sample, h = as_float_arrays(line, sample, h_m)
        cam = np.stack([(sample - self.c) / self.f, (line - self.c) / self.f, 1.0 + 0 * h], -1)
        d = cam @ self.axes.T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        a, b = WGS84_A_M + h, WGS84_B_M + h
        scale = np.stack([1.0 / a, 1.0 / a, 1.0 / b], axis=-1)
        p, q = self.centre * scale, d * scale  # unit sphere: |p + t q| = 1
        qq, pq, pp = (q * q).sum(-1), (p * q).sum(-1), (p * p).sum(-1)
        t = (-pq - np.sqrt(pq**2 - qq * (pp - 1.0))) / qq
        for _ in range(4):
            lon, lat, height = ecef_to_geodetic(self.centre + t[..., None] * d)
            t = t + (h - height) / (d * ellipsoid_normal(lon, lat)).sum(-1)
        lon, lat, _ = ecef_to_geodetic(self.centre + t[..., None] * d)
        return lon, lat


class CurvedSensor(Sensor):
    """RPC-like sensor with curved lines of sight: image coordinates are affine in lon/lat
    plus ``p h + q h^2`` (the location at height h moves along a parabola)."""

    def __init__(self, parallax_px_m: float, curvature_px_m2: float):
        self.p, self.q = parallax_px_m, curvature_px_m2
        self.k_lon = 79_600.0 / 0.5  # px per degree: about 0.5 m pixels
        self.k_lat = 111_100.0 / 0.5

    @property
    def image_shape(self) -> tuple[int, int]:
        return (40_000, 40_000)

    def ground_to_image(self, lon_deg, lat_deg, h_m):
        lon, lat, h = as_float_arrays(lon_deg, lat_deg, h_m)
        shift = self.p * h + self.q * h**2
        return 20_000 - self.k_lat * (lat - 44.2) + shift, 20_000 + self.k_lon * (lon - 5.2)

    def image_to_ground(self, line, sample, h_m):
        line, sample, h = as_float_arrays(line, sample, h_m)
        shift = self.p * h + self.q * h**2
        return 5.2 + (sample - 20_000) / self.k_lon, 44.2 - (line - 20_000 - shift) / self.k_lat


def _frame_cameras(k: int) -> list[FrameCamera]:
    target = geodetic_to_ecef(5.2, 44.21, 800.0)
    return [FrameCamera(c, target) for c in _satellites(k)]


def _project(sensors, lon, lat, h) -> tuple[np.ndarray, np.ndarray]:
    image = [s.ground_to_image(lon, lat, h) for s in sensors]
    return np.stack([i[0] for i in image]), np.stack([i[1] for i in image])


def test_sensor_rays_pass_through_both_heights():
    camera = _frame_cameras(1)[0]
    line, sample = np.array([100.0, 5000.0, 9000.0]), np.array([3000.0, 5000.0, 200.0])
    origins, directions = sensor_rays(camera, line, sample, 0.0, 3000.0)
    assert origins.shape == directions.shape == (3, 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=-1), 1.0)
    for h in (0.0, 3000.0, -200.0):  # a frame camera's line of sight is straight
        point = geodetic_to_ecef(*camera.image_to_ground(line, sample, h), h)
        np.testing.assert_allclose(_hand_distances(point, origins, directions), 0.0, atol=1e-5)
    _, _, h_top = ecef_to_geodetic(origins)
    np.testing.assert_allclose(h_top, 3000.0, atol=1e-6)
    assert (np.einsum("ni,ni->n", directions, ellipsoid_normal(5.2, 44.2)[None]) < 0).all()


@pytest.mark.parametrize("k", [2, 3])
def test_frame_cameras_recover_the_ground_points(k: int):
    cameras = _frame_cameras(k)
    lon, lat, h = _ground_points(np.random.default_rng(3), 300)
    lines, samples = _project(cameras, lon, lat, h)
    result = intersect_sensors(cameras, lines, samples)
    assert result.valid.all()
    np.testing.assert_allclose(result.h_m, h, rtol=0, atol=1e-4)
    np.testing.assert_allclose(result.xyz_ecef, geodetic_to_ecef(lon, lat, h), rtol=0, atol=1e-4)
    assert result.residuals_px.shape == (k, 300, 2)
    assert np.max(np.abs(result.residuals_px)) < 1e-4
    assert np.max(result.residuals_m) < 1e-4


def test_curved_lines_of_sight_are_followed_exactly():
    sensors = [CurvedSensor(0.35, 2e-5), CurvedSensor(-0.3, -1.5e-5)]
    lon, lat, h = _ground_points(np.random.default_rng(4), 300)
    lines, samples = _project(sensors, lon, lat, h)
    straight = intersect_sensors(sensors, lines, samples, iterations=0)
    assert np.median(np.abs(straight.h_m - h)) > 10.0  # chords of the parabolas miss by far
    result = intersect_sensors(sensors, lines, samples, tol_m=1e-6)
    assert 1 <= result.iterations <= 10
    np.testing.assert_allclose(result.lon_deg, lon, rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.lat_deg, lat, rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.h_m, h, rtol=0, atol=1e-5)
    assert np.max(np.abs(result.residuals_px)) < 1e-5
    # residuals in metres are measured to the local (tangent) lines of sight: ~0 here
    assert np.max(result.residuals_m) < 1e-4


def test_noisy_image_points_least_squares_and_residuals():
    cameras = _frame_cameras(3)
    rng = np.random.default_rng(5)
    lon, lat, h = _ground_points(rng, 40)
    lines, samples = _project(cameras, lon, lat, h)
    lines = lines + rng.normal(0.0, 0.5, lines.shape)
    samples = samples + rng.normal(0.0, 0.5, samples.shape)
    weights = np.array([1.0, 1.0, 4.0])
    result = intersect_sensors(cameras, lines, samples, weights=weights, tol_m=1e-7)
    # residuals are measured minus reprojected, by hand
    back_lines, back_samples = _project(cameras, result.lon_deg, result.lat_deg, result.h_m)
    np.testing.assert_allclose(result.residuals_px[..., 0], lines - back_lines, atol=1e-9)
    np.testing.assert_allclose(result.residuals_px[..., 1], samples - back_samples, atol=1e-9)
    norms = np.hypot(lines - back_lines, samples - back_samples)
    rms = np.sqrt((weights[:, None] * norms**2).sum(0) / weights.sum())
    np.testing.assert_allclose(result.rms_px, rms, rtol=1e-9)
    assert 0.1 < np.median(result.rms_px) < 2.0
    # the point minimises the weighted image residuals: compare with an independent minimiser
    m_lat = math.radians(1.0) * 6_367_000.0
    m_lon = m_lat * math.cos(math.radians(44.2))
    for j in range(0, 40, 8):

        def image_residuals(x, j=j):
            point = (lon[j] + x[0] / m_lon, lat[j] + x[1] / m_lat, h[j] + x[2])
            bl, bs = _project(cameras, *point)
            return (
                np.sqrt(weights).repeat(2)
                * np.stack([lines[:, j] - bl, samples[:, j] - bs], 1).ravel()
            )

        best = least_squares(
            image_residuals, np.zeros(3), jac="3-point", diff_step=1e-3, xtol=1e-14
        ).x
        expected = geodetic_to_ecef(
            lon[j] + best[0] / m_lon, lat[j] + best[1] / m_lat, h[j] + best[2]
        )
        np.testing.assert_allclose(result.xyz_ecef[j], expected, rtol=0, atol=1e-5)


def test_missing_observations_and_degenerate_sensors():
    cameras = _frame_cameras(3)
    lon, lat, h = _ground_points(np.random.default_rng(6), 5)
    lines, samples = _project(cameras, lon, lat, h)
    lines[2, 0] = np.nan  # point 0 is seen in two images only: still solved
    lines[1:, 1] = np.nan  # point 1 is seen in one image: no solution
    result = intersect_sensors(cameras, lines, samples)
    np.testing.assert_array_equal(result.valid, [True, False, True, True, True])
    np.testing.assert_allclose(result.h_m[result.valid], h[result.valid], atol=1e-4)
    assert np.isnan(result.residuals_px[2, 0]).all()
    assert np.isnan(result.h_m[1])
    with pytest.raises(GeometryError):
        intersect_sensors(cameras, lines, samples, on_degenerate="raise")
    same = [cameras[0], cameras[0]]
    with pytest.raises(GeometryError, match="5 of 5"):
        intersect_sensors(same, lines[[0, 0]], samples[[0, 0]])
    with pytest.raises(InputError, match="K = 3"):
        intersect_sensors(cameras, lines[:2], samples[:2])
    single = intersect_sensors(cameras, lines[:, 2], samples[:, 2])
    assert single.h_m.shape == (1,)
    assert single.h_m[0] == pytest.approx(h[2], abs=1e-4)
