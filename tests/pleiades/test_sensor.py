"""The Pleiades physical model as a Carto line scanner, against independent truth: CNES's
direct-location grid computed from the same physical model, and the vendor's RPC in the same
file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from carto.framework.geometry import frames
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.rpc.sensor import RPCSensorType
from carto.pleiades.dimap import read_dimap

pytestmark = pytest.mark.realdata

GRID_MAX_PX = 0.05
GRID_RMS_PX = 0.01
RPC_MAX_PX = 0.05
GUARD_MAX_PX = 0.002
"""Measured: 0.0004 px max and RMS at every height; a guard against subtle regressions (a
convention slip of 0.01 px) that the acceptance thresholds would let through."""


def project_grid(sensor, grid):
    """Ground -> image of every node at every height: errors (9, 65, 65) in px."""
    shape = grid.lon_deg.shape
    h = np.broadcast_to(grid.h_m[:, None, None], shape)
    line, sample = sensor.ground_to_image(grid.lon_deg, grid.lat_deg, h)
    return np.hypot(line - grid.line, sample - grid.sample)


def test_ground_to_image_agrees_with_the_cnes_grid(pleiades_sensor, location_grid):
    err = project_grid(pleiades_sensor, location_grid)
    assert err.shape == (9, 65, 65)
    assert np.isfinite(err).all()  # every node, including the image corners, is inside
    per_height_max = err.max(axis=(1, 2))
    assert per_height_max.max() <= GRID_MAX_PX, per_height_max
    assert np.sqrt(np.mean(err**2)) <= GRID_RMS_PX
    assert err.max() <= GUARD_MAX_PX


def test_image_to_ground_agrees_with_the_cnes_grid(pleiades_sensor, location_grid):
    g = location_grid
    lon, lat = pleiades_sensor.image_to_ground(g.line[None], g.sample[None], g.h_m[:, None, None])
    east_m = (lon - g.lon_deg) * np.cos(np.radians(g.lat_deg)) * 111320.0
    north_m = (lat - g.lat_deg) * 110900.0
    assert np.hypot(east_m, north_m).max() < 0.01  # m; a pixel is about 0.53 m


def test_agrees_with_the_vendor_rpc(pleiades_sensor, dimap_xml: Path, location_grid):
    rpc = RPCSensorType().open(dimap_xml)
    g = location_grid
    # inside the RPC's validity domain (heights 490 .. 660 m): the image nodes located there
    for h in (rpc.rpc.height_off - rpc.rpc.height_scale, rpc.rpc.height_off,
              rpc.rpc.height_off + rpc.rpc.height_scale):  # fmt: skip
        lon, lat = pleiades_sensor.image_to_ground(g.line, g.sample, h)
        line, sample = rpc.ground_to_image(lon, lat, h)
        assert np.hypot(line - g.line, sample - g.sample).max() <= RPC_MAX_PX
    # at the grid's nodes and heights: within 0.05 px up to 1202.5 m ...
    shape = g.lon_deg.shape
    h = np.broadcast_to(g.h_m[:, None, None], shape)
    ours = pleiades_sensor.ground_to_image(g.lon_deg, g.lat_deg, h)
    theirs = rpc.ground_to_image(g.lon_deg, g.lat_deg, h)
    gap = np.hypot(theirs[0] - ours[0], theirs[1] - ours[1]).max(axis=(1, 2))
    low = g.h_m <= 1202.5
    assert low.sum() == 3
    assert gap[low].max() <= RPC_MAX_PX, gap
    # ... and above, where the RPC extrapolates its height polynomial 15-50 height scales out,
    # CNES's grid departs from the RPC exactly as much as we do: the limit is the RPC's
    grid_gap = np.hypot(theirs[0] - g.line, theirs[1] - g.sample).max(axis=(1, 2))
    np.testing.assert_allclose(gap, grid_gap, rtol=0, atol=GUARD_MAX_PX)


def test_round_trips(pleiades_sensor):
    rng = np.random.default_rng(3)
    n_lines, n_samples = pleiades_sensor.image_shape
    line = np.concatenate([[0.5, 0.0, n_lines, n_lines - 0.5], rng.uniform(0, n_lines, 200)])
    sample = np.concatenate(
        [[0.5, n_samples, 0.0, n_samples - 0.5], rng.uniform(0, n_samples, 200)]
    )
    h = rng.uniform(-100, 5000, line.size)
    lon, lat = pleiades_sensor.image_to_ground(line, sample, h)
    back_line, back_sample = pleiades_sensor.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(back_line, line, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back_sample, sample, rtol=0, atol=1e-6)


def test_model_file_round_trip(pleiades_sensor, location_grid, tmp_path: Path):
    """The converted model is an ordinary Carto model file (``carto project x.model.json``)."""
    loaded = LineScanner.load(pleiades_sensor.save(tmp_path / "phr.model.json"))
    g = location_grid
    a = pleiades_sensor.ground_to_image(g.lon_deg[4], g.lat_deg[4], g.h_m[4])
    b = loaded.ground_to_image(g.lon_deg[4], g.lat_deg[4], g.h_m[4])
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)


def test_adjustable_parameters(pleiades_sensor):
    names = [p.name for p in pleiades_sensor.parameters if p.free]
    assert names == [f"trajectory.attitude.{a}.c0" for a in ("roll", "pitch", "yaw")]
    # a 1e-5 rad roll bias turns the line of sight mainly across track, by 1e-5 rad / 7.11e-7 rad
    # per detector (the PsiX slope) ~ 14 px
    moved = pleiades_sensor.with_parameters({"trajectory.attitude.roll.c0": 1e-5})
    lon, lat = pleiades_sensor.image_to_ground(19124.0, 20000.0, 500.0)
    line, sample = moved.ground_to_image(lon, lat, 500.0)
    assert 12.0 < np.hypot(line - 19124.0, sample - 20000.0) < 16.0
    assert abs(sample - 20000.0) > 3 * abs(line - 19124.0)


def test_the_conversion_is_exact(pleiades_sensor, dimap_xml: Path):
    """Timing, attitude and ephemeris of the line scanner equal the vendor's model."""
    model = read_dimap(dimap_xml)
    row = np.array([1.0, 2.0, 19124.0, 38248.0])  # DIMAP rows, from 1
    line = row - 0.5
    np.testing.assert_allclose(
        pleiades_sensor.timing.time(line), model.row_dt_s(row), rtol=0, atol=1e-12
    )
    _, r_cam = pleiades_sensor.camera_to_ecef(np.linspace(-100.0, 38348.0, 401))
    dt = model.row_dt_s(np.linspace(-100.0, 38348.0, 401) + 0.5)
    r_vendor = frames.quat_to_matrix(model.quaternion_wxyz(dt))
    err = frames.matrix_to_rotvec(np.swapaxes(r_vendor, -1, -2) @ r_cam)
    assert np.abs(err).max() < 1e-12  # rad
    p, _ = pleiades_sensor.trajectory.evaluate(model.ephemeris_dt_s)
    np.testing.assert_allclose(p, model.position_ecef_m, rtol=0, atol=1e-6)
    # the camera's line of sight is (PsiY(k), -PsiX(k), 1) with k = sample - 0.5
    s = np.array([0.5, 20000.0, 39999.5])
    tx, ty = pleiades_sensor.camera.tan_psi(s)
    np.testing.assert_allclose(tx, model.psi_y_coeffs[0], rtol=0, atol=1e-18)
    k = s - 0.5
    np.testing.assert_allclose(ty, -(model.psi_x_coeffs[0] + model.psi_x_coeffs[1] * k), atol=1e-17)
