"""The local ray model of an IOR tile: it finds the ground point that two image points of the
sensor models show (as the rigorous intersection :func:`intersect_sensors` does), for height
errors of centimetres to 80 m."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.geometry.intersection import intersect_sensors
from carto.framework.raster.dem import DEM
from carto.ior.rays import RayField, intersect_offsets
from carto.ior.refine import IORSettings, _grids
from carto.ior.start import starting_surface


@pytest.fixture(scope="module")
def setting(hilly):
    truth = hilly.truth_sensors()
    left, right = truth["aft"], truth["fore"]
    init = DEM.open(hilly.path("init_dem.tif"))
    grid, _, _ = _grids(left, right, init, IORSettings(posting_m=10.0))
    heights = starting_surface(init, grid, (left, right), 0.75).heights
    return left, right, grid, heights


@pytest.mark.parametrize("dh_m", [0.5, 30.0, -80.0])
def test_local_rays_find_the_point_both_images_see(setting, dh_m):
    """A ground point ``dh_m`` above or below the node's surface, on the node's left ray: the
    right image sees it at one image point, which the right ortho-image shows at the
    surface point of that ray; the local ray model must give the point back (as the
    rigorous intersection of the two sensor models does)."""
    left, right, grid, heights = setting
    rng = np.random.default_rng(3)
    nr = rng.integers(0, grid.shape[0], 400)
    nc = rng.integers(0, grid.shape[1], 400)
    h_n = heights[nr, nc]
    lon_n, lat_n = grid.lonlat(nr, nc)
    line_l, sample_l = left.ground_to_image(lon_n, lat_n, h_n)
    h_true = h_n + dh_m
    lon_p, lat_p = left.image_to_ground(line_l, sample_l, h_true)
    line_r, sample_r = right.ground_to_image(lon_p, lat_p, h_true)
    h_r = h_n + 7.0  # the current surface at the match (a sloping terrain)
    lon_r, lat_r = right.image_to_ground(line_r, sample_r, h_r)
    x_r, y_r = grid.map_xy(lon_r, lat_r)
    seen = np.isfinite(x_r) & np.isfinite(line_l)  # the grid is the footprint's box
    assert seen.mean() > 0.5

    rays = RayField.sample((left, right), grid, heights)
    x, y, h = intersect_offsets(rays, nr, nc, h_n, x_r, y_r, h_r)
    x_p, y_p = grid.map_xy(lon_p, lat_p)
    assert np.abs(h - h_true)[seen].max() < 0.01
    assert np.hypot(x - x_p, y - y_p)[seen].max() < 0.01

    rigorous = intersect_sensors(
        [left, right], np.stack([line_l, line_r]), np.stack([sample_l, sample_r])
    )
    assert np.abs(rigorous.h_m - h_true)[seen].max() < 0.01


def test_unknown_ray_directions_give_no_height(setting):
    left, right, grid, heights = setting
    rays = RayField.sample((left, right), grid, heights)
    blind = RayField(rays.grid, rays.rows, rays.cols, np.full_like(rays.t_xy, np.nan))
    x_n, y_n = grid.xy(np.array([3]), np.array([4]))
    _, _, h = intersect_offsets(
        blind, np.array([3]), np.array([4]), heights[3:4, 4], x_n + 1.0, y_n, heights[3:4, 4]
    )
    assert np.isnan(h).all()


def test_directions_on_a_block_of_nodes_are_the_pointwise_bilinear_ones():
    # an irregular last lattice step (the grid's last node), clamping beyond the lattice
    rows = np.r_[np.arange(0, 100, 32), 99]
    cols = np.r_[np.arange(0, 70, 32), 69]
    t_xy = np.random.default_rng(3).normal(size=(2, 2, rows.size, cols.size))
    rays = RayField(None, rows, cols, t_xy)
    block = rays.on_nodes(slice(10, 100), slice(0, 70))
    rr, cc = np.meshgrid(np.arange(10, 100), np.arange(70), indexing="ij")
    np.testing.assert_allclose(block, rays.at(rr, cc), rtol=0, atol=1e-12)
    # at a lattice node, the node's own direction
    np.testing.assert_allclose(block[..., 54, 32], t_xy[..., 2, 1], atol=1e-12)
